"""Truth configuration: TOML schema, units, validation (issue 3, items 1 and 6)."""
import math

import numpy as np
import pytest

from hse_opt.sim.truth import RunError, RunSpec, TruthConfig, load_truth, validate_run

# independent unit factors written out here (not taken from hse_opt.units)
ARCSEC = math.pi / 180 / 3600
DPH = math.pi / 180 / 3600
UG = 9.80665e-6


def test_toml_round_trip_default_and_modified(tmp_path):
    t = TruthConfig.default()
    p = tmp_path / "truth.toml"
    t.to_toml(p)
    assert load_truth(p) == t
    t2 = t.updated({"encoder": {"harmonics": [{"order": 1, "amplitude_arcsec": 1.5, "phase_deg": 30.0},
                                              {"order": 4, "amplitude_arcsec": 0.2}]},
                    "stand": {"azimuth_harmonics": [{"order": 2, "amplitude_arcsec": 3.0}]},
                    "gyro": {"sf_nonlinearity_ppm_per_dps": [0.1, -0.2, 0.05]}})
    t2.to_toml(p)
    back = load_truth(p)
    assert back == t2
    assert back.encoder.harmonics[0].phase == pytest.approx(30 * math.pi / 180, rel=1e-15)


def test_toml_round_trip_is_exact_for_any_values(tmp_path):
    """Values with all 17 digits, from every unit, come back bit for bit (TRUTH.toml written
    with --write-truth reproduces the simulation exactly)."""
    rng = np.random.default_rng(7)
    p = tmp_path / "t.toml"
    for _ in range(20):
        t = TruthConfig.default().updated({
            "site": {"latitude_deg": rng.uniform(-80, 80)},
            "gyro": {"eps_arcsec": list(rng.normal(0, 5, 3)), "arw_dph_rthz": rng.uniform(0, 0.1),
                     "bias_dph": list(rng.normal(0, 0.01, 3)), "sf_nonlinearity_ppm_per_dps": list(rng.normal(0, 1, 3))},
            "encoder": {"sync_delay_us": rng.normal(0, 50), "harmonics": [
                {"order": 1, "amplitude_arcsec": rng.normal(), "phase_deg": rng.uniform(0, 360)}]},
            "accel": {"vrw_ug_rthz": rng.uniform(0, 10)}, "stand": {"mount_tilt_arcsec": list(rng.normal(0, 300, 2))}})
        t.to_toml(p)
        assert load_truth(p) == t


def test_units_in_key_names_convert_to_si():
    t = TruthConfig.default().updated({
        "site": {"latitude_deg": 30.0},
        "gyro": {"arw_dph_rthz": 0.06, "bias_dph": [0.01, 0.0, -0.02], "pulse_arcsec": 2.0},
        "accel": {"vrw_ug_rthz": 5.0, "bias_ug": [100.0, 0.0, 0.0]},
        "encoder": {"sync_delay_us": 12.5},
        "timing": {"sample_period_ms": 2.0},
    })
    assert t.site.latitude == pytest.approx(math.pi / 6, rel=1e-15)
    assert t.gyro.arw == pytest.approx(0.06 * DPH, rel=1e-15)
    assert t.gyro.bias[2] == pytest.approx(-0.02 * DPH, rel=1e-15)
    assert t.gyro.pulse == pytest.approx(2 * ARCSEC, rel=1e-15)
    assert t.accel.vrw == pytest.approx(5 * UG, rel=1e-15)
    assert t.accel.bias[0] == pytest.approx(100 * UG, rel=1e-15)
    assert t.encoder.sync_delay == pytest.approx(12.5e-6, rel=1e-15)
    assert t.timing.sample_period == pytest.approx(0.002, rel=1e-15)


@pytest.mark.parametrize("changes, key, hint", [
    ({"site": {"latitude_dge": 3.0}}, "latitude_dge", "latitude_deg"),
    ({"gyro": {"arw_deg_rthz": 0.1}}, "arw_deg_rthz", "arw_dph_rthz"),
    ({"gyros": {}}, "gyros", "gyro"),
    ({"encoder": {"harmonics": [{"order": 1, "amplitude_arcsecs": 1.0}]}}, "amplitude_arcsecs",
     "amplitude_arcsec"),
])
def test_unknown_or_misspelt_key_is_an_error_naming_it(changes, key, hint):
    with pytest.raises(ValueError) as exc:
        TruthConfig.default().updated(changes)
    assert repr(key) in str(exc.value)
    assert repr(hint) in str(exc.value)


def test_unknown_key_in_file_names_file_and_key(tmp_path):
    p = tmp_path / "t.toml"
    p.write_text("[site]\nlatitude_deg = 30.0\nlattitude_deg = 31.0\n")
    with pytest.raises(ValueError, match=r"t\.toml.*'lattitude_deg'.*'latitude_deg'"):
        load_truth(p)


@pytest.mark.parametrize("changes, key, allowed", [
    ({"gyro": {"arw_dph_rthz": -0.01}}, "gyro.arw_dph_rthz", ">= 0|\\[0"),
    ({"accel": {"vrw_ug_rthz": -1.0}}, "accel.vrw_ug_rthz", "\\[0"),
    ({"gyro": {"pulse_arcsec": -1.0}}, "gyro.pulse_arcsec", "\\[0"),
    ({"accel": {"pulse_mps": -1e-4}}, "accel.pulse_mps", "\\[0"),
    ({"encoder": {"resolution_arcsec": -0.18}}, "encoder.resolution_arcsec", "\\[0"),
    ({"stand": {"mount_tilt_arcsec": [5000.0, 0.0]}}, "stand.mount_tilt_arcsec", "3600"),
    ({"stand": {"tilt_arcsec": [0.0, -4000.0]}}, "stand.tilt_arcsec", "3600"),
    ({"site": {"latitude_deg": 95.0}}, "site.latitude_deg", "89"),
    ({"gyro": {"eps_arcsec": [1.0, 2.0]}}, "gyro.eps_arcsec", "3 numbers"),
    ({"table": {"ripple_order": 1.5}}, "table.ripple_order", "integer"),
    ({"mount": {"r_zb_s_true": [-0.6, -0.6, -0.6]}}, "r_zb_s_true", "unit vector"),
])
def test_invalid_values_name_key_and_allowed_range(changes, key, allowed):
    with pytest.raises(ValueError, match=allowed) as exc:
        TruthConfig.default().updated(changes)
    assert key in str(exc.value)


def test_lockin_zone_rate_is_rejected_with_allowed_rate():
    # ideal skew: each gyro sees |Omega|/sqrt(3); lock-in 1 deg/s -> |rate| must exceed
    # sqrt(3) * (1 deg/s + Earth rate), about 1.7322 deg/s
    t = TruthConfig.ideal().updated({"gyro": {"lockin_dps": 1.0, "axes_nonorth_arcsec": [0.0, 0.0, 0.0]}})
    limit = math.sqrt(3) * (1.0 + 7.292115e-5 * 180 / math.pi)
    with pytest.raises(ValueError, match=r"rate_dps = 1\.5 .*lock-in.*allowed \|rate_dps\| > 1\.73"):
        validate_run(t, RunSpec(rate=1.5 * math.pi / 180, duration=600.0))
    validate_run(t, RunSpec(rate=(limit + 0.01) * math.pi / 180, duration=600.0))
    with pytest.raises(ValueError, match="rate_dps"):
        validate_run(t, RunSpec(rate=0.0, duration=600.0))


def test_duration_shorter_than_one_revolution_is_rejected():
    t = TruthConfig.default()
    # 40 deg/s: one revolution takes 9 s, plus one 2 ms sample
    with pytest.raises(RunError, match=r"duration_s = 9 .*allowed duration_s >= 9\.002 s") as exc:
        validate_run(t, RunSpec(rate=40 * math.pi / 180, duration=9.0))
    assert exc.value.column == "duration_s"
    validate_run(t, RunSpec(rate=40 * math.pi / 180, duration=9.002))


def test_thermal_mount_rotation_too_large_is_rejected():
    t = TruthConfig.ideal().updated({"mount": {"warmup_xi_z_arcsec": 300.0, "warmup_tau_s": 600.0}})
    from hse_opt.sim.imu import generate
    with pytest.raises(ValueError, match=r"thermal mount rotation exceeds.*allowed \|warmup_xi_z"):
        generate(t, RunSpec(rate=0.7, duration=20.0, t_start=0.0, alpha0=0.0))


def test_run_tilt_too_large_names_plan_column():
    t = TruthConfig.ideal()
    with pytest.raises(ValueError, match="tilt_y_arcsec.*too large.*3600"):
        validate_run(t, RunSpec(rate=0.7, duration=60.0, tilt=(0.0, 3700 * ARCSEC)))


def test_ideal_is_free_of_errors_and_noise():
    t = TruthConfig.ideal()
    assert t.is_noise_free and t.encoder.resolution == 0
    assert np.allclose(t.mount.r_zb_s_true, -1 / np.sqrt(3))
    assert not any(t.gyro.eps) and not any(t.mount.xi) and t.encoder.sync_delay == 0
    assert not TruthConfig.default().is_noise_free


def test_shipped_default_toml_is_the_default_system():
    from pathlib import Path

    import hse_opt
    path = Path(hse_opt.__file__).parent / "datasets" / "truth_default.toml"
    assert load_truth(path) == TruthConfig.default()
