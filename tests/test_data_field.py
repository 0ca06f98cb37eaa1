"""RUNS.csv of field campaigns: ``position`` labels, ``heading_deg`` instead of a reference,
mixed surveyed / unsurveyed positions (the contract in the docstring of ``hse_opt.data``).

References are hand computations from the file's text (the heading minus the position's
mean heading, in arcsec), never the loader's own output.
"""
import numpy as np
import pytest

from hse_opt.data import DataError, Runs, load_runs, save_runs
from hse_opt.units import ARCSEC, DEG

HEADER = "run,rate_dps,position,heading_deg,azimuth_deg,latitude_deg,duration_s,pitch_arcsec,roll_arcsec\n"
MIXED = HEADER + (
    "1,20,A,45.0012,,28.07,600,100,50\n"
    "2,40,A,45.0022,,28.07,600,100,50\n"
    "3,-40,A,45.0005,,28.07,600,100,50\n"
    "4,40,pier 2,135.0022,135,28.07,600,100,50\n"
    "5,-40,pier 2,135.0002,135,28.07,600,100,50\n"
    "6,40,C,359.9995,,28.07,600,100,50\n"
    "7,20,C,0.0011,,28.07,600,100,50\n")


def _write(tmp_path, text, name="RUNS.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_mixed_campaign_loads_with_heading_err_up_to_one_constant_per_position(tmp_path):
    runs = load_runs(_write(tmp_path, MIXED))
    assert runs.surveyed.tolist() == [False, False, False, True, True, False, False]
    assert runs.position.tolist() == ["A", "A", "A", "pier 2", "pier 2", "C", "C"]
    index, labels = runs.reference_groups()
    assert labels == ("A", "C") and index.tolist() == [0, 0, 0, -1, -1, 1, 1]
    # by hand: position A's mean heading 45.0013 deg -> -0.0001, +0.0009, -0.0008 deg
    assert runs.heading_err[:3] / ARCSEC == pytest.approx([-0.36, 3.24, -2.88], abs=1e-9)
    # surveyed: heading minus azimuth, 0.0022 and 0.0002 deg
    assert runs.heading_err[3:5] / ARCSEC == pytest.approx([7.92, 0.72], abs=1e-9)
    # position C straddles north: mean 0.0003 deg (359.9995 is -0.0005)
    assert runs.heading_err[5:] / ARCSEC == pytest.approx([-2.88, 2.88], abs=1e-9)
    # the position's mean own heading stands in for the azimuth (C23): one heading per position
    assert runs.azimuth[:3] / DEG == pytest.approx([45.0013] * 3, abs=1e-12)
    assert np.mod(runs.azimuth[5:] / DEG, 360) == pytest.approx([0.0003] * 2, abs=1e-12)


def test_field_file_round_trips_and_keeps_empty_cells(tmp_path):
    runs = load_runs(_write(tmp_path, MIXED))
    out = tmp_path / "OUT.csv"
    save_runs(runs, out)
    text = out.read_text().splitlines()
    header = text[0].split(",")
    assert "position" in header and "heading_deg" in header
    row1 = dict(zip(header, text[1].split(",")))
    assert row1["azimuth_deg"] == "" and row1["heading_err_arcsec"] == "" and row1["position"] == "A"
    row4 = dict(zip(header, text[4].split(",")))
    assert row4["heading_err_arcsec"] == "7.92"          # exact decimals, not 7.91999...
    back = load_runs(out)
    for name in ("heading_err", "azimuth", "heading", "rate", "pitch"):
        assert np.array_equal(getattr(back, name), getattr(runs, name)), name
    assert back.position.tolist() == runs.position.tolist()
    assert back.surveyed.tolist() == runs.surveyed.tolist()
    sub = runs.subset([0, 3])
    assert sub.position.tolist() == ["A", "pier 2"] and sub.surveyed.tolist() == [False, True]
    cols = runs.to_columns()
    assert np.isnan(cols["azimuth_deg"][0]) and cols["position"][3] == "pier 2"
    again = Runs.from_columns(cols)
    assert np.array_equal(again.surveyed, runs.surveyed)
    assert again.heading_err / ARCSEC == pytest.approx(runs.heading_err / ARCSEC, abs=1e-9)


def test_no_reference_at_all_and_no_position_column_is_one_position(tmp_path):
    text = ("run,rate_dps,heading_deg,latitude_deg,duration_s\n"
            "1,20,10.0010,28,600\n2,40,10.0020,28,600\n3,60,10.0030,28,600\n")
    runs = load_runs(_write(tmp_path, text))
    assert runs.position is None and not runs.surveyed.any()
    assert runs.reference_groups()[1] == ("field",)
    assert runs.heading_err / ARCSEC == pytest.approx([-3.6, 0.0, 3.6], abs=1e-9)
    assert any("taken as one stand position" in note for note in runs.notes)
    out = tmp_path / "OUT.csv"
    save_runs(runs, out)
    header = out.read_text().splitlines()[0].split(",")
    assert "azimuth_deg" not in header and "heading_err_arcsec" not in header


def test_surveyed_rows_with_heading_only_get_heading_minus_azimuth(tmp_path):
    text = "run,rate_dps,azimuth_deg,heading_deg,latitude_deg,duration_s\n1,40,359.999,0.001,28,600\n2,40,90,89.9995,28,600\n"
    runs = load_runs(_write(tmp_path, text))
    assert runs.surveyed is None
    assert runs.heading_err / ARCSEC == pytest.approx([7.2, -1.8], abs=1e-9)   # wrapped through north


def test_position_label_alone_is_a_label_not_a_covariate(tmp_path):
    text = "run,rate_dps,azimuth_deg,heading_err_arcsec,latitude_deg,duration_s,position\n1,40,0,1,28,600,7\n"
    runs = load_runs(_write(tmp_path, text))
    assert runs.position.tolist() == ["7"] and "position" not in runs.covariates and runs.surveyed is None


@pytest.mark.parametrize("text, where", [
    # a position surveyed in one row only
    (HEADER + "1,20,A,45.001,45,28,600,1,1\n2,40,A,45.002,,28,600,1,1\n", "row 2 (line 3), column 'azimuth_deg'"),
    # heading_err without the azimuth it refers to
    ("run,rate_dps,heading_deg,azimuth_deg,heading_err_arcsec,latitude_deg,duration_s\n"
     "1,40,45,,3,28,600\n", "row 1 (line 2), column 'heading_err_arcsec'"),
    # no position column but two stand headings: a forgotten position column
    ("run,rate_dps,heading_deg,latitude_deg,duration_s\n1,40,45,28,600\n2,40,135,28,600\n",
     "column 'heading_deg'"),
    # an empty label
    (HEADER + "1,20, ,45.001,,28,600,1,1\n", "row 1 (line 2), column 'position'"),
    # neither a reference nor the own heading
    ("run,rate_dps,azimuth_deg,latitude_deg,duration_s\n1,40,0,28,600\n", "column 'heading_err_arcsec'"),
    # an empty azimuth without heading_deg is not a field row: it is an empty value
    ("run,rate_dps,azimuth_deg,heading_err_arcsec,latitude_deg,duration_s\n1,40,,3,28,600\n",
     "row 1 (line 2), column 'azimuth_deg'"),
])
def test_bad_field_files_name_row_and_column(tmp_path, text, where):
    with pytest.raises(DataError) as err:
        load_runs(_write(tmp_path, text))
    assert where in str(err.value) and "allowed" in str(err.value)
