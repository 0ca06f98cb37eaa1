"""The ``hse-opt`` command line.

Exit status: 0 success, 2 bad input or data that cannot answer the question (one line on
stderr naming what is wrong and what is allowed), 1 anything else.
"""
import argparse
import dataclasses
import json
import sys

EXAMPLES = {
    "demo": "example: hse-opt demo --json",
}


def _demo(args):
    from .model.paper import reproduce, summary

    numbers = reproduce()
    if args.json:
        print(json.dumps(dataclasses.asdict(numbers), indent=2))
    else:
        print("hse-opt demo: the paper's model evaluated with the symbolic CasADi model")
        print("\n".join(summary(numbers)))
    return 0


def build_parser():
    parser = argparse.ArgumentParser(
        prog="hse-opt",
        description="Calibration and compensation of the heading-sensitive error of a "
                    "constant-rate biased RLG system.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    demo = sub.add_parser("demo", help="the main job on an embedded default",
                          description="Reproduce the paper's model numbers with the symbolic model.",
                          epilog=EXAMPLES["demo"])
    demo.add_argument("--out", metavar="DIR", help="directory for the report (later issues)")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    demo.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    demo.set_defaults(run=_demo)
    return parser


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except ValueError as err:
        print(f"hse-opt {args.command}: error: {err}", file=sys.stderr)
        return 2
    except Exception as err:  # noqa: BLE001 - the command line reports, never tracebacks
        print(f"hse-opt {args.command}: internal error: {type(err).__name__}: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
