"""The one error of bad PLAN/RUNS input: :class:`DataError`, naming file, row, line and column;
and :class:`DataWarning`, for input that is read but not as the user probably meant."""
from __future__ import annotations

__all__ = ["DataError", "DataWarning"]


class DataError(ValueError):
    """Invalid PLAN/RUNS data; the message names file, row (with line), column and what is allowed.

    Attributes ``source``, ``problem``, ``row`` (1-based data row or None), ``line`` (line in
    the file or None) and ``column`` (name or None) carry the parts of the message.
    """

    def __init__(self, source, problem, row=None, line=None, column=None):
        self.source, self.problem, self.row, self.line, self.column = source, problem, row, line, column
        where = [str(source)]
        if row is not None:
            where.append(f"row {row}" + (f" (line {line})" if line is not None else ""))
        elif line is not None:
            where.append(f"line {line}")
        if column is not None:
            where.append(f"column '{column}'")
        super().__init__(", ".join(where) + ": " + problem)

    def __reduce__(self):
        return type(self), (self.source, self.problem, self.row, self.line, self.column)


class DataWarning(UserWarning):
    """Input read, but not as its shape suggests (a column of numbers with one text cell, kept
    as text); the message names file, row and column (``Runs.warnings``)."""
