"""Render an HTML page in a real headless browser (Debian's chromium) and report what it shows.

Used by the report tests. ``.ci/run`` installs chromium when it is missing and it can (root
with apt-get); without it the browser tests skip and say why.
"""
import json
import re
import shutil
import subprocess

import numpy as np
import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--disable-gpu", "--no-sandbox", "--hide-scrollbars", "--mute-audio",
         "--force-device-scale-factor=1", "--virtual-time-budget=10000",
         "--disable-dev-shm-usage", "--no-first-run"]
WIDTH = 1100

# runs after the page has loaded: what the browser actually decoded and laid out
_PROBE = """<script>
window.addEventListener('load', () => {
  const imgs = Array.from(document.images);
  const rect = (e) => { const r = e.getBoundingClientRect();
    return [r.left + window.scrollX, r.top + window.scrollY, r.width, r.height]; };
  const out = {images: imgs.length,
    decoded: imgs.filter(i => i.complete && i.naturalWidth > 0 && i.naturalHeight > 0).length,
    rects: imgs.map(rect), sections: document.querySelectorAll('section').length,
    height: document.documentElement.scrollHeight, width: document.documentElement.scrollWidth};
  const p = document.createElement('pre'); p.id = 'probe'; p.textContent = JSON.stringify(out);
  document.body.appendChild(p);
});
</script>"""


def require_chromium():
    if CHROMIUM is None:
        pytest.skip("chromium is not installed (Debian package 'chromium'; .ci/run installs it "
                    "when run as root with apt-get): cannot check the page in a real browser")
    return CHROMIUM


def _chromium(args, timeout=120):
    out = subprocess.run([require_chromium(), *FLAGS, *args], capture_output=True, text=True,
                         timeout=timeout)
    if out.returncode != 0:
        raise AssertionError(f"chromium failed ({out.returncode}): {out.stderr[-2000:]}")
    return out.stdout


def render(page, workdir):
    """Load ``page`` (an HTML file) in headless chromium.

    Returns
    -------
    probe : dict
        ``images`` (count), ``decoded`` (images the browser decoded, non-zero size),
        ``rects`` (each image's [left, top, width, height], CSS px), ``sections``, ``height``,
        ``width`` (the page's scroll width, CSS px: more than ``WIDTH`` when something overflows).
    pixels : numpy.ndarray, shape (height, WIDTH, 3), uint8
        A screenshot of the whole page.
    """
    from PIL import Image

    text = page.read_text(encoding="utf-8")
    probed = workdir / "probed.html"
    probed.write_text(text.replace("</body>", _PROBE + "</body>"), encoding="utf-8")
    dom = _chromium([f"--window-size={WIDTH},900", "--dump-dom", probed.as_uri()])
    m = re.search(r'<pre id="probe">(.*?)</pre>', dom, flags=re.S)
    assert m, "the probe did not run: the page did not finish loading"
    probe = json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    height = int(min(max(probe["height"], 900), 16000))
    shot = workdir / "page.png"
    _chromium([f"--window-size={WIDTH},{height}", f"--screenshot={shot}", page.as_uri()])
    pixels = np.asarray(Image.open(shot).convert("RGB"))
    return probe, pixels


def ink(pixels):
    """Fraction of pixels that are not (near) white."""
    return float(np.mean(np.any(pixels < 235, axis=-1)))


def colour(pixels):
    """Number of saturated (coloured, not grey) pixels: plot markers and lines."""
    p = pixels.astype(int)
    return int(np.sum(p.max(axis=-1) - p.min(axis=-1) > 60))
