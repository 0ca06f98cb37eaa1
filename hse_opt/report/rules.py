"""What the report's plots are drawn against and grouped by: the factors a residual can follow,
groups of nearby values (stand azimuths, rates) and the tilt setups of a campaign."""
from __future__ import annotations

import numpy as np

from .. import units
from ..factors import campaign_factors


def factors(runs, derived=(), resolution=None):
    """The factors a residual is plotted against, as ``(key, label, values)``, values in the
    edge units of the label: those that vary beyond their resolution, never a column derived
    from the heading error (:func:`hse_opt.factors.campaign_factors` has the rules).

    Parameters
    ----------
    runs : hse_opt.data.Runs
    derived : sequence of str
        Covariate columns derived from the heading error (besides those named ``heading...``).
    resolution : mapping, optional
        Resolutions overriding :data:`hse_opt.factors.RESOLUTION`.

    Returns
    -------
    list of (str, str, numpy.ndarray of shape (n,))
    """
    return [(f.key, f.label, f.values) for f in campaign_factors(runs, derived, resolution).varying]


def _groups(values, tol):
    """Group labels of ``values`` (neighbours closer than ``tol`` share one), numbered in
    increasing order, and the group means."""
    order = np.argsort(values)
    v = np.asarray(values)[order]
    sorted_labels = np.cumsum(np.r_[True, np.diff(v) > tol]) - 1
    labels = np.empty_like(sorted_labels)
    labels[order] = sorted_labels
    return labels, np.bincount(sorted_labels, v) / np.bincount(sorted_labels)


#: runs whose leveled tilts (pitch, roll) differ by less than this belong to one tilt setup
#: (a fixture setting or the stand's own tilt): stand tilts that turn with azimuth stay
#: well inside it, deliberate fixture tilts (>= 0.1 deg) well outside
SETUP_TOL = 300 * units.ARCSEC


def tilt_setups(runs):
    """Runs grouped by tilt setup (fixture setting), as ``[(mask, label)]``.

    Runs without pitch/roll form one setup. Otherwise runs join the first setup whose mean
    pitch and roll are both within :data:`SETUP_TOL` of theirs.
    """
    n = len(runs)
    if runs.pitch is None:
        return [(np.ones(n, bool), "tilt not recorded")]
    tilt = np.column_stack([runs.pitch, runs.roll])
    labels = np.full(n, -1)
    centres = []
    for i in range(n):
        for k, c in enumerate(centres):
            if np.all(np.abs(tilt[i] - c) < SETUP_TOL):
                labels[i] = k
                break
        else:
            centres.append(tilt[i])
            labels[i] = len(centres) - 1
        centres[labels[i]] = tilt[labels == labels[i]].mean(axis=0)
    out = []
    for k in range(len(centres)):
        m = labels == k
        p, r = tilt[m].mean(axis=0) / units.ARCSEC
        out.append((m, f"pitch {p:.0f}, roll {r:.0f} arcsec"))
    return out


def _tilt_of_azimuth(runs, mask):
    """pitch/roll (rad) as functions of the stand azimuth within one tilt setup: a first
    harmonic fitted to the runs' own leveling (a stand tilt fixed in n turns with azimuth,
    one fixed in b0 does not), or the mean when fewer than three azimuths were visited."""
    if runs.pitch is None:
        return lambda az: (np.zeros_like(az), np.zeros_like(az))
    az, pitch, roll = runs.azimuth[mask], runs.pitch[mask], runs.roll[mask]
    _, centres = _groups(np.mod(az, 2 * np.pi), 1 * units.DEG)
    if centres.size >= 3:
        A = np.column_stack([np.ones_like(az), np.cos(az), np.sin(az)])
        cp = np.linalg.lstsq(A, pitch, rcond=None)[0]
        cr = np.linalg.lstsq(A, roll, rcond=None)[0]

        def tilt(a):
            B = np.column_stack([np.ones_like(a), np.cos(a), np.sin(a)])
            return B @ cp, B @ cr
        return tilt
    mp, mr = float(np.mean(pitch)), float(np.mean(roll))
    return lambda a: (np.full_like(a, mp), np.full_like(a, mr))


#: at most this many tilt setups get panels of their own
_MAX_SETUPS = 3
