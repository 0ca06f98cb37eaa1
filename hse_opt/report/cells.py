"""HTML fragments of the report: numbers in cells, tables with machine-readable row keys,
paragraphs and notes, all escaped."""
from __future__ import annotations

import html
import json

import numpy as np


def _fmt(x, digits=4):
    """A number for a table cell."""
    if x is None:
        return "&ndash;"
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    x = float(x)
    if not np.isfinite(x):
        return html.escape(str(x))
    return f"{x:.{digits}g}"


def _table(header, rows, keys=None, cls=""):
    """An HTML table; ``keys`` (per row, optional) become ``data-key`` attributes of the
    rows so machines can read the numbers back."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = []
    for i, row in enumerate(rows):
        key = f' data-key="{html.escape(keys[i])}"' if keys is not None else ""
        body.append(f"<tr{key}>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>")
    return (f'<table class="{cls}"><thead><tr>{head}</tr></thead><tbody>'
            + "".join(body) + "</tbody></table>")


def _paragraph(text):
    return f"<p>{html.escape(text)}</p>"


def _notes(notes):
    if not notes:
        return ""
    return ('<ul class="notes">' + "".join(f"<li>{html.escape(n)}</li>" for n in notes)
            + "</ul>")


def _missing_figure(what, why):
    return f'<p class="notes">No {html.escape(what)}: {html.escape(why)}</p>'


def _cell(x):
    if isinstance(x, str):
        return html.escape(x)
    if isinstance(x, float) and 0 < abs(x) < 1e-3:
        return _p_text(x)
    return _fmt(x)


def _p_text(p):
    return "&ndash;" if p is None else (f"{p:.2g}" if p >= 1e-300 else "&lt;1e-300")


def _jsonable(obj):
    """``obj`` with numpy scalars and arrays made JSON-serialisable."""
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
