"""The sensors' noise in the report: Allan deviation curves of the logs with the fitted IEEE
Std 952 terms as slope lines, and the figures per log and pooled
(:mod:`hse_opt.align.noise`).

Units at the edge: gyros in deg/h, accelerometers in ug, cluster times in s.
"""
from __future__ import annotations

import math

import numpy as np

from .. import units
from ..align.noise import NOISE_COLUMNS, TERMS
from .cells import _fmt, _notes, _table
from .page import Section
from .style import _COLORS, _embed, _new_figure, _plotting

#: each term's slope of the Allan deviation and the label of its line
_SLOPES = {"quantization": (-1.0, "quantization, slope -1"), "random_walk": (-0.5, "random walk, slope -1/2"),
           "bias_instability": (0.0, "bias instability, slope 0"),
           "rate_random_walk": (0.5, "rate random walk, slope +1/2")}
_GROUPS = (("gyros", slice(0, 3), units.DEG_PER_H, "deg/h"), ("accelerometers", slice(3, 6), units.MICRO_G, "ug"))


@_plotting
def plot_allan(figures, pooled):
    """Two panels (gyros, accelerometers): each log's Allan deviation (thin, the mean of the
    three sensors' variances), the pooled curve (points) with the fitted model, and each
    fitted term as its slope line (dashed). Returns a matplotlib Figure.

    Parameters
    ----------
    figures : sequence of NoiseFigures
        One per log.
    pooled : NoiseFigures
        Their pooling (:func:`hse_opt.align.noise.combine_noise`).
    """
    fig = _new_figure(9.0, 3.8)
    axes = fig.subplots(1, 2)
    for ax, (name, rows, factor, unit) in zip(axes, _GROUPS):
        for f in figures:
            ax.loglog(f.tau, np.sqrt(np.mean(f.adev[rows] ** 2, axis=0)) / factor, color="#bbbbbb", lw=0.6)
        tau = pooled.tau
        ax.loglog(tau, np.sqrt(np.mean(pooled.adev[rows] ** 2, axis=0)) / factor, "o", ms=3.5, color=_COLORS[0],
                  label=f"pooled, {pooled.n_logs} log{'s' if pooled.n_logs != 1 else ''}")
        grid = np.geomspace(tau[0], tau[-1], 200)
        model = np.sqrt(np.mean(pooled.model_adev(grid)[rows] ** 2, axis=0))
        ax.loglog(grid, model / factor, "-", color="#1b1b1b", lw=1.2, label="fitted model")
        coef = pooled.coefficients[rows].mean(axis=0)
        for k, (term, (slope, label)) in enumerate(_SLOPES.items()):
            a = coef[TERMS.index(term)]
            if a > 0:      # sigma = sqrt(a tau^(2 slope))
                ax.loglog(grid, np.sqrt(a) * grid ** slope / factor, "--", lw=0.9, color=_COLORS[k + 1],
                          label=label)
        top = np.nanmax(model) / factor
        ax.set_ylim(np.nanmin(model) / factor / 3.0, top * 3.0)
        ax.set_xlabel("cluster time tau (s)")
        ax.set_ylabel(f"Allan deviation ({unit})")
        ax.set_title(name)
        ax.legend(loc="best")
    return fig


def _term_rows(pooled):
    """Table rows: each term of the pooled figures, per sensor, in file units."""
    def fmt(values, factor):
        return [_fmt(v / factor, 3) for v in values]
    g = slice(0, 3)
    a = slice(3, 6)
    rth = math.sqrt(units.HOUR)
    return [
        ["gyro angle random walk (deg/h/sqrt(Hz))", *fmt(pooled.random_walk[g], units.DEG_PER_H)],
        ["gyro angle random walk (deg/sqrt(h))", *fmt(pooled.random_walk[g], units.DEG_PER_H * 60.0)],
        ["gyro bias instability (deg/h)", *fmt(pooled.bias_instability[g], units.DEG_PER_H)],
        ["gyro quantization (arcsec)", *fmt(pooled.quantization[g], units.ARCSEC)],
        ["gyro rate random walk (deg/h/sqrt(h))", *fmt(pooled.rate_random_walk[g], units.DEG_PER_H / rth)],
        ["accelerometer velocity random walk (ug/sqrt(Hz))", *fmt(pooled.random_walk[a], units.MICRO_G)],
        ["accelerometer bias instability (ug)", *fmt(pooled.bias_instability[a], units.MICRO_G)],
        ["accelerometer quantization (m/s)", *fmt(pooled.quantization[a], 1.0)],
    ]


def noise_section(figures, pooled, names=None):
    """The report section of the sensors' noise.

    Parameters
    ----------
    figures : sequence of NoiseFigures
        One per log.
    pooled : NoiseFigures
        Their pooling (:func:`hse_opt.align.noise.combine_noise`).
    names : sequence of str, optional
        The logs' names (default log 1, 2, ...).

    Returns
    -------
    Section
    """
    figures = list(figures)
    names = [f"log {i + 1}" for i in range(len(figures))] if names is None else [str(n) for n in names]
    blocks = [_notes([
        "From the logs themselves (hse_opt/align/noise.py): the overlapping Allan deviation of each "
        "gyro and accelerometer channel, with the table's turn, the Earth rate and gravity fitted out "
        "through the encoder angle, and the IEEE Std 952 terms fitted to it (least squares of "
        "sigma^2 = sum A_k tau^k, k = -2..1, every A_k >= 0). A gyro's quantization holds the encoder's "
        "resolution too, seen through the axis's share of the turn."])]
    blocks.append(_embed(plot_allan(figures, pooled),
                         "Allan deviation of the gyros and the accelerometers (mean of the three sensors' "
                         "variances): each log (grey), the pooled curve (points), the fitted model (line) and "
                         "each fitted term on its own (dashed, with its slope).",
                         "Allan deviation against cluster time, log-log, with slope lines"))
    blocks.append(_table(["pooled term", "x", "y", "z"], _term_rows(pooled), cls="num"))
    cols = list(NOISE_COLUMNS)
    rows = [[n, *(_fmt(f.columns()[c], 3) for c in cols)] for n, f in zip(names, figures)]
    rows.append(["pooled", *(_fmt(pooled.columns()[c], 3) for c in cols)])
    blocks.append(_table(["log", *cols], rows, keys=[*names, "pooled"], cls="num"))
    data = {"pooled": pooled.columns(), "logs": {n: f.columns() for n, f in zip(names, figures)},
            "tau_s": pooled.tau.tolist()}
    return Section("Sensor noise (Allan deviation, IEEE Std 952)", tuple(b for b in blocks if b is not None), data)
