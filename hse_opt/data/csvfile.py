"""RUNS.csv and PLAN.csv on disk: read (bounded, UTF-8, one line per error) and written whole."""
from __future__ import annotations

import csv
import dataclasses
import io
import os
import warnings

from ..names import ALLOWED_NAMES, is_name, shown
from ..ranges import MAX_COLUMNS, MAX_FILE_BYTES, MAX_ROWS
from .atomic import _atomic
from .errors import DataError, DataWarning
from .plan import Plan
from .runs import Runs
from .table import DEFAULT_MIN_RATE_DPS

__all__ = ["load_runs", "load_plan", "save_runs", "save_plan", "read_text"]


def _read(cls, path, min_rate_dps, allow_small_azimuths):
    src = os.fspath(path)
    try:
        reader = csv.reader(io.StringIO(read_text(src, "a UTF-8 CSV file"), newline=""))
        rows, lines = [], []
        start = 1
        for fields in reader:
            if any(f.strip() for f in fields):
                rows.append(fields)
                lines.append(start)
            start = reader.line_num + 1
            if len(rows) > MAX_ROWS + 1:
                raise DataError(src, f"has more than {MAX_ROWS} data rows; allowed: at most {MAX_ROWS}",
                                line=reader.line_num)
    except UnicodeDecodeError as e:
        raise DataError(src, f"is not UTF-8 text ({e.reason} at byte {e.start}); allowed: a UTF-8 CSV "
                             "file") from None
    except csv.Error as e:
        raise DataError(src, f"is not valid CSV ({e}); allowed: comma-separated values") from None
    if not rows:
        need = ", ".join(c.name for c in cls._COLUMNS if c.required)
        raise DataError(src, f"the file is empty; allowed: a header row with {need}, then data rows")
    _one_line(src, rows, lines, rows[0])
    header = [h.strip() for h in rows[0]]
    if len(header) > MAX_COLUMNS:
        raise DataError(src, f"the header has {len(header)} columns; allowed: at most {MAX_COLUMNS}",
                        line=lines[0])
    if len(header) == 1 and any(sep in header[0] for sep in ";\t"):
        raise DataError(src, "the header has one column; allowed: comma-separated columns", line=lines[0])
    for j, name in enumerate(header):
        if not name:
            raise DataError(src, f"header field {j + 1} is empty; allowed: a column name", line=lines[0])
        if not is_name(name):
            raise DataError(src, f"header field {j + 1} {shown(name)} is not a column name; allowed: {ALLOWED_NAMES}",
                            line=lines[0])
        if name in header[:j]:
            raise DataError(src, "column name repeats; allowed: each name once", line=lines[0], column=name)
    for k, fields in enumerate(rows[1:]):
        if len(fields) != len(header):
            raise DataError(src, f"has {len(fields)} fields but the header has {len(header)}; allowed: one "
                                 "value per column", row=k + 1, line=lines[k + 1])
    columns = {name: [fields[j] for fields in rows[1:]] for j, name in enumerate(header)}
    table = cls._build(columns, src, lines[1:], min_rate_dps, allow_small_azimuths, header_line=lines[0])
    for text in table.warnings:
        warnings.warn(text, DataWarning, stacklevel=3)
    return table


def _one_line(src, rows, lines, header):
    """DataError for a cell that spans lines: an unbalanced quote (``"27.5``) makes the CSV
    reader take every line up to the next quote, or to the end of the file, into one cell,
    and the rows in between would silently vanish (the row count no longer matches the line
    count). ``lines[k]`` is the line row ``k`` starts on (row 0: the header)."""
    for k, fields in enumerate(rows):
        for j, cell in enumerate(fields):
            if "\n" in cell or "\r" in cell:
                column = (header[j].strip() or None) if 0 < k and j < len(header) and "\n" not in header[j] \
                    else None
                raise DataError(src, f"a quoted {'header field' if k == 0 else 'cell'} does not end on its "
                                     "line (a quote '\"' not closed on its own line takes the lines after it "
                                     "into one cell, and their rows would be lost); allowed: one line per "
                                     "row, quotes in pairs within a line", row=k or None, line=lines[k],
                                column=column)


def read_text(path, allowed, limit=MAX_FILE_BYTES):
    """The text of a UTF-8 input file (a BOM is dropped), at most ``limit`` bytes; DataError
    beyond (``/dev/zero`` too) or for bytes that are no UTF-8. ``allowed`` names the file kind."""
    src = os.fspath(path)
    with open(src, "rb") as fh:
        data = fh.read(limit + 1)
    if len(data) > limit:
        raise DataError(src, f"is larger than {limit / 2**20:g} MiB; allowed: {allowed} of at most "
                             f"{limit / 2**20:g} MiB")
    return data.decode("utf-8-sig")


def read_toml(path, allowed, *, parse_float=float):
    """The tables of a UTF-8 TOML input file (:func:`read_text`); ValueError naming the file
    for text that is no TOML, no UTF-8 or nested too deeply. ``allowed`` names the file kind
    (``"a mapping file (TOML)"``); ``parse_float=decimal.Decimal`` keeps numbers exact."""
    try:
        import tomllib
    except ModuleNotFoundError:  # pragma: no cover - Python < 3.11
        import tomli as tomllib
    src = os.fspath(path)
    try:
        return tomllib.loads(read_text(src, allowed), parse_float=parse_float)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{src}: not valid TOML: {exc}; allowed: {allowed}") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{src}: is not UTF-8 text ({exc.reason} at byte {exc.start}); allowed: "
                         f"{allowed}") from None
    except RecursionError:
        raise ValueError(f"{src}: arrays or tables nested too deeply; allowed: {allowed}") from None


def load_runs(path, *, min_rate_dps=DEFAULT_MIN_RATE_DPS, allow_small_azimuths=False) -> Runs:
    """Read and validate a ``RUNS.csv`` file (the file is only read).

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file.
    min_rate_dps : float
        Lock-in limit, deg/s; ``|rate_dps|`` below it is an error (0 turns the check off).
    allow_small_azimuths : bool
        Accept ``azimuth_deg`` values that look like radians.

    Returns
    -------
    Runs

    Raises
    ------
    DataError
        Invalid content; the message names file, row (and line), column and what is allowed.
    OSError
        The file cannot be read.
    """
    return _read(Runs, path, min_rate_dps, allow_small_azimuths)


def load_plan(path, *, min_rate_dps=DEFAULT_MIN_RATE_DPS, allow_small_azimuths=False) -> Plan:
    """Read and validate a ``PLAN.csv`` file; parameters and errors as :func:`load_runs`."""
    return _read(Plan, path, min_rate_dps, allow_small_azimuths)


def _write_atomic(table, cls, path):
    if not isinstance(table, cls):
        raise TypeError(f"expected a {cls.__name__}, got {type(table).__name__}")
    table = dataclasses.replace(table)  # re-run the checks: arrays could have been made writable
    columns = table._text_columns()

    def write(fh):
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(columns)
        writer.writerows(zip(*columns.values()))
    _atomic(path, write)


def save_runs(runs: Runs, path) -> None:
    """Write ``runs`` to ``path`` as ``RUNS.csv``, whole or not at all.

    Contract columns come first, in contract order, then the covariates; numbers are the
    shortest decimals that read back exactly. The file is written to a temporary file in the
    same directory, fsynced and renamed over ``path``; on any error ``path`` is untouched.
    """
    _write_atomic(runs, Runs, path)


def save_plan(plan: Plan, path) -> None:
    """Write ``plan`` to ``path`` as ``PLAN.csv``, whole or not at all (as :func:`save_runs`)."""
    _write_atomic(plan, Plan, path)
