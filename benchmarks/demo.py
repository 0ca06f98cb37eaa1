"""Demo benchmark (issue 7): prints its figures.

The target: ``hse-opt demo`` in under one minute on one core, report included. Run it pinned
to one core, in a fresh process (imports count: a user pays them):

    taskset -c 0 python benchmarks/demo.py              # one full demo through the CLI
    taskset -c 0 python benchmarks/demo.py --seeds 20   # also: which effect each seed hides,
                                                        # whether the diagnosis names it

The first figure is the wall time of ``hse_opt.cli.main(["demo", ...])`` from a cold start of
this process, imports included, and the step times the demo records. With ``--seeds N`` the
chain (without the report) runs for seeds 0..N-1 and the hidden and named effects are listed.
"""
import argparse
import contextlib
import io
import json
import os
import tempfile
import time

T_PROCESS = time.perf_counter()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--seeds", type=int, default=0, help="also run the chain for seeds 0..N-1")
    args = ap.parse_args()
    if hasattr(os, "sched_getaffinity"):
        print(f"cores available to this process: {len(os.sched_getaffinity(0))}")

    from hse_opt.cli import main as cli
    with tempfile.TemporaryDirectory() as tmp:
        buf = io.StringIO()
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(buf):
            status = cli(["demo", "--seed", str(args.seed), "--out", tmp, "--json", "--no-progress"])
        wall = time.perf_counter() - T_PROCESS
        cpu = time.process_time()
        assert status == 0
        data = json.loads(buf.getvalue())
    print(f"hse-opt demo --seed {args.seed}: {wall:.1f} s wall from process start "
          f"({time.perf_counter() - t0:.1f} s in the command), "
          f"{cpu:.1f} s CPU (target < 60 s on one core)")
    print("  steps: " + ", ".join(f"{k} {v:.2f} s" for k, v in data["seconds"].items()))
    print(f"  hidden {data['hidden_effect']}, named {data['named_effect']}, "
          f"RMS {data['before']['rms_arcsec']:.1f} -> "
          f"{(data['after'] or {}).get('rms_arcsec', float('nan')):.1f} arcsec "
          f"(noise {data['noise_arcsec']:.1f})")

    if args.seeds:
        from hse_opt.demo import run_demo
        found = 0
        for seed in range(args.seeds):
            t0 = time.perf_counter()
            r = run_demo(seed)
            found += r.found
            after = r.fit_after.rms_arcsec if r.fit_after is not None else float("nan")
            print(f"  seed {seed:3d}: hidden {r.hidden.name:<20} named {str(r.named):<20} "
                  f"RMS {r.fit_before.rms_arcsec:5.1f} -> {after:5.1f} arcsec  "
                  f"{time.perf_counter() - t0:5.1f} s")
        print(f"named the hidden effect in {found} of {args.seeds} seeds")


if __name__ == "__main__":
    main()
