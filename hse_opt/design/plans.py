"""Plans as a stand sees them: the paper's plan, and a plan's runs grouped by setting in words."""
from __future__ import annotations

import numpy as np

from .. import units
from ..data import Plan
from .space import Costs


def paper_plan(azimuth0=0.0, costs=None, azimuths_deg=(0.0, 91.8795, 181.2953, 272.8711)):
    """The paper's plan: 3 alignments at each of 20, 40, 60 deg/s at one position, then 3 at
    40 deg/s at each of 4 stand azimuths (Table 1's, shifted by ``azimuth0``, rad; the one
    position is Table 1's first): 21 ten-minute alignments, start times from ``costs``."""
    costs = costs or Costs()
    rate = np.array([20.0] * 3 + [40.0] * 3 + [60.0] * 3 + [40.0] * 12) * units.DEG_PER_S
    az = np.concatenate([np.zeros(9), np.repeat(np.asarray(azimuths_deg) * units.DEG, 3)]) + azimuth0
    dur = np.full(rate.size, 600.0)
    return Plan(run=np.arange(1, rate.size + 1), rate=rate, azimuth=np.mod(az, 2 * np.pi),
                t_start=costs.schedule(rate, az, np.zeros(rate.size), np.zeros(rate.size), dur), duration=dur)


def plan_lines(plan):
    """Runs grouped by setting, in order: ``runs 1-5  -60 deg/s  az 294.62 deg ...``."""
    cols = plan.to_columns()
    # at an unsurveyed position (a field plan) the azimuth holds the heading to set: said so
    field = np.zeros(len(plan), bool) if plan.surveyed is None else ~np.asarray(plan.surveyed, bool)
    keys = [cols["rate_dps"], np.mod(np.degrees(np.asarray(plan.azimuth, float)), 360.0), cols["duration_s"],
            field.astype(float)]
    if "tilt_x_arcsec" in cols:
        keys += [cols["tilt_x_arcsec"], cols["tilt_y_arcsec"]]
    key = np.round(np.column_stack(keys), 6)
    lines, i, n = [], 0, key.shape[0]
    while i < n:
        j = i
        while j + 1 < n and np.array_equal(key[j + 1], key[i]):
            j += 1
        ids = f"{plan.run[i]}" if i == j else f"{plan.run[i]}-{plan.run[j]}"
        where = (f"heading ~{key[i, 1]:.0f} deg" + (f" ({plan.position[i]})" if plan.position is not None else "")
                 if key[i, 3] else f"azimuth {key[i, 1]:8.3f} deg")
        text = (f"  runs {ids:<8} {key[i, 0]:+8.3f} deg/s  {where}  {key[i, 2]:g} s"
                f"  from {plan.t_start[i] / units.HOUR:6.3f} h")
        if key.shape[1] > 4:
            text += f"  tilt ({key[i, 4]:+.0f}, {key[i, 5]:+.0f}) arcsec"
        lines.append(text)
        i = j + 1
    return lines

