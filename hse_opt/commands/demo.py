"""``hse-opt demo``: the main job on an embedded default."""
import dataclasses

from . import print_json

NAME = "demo"
HELP = "the main job on an embedded default"
DESCRIPTION = "Reproduce the paper's model numbers with the symbolic model."
EXAMPLE = "example: hse-opt demo --json"


def add_arguments(parser):
    parser.add_argument("--out", metavar="DIR", help="directory for the report (later issues)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def run(args):
    from ..model.paper import reproduce, summary

    numbers = reproduce()
    if args.json:
        print_json(dataclasses.asdict(numbers))
    else:
        print("hse-opt demo: the paper's model evaluated with the symbolic CasADi model")
        print("\n".join(summary(numbers)))
    return 0
