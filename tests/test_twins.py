"""The effect <-> simulator twin map (:mod:`hse_opt.validation.twins`): every effect's truth
changes make the numeric simulator's heading errors what the symbolic model predicts, every
key exists in the simulator's schema, and an effect without a twin stops loudly."""
import casadi as ca
import numpy as np
import pytest

from hse_opt import demo, units
from hse_opt.model import CATALOGUE, Effect, Model, Param
from hse_opt.sim import TruthConfig, simulate_heading_error
from hse_opt.validation.twins import TWINS, effect_names, truth_changes, twin

#: six runs that vary every factor an effect can follow: rate and sense, azimuth, time since
#: power-on, the base tilt (x: roll, y: pitch) and, through the time, the temperature
RATE_DPS = np.array([20.0, -40.0, 60.0, -20.0, 40.0, -60.0])
AZIMUTH_DEG = np.array([0.0, 60.0, 150.0, 210.0, 290.0, 330.0])
T_START_S = np.array([0.0, 700.0, 1400.0, 2100.0, 2800.0, 3500.0])
TILT_ARCSEC = np.array([(200.0, -300.0), (-250.0, 150.0), (300.0, 250.0), (-150.0, -200.0),
                        (100.0, 300.0), (-300.0, -100.0)])
BASE = TruthConfig.ideal().updated({"thermal": {"swing_c": 1.5, "swing_period_s": 7200.0}})
#: the encoder's 1st harmonic with a horizontal mount error: a product, sized by hand
ENCODER_MOUNT = {"enc_c1": 12.0, "enc_s1": -9.0, "enc_c2": 5.0, "enc_s2": 3.0, "xi_x": 40.0, "xi_y": 25.0}


def _changed_keys(changes, prefix=""):
    for k, v in changes.items():
        if isinstance(v, dict):
            yield from _changed_keys(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}"


def test_every_effect_has_a_twin_within_the_simulators_schema():
    schema = BASE.to_dict()
    assert set(effect_names()) == set(TWINS) and set(CATALOGUE) <= set(TWINS)
    for name in effect_names():
        t = twin(name)
        for key in t.keys:
            section, _, field = key.partition(".")
            assert section in schema and (not field or field in schema[section]), (name, key)
        nominal = {q.name: q.nominal for q in Model([name]).params}
        changes = t.truth_changes(nominal)
        assert set(_changed_keys(changes)) <= set(t.keys), name   # it writes only its keys
        BASE.updated(changes)                                       # and the simulator takes them


def test_a_catalogue_effect_without_a_twin_fails_loudly(monkeypatch):
    class XiX(Effect):
        """IMU mount turned about x_b."""
        name = "xi_x"
        params = (Param("xi_x", "arcsec", units.ARCSEC, 0.0, -600.0, 600.0, "mount turn about x_b"),)

        def act(self, p, op, errors):
            errors.add_xi(ca.vertcat(p["xi_x"], 0, 0))

    monkeypatch.setitem(CATALOGUE, "xi_x", XiX)
    for derived in (effect_names, demo.hideable, demo.showable):
        with pytest.raises(LookupError, match="effect 'xi_x' has no twin in the simulator"):
            derived()


def _size(mm, X, name, rng):
    """Parameter values of ``name`` (display units): a random direction in its linear
    parameters scaled to a 20-arcsec RMS heading signature on the runs (about its mean) (at most half their
    declared range), nonlinear ones at nominal; the other effects at nominal."""
    own = [q.name for q in Model([name]).params]
    values = {q.name: q.nominal for q in mm.params}
    lin = [mm.names.index(n) for n in own if n not in mm.nonlinear]
    d = rng.normal(size=len(lin))
    d /= np.linalg.norm(d)
    sig = (mm.jacobian(mm.vector(values), X)[:, lin] * mm.scale[lin]) @ d
    room = min(0.5 * max(abs(mm.params[i].lower), abs(mm.params[i].upper)) / abs(c) for i, c in zip(lin, d))
    scale = min(20 * units.ARCSEC / max(np.std(sig), 1e-300), room)
    values.update({mm.names[i]: scale * c for i, c in zip(lin, d)})
    return {n: values[n] for n in own}


@pytest.mark.parametrize("name", effect_names() + ("encoder_harmonic+mount_xi",))
def test_every_twin_makes_the_simulator_what_the_model_predicts(name, rng):
    """Noise-free simulator runs of the twin's truth against the symbolic model at the same
    parameter values: run-to-run differences agree within 3 % of their spread + 0.1 arcsec
    (the paper's model alone: absolute values too, which checks the offset's sign)."""
    mm = Model(dict.fromkeys(["hse", *name.split("+")])).measurement(tilt_known=True)
    tilt = TILT_ARCSEC * units.ARCSEC
    temp_c = np.array([_mean_temperature(BASE.thermal, t) for t in T_START_S])
    X = mm.inputs(RATE_DPS * units.DEG_PER_S, np.radians(AZIMUTH_DEG), BASE.site.latitude, 600.0,
                  T_START_S, pitch=tilt[:, 1], roll=tilt[:, 0],
                  covariates={"temp_c": temp_c} if mm.covariates else None)
    values = _size(mm, X, name, rng) if "+" not in name else dict(ENCODER_MOUNT)
    if name == "hse":
        values["offset"] = 25.0                           # a constant signature: sized by hand
    truth = BASE.updated(truth_changes(name, values))
    sim = np.array([simulate_heading_error(truth, r * units.DEG_PER_S, np.radians(a), duration=600.0,
                                           t_start=t, tilt=tuple(tl))
                    for r, a, t, tl in zip(RATE_DPS, AZIMUTH_DEG, T_START_S, tilt)]) / units.ARCSEC
    pred = mm.predict(mm.vector(values), X) / units.ARCSEC
    d_sim, d_mod = sim - sim.mean(), pred - pred.mean()
    assert np.max(np.abs(d_sim - d_mod)) < 0.03 * np.ptp(d_mod) + 0.1, (name, values, d_sim, d_mod)
    if name not in ("encoder_harmonic", "mount_xi"):      # no signature alone (test_encoder_coupling)
        assert np.ptp(d_mod) > 10, name
    if name == "hse":
        assert abs(sim.mean() - pred.mean()) < 0.03 * abs(pred.mean()) + 0.1, (sim, pred)


def _mean_temperature(thermal, t_start, duration=600.0):
    from hse_opt.sim.truth import temperature
    return float(np.mean(temperature(thermal, t_start + np.linspace(0.0, duration, 601))))
