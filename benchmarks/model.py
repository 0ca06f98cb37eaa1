"""Benchmark of the symbolic model (issue 2, item 10).

Prints: operating points per second for the averaged heading-error model over 1,000,000
points (paper model and the whole catalogue; CasADi jit after a one-off compile), build and
compile times, and the time of the measurement model's Jacobian over 10,000 runs x all
catalogue parameters.

Run: python benchmarks/model.py   (one core: OMP/MKL threads are not used by CasADi's VM/jit)
"""
import time

import numpy as np

from hse_opt import units
from hse_opt.model import Model

CATALOGUE = ["hse", "axis_bias", "sync_delay", "scale_nonlinearity", "warmup", "azimuth_harmonic2",
             "encoder_harmonic", "covariate:temp_c"]


def runs(m, n, rng):
    return m.inputs(rate=rng.choice([-1, 1], n) * rng.uniform(20, 60, n) * units.DEG_PER_S,
                    azimuth=rng.uniform(0, 2 * np.pi, n), latitude=0.49, duration=600.0,
                    t_start=rng.uniform(0, 7200, n), pitch=rng.uniform(-1e-3, 1e-3, n),
                    roll=rng.uniform(-1e-3, 1e-3, n), covariates={"temp_c": rng.normal(25, 2, n)})


def best_of(f, k=3):
    times = []
    for _ in range(k):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
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
        m.predict(p, X)  # first call compiles the mapped Function (CasADi jit, gcc -O3)
        first = time.perf_counter() - t
        run = best_of(lambda: m.predict(p, X))
        print(f"{label}: {len(m.names)} parameters, averaging degree {m.degree}")
        print(f"  build (symbolic model + Functions): {build * 1e3:.1f} ms; "
              f"first 1e6-point call incl. jit compile: {first:.2f} s")
        print(f"  1,000,000 operating points: {run:.3f} s -> {1e6 / run:.3g} points/s (target >= 1e6)")
    X = runs(m, 10_000, rng)
    m.jacobian(p, X)
    jac = best_of(lambda: m.jacobian(p, X), 5)
    print(f"Jacobian, 10,000 runs x {len(m.names)} catalogue parameters: {jac * 1e3:.1f} ms (target < 50 ms)")


if __name__ == "__main__":
    main()
