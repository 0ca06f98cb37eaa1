"""Experiment-design benchmark (issue 5, item 4): prints its figures.

The approximate design over >= 10,000 candidate runs (8 rate levels x 2 senses x 72 azimuths x
9 tilt-fixture settings = 10,368; and a 4x larger grid) for the model extended by axis_bias and
sync_delay, each criterion: time of the convex programs (column generation with the
equivalence-theorem certificate over every candidate), its certified efficiency, and the time
of the whole design (candidate Jacobians, rounding, setup-aware pruning, IPOPT refinement,
run order). Target: the approximate design of >= 10,000 candidates in < 10 s on one core.

    taskset -c 0 python benchmarks/design.py
    taskset -c 0 python benchmarks/design.py --quick      (the 10,368-candidate grid only)
"""
import argparse
import time

from hse_opt import units
from hse_opt.design import DesignSpace, design


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="only the 10,368-candidate grid")
    args = parser.parse_args()
    grids = [("8 rates x 2 senses x 72 azimuths x 9 tilts", dict(n_rates=8, azimuth_step=5 * units.DEG))]
    if not args.quick:
        grids.append(("16 rates x 2 senses x 144 azimuths x 9 tilts",
                      dict(n_rates=16, azimuth_step=2.5 * units.DEG)))
    design("hse", "D", budget=5 * 3600.0, space=DesignSpace(reverse=True))  # imports, CasADi, cvxpy warm-up
    for label, kw in grids:
        space = DesignSpace(reverse=True, max_tilt=0.5 * units.DEG, **kw)
        n = len(space.candidates())
        print(f"{n} candidates ({label}), model hse+axis_bias+sync_delay, budget 5 h:")
        print(f"  {'criterion':<11}{'convex programs':>16}{'rounds':>8}{'active':>8}{'certified':>12}"
              f"{'whole design':>14}{'runs':>6}{'efficiency':>12}")
        for crit in ("D", "A", "E", "c:lambda2"):
            t0 = time.perf_counter()
            r = design("hse,axis_bias,sync_delay", crit, budget=5 * 3600.0, space=space)
            total = time.perf_counter() - t0
            a = r.approximate
            print(f"  {crit:<11}{a.solve_time:>14.2f} s{a.iterations:>8}{a.n_active:>8}"
                  f"{a.certified_efficiency:>12.6f}{total:>12.2f} s{r.n_runs:>6}{r.efficiency:>12.4f}")
    print("target: the approximate design of >= 10,000 candidates in < 10 s on one core (taskset -c 0)")


if __name__ == "__main__":
    main()
