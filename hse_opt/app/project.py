"""The project file ``hse-opt.toml``: what repeats from command to command, written once.

A field session repeats the same settings in every command: the site's latitude, the lab
calibration, the stand's resolution and tilt fixture, the effects in the model, the time
budget, the number of jobs. ``hse-opt.toml`` in the working folder (or the file that
``--config PATH`` names, anywhere on the command line) holds them; every command reads it and
takes each key whose option it has as that option's default, so a flag on the command line
always wins. ``hse-opt config`` prints what is in force, for which commands, and from where.

Keys (each is the option of the same name; units in the key as in the option)::

    [site]
    latitude_deg = 28.2            # --latitude-deg (align, design, calibrate)

    [system]
    calibration = "lab/CAL.toml"   # --calibration: the lab calibration file (align, calibrate)
    arw_dph_rthz = 0.012           # --arw-dph-rthz: the gyros' angle random walk (design)

    [stand]
    max_tilt_arcsec = 1800         # --max-tilt-arcsec: the tilt fixture's reach (design)
    stand_tilt_arcsec = 0          # --stand-tilt-arcsec (design)
    rates = "10:60"                # --rates LO:HI, deg/s (design)
    resolution_rate_dps = 1        # --resolution-rate-dps (design)
    resolution_azimuth_deg = 1     # --resolution-azimuth-deg (design)
    resolution_tilt_arcsec = 10    # --resolution-tilt-arcsec (design)

    [model]
    effects = ["hse", "sync_delay"]   # --effects (fit, diagnose, design, calibrate); or "hse,sync_delay"

    [campaign]
    budget_h = 5                   # --budget-h (design)
    time_left_h = 3                # --time-left-h (calibrate)

    [compute]
    jobs = 2                       # --jobs (simulate, align, calibrate)
    dask = "tcp://host:8786"       # --dask (simulate, align, calibrate)

Rules: a relative path (``calibration``) is relative to the project file's folder; a value is
checked by its option's own rules, and a bad one is refused naming the file and key; an
unknown section or key is refused with the keys allowed (a misspelt key never passes
silently). A command without a key's option ignores it (``hse-opt fit`` has no ``--jobs``).
"""
from __future__ import annotations

import argparse
import os
from dataclasses import dataclass
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

#: the file a command looks for in the working folder
FILE_NAME = "hse-opt.toml"

#: section -> key -> (option, kind): kind "path" is resolved against the file's folder,
#: "list" may also be a TOML array (joined by commas as the option takes it)
KEYS = {
    "site": {"latitude_deg": ("--latitude-deg", "number")},
    "system": {"calibration": ("--calibration", "path"), "arw_dph_rthz": ("--arw-dph-rthz", "number")},
    "stand": {"max_tilt_arcsec": ("--max-tilt-arcsec", "number"),
              "stand_tilt_arcsec": ("--stand-tilt-arcsec", "number"),
              "rates": ("--rates", "text"),
              "resolution_rate_dps": ("--resolution-rate-dps", "number"),
              "resolution_azimuth_deg": ("--resolution-azimuth-deg", "number"),
              "resolution_tilt_arcsec": ("--resolution-tilt-arcsec", "number")},
    "model": {"effects": ("--effects", "list")},
    "campaign": {"budget_h": ("--budget-h", "number"), "time_left_h": ("--time-left-h", "number")},
    "compute": {"jobs": ("--jobs", "integer"), "dask": ("--dask", "text")},
}


@dataclass(frozen=True)
class Setting:
    """One key in force: ``option`` takes ``text`` (as it would be typed) by default."""
    section: str
    key: str
    option: str
    text: str
    source: str


@dataclass(frozen=True)
class Project:
    """The settings of one project file (``path`` None: no file, nothing in force)."""
    path: Path | None
    settings: tuple[Setting, ...] = ()

    def for_parser(self, parser):
        """The settings ``parser`` (a command's) has options for: dest -> (action, setting)."""
        actions = {opt: a for a in parser._actions for opt in a.option_strings}
        return {actions[s.option].dest: (actions[s.option], s) for s in self.settings if s.option in actions}

    def apply(self, parser):
        """Make the settings ``parser``'s defaults (checked by each option's own type); flags given
        on the command line still win. Raises ValueError naming the file and key."""
        defaults = {}
        for dest, (action, s) in self.for_parser(parser).items():
            value = s.text
            if action.type is not None:
                try:
                    value = action.type(s.text)
                except (argparse.ArgumentTypeError, TypeError, ValueError) as err:
                    raise ValueError(f"{s.source}: {' '.join(str(err).split())}") from None
            if action.choices is not None and value not in action.choices:
                raise ValueError(f"{s.source}: {s.text!r} is not a choice of {s.option}; "
                                 f"allowed: {', '.join(map(str, action.choices))}")
            defaults[dest] = value
        parser.set_defaults(**defaults)


def _text(value, kind, where, folder):
    """A TOML value as the option's text; ValueError naming ``where``."""
    if kind == "list" and isinstance(value, list) and value and all(isinstance(v, str) for v in value):
        return ",".join(value)
    if kind in ("text", "path", "list"):
        if not isinstance(value, str) or not value.strip():
            raise ValueError(f"{where}: {value!r}; allowed: a non-empty string"
                             + (" or an array of strings" if kind == "list" else ""))
        if kind == "path":
            return str((folder / value) if not os.path.isabs(value) else Path(value))
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            (kind == "integer" and not isinstance(value, int)):
        allowed = "an integer" if kind == "integer" else "a number"
        raise ValueError(f"{where}: {value!r}; allowed: {allowed}")
    return repr(value)


def load(path):
    """The project file at ``path``. Raises ValueError naming the file (and key) when it cannot
    be read, is not TOML, or holds a section, key or value that is not allowed."""
    path = Path(path)
    from hse_opt.ranges import MAX_FILE_BYTES
    try:
        with open(path, "rb") as fh:  # bounded: /dev/zero is no project file
            raw = fh.read(MAX_FILE_BYTES + 1)
        if len(raw) > MAX_FILE_BYTES:
            raise ValueError(f"{path}: larger than {MAX_FILE_BYTES / 2**20:g} MiB; allowed: a project file "
                             "(TOML) of a few lines")
    except OSError as err:
        raise ValueError(f"{path}: cannot read the project file ({err.strerror or err}); "
                         f"allowed: a readable TOML file") from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        raise ValueError(f"{path}: not a TOML file ({' '.join(str(err).split())}); allowed: TOML "
                         f"with sections {', '.join(KEYS)}") from None
    except RecursionError:  # arrays nested thousands deep
        raise ValueError(f"{path}: not a TOML file this tool reads (arrays or tables nested too deeply); "
                         f"allowed: TOML with sections {', '.join(KEYS)}") from None
    folder = path.resolve().parent
    settings = []
    for section, table in data.items():
        if section not in KEYS:
            raise ValueError(f"{path}: unknown section [{section}]; allowed: {', '.join(KEYS)}")
        if not isinstance(table, dict):
            raise ValueError(f"{path}: {section} is not a section; allowed: [{section}] with keys "
                             f"{', '.join(KEYS[section])}")
        for key, value in table.items():
            if key not in KEYS[section]:
                raise ValueError(f"{path}: [{section}] {key}: unknown key; allowed: "
                                 f"{', '.join(KEYS[section])}")
            option, kind = KEYS[section][key]
            where = f"{path}, [{section}] {key}"
            settings.append(Setting(section, key, option, _text(value, kind, where, folder), where))
    return Project(path, tuple(settings))


def pop_config(argv):
    """``argv`` without ``--config PATH`` / ``--config=PATH`` (anywhere), and that PATH or
    None. Raises ValueError when ``--config`` has no value."""
    argv, out, path = list(argv), [], None
    i = 0
    while i < len(argv):
        arg = argv[i]
        if arg == "--config":
            if i + 1 >= len(argv) or argv[i + 1].startswith("--"):
                raise ValueError("--config needs a value; allowed: --config PATH (a project file)")
            path, i = argv[i + 1], i + 2
            continue
        if arg.startswith("--config="):
            path = arg.split("=", 1)[1]
            if not path:
                raise ValueError("--config needs a value; allowed: --config PATH (a project file)")
        else:
            out.append(arg)
        i += 1
    return out, path


def find(explicit=None, folder=None):
    """The project in force: ``explicit`` (``--config``) if given, else ``hse-opt.toml`` in
    ``folder`` (default: the working folder) if it is a file, else an empty project."""
    if explicit is not None:
        return load(explicit)
    candidate = Path(folder or os.getcwd()) / FILE_NAME
    return load(candidate) if candidate.is_file() else Project(None)
