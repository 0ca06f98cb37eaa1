"""PLAN and RUNS tables: load, validate and save (the data-format contract).

Both files are CSV with one header row and units in the column names (``docs/formats.md``,
the contract). In memory a table is a frozen dataclass of read-only float64 arrays in SI units
(rad, rad/s, s); the run id is int64. Every extra numeric column is kept as a covariate, in
the file's own unit and under its own name (``temp_c``). An extra column with a cell that is
not a finite number (a date, an operator, a serial number, an empty cell) is text: kept as
metadata (:attr:`Runs.metadata`, strings), passed through to every table written from it
(``hse-opt compensate``, ``hse-opt simulate``) and never an error; :attr:`Runs.notes` names
the first cell that made it text. A text column with numbers in other rows (a NaN, an empty
cell or a typo among numbers) is most likely a covariate with a hole: the loaders warn
(:class:`DataWarning`, :attr:`Runs.warnings`, one line on stderr in every command), and a
command that uses it as a covariate (``--effects covariate:NAME``, ``diagnose --covariates``)
refuses it naming the row (:meth:`Runs.covariate`).

``RUNS.csv`` (:class:`Runs`): ``run, rate_dps, azimuth_deg, heading_err_arcsec,
latitude_deg, duration_s`` and optionally ``t_start_s``, ``pitch_arcsec`` with
``roll_arcsec``, ``heading_std_arcsec``, ``azimuth_std_arcsec`` (the stand reference's own
1-sigma; the fit adds it to each run's sigma in quadrature, :mod:`hse_opt.fit.weights`),
``heading_deg`` and ``position`` (field campaigns, below: then ``azimuth_deg`` and
``heading_err_arcsec`` may be empty or absent).

Field campaigns (positions without a heading reference)
-------------------------------------------------------
In the field nobody knows the true heading of the stand: the system aligns at a position
several times (rates, senses, repeats) and the calibration comes from the heading
*differences* between those runs (the paper's on-line calibration). ``RUNS.csv`` then carries:

``position``
    Optional text label (any text: ``A``, ``pier 3``, ``1``). Rows with one label share one
    stand position, i.e. one true heading. Kept as text (:attr:`Runs.position`), never a
    covariate.
``heading_deg``
    The alignment's own heading estimate, deg. It replaces ``heading_err_arcsec`` where no
    reference exists, and it is what the tools use for the heading in C23 at such a
    position (an arcminute is plenty there: see below).
``azimuth_deg``, ``heading_err_arcsec``
    Required only where a reference exists. With ``heading_deg`` present, a row whose
    ``azimuth_deg`` cell is empty (or a file without that column) belongs to an
    *unsurveyed* position; its ``heading_err_arcsec`` cell must be empty too. A surveyed
    row with ``heading_deg`` and an empty ``heading_err_arcsec`` gets ``heading_deg -
    azimuth_deg`` (exact decimals). Mixed campaigns -- some positions surveyed, some not --
    are allowed; a position is surveyed in all its rows or in none.

Without a ``position`` column, all unsurveyed rows are one position (the paper's
single-position procedure; :attr:`Runs.notes` says so), and a heading more than
:data:`MAX_POSITION_SPREAD_DEG` from its position's mean heading is an error (one position
is one stand heading: it catches a forgotten ``position`` column).

In memory (:class:`Runs`) an unsurveyed row has ``surveyed = False``, ``azimuth`` = the
position's mean heading (the system's own headings averaged: one true heading per position)
and ``heading_err`` = its heading minus that mean: the heading error up to one unknown
constant per position. :meth:`Runs.reference_groups` tells which
rows share which constant. What this data can estimate:

* Surveyed rows share the one unknown constant of the stand reading (``offset``), as
  before; each unsurveyed position adds one nuisance constant (its unknown true heading
  plus the offset), which the fit eliminates exactly and never reports.
* Within an unsurveyed position only *contrasts* count: everything that is constant at the
  position (the offset, the stand's azimuth errors, a tilt-coupled term at a single rate) is
  absorbed by its constant. lambda2 (K_HSE) is seen through the heading change with the
  bias rate Omega, so a position must be visited at two or more different rates (or both
  senses) to contribute; a position with one rate only carries no information on it.
  Time-dependent effects (warm-up) are seen through the time between its runs.
* Why the own heading is good enough in C23 = -gamma cos(psi) + theta sin(psi): an error
  d psi in psi changes C23 by at most |tilt| d psi. With a tilt of 1e-3 rad (the paper's
  worked example) and a heading off by 1 arcmin (an alignment is good to arcseconds, a
  position's unknown heading error by the HSE itself to tens of arcseconds), C23 changes
  by 3e-7 rad, a relative 3e-4 of C23 and ~0.01 arcsec of heading error at 40 deg/s.

``PLAN.csv`` (:class:`Plan`): ``run, rate_dps, azimuth_deg, t_start_s, duration_s`` and
optionally ``tilt_x_arcsec`` with ``tilt_y_arcsec``, and ``position`` (a text label); at an
unsurveyed position of a field plan ``azimuth_deg`` is empty and ``heading_deg`` is the heading
to set the system to (:attr:`Plan.surveyed`).

Checks
------
Every construction checks the structure: equal 1-D lengths, finite values, unique integer
run ids, ``|latitude| <= 90 deg``, ``duration > 0``, ``t_start >= 0``, ``heading_std > 0``
and paired columns given together. Reading a table from columns or a file
(:meth:`Runs.from_columns`, :func:`load_runs`, ...) also checks two things that concern the
file rather than the physics:

* Lock-in. A constant-rate biased RLG system needs the table rate well outside the gyros'
  lock-in zone: each skewed gyro sees only ``|Omega| cos(54.74 deg) = |Omega|/sqrt(3)``, RLG
  lock-in thresholds are of the order of 0.01-0.5 deg/s, and the scale factor is nonlinear
  up to several times the threshold. ``|rate_dps| < min_rate_dps`` is therefore an error;
  the default :data:`DEFAULT_MIN_RATE_DPS` = 5 deg/s leaves each gyro about 2.9 deg/s, at
  least six times a large lock-in threshold (the paper uses 20-60 deg/s). It also catches a
  rate written in rad/s (40 deg/s is 0.70 rad/s). Pass ``min_rate_dps=0`` to turn it off.
* Azimuths in radians. ``azimuth_deg`` is taken to hold radians when it has at least two
  distinct values, all of them within +-2 pi, spread over at least 1 (57 deg if radians, a
  multi-position test; 1 deg if degrees, one stand position with reading jitter) and not
  all whole numbers (0, 90, 180 deg written as radians are not). Degrees inside +-6.28 deg
  with such a spread are a fine azimuth sweep; ``allow_small_azimuths=True`` accepts them.
  Azimuths outside [0, 360) deg are kept as given.

Every failure is a :class:`DataError` (a ``ValueError``) whose message names the file, the
1-based data row with its line in the file, the column, and what is allowed.

Numbers
-------
A file value is read as the decimal number it is written as (a float given to
:meth:`Runs.from_columns` as its shortest repr), multiplied exactly by the unit factor of
:mod:`hse_opt.units` and rounded once to float64. On saving, each SI value is written as
the shortest decimal (at most 18 significant digits) that reads back to exactly the same
float64, so ``load -> save -> load`` and ``save -> load`` are exact and a saved
``91.8795`` stays ``91.8795``. Files are written whole: a temporary file in the target's
directory, flushed and fsynced, then ``os.replace``; on any error the target is untouched.
Input files are only read.

The package: :mod:`~hse_opt.data.errors` (:class:`DataError`), :mod:`~hse_opt.data.decimals`
(file text <-> SI, exactly), :mod:`~hse_opt.data.table` (the columns, checks and parse both
tables share), :mod:`~hse_opt.data.runs` (:class:`Runs`, field campaigns),
:mod:`~hse_opt.data.plan` (:class:`Plan`), :mod:`~hse_opt.data.csvfile` (read and save) and
:mod:`~hse_opt.data.atomic` (outputs whole or not at all); every name is re-exported here.
"""
from __future__ import annotations

from .atomic import TEMP_TAG, atomic_path, fsync_folder, remove_leftovers, temp_path, write_text_atomic
from .csvfile import load_plan, load_runs, read_text, read_toml, save_plan, save_runs
from .errors import DataError, DataWarning
from .plan import Plan
from .runs import MAX_POSITION_SPREAD_DEG, Runs
from .table import DEFAULT_MIN_RATE_DPS

__all__ = ["DataError", "DataWarning", "Runs", "Plan", "load_runs", "load_plan", "save_runs", "save_plan",
           "DEFAULT_MIN_RATE_DPS", "MAX_POSITION_SPREAD_DEG", "read_text", "read_toml", "write_text_atomic", "atomic_path",
           "temp_path", "remove_leftovers", "fsync_folder", "TEMP_TAG"]
