"""``hse-opt align``: raw logs -> RUNS.csv through the alignment processor, one row per log."""
import os
import sys

from . import add_dask_argument, add_report_argument, dask_client, message, write_report
from .outputs import FILE, REPORT

NAME = "align"
HELP = "align raw logs (gyro/accelerometer/encoder records) into RUNS.csv, one row per log"
DESCRIPTION = (
    "Run each raw log (the formats of hse_opt/align/rawlog.py: .npz, .csv with increments in "
    "rad and m/s, or .csv with pulse counts and the pulse weights in its .json sidecar) "
    "through the alignment processor (coarse TRIAD, Kalman filter, whole-revolution "
    "smoothing) with the system's lab calibration, and write one RUNS.csv row per log: the "
    "bias rate from the encoder, the alignment's heading (heading_deg), its leveling "
    "(pitch_arcsec, roll_arcsec) and 1-sigma (heading_std_arcsec), the log's duration, and "
    "from the log's metadata run, position, azimuth_deg (the stand reading: then "
    "heading_err_arcsec too; without it the run has no heading reference), t_start_s and "
    "temp_c. A directory stands for the raw logs in it. Before alignment each log's quality "
    "is checked (hse_opt/align/quality.py: encoder samples against the table's rate and the "
    "gyros, the table's rate, stuck, saturated or spiking channels, metadata types): an "
    "isolated glitch is repaired by a documented rule and the row's text column quality says "
    "so ('ok' otherwise); anything else refuses the log. A bad log (truncated, gaps, NaN, a "
    "dead channel, wrong units, a refused quality check) is reported on one line naming the "
    "file, sample and time; the others are still aligned and written, and the exit status is "
    "2 with the count of bad logs. Each log's sensor noise comes from the log itself "
    "(hse_opt/align/noise.py: the overlapping Allan deviation of the six channels with the "
    "table's turn, Earth rate and gravity fitted out, and the IEEE Std 952 terms) into the "
    "columns gyro_arw_dph_rthz (angle random walk, deg/h/sqrt(Hz), as TRUTH.toml's "
    "arw_dph_rthz), gyro_bias_instability_dph, gyro_quantization_arcsec, gyro_rrw_dph_rth, "
    "accel_vrw_ug_rthz, accel_bias_instability_ug and accel_quantization_mps (means over the "
    "three sensors), and the campaign's pooled figures are printed. The lab calibration "
    "applied is --calibration CAL.toml (docs/calibration.md; `hse-opt simulate "
    "--write-calibration` writes a simulated system's), or --truth TRUTH.toml (a simulated "
    "system's), else the orthogonal system with the paper's ideal mount (K_g = K_a = I, every "
    "gyro axis at 54.74 deg from the rotation axis; said once on stderr); each of the filter's "
    "noise figures the calibration file does not give ([noise] ARW and VRW, one number or one "
    "per axis, and the pulse weights) is measured from the pooled figures of up to 8 logs "
    "spread over the campaign, and the text column noise_source says which came from where.")
INPUTS = ("logs", "truth", "calibration", "mapping")
OUTPUTS = {"output": FILE, "report": REPORT}
EXAMPLE = """examples:
  hse-opt align logs/ -o RUNS.csv --jobs 2
  hse-opt align logs/ -o RUNS.csv --calibration CALIBRATION.toml
  hse-opt align logs/ -o RUNS.csv --dask tcp://scheduler:8786
  hse-opt align run_01.npz run_02.csv -o RUNS.csv --truth TRUTH.toml --latitude-deg 28.07
  hse-opt align stand_logs/ --mapping counter_stand.toml -o RUNS.csv
  hse-opt align logs/ -o RUNS.csv --report align_report   (HTML: the Allan curves, align_report/report.html)"""

_SUFFIXES = (".npz", ".csv")
_MAPPED_SUFFIXES = (".csv", ".txt", ".dat")


def add_arguments(parser):
    parser.add_argument("logs", nargs="+", metavar="LOG", help="raw-log files or directories of them")
    parser.add_argument("-o", "--output", metavar="RUNS.csv", required=True, help="results to write")
    add_processor_arguments(parser)
    parser.add_argument("--jobs", type=int, default=1, help="local worker processes (default 1)")
    add_dask_argument(parser)
    add_report_argument(parser)
    parser.add_argument("--no-progress", dest="progress", action="store_false",
                        help="no progress bar on stderr")


def add_processor_arguments(parser):
    """The alignment processor's options (also ``hse-opt calibrate``'s): --calibration or
    --truth, --latitude-deg, --mapping."""
    calib = parser.add_mutually_exclusive_group()
    calib.add_argument("--calibration", metavar="CAL.toml",
                       help="the system's lab calibration: [gyro] K_g (gyro outputs -> s), [accel] K_a "
                            "(accelerometer outputs -> s), [mount] C_s_b (s -> b) or r_zb_s, optionally "
                            "pulse weights, [noise] (one number or one per axis; a figure left out is "
                            "measured from the logs), [encoder] counts_per_rev (the quality checks' encoder "
                            "quantum) and [site] latitude_deg (docs/calibration.md; e.g. --calibration "
                            "CALIBRATION.toml; default: the orthogonal system with the paper's ideal mount, "
                            "said in a note)")
    calib.add_argument("--truth", metavar="TRUTH.toml",
                       help="a simulated system: its lab calibration (K~_g, C~_s^b) and sensor noise "
                            "(e.g. --truth TRUTH.toml; hse_opt/datasets/truth_default.toml is the "
                            "paper-like system)")
    parser.add_argument("--latitude-deg", type=float, metavar="L",
                        help="latitude for logs without latitude_deg metadata (the log's wins; a log whose "
                             "latitude_deg differs is an error naming both), e.g. --latitude-deg 28.07")
    parser.add_argument("--mapping", metavar="MAP.toml",
                        help="read every log as a test stand's own CSV through this mapping file (column "
                             "names, units, time base, pulse weights, encoder counts per revolution, signs "
                             "and axis order: docs/rawlogs.md; examples in hse_opt/datasets/mappings/), "
                             "e.g. --mapping counter_stand.toml; a directory then stands for its .csv, "
                             ".txt and .dat files")


def _expand(items, suffixes=_SUFFIXES):
    """Files as given; a directory -> its raw logs (``suffixes``), sorted by name
    (:func:`hse_opt.app.session.log_paths`)."""
    from ..session import log_paths
    return log_paths(items, suffixes)


def processor(args):
    """The alignment processor the options of :func:`add_processor_arguments` ask for.

    Returns
    -------
    config : hse_opt.align.AlignConfig
    kw : dict
        :func:`hse_opt.align.batch.align_logs`'s ``mapping``, ``tune_from_data`` (the noise
        figures the calibration file does not give: measured from the logs), ``pulse_weights``
        and ``given_by``.
    suffixes : tuple of str
        The file names a folder's raw logs end with.
    """
    import dataclasses

    from ... import units
    from ...align import LabCalibration, load_calibration
    from ...align.processor import LATITUDE_TOL_DEG

    if args.latitude_deg is not None and not abs(args.latitude_deg) < 89.0:
        raise ValueError(f"--latitude-deg {args.latitude_deg:g}: allowed: |latitude| < 89 deg")
    if args.truth:
        from ...sim import TruthConfig
        from ...sim.campaign import default_align_config
        try:
            truth = TruthConfig.from_toml(args.truth)
        except OSError as err:
            raise ValueError(f"{args.truth}: cannot read the truth: {err.strerror or err}; allowed: a "
                             "TRUTH.toml you can read") from None
        config, weights, from_data, given_by = default_align_config(truth), None, (), "truth"
    else:
        cal = load_calibration(args.calibration) if args.calibration else LabCalibration.orthogonal()
        config, weights, given_by = cal.align_config(), cal.pulse_weights, "file"
        from_data = tuple(k for k, given in cal.noise_given().items() if not given)   # measured from the logs
    if args.latitude_deg is not None:
        if config.latitude is not None and abs(config.latitude / units.DEG - args.latitude_deg) > LATITUDE_TOL_DEG:
            raise ValueError(f"--latitude-deg {args.latitude_deg:g} and site.latitude_deg "
                             f"{config.latitude / units.DEG:.10g} of {args.calibration} differ; allowed: one latitude")
        config = dataclasses.replace(config, latitude=float(args.latitude_deg) * units.DEG)
    mapping = None
    if args.mapping:
        from ...align.mapping import load_mapping
        mapping = load_mapping(args.mapping)
    return (config, dict(mapping=mapping, tune_from_data=from_data, pulse_weights=weights, given_by=given_by),
            _MAPPED_SUFFIXES if mapping else _SUFFIXES)


def noise_source_line(row):
    """Where the filter's noise figures came from (an aligned row's ``noise_source``), one line."""
    from ...align.batch import TUNING_LOGS
    return (f"the filter's noise: {row['noise_source']} (data: measured from the logs, the Allan analysis of up "
            f"to {TUNING_LOGS} of them pooled; file: the calibration file; truth: TRUTH.toml)")


def assumption(args):
    """The one-line note on what the processor assumed without a lab calibration (neither
    --calibration nor --truth), else None: ``hse-opt align`` and ``calibrate`` say it once on
    stderr and in their report (and summary.json)."""
    if args.calibration or args.truth:
        return None
    return ("no --calibration: assumed an orthogonal, perfectly mounted IMU (K_g = K_a = I, every gyro axis at "
            "54.74 deg from the rotation axis); a real system's axes are off by tens of arcsec, which moves its "
            "headings, and what is calibrated from them, by as much: give its lab calibration with --calibration "
            "CALIBRATION.toml (docs/calibration.md)")


def run(args):
    from tqdm import tqdm

    from ...align.batch import align_logs, runs_from_rows
    from ...align.noise import combine_noise
    from ...data import save_runs

    if args.jobs < 1:
        raise ValueError(f"--jobs {args.jobs}: allowed: an integer >= 1")
    config, kw, suffixes = processor(args)
    paths = _expand(args.logs, suffixes)
    assumed = assumption(args)
    with dask_client(args.dask) as client, tqdm(total=len(paths), unit="log", desc="align", file=sys.stderr,
                                                disable=None if args.progress else True) as bar:
        rows, errors = align_logs(paths, config, jobs=args.jobs, client=client, **kw,
                                  progress=lambda done, total: bar.update(done - bar.n))
    for err in errors:
        message(f"hse-opt align: error: {' '.join(err.split())}")
    if not rows:
        message(f"hse-opt align: none of the {len(paths)} logs could be aligned; nothing written")
        return 2
    runs, notes = runs_from_rows(rows)
    for note in [assumed] * bool(assumed) + notes:      # once the logs are read (bad input stays one line)
        message(f"hse-opt align: note: {note}")
    try:
        save_runs(runs, args.tx.path("output"))
    except OSError as err:
        raise ValueError(f"{args.output}: cannot write the runs: {err.strerror or err}") from None
    pooled = combine_noise(r["noise"] for r in rows)
    message(f"hse-opt align: noise (Allan, IEEE 952) over {pooled.n_logs} log{'s' if pooled.n_logs != 1 else ''}: "
            f"{pooled.summary()}")
    tuning = noise_source_line(rows[0])
    message(f"hse-opt align: {tuning}")
    if args.report:
        from ...report import noise_section, text_section
        write_report(args, [text_section("The processor", [x for x in (assumed, tuning) if x]),
                            noise_section([r["noise"] for r in rows], pooled,
                                          names=[os.path.basename(r["log"]) for r in rows])],
                     f"hse-opt align: {len(rows)} log{'s' if len(rows) != 1 else ''}")
    touched = sum(r.get("quality", "ok") != "ok" for r in rows)
    if touched:
        message(f"hse-opt align: note: {touched} log{'s' if touched != 1 else ''} repaired or noted by the quality "
                "checks before alignment (RUNS.csv column quality says what, at which sample and time)")
    bad = f"; {len(errors)} bad log{'s' if len(errors) != 1 else ''} (above) left out" if errors else ""
    message(f"hse-opt align: {len(runs)} of {len(paths)} logs aligned, written to {args.output}{bad}")
    return 2 if errors else 0
