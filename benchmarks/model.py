"""Benchmark of the symbolic model (issue 2, item 10).

Prints: operating points per second for the averaged heading-error model over 1,000,000
points (paper model and the whole catalogue; compiled C after a one-off compile, kept in the
compile cache: :mod:`hse_opt.compile_cache`), build and first-call times, points per second of
the whole catalogue in batches of 100, 1,000 and 4,000 (issue 19: >= 1e6 at 1,000), and the
time of the measurement model's Jacobian over 10,000 runs x all catalogue parameters.

Run: taskset -c 0 python benchmarks/model.py   (times are CPU times of this process: one core,
CasADi's VM and compiled code use no threads; a shared machine moves them less than wall
time); build and first-call times are wall times (the compiler runs in its own process).
"""
import time

import numpy as np

from hse_opt import units
from hse_opt.model import Model
from hse_opt.validation.twins import effect_names

CATALOGUE = list(effect_names())  # the whole catalogue and the simulator's covariate


def runs(m, n, rng):
    return m.inputs(rate=rng.choice([-1, 1], n) * rng.uniform(20, 60, n) * units.DEG_PER_S,
                    azimuth=rng.uniform(0, 2 * np.pi, n), latitude=0.49, duration=600.0,
                    t_start=rng.uniform(0, 7200, n), pitch=rng.uniform(-1e-3, 1e-3, n),
                    roll=rng.uniform(-1e-3, 1e-3, n), covariates={"temp_c": rng.normal(25, 2, n)})


def best_of(f, k=3):
    times = []
    for _ in range(k):
        t = time.process_time()
        f()
        times.append(time.process_time() - t)
    return min(times)


def main():
    rng = np.random.default_rng(0)
    for label, effects in (("paper model (hse)", ["hse"]), ("whole catalogue", CATALOGUE)):
        t = time.perf_counter()
        model = Model(effects)
        m = model.measurement()
        build = time.perf_counter() - t
        p = m.nominal
        X = runs(m, 1_000_000, rng)
        t = time.perf_counter()
        m.predict(p, X)  # first call compiles the mapped Function (or loads it from the cache)
        first = time.perf_counter() - t
        run = best_of(lambda: m.predict(p, X))
        print(f"{label}: {len(m.names)} parameters, averaging degree {m.degree}")
        print(f"  build (symbolic model + Functions): {build * 1e3:.1f} ms; "
              f"first 1e6-point call incl. compile or cache load: {first:.2f} s")
        print(f"  1,000,000 operating points: {run:.3f} s -> {1e6 / run:.3g} points/s (target >= 1e6)")
    print("small batches, whole catalogue (compiled chunk from 1,000 runs; repeated calls):")
    for n in (100, 1_000, 4_000):
        X = runs(m, n, rng)
        m.predict(p, X)
        k = max(1, 100_000 // n)
        run = best_of(lambda: [m.predict(p, X) for _ in range(k)], 5) / k
        print(f"  {n:5d} points: {run * 1e3:7.3f} ms a call -> {n / run:.3g} points/s"
              + ("   (target >= 1e6)" if n == 1_000 else ""))
    X = runs(m, 10_000, rng)
    m.jacobian(p, X)
    jac = best_of(lambda: m.jacobian(p, X), 5)
    print(f"Jacobian, 10,000 runs x {len(m.names)} catalogue parameters: {jac * 1e3:.1f} ms (target < 50 ms)")


if __name__ == "__main__":
    main()
