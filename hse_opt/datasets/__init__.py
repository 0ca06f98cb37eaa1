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

__all__ = ["paper_table1", "paper_table1_path"]


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
