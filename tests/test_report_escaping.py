"""The HTML report escapes every user string: text a user puts in RUNS.csv (a metadata column,
``position`` labels) reaches the page as text, never as markup or script. Checked in a real
browser (chromium, :mod:`browser`): the hostile values' scripts and event handlers do not run,
the text shows escaped, and the page's JSON data block parses back to the very strings (a
value ``<!--<script>`` or ``</script>`` cannot end it early or change how the browser reads
it). Names cannot carry markup at all (:mod:`hse_opt.names`, ``tests/test_names.py``)."""
import csv
import json
import re

import numpy as np
import pytest

from browser import _chromium, require_chromium
from hse_opt.cli import main as cli
from hse_opt.data import save_runs

#: each sets a flag (or the title) if it ever runs
HOSTILE = ['<!--<script>window.__pwned = 1; document.title = "PWNED"</script>',
           '<img src=x onerror="window.__pwned = 2">',
           '<!--<script>',
           '</script><script>window.__pwned = 3</script>',
           '"quoted" & <b>bold</b> $x^$']

_PROBE = """<script>
window.addEventListener('load', () => {
  let data = null, error = null;
  try { data = JSON.parse(document.getElementById('hse-opt-data').textContent); }
  catch (e) { error = String(e); }
  const out = {pwned: window.__pwned || 0, title: document.title, text: document.body.innerText,
               images: document.images.length,
               bold: Array.from(document.querySelectorAll('b')).filter(b => b.textContent === 'bold').length,
               data: data, error: error};
  const p = document.createElement('pre'); p.id = 'probe'; p.textContent = JSON.stringify(out);
  document.body.appendChild(p);
});
</script>"""


def _hostile_runs(tmp_path):
    """A campaign whose 'operator' column and position labels are the hostile values."""
    from conftest import campaign
    from hse_opt.validation.synthetic import diagnostic_plan
    runs = campaign({}, 5, plan=diagnostic_plan(sessions=1, runs_per_session=20))
    save_runs(runs, tmp_path / "CLEAN.csv")
    rows = list(csv.reader(open(tmp_path / "CLEAN.csv", newline="")))
    rows[0] += ["operator"]
    for i, r in enumerate(rows[1:]):
        r += [HOSTILE[i % len(HOSTILE)]]
    with open(tmp_path / "RUNS.csv", "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    return tmp_path / "RUNS.csv"


def _probe(page, tmp_path):
    text = page.read_text(encoding="utf-8")
    probed = tmp_path / "probed.html"
    probed.write_text(text.replace("</body>", _PROBE + "</body>"), encoding="utf-8")
    dom = _chromium(["--window-size=1100,900", "--dump-dom", probed.as_uri()])
    m = re.search(r'<pre id="probe">(.*?)</pre>', dom, flags=re.S)
    assert m, "the probe did not run: the page did not finish loading"
    return json.loads(m.group(1).replace("&quot;", '"').replace("&lt;", "<").replace("&gt;", ">")
                      .replace("&amp;", "&"))


@pytest.mark.parametrize("command", ["fit", "diagnose"])
def test_report_escapes_user_text_in_the_browser(tmp_path, command):
    require_chromium()
    path = _hostile_runs(tmp_path)
    assert cli([command, str(path), "--report", str(tmp_path / "out")]) == 0
    page = tmp_path / "out" / "report.html"
    html = page.read_text()
    assert html.count("<script") == 1          # the data block alone, before the probe is added
    out = _probe(page, tmp_path)
    assert out["pwned"] == 0 and out["title"] != "PWNED"
    assert out["error"] is None and out["data"] is not None
    assert out["images"] == len(re.findall(r"<img ", html)) and out["bold"] == 0  # no user markup became elements
    # the note about the text column quotes the first hostile value: shown as text on the page
    assert HOSTILE[0] in out["text"]
    # and the data block holds the very string (JSON.parse in the browser)
    assert any(HOSTILE[0] in t for t in _strings(out["data"]))


def _strings(x):
    """Every string in a JSON value."""
    if isinstance(x, str):
        yield x
    elif isinstance(x, dict):
        for v in x.values():
            yield from _strings(v)
    elif isinstance(x, list):
        for v in x:
            yield from _strings(v)


def test_data_block_escapes_every_angle_bracket(tmp_path):
    """Without a browser too: the JSON block holds no '<', '>' or '&' of its own (each is a
    JSON escape), and json.loads gives back the original strings."""
    from hse_opt.report.page import Section, render_html

    text = "".join(HOSTILE)
    page = render_html([Section("s", ("<p>x</p>",), {"notes": [text]})], "t")
    block = re.search(r'id="hse-opt-data">(.*?)</script>', page, re.S).group(1)
    assert not set(block) & set("<>&")
    assert json.loads(block)["s"]["notes"] == [text]
    assert np.all([h not in page for h in HOSTILE[:2]])
