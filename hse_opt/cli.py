"""The ``hse-opt`` command line. Exit status: 0 success, 2 bad input, 1 anything else."""
import argparse
import sys


def main(argv=None):
    parser = argparse.ArgumentParser(prog="hse-opt", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("demo", help="the main job on an embedded default")
    args = parser.parse_args(argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
