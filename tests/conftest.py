import numpy as np
import pytest

from hse_opt import frames, units
from hse_opt.validation.twins import effect_names

#: every catalogue effect and the simulator's covariate
ALL_EFFECTS = list(effect_names())


def pytest_collection_modifyitems(items):
    """Slow tests first, so that parallel workers (pytest-xdist, one file at a time) start the
    long files early and finish together."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.fixture
def rng():
    return np.random.default_rng(20131204)


def random_case(rng, eps_max=1e-4, xi_max=1e-4, tilt_max=2e-3, rate_max_dps=100.0,
                lat_max_deg=70.0, dr_max=1e-3):
    """A random operating point and error set over the issue's ranges."""
    r = frames.R_ZB_S_IDEAL + rng.uniform(-dr_max, dr_max, 3)
    return dict(
        eps=rng.uniform(-eps_max, eps_max, 3),
        xi=rng.uniform(-xi_max, xi_max, 3),
        theta=rng.uniform(-tilt_max, tilt_max),
        gamma=rng.uniform(-tilt_max, tilt_max),
        rate=rng.choice([-1, 1]) * rng.uniform(10, rate_max_dps) * units.DEG_PER_S,
        L=rng.uniform(-lat_max_deg, lat_max_deg) * units.DEG,
        r=r / np.linalg.norm(r),
    )


#: the diagnosis tests' campaigns: the paper's two parameters and the default stand's mount tilt
DIAGNOSTIC_BASE = {"offset": 3.0, "lambda2": 4.2}
DIAGNOSTIC_TILT = (-120 * units.ARCSEC, -55 * units.ARCSEC)


def campaign(values, seed, plan=None, **kw):
    """Runs of :func:`hse_opt.validation.synthetic.model_runs` on the diagnostic plan (or
    ``plan``) with ``DIAGNOSTIC_BASE`` updated by ``values`` and noise seeded by ``seed``."""
    from hse_opt.validation.synthetic import diagnostic_plan, model_runs
    return model_runs(diagnostic_plan() if plan is None else plan, {**DIAGNOSTIC_BASE, **values},
                      np.random.default_rng(seed), base_tilt=DIAGNOSTIC_TILT, **kw)
