"""Experiment-design benchmark (issue 19, items 1-2): every criterion, model and design space.

The matrix criteria {D, A, E, c:lambda2, protect (the default)} x models {hse, hse+axis_bias, hse+axis_bias+sync_delay,
hse+warmup} x spaces {the paper's limits (20-60 deg/s, one sense, no fixture), both senses, both
senses with a 0.5-deg tilt fixture}, each at 10,368 candidate runs, budget 5 h. Each cell prints
the time of the whole design (candidate Jacobians, approximate design with its certificate,
rounding, setup-aware pruning, IPOPT refinement, run order), the time of the convex programs,
the certified efficiency of the approximate design, the efficiency of the rounded plan (before
and after refinement), the support of the approximate design and the runs of the plan; the worst
cell (by CPU time) is named at the end. A protecting criterion's cell also prints the plan's
sigma of lambda2 and the diagnosis' power against each effect outside the model. Target: every
cell < 10 s on one core. The CPU time of the process is printed beside the wall time: on a
shared machine it is the figure that does not depend on what else runs.

    taskset -c 0 python benchmarks/design.py
    taskset -c 0 python benchmarks/design.py --criteria E --models hse,axis_bias --timeout 120
    taskset -c 0 python benchmarks/design.py --criteria protect --spaces paper --models hse   (the default design)

The candidate grids (10,368 each): paper's limits 144 rates x 72 azimuths; both senses
2 x 72 rates x 72 azimuths; tilt fixture 2 x 8 rates x 72 azimuths x 9 settings. For
hse+warmup time since power-on is a factor (4 slots), so the rate levels are 4x fewer.
"""
import argparse
import signal
import time

from hse_opt import units
from hse_opt.design import DesignSpace, design

MODELS = ("hse", "hse,axis_bias", "hse,axis_bias,sync_delay", "hse,warmup")
CRITERIA = ("D", "A", "E", "c:lambda2", "protect")
SPACES = ("paper", "senses", "tilt")
WARMUP = {"warmup_amp": -90.0, "warmup_tau": 1500.0}


def space(kind, slots):
    """The 10,368-candidate design space of one column of the matrix."""
    n_rates = {"paper": 144, "senses": 72, "tilt": 8}[kind] // slots
    return DesignSpace(n_rates=n_rates, reverse=kind != "paper", azimuth_step=5 * units.DEG,
                       max_tilt=0.5 * units.DEG if kind == "tilt" else 0.0, time_slots=slots)


class Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise Timeout


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--criteria", default=",".join(CRITERIA), help="comma-separated (default all)")
    parser.add_argument("--models", default=";".join(MODELS), help="';'-separated effect lists (default all)")
    parser.add_argument("--spaces", default=",".join(SPACES), help="of paper,senses,tilt (default all)")
    parser.add_argument("--timeout", type=int, default=0, help="give up a cell after this many s (0: never)")
    args = parser.parse_args()
    design("hse", "D", budget=5 * 3600.0, space=DesignSpace(reverse=True))  # imports, CasADi, cvxpy warm-up
    signal.signal(signal.SIGALRM, _alarm)
    print(f"{'model':<26}{'space':<8}{'criterion':<11}{'candidates':>11}{'time':>9}{'cpu':>9}{'convex':>9}"
          f"{'certified':>11}{'rounding':>10}{'final':>8}{'support':>9}{'runs':>6}")
    worst = low = None
    for model in args.models.split(";"):
        slots = 4 if "warmup" in model else 1
        nominal = WARMUP if "warmup" in model else None
        for kind in args.spaces.split(","):
            sp = space(kind, slots)
            n = len(sp.candidates())
            for crit in args.criteria.split(","):
                signal.alarm(args.timeout)
                t0, c0 = time.perf_counter(), time.process_time()
                try:
                    r = design(model, crit, budget=5 * 3600.0, space=sp, nominal=nominal)
                except Timeout:
                    print(f"{model:<26}{kind:<8}{crit:<11}{n:>11}  > {args.timeout} s (timed out)")
                    cell = (float(args.timeout), f"{model} / {kind} / {crit} (timed out)")
                    worst = max(worst or cell, cell)
                    continue
                finally:
                    signal.alarm(0)
                total, cpu = time.perf_counter() - t0, time.process_time() - c0
                a = r.approximate
                print(f"{model:<26}{kind:<8}{crit:<11}{n:>11}{total:>7.2f} s{cpu:>7.2f} s{a.solve_time:>7.2f} s"
                      f"{a.certified_efficiency:>11.6f}{r.rounding_efficiency:>10.4f}{r.efficiency:>8.4f}"
                      f"{a.support.size:>9}{r.n_runs:>6}")
                if r.protection:
                    print(f"{'':<26}sigma lambda2 {r.std_of('lambda2'):.4g} arcsec; power: " + ", ".join(
                        f"{p.effect} {'-' if p.power is None else format(p.power, '.3f')}"
                        f"{'' if p.protected else ' (not protected)'}" for p in r.protection))
                worst = max(worst or (cpu, ""), (cpu, f"{model} / {kind} / {crit} (wall {total:.2f} s)"))
                low = min(low or (2.0, ""), (min(a.certified_efficiency, r.rounding_efficiency),
                                             f"{model} / {kind} / {crit}"))
    if worst:
        print(f"worst cell: {worst[1]}, CPU {worst[0]:.2f} s (target: every cell < 10 s CPU on one core)")
    if low:
        print(f"lowest certified or rounding efficiency: {low[1]}, {low[0]:.4f} (target: >= 0.99)")


if __name__ == "__main__":
    main()
