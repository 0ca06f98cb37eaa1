"""Two source trees of hse_opt timed against each other on issue 25's figure: what the quality
checks and the Allan analysis add to ``align`` of a 10-minute 500 Hz log (the first figure of
``benchmarks/align.py``), in alternating fresh processes so that both see the same machine
state (on a shared machine that state moves the figure by 10 % within an hour; a paired
comparison does not). Each process runs 80 cycles of align, then block sums, checks and Allan
analysis, BLAS on one thread as the command line loads it, and prints the medians of their CPU
times.

    python benchmarks/align_pair.py OLD_TREE NEW_TREE --rounds 4
    git worktree add --detach /tmp/old 4e375f7 && python benchmarks/align_pair.py /tmp/old .
"""
import argparse
import os
import subprocess
import sys

_CYCLE = r"""
import statistics, sys, time
import hse_opt
print(hse_opt.__file__, file=sys.stderr)
from hse_opt.app.cli import _one_blas_thread
_one_blas_thread()
import numpy as np
from hse_opt.align.noise import block_sums, noise_from_log
from hse_opt.align.quality import assess
from hse_opt.sim import RunSpec, TruthConfig, align, align_config_from_truth, generate
from hse_opt.units import DEG_PER_S
truth = TruthConfig.default()
log = generate(truth, RunSpec(rate=40 * DEG_PER_S, azimuth=0.3, duration=600.0, t_start=7200.0),
               np.random.default_rng(0))
cfg = align_config_from_truth(truth)
ta, tc = [], []
for i in range(82):
    t0 = time.process_time(); align(log, cfg); t1 = time.process_time()
    s = block_sums(log); q = assess(log, sums=s); noise_from_log(q.log, sums=s); t2 = time.process_time()
    if i >= 2:
        ta.append(t1 - t0); tc.append(t2 - t1)
print(statistics.median(ta), statistics.median(tc))
"""


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("trees", nargs="+", help="source trees (repository roots) to compare")
    ap.add_argument("--rounds", type=int, default=4)
    args = ap.parse_args()
    rows = {tree: [] for tree in args.trees}
    for r in range(args.rounds):
        for tree in args.trees:
            root = os.path.abspath(tree)               # (run there: "-c" puts the working directory first)
            out = subprocess.run([sys.executable, "-c", _CYCLE], cwd=root, env=dict(os.environ, PYTHONPATH=root),
                                 check=True, capture_output=True, text=True)
            if not out.stderr.strip().startswith(root):
                sys.exit(f"align_pair: {tree} imported hse_opt from {out.stderr.strip()}; allowed: a tree that holds "
                         "the hse_opt package")
            a, c = map(float, out.stdout.split())
            rows[tree].append(c / a)
            print(f"round {r + 1}: {tree}: align {1e3 * a:.2f} ms CPU, checks + Allan {1e3 * c:.2f} ms: "
                  f"{100 * c / a:.1f} %", flush=True)
    for tree, ratios in rows.items():
        print(f"{tree}: checks + Allan / align {100 * min(ratios):.0f}-{100 * max(ratios):.0f} % over "
              f"{len(ratios)} rounds (target <= 50 %)")


if __name__ == "__main__":
    main()
