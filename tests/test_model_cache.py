"""Built measurement models kept on disk (hse_opt.model.cache): a model loaded in a new
process evaluates exactly like one built from scratch (the symbolic chain, an independent
construction); a changed effect source is a new entry; effects that cannot be stamped are
never cached; the cache can be turned off; a damaged entry is rebuilt."""
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

from hse_opt.model import Model
from hse_opt.model import cache as model_cache
from hse_opt.model.measurement import MeasurementModel

ROOT = Path(__file__).resolve().parents[1]

CHILD = textwrap.dedent("""
    import sys
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    from hse_opt.model import Model
    import user_effect
    mm = Model(["hse", "axis_bias", "warmup", user_effect.Bump()]).measurement(sys.argv[2] == "known")
    X = np.zeros((mm.n_x, 5))
    X[0] = np.linspace(-0.8, 0.8, 5)
    X[1] = np.linspace(0, 6, 5)
    X[2:4] = 1e-3
    X[4] = 0.5
    X[5] = np.linspace(0, 7000, 5)
    X[6] = 600.0
    p = mm.nominal * 1.1 + 1e-6
    print(repr([mm.predict(p, X).tolist(), mm.jacobian(p, X).tolist(), list(mm.names)]))
""")

EFFECT = textwrap.dedent("""
    from hse_opt import units
    from hse_opt.model.effects import Effect, Param

    class Bump(Effect):
        name = "bump"
        params = (Param("bump", "arcsec", units.ARCSEC, 0.0, -100.0, 100.0, "a heading bump"),)

        def act(self, p, op, errors):
            errors.add_reference_error(SCALE * p["bump"])
""")


def _child(cache, folder, tilt="known", env=None):
    environ = {**os.environ, "PYTHONPATH": str(ROOT), "HSE_OPT_CACHE_DIR": str(cache)}
    environ.pop("HSE_OPT_NO_CACHE", None)
    environ.update(env or {})
    out = subprocess.run([sys.executable, "-c", CHILD, str(folder), tilt], env=environ, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    h, J, names = eval(out.stdout)  # noqa: S307 - our own child's repr
    return np.array(h), np.array(J), names


def _entries(cache):
    return sorted((cache / "models").glob("*.pkl")) if (cache / "models").is_dir() else []


def test_loaded_model_evaluates_like_a_built_one_and_source_changes_are_new_entries(tmp_path):
    folder = tmp_path / "src"
    folder.mkdir()
    (folder / "user_effect.py").write_text(EFFECT.replace("SCALE", "1.0"))
    cache = tmp_path / "cache"
    for tilt in ("known", "unknown"):
        built = _child(cache, folder, tilt, {"HSE_OPT_NO_CACHE": "1"})
        first = _child(cache, folder, tilt)    # builds and stores
        again = _child(cache, folder, tilt)    # loads
        assert first[2] == again[2] == built[2]
        for a, b in zip(built[:2], again[:2]):
            np.testing.assert_array_equal(a, b)
    assert len(_entries(cache)) == 2
    # the effect's physics changes in its file: a new entry, the new physics
    (folder / "user_effect.py").write_text(EFFECT.replace("SCALE", "2.0") + "\n# edited\n")
    changed = _child(cache, folder, "known")
    assert len(_entries(cache)) == 3
    j = changed[2].index("bump")
    np.testing.assert_allclose(changed[1][:, j], 2.0 * built_known_bump(cache, folder), rtol=1e-12)


def built_known_bump(cache, folder):
    (folder / "user_effect.py").write_text(EFFECT.replace("SCALE", "1.0"))
    h, J, names = _child(cache, folder, "known", {"HSE_OPT_NO_CACHE": "1"})
    return J[:, names.index("bump")]


def test_no_cache_writes_nothing_and_damaged_entries_are_rebuilt(tmp_path, monkeypatch):
    monkeypatch.setenv("HSE_OPT_CACHE_DIR", str(tmp_path))
    model = Model(["hse", "sync_delay"])
    monkeypatch.setenv("HSE_OPT_NO_CACHE", "1")
    model_cache.load_or_build(MeasurementModel, model, True)
    assert _entries(tmp_path) == []
    monkeypatch.delenv("HSE_OPT_NO_CACHE")
    ref = model_cache.load_or_build(MeasurementModel, model, True)
    (entry,) = _entries(tmp_path)
    entry.write_bytes(entry.read_bytes()[:100])      # truncated by a crash or by hand
    again = model_cache.load_or_build(MeasurementModel, model, True)
    assert again.names == ref.names and again.model is model
    X = ref.inputs(0.7, 1.0, 0.5, 600.0, 100.0, 1e-3, -1e-3)
    np.testing.assert_array_equal(again.predict(ref.nominal, X), ref.predict(ref.nominal, X))
    assert entry.stat().st_size > 1000                # written whole again


def test_effects_without_a_source_file_are_not_cached():
    from hse_opt import units
    from hse_opt.model.effects import Effect, Param

    class Local(Effect):
        name = "local"
        params = (Param("local", "arcsec", units.ARCSEC, 0.0, -1.0, 1.0, "defined in a function"),)

        def act(self, p, op, errors):
            errors.add_reference_error(p["local"])

    assert model_cache.fingerprint(Model(["hse", Local()]), True) is None
    assert model_cache.fingerprint(Model(["hse"]), True) != model_cache.fingerprint(Model(["hse"]), False)
