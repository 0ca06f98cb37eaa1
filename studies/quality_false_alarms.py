"""False alarms of the raw-log quality checks (``hse_opt.align.quality.assess``) on clean
simulated logs: per system and duration, the fraction of logs with any finding, and per check
the logs it fired on (issue 25, item 3).

Every log is a clean simulation (``hse_opt.sim.generate``): no fault is injected, so every
finding is a false alarm (a repair changes a good log, a refusal loses it). Each log draws its
rate uniformly from 10-60 deg/s in either sense, its azimuth, start time and tilt at random; its
duration is the case's, or one revolution and a second when that is longer (a 20-s log at
10 deg/s cannot hold a revolution). Systems: the paper-like default, coarse pulses (1 arcsec,
1e-3 m/s), the noise-free one, the ideal one, a high angle random walk (0.05 deg/sqrt(h) gyros,
50 ug/sqrt(Hz) accelerometers), and a coarse encoder (20 arcsec, no table jitter).

The design figure (module docstring of ``hse_opt.align.quality``): a per-log false-alarm
probability of at most 1e-4 for a log of any length. The check below is a one-sided binomial
one: with ``F`` false alarms in ``N`` logs, the rate is consistent with 1e-4 when
P(X >= F | N, 1e-4) >= 1e-3 (for ``N`` = 1,200 that is ``F`` <= 1).

    python studies/quality_false_alarms.py            # CI size: 20 seeds a case, 20-s and 60-s logs
    python studies/quality_false_alarms.py --full     # 200 seeds a case, 20 s to 10 min (3,600 logs)
    python studies/quality_false_alarms.py --full --resolution-unknown

The checks are given each system's encoder resolution (``assess(...,
encoder_counts_per_rev=...)``, as the calibration file's ``encoder.counts_per_rev`` or a
mapping file's gives it); ``--resolution-unknown`` leaves it out (the checks then see the
encoder's quantum only in the data).

Prints the table (logs with a finding / logs) and the findings of the first few false alarms.
"""
import argparse
import re
import sys
import time
from collections import Counter

import numpy as np
from scipy import stats

from hse_opt import units
from hse_opt.align.quality import assess
from hse_opt.sim import RunSpec, TruthConfig, generate

#: the design figure: false-alarm probability per clean log
DESIGN_RATE = 1e-4


def systems():
    """The clean systems of the sweep, by name."""
    truth = TruthConfig.default()
    return {
        "default": truth,
        "coarse pulses": truth.updated({"gyro": {"pulse_arcsec": 1.0, "arw_dph_rthz": 0.05},
                                        "accel": {"pulse_mps": 1e-3, "vrw_ug_rthz": 20.0}}),
        "noise-free": truth.noise_free(),
        "ideal": TruthConfig.ideal(),
        "high ARW": truth.updated({"gyro": {"arw_dph_rthz": 0.05}, "accel": {"vrw_ug_rthz": 50.0}}),
        "coarse encoder": truth.updated({"encoder": {"resolution_arcsec": 20.0}, "table": {"jitter_arcsec": 0.0}}),
    }


def check_of(finding):
    """The check a finding comes from, finer than ``Finding.check`` for the channel check."""
    d = finding.detail
    if finding.check != "channel":
        return f"{finding.check} {finding.action}"
    for key in ("saturated", "stuck", "does not follow", "spike", "the gyros turn", "specific force"):
        if key in d:
            return f"channel {re.sub(' ', '-', key)}"
    return "channel other"


def run_case(truth, duration, seeds, case_seed, resolution_known=True):
    """Findings of ``assess`` on ``seeds`` clean logs: (list of (spec, seed, Quality), seconds);
    ``resolution_known``: the checks are given the encoder's counts per revolution."""
    rng = np.random.default_rng(case_seed)
    res = truth.encoder.resolution
    counts = 2.0 * np.pi / res if resolution_known and res > 0 else None
    out, spent = [], 0.0
    for seed in range(seeds):
        rate = float(rng.choice([-1.0, 1.0]) * rng.uniform(10.0, 60.0))
        spec = RunSpec(rate=rate * units.DEG_PER_S, azimuth=float(rng.uniform(0.0, 2.0 * np.pi)),
                       duration=max(duration, 360.0 / abs(rate) + 1.0), t_start=float(rng.uniform(0.0, 7200.0)),
                       tilt=tuple(rng.normal(0.0, 1e-3, 2)))
        log = generate(truth, spec, np.random.default_rng(seed))
        t0 = time.perf_counter()
        q = assess(log, encoder_counts_per_rev=counts)
        spent += time.perf_counter() - t0
        out.append((spec, seed, q))
    return out, spent


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--full", action="store_true", help="200 seeds a case, durations 20, 120 and 600 s")
    ap.add_argument("--seeds", type=int, default=None, help="seeds a case (default 20, or 200 with --full)")
    ap.add_argument("--resolution-unknown", action="store_true",
                    help="do not give the checks the encoder's counts per revolution")
    args = ap.parse_args(argv)
    seeds = args.seeds or (200 if args.full else 20)
    durations = (20.0, 120.0, 600.0) if args.full else (20.0, 60.0)
    cases = [(name, truth, d) for name, truth in systems().items() for d in durations]
    checks = Counter()
    total_logs = total_bad = 0
    examples = []
    print(f"{'system':<15}{'duration':>10}{'logs':>7}{'with a finding':>16}   checks that fired")
    for i, (name, truth, d) in enumerate(cases):
        res, spent = run_case(truth, d, seeds, [i, int(d)], resolution_known=not args.resolution_unknown)
        fired = Counter()
        bad = 0
        for spec, seed, q in res:
            kinds = {check_of(f) for f in q.findings}
            fired.update(kinds)
            if kinds:
                bad += 1
                if len(examples) < 8:
                    examples.append(f"{name}, {spec.duration:g} s, {spec.rate / units.DEG_PER_S:+.4g} deg/s, "
                                    f"seed {seed}: {q.summary()[:240]}")
        checks.update(fired)
        total_logs += len(res)
        total_bad += bad
        what = ", ".join(f"{k} {v}" for k, v in sorted(fired.items())) or "-"
        print(f"{name:<15}{d:>9g}s{len(res):>7}{bad:>10} ({bad / len(res):5.1%})   {what}"
              f"   [assess {1e3 * spent / len(res):.2f} ms a log]")
    print(f"\nall: {total_bad} of {total_logs} clean logs with a finding ({total_bad / total_logs:.2%})")
    for k, v in sorted(checks.items()):
        print(f"  {k:<28}{v:>6} logs ({v / total_logs:.2%})")
    for e in examples:
        print("  e.g. " + e)
    p = float(stats.binom.sf(total_bad - 1, total_logs, DESIGN_RATE)) if total_bad else 1.0
    print(f"\nP(>= {total_bad} false alarms in {total_logs} logs | rate {DESIGN_RATE:g} a log) = {p:.3g}")
    if p < 1e-3:
        print(f"FAIL: the false-alarm rate exceeds the design figure {DESIGN_RATE:g} a log")
        return 1
    print(f"OK: consistent with at most {DESIGN_RATE:g} false alarms a log (one-sided binomial, level 1e-3)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
