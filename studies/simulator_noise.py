"""Noise on: the simulator's heading scatter against the alignment filter's own 1-sigma, the
angle-random-walk prediction, and the repeat scatter of the paper's Table 1 (issue 3, item 5).

The default (paper-like) system, noise and quantization on, 200 ten-minute alignments at
40 deg/s at one stand position, each with its own seed. Three independent numbers for the
10-minute heading scatter:

* the Monte-Carlo scatter of the simulated alignments (raw 500 Hz data through the
  processor), with its standard error ``s / sqrt(2 (n - 1))`` (5 % for 200 runs);
* the filter's own 1-sigma (its covariance, from the noise it is tuned with);
* the gyrocompass limit ``N / (w_ie cos L sqrt(T))`` of the angle random walk N, the
  gyros' own and the pulse quantization's, ``q |Omega| sqrt(dt / 12)`` (the counters' bounded
  remainder, dithered by the table jitter, turned into b0 sample by sample), added in
  quadrature;
* the paper's repeat scatter: Table 1, pooled within positions 2-4 (position 1 is the
  cold start, with the warm-up drift in it).

Run: python studies/simulator_noise.py [--runs 200] [--jobs 2]
"""
import argparse
import math
import time

import numpy as np

from hse_opt import units
from hse_opt.datasets import paper_table1
from hse_opt.frames import EARTH_RATE
from hse_opt.sim import TruthConfig, run_campaign

p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
p.add_argument("--runs", type=int, default=200)
p.add_argument("--jobs", type=int, default=2)
args = p.parse_args()

truth = TruthConfig.default()
T = 600.0
plan = [{"run": i, "rate_dps": 40.0, "azimuth_deg": 30.0, "t_start_s": 7200.0, "duration_s": T}
        for i in range(args.runs)]
t0 = time.perf_counter()
runs = run_campaign(plan, truth, seed=20130401, jobs=args.jobs)
elapsed = time.perf_counter() - t0

err = runs.heading_err / units.ARCSEC
filt = runs.heading_std / units.ARCSEC
scatter = err.std(ddof=1)
se = scatter / math.sqrt(2 * (len(err) - 1))
rate = 40.0 * units.DEG_PER_S
n_quant = truth.gyro.pulse * rate * math.sqrt(truth.timing.sample_period / 12.0)
n_total = math.hypot(truth.gyro.arw, n_quant)
arw = n_total / (EARTH_RATE * math.cos(truth.site.latitude) * math.sqrt(T)) / units.ARCSEC

table = paper_table1()
pos = table.position.astype(int)
groups = [table.heading_err[pos == k] / units.ARCSEC for k in (2, 3, 4)]
ss = sum(((g - g.mean()) ** 2).sum() for g in groups)
paper = math.sqrt(ss / sum(len(g) - 1 for g in groups))

print(f"{len(err)} simulated 10-minute alignments at 40 deg/s (default system), "
      f"{elapsed:.1f} s with --jobs {args.jobs}")
print(f"  Monte-Carlo heading scatter   {scatter:6.2f} arcsec (+- {se:.2f}, 1 s.e.)")
print(f"  filter's own 1-sigma (mean)   {filt.mean():6.2f} arcsec")
print(f"  ARW prediction N/(w cosL vT)  {arw:6.2f} arcsec   (N = {truth.gyro.arw / units.DEG_PER_H:.4f} gyro (+) "
      f"{n_quant / units.DEG_PER_H:.4f} pulses = {n_total / units.DEG_PER_H:.4f} deg/h/rtHz)")
print(f"  paper Table 1 repeat scatter  {paper:6.2f} arcsec   (positions 2-4 pooled, 6 dof)")
print(f"  mean heading error            {err.mean():6.2f} arcsec (the default system's HSE + offsets)")
print(f"  ratios: scatter/filter {scatter / filt.mean():.3f}, scatter/ARW {scatter / arw:.3f}, "
      f"filter/ARW {filt.mean() / arw:.3f}, filter/paper {filt.mean() / paper:.3f}")

assert len(err) >= 200, "the comparison needs at least 200 seeds"
assert abs(scatter / filt.mean() - 1) < 0.15, "scatter vs the filter's 1-sigma"
assert abs(scatter / arw - 1) < 0.15, "scatter vs the ARW prediction"
assert abs(filt.mean() / arw - 1) < 0.15, "filter 1-sigma vs the ARW prediction"
assert np.ptp(filt) < 1e-6 * filt.mean(), "one configuration, one filter sigma"
assert abs(paper - 7.90) < 0.01 and abs(filt.mean() / paper - 1) < 0.05, "default system vs Table 1"
assert abs(scatter / paper - 1) < 0.15
print("OK: scatter, filter 1-sigma and ARW prediction agree within 15 %")
