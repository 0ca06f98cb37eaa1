"""Reference data shipped with hse_opt, with provenance (see ``README.md`` here).

``paper_table1.csv`` is Table 1 of Yu, Wu, Cao, Zhao and Liu, "On-line calibration and
compensation of heading-sensitive error for triad constant-rate biased RLG system",
J. National University of Defense Technology 35(4), 2013: 12 static-base alignments of
10 min at a bias rate of 40 deg/s, 3 at each of 4 stand azimuths about 90 deg apart.
``heading_err_arcsec`` is before HSE compensation, ``heading_err_compensated_arcsec`` after
the paper's on-line compensation (Eq. 14); the table prints peak-to-peak values of 40.50 and
28.50 arcsec. The latitude is not in the table: 28.07 deg (0.49 rad), the paper's
worked-example latitude, is assumed. The first position was measured right after a cold
start; the paper gives no times, tilts or temperatures.
"""
from importlib import resources

from ..data import Runs, load_runs

__all__ = ["paper_table1", "paper_table1_path", "example_campaign", "calibration_example_path"]


def calibration_example_path():
    """The path of ``calibration_example.toml`` inside the installed package (a ``pathlib.Path``
    or a resource path): an example ``CALIBRATION.toml``, the lab calibration of the paper-like
    default system (``docs/calibration.md``; :func:`hse_opt.align.load_calibration`)."""
    return resources.files(__name__).joinpath("calibration_example.toml")


def paper_table1_path():
    """The path of ``paper_table1.csv`` inside the installed package (a ``pathlib.Path``)."""
    return resources.files(__name__).joinpath("paper_table1.csv")


def paper_table1() -> Runs:
    """Table 1 of the paper as :class:`~hse_opt.data.Runs`.

    Returns
    -------
    Runs
        12 runs; ``heading_err`` is the uncompensated heading error (rad). The covariates
        ``position`` (stand position 1-4) and ``heading_err_compensated_arcsec`` (arcsec,
        after the paper's compensation) keep their file units. No ``t_start``, tilts or
        ``heading_std``: see ``Runs.notes``.
    """
    with resources.as_file(paper_table1_path()) as path:
        return load_runs(path)


def example_campaign(sessions=1, seed=1) -> Runs:
    """The README's simulated campaign: the paper-like system (``TruthConfig.default()``) with
    a gyro/encoder time offset of 300 us that the paper's model lacks, twelve 10-minute
    alignments per session at 20, 40 and 60 deg/s and stand azimuths 0, 90, 180 and 270 deg,
    raw data through the alignment filter (about 1 s per session).

    Parameters
    ----------
    sessions : int
        Sessions one after the other (run ids and start times continue): a later session is
        a new campaign on the same system.
    seed : int
        Seed of the simulation (run ``r`` draws from ``SeedSequence([seed, r])``).

    Returns
    -------
    Runs
        ``12 * sessions`` runs with heading_std, pitch and roll.
    """
    import numpy as np

    from ..data import Plan
    from ..sim import TruthConfig, run_campaign

    truth = TruthConfig.default().updated({"encoder": {"sync_delay_us": 300.0}})
    az, rate = np.meshgrid([0.0, 90.0, 180.0, 270.0], [20.0, 40.0, 60.0])
    n = az.size * int(sessions)
    plan = Plan.from_columns({"run": np.arange(1, n + 1), "rate_dps": np.tile(rate.ravel(), sessions),
                              "azimuth_deg": np.tile(az.ravel(), sessions),
                              "t_start_s": 3600 + 700.0 * np.arange(n), "duration_s": np.full(n, 600.0)})
    return run_campaign(plan, truth, seed=seed)
