"""The report page: :class:`Section` and :class:`Figure`, rendered into one self-contained HTML
file with the sections' numbers as an inert JSON block, written whole."""
from __future__ import annotations

import base64
import html
import json
from dataclasses import dataclass, field
from pathlib import Path

from .. import __version__
from ..data import write_text_atomic
from .cells import _notes

#: file name of the report inside the report directory
REPORT_NAME = "report.html"


@dataclass(frozen=True)
class Figure:
    """One embedded plot: an SVG document with its caption.

    Attributes
    ----------
    svg : bytes
        The SVG document.
    caption : str
        Plain text shown under the plot.
    alt : str
        Text alternative of the image.
    """

    svg: bytes
    caption: str
    alt: str

    def html(self):
        uri = "data:image/svg+xml;base64," + base64.b64encode(self.svg).decode("ascii")
        return (f'<figure><img class="plot" src="{uri}" alt="{html.escape(self.alt)}">'
                f"<figcaption>{html.escape(self.caption)}</figcaption></figure>")


@dataclass(frozen=True)
class Section:
    """One section of a report.

    Attributes
    ----------
    title : str
    blocks : tuple
        Parts in order: :class:`Figure` objects and HTML fragments (str, already escaped).
    data : dict
        The section's numbers (JSON-serialisable), embedded in the page for machines.
    """

    title: str
    blocks: tuple
    data: dict = field(default_factory=dict)

    @property
    def figures(self):
        return tuple(b for b in self.blocks if isinstance(b, Figure))

    def html(self, anchor):
        body = "\n".join(b.html() if isinstance(b, Figure) else b for b in self.blocks)
        return f'<section id="{anchor}"><h2>{html.escape(self.title)}</h2>\n{body}\n</section>'


def text_section(title, lines):
    """A section of plain text lines (a list)."""
    return Section(title, (_notes(list(lines)),))


_CSS = """
body{font-family:-apple-system,"Segoe UI",Roboto,"Helvetica Neue",Arial,sans-serif;margin:0;
color:#1b1b1b;background:#fff;line-height:1.45}
main{max-width:60rem;margin:0 auto;padding:1rem 1.5rem 3rem}
h1{font-size:1.6rem;margin:.5rem 0}h2{font-size:1.25rem;border-bottom:1px solid #ddd;
padding-bottom:.2rem;margin-top:2.2rem}
table{border-collapse:collapse;margin:.6rem 0;font-size:.88rem;display:block;width:max-content;max-width:100%;overflow-x:auto}
th,td{border-bottom:1px solid #e3e3e3;padding:.2rem .6rem;text-align:left;vertical-align:top}
th{background:#f4f6f8}td{font-variant-numeric:tabular-nums}
.cols{display:flex;flex-wrap:wrap;gap:1.5rem;align-items:flex-start}
figure{margin:1rem 0}img.plot{max-width:100%;height:auto;display:block}
figcaption{font-size:.85rem;color:#444;margin-top:.3rem}
.summary{background:#f4f8f4;border-left:4px solid #2ca02c;padding:.6rem 1rem}
.summary.warn{background:#fdf5f4;border-left-color:#d62728}
.notes{font-size:.85rem;color:#555}.hi{color:#d62728;font-weight:600}
nav ol{margin:.3rem 0;padding-left:1.3rem}code{font-size:.9em}
footer{font-size:.8rem;color:#777;margin-top:3rem}
"""


def render_html(sections, title="hse_opt report", summary=None):
    """The report page as one HTML string.

    Parameters
    ----------
    sections : sequence of Section
    title : str
    summary : sequence of str, optional
        Lines shown at the top, before the sections.

    Returns
    -------
    str
    """
    anchors = [f"s{i + 1}" for i in range(len(sections))]
    toc = "".join(f'<li><a href="#{a}">{html.escape(s.title)}</a></li>'
                  for a, s in zip(anchors, sections))
    top = ""
    if summary:
        top = '<div class="summary">' + "".join(f"<p>{html.escape(line)}</p>" for line in summary) + "</div>"
    data = {s.title: s.data for s in sections}
    # a JSON data block is inert (never executed); with <, > and & as JSON escapes no user text
    # can end it early ("</script>") or switch the parser's state ("<!--<script>")
    payload = (json.dumps(data, allow_nan=False, default=float)
               .replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026"))
    body = "\n".join(s.html(a) for a, s in zip(anchors, sections))
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head>\n<body><main>"
            f"<h1>{html.escape(title)}</h1>{top}<nav><ol>{toc}</ol></nav>\n{body}\n"
            f'<footer>hse_opt {html.escape(__version__)}. Heading errors are estimated minus '
            f'true (the paper\'s delta-psi has the opposite sign).</footer></main>\n'
            f'<script type="application/json" id="hse-opt-data">{payload}</script>'
            f"</body></html>\n")


def write_report(directory, sections, title="hse_opt report", summary=None):
    """Render ``sections`` into ``directory/report.html`` (the directory is created when
    missing; the file is written whole or not at all).

    Returns
    -------
    pathlib.Path
        The report file.
    """
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise ValueError(f"report directory {str(directory)!r} is a file; allowed: a directory "
                         "(created when missing)")
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / REPORT_NAME
    write_text_atomic(path, render_html(sections, title, summary))
    return path
