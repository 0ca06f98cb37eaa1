"""Number formatting shared by the results' text and JSON forms."""
from __future__ import annotations

import math

def num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def p_text(p):
    return "-" if p is None else f"{p:.2g}"


def f_text(x):
    return "-" if x is None else f"{x:.3g}"


def cell(x):
    if x is None:
        return "-"
    if isinstance(x, str):
        return x
    return f"{x:.4g}"


def pm(v, s):
    return "-" if v is None else f"{v:.4g} +- {s:.2g}"


def test_text(t):
    if not t.tested:
        return f"not computable ({t.note})"
    if len(t.dof) == 1:
        return f"chi2({t.dof[0]}) = {t.statistic:.4g}, p = {t.p_value:.3g}{t.adjustment}"
    return f"F({t.dof[0]}, {t.dof[1]}) = {t.statistic:.4g}, p = {t.p_value:.3g}{t.adjustment}"


def run_text(r):
    parts = [f"{r['rate_dps']:+.4g} deg/s", f"azimuth {r['azimuth_deg']:.4g} deg",
             f"t_start {r['t_start_s']:.4g} s"]
    if "pitch_arcsec" in r:
        parts.append(f"pitch {r['pitch_arcsec']:.4g} / roll {r['roll_arcsec']:.4g} arcsec")
    extra = [k for k in r if k not in ("rate_dps", "azimuth_deg", "t_start_s", "duration_s", "pitch_arcsec",
                                       "roll_arcsec", "pred_a_arcsec", "pred_b_arcsec", "separation", "a", "b")]
    parts += [f"{c} {r[c]:.4g}" for c in extra]
    return (", ".join(parts) + f": predicted {r['pred_a_arcsec']:.3g} vs {r['pred_b_arcsec']:.3g} arcsec "
            f"({r['separation']:.2g} sigma apart)")
