"""``hse-opt config``: what the project file (``hse-opt.toml``) puts in force, and from where."""
from . import print_json

NAME = "config"
HELP = "print the settings in force from the project file (hse-opt.toml) and which commands take them"
DESCRIPTION = """\
A project file holds what repeats from command to command (site latitude, lab calibration,
stand resolution and tilt fixture, effects, time budget, jobs): hse-opt.toml in the working
folder, or the file --config PATH names (anywhere on any command's line). Every command takes
each key whose option it has as that option's default; a flag on the command line wins.
An unknown section or key, or a value its option refuses, is an error naming the file and key.

  [site]     latitude_deg
  [system]   calibration (a path, relative to the file's folder), arw_dph_rthz
  [stand]    max_tilt_arcsec, stand_tilt_arcsec, rates, resolution_rate_dps,
             resolution_azimuth_deg, resolution_tilt_arcsec
  [model]    effects ("hse,sync_delay" or ["hse", "sync_delay"])
  [campaign] budget_h, time_left_h
  [compute]  jobs, dask

Each key is the option of the same name (--latitude-deg, --calibration, ...), units as there."""
INPUTS = ()
OUTPUTS = {}
EXAMPLE = """\
example:
  printf '[site]\\nlatitude_deg = 28.2\\n[compute]\\njobs = 2\\n' > hse-opt.toml
  hse-opt config                      # latitude_deg = 28.2 -> --latitude-deg of align, design
  hse-opt align LOGS/ -o RUNS.csv     # runs with --latitude-deg 28.2 --jobs 2
  hse-opt --config site/hse-opt.toml config --json"""


def add_arguments(parser):
    parser.add_argument("--json", action="store_true",
                        help="print the settings as one JSON object on stdout")


def settings_in_force(project, commands):
    """Per key of the project: its value, source and the commands that take it.

    ``commands``: command name -> its parser."""
    rows = []
    for s in project.settings:
        takers = [name for name, p in commands.items() if name != NAME and s.option in
                  {o for a in p._actions for o in a.option_strings}]
        rows.append({"section": s.section, "key": s.key, "value": s.text, "option": s.option,
                     "source": s.source, "commands": takers})
    return rows


def run(args):
    from ..cli import build_parser

    project = args.project
    rows = settings_in_force(project, build_parser().commands)
    if args.json:
        print_json({"file": None if project.path is None else str(project.path), "settings": rows})
        return 0
    if project.path is None:
        print("hse-opt config: no project file (no hse-opt.toml in the working folder, no --config): "
              "every option has its command's default")
        return 0
    print(f"hse-opt config: {project.path}")
    for r in rows:
        takers = ", ".join(r["commands"]) or "no command (ignored)"
        print(f"  [{r['section']}] {r['key']} = {r['value']}  -> {r['option']} of {takers}")
    return 0
