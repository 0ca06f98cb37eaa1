"""Names users give - CSV column names and the ``covariate:<column>`` effects - under one rule,
checked where they enter.

A name reaches generated C (macros, comments), JSON keys, the HTML report, parameter names
(``k_<column>``) and messages. Rather than escape it differently at each of those sinks, the
tool accepts only names that are safe in all of them: :data:`NAME_CHARACTERS`, at most
:data:`MAX_NAME_LENGTH` characters. The entry points check it - the CSV header reader
(:mod:`hse_opt.data.csvfile`, every column, numeric or text), the covariate effect
(:class:`hse_opt.model.effects.Covariate`: ``--effects covariate:NAME``, FIT.json's effects,
the Python API) - and refuse any other name (exit 2, "allowed: ..."). Every name the tool
itself uses (``docs/formats.md``) satisfies the rule. Values (a ``position`` label, a text
column's cells) are data, not names: the HTML report escapes them and the CSV writer quotes
them (``docs/threats.md``).
"""
import re

__all__ = ["NAME_CHARACTERS", "MAX_NAME_LENGTH", "ALLOWED_NAMES", "is_name", "check_name", "shown"]

#: the characters of a name
NAME_CHARACTERS = "A-Za-z0-9_"
#: the longest name
MAX_NAME_LENGTH = 64
#: what a message says is allowed
ALLOWED_NAMES = (f"letters A-Z a-z, digits 0-9 and _, 1 to {MAX_NAME_LENGTH} characters "
                 "(units in the name: temp_c)")
_PATTERN = re.compile(f"[{NAME_CHARACTERS}]{{1,{MAX_NAME_LENGTH}}}")


def is_name(name):
    """True when ``name`` is a str that follows the rule."""
    return isinstance(name, str) and _PATTERN.fullmatch(name) is not None


def shown(name, limit=40):
    """``name`` for a one-line message: Python's escaped repr (newlines as ``\\n``), cut at
    ``limit`` characters."""
    text = ascii(name) if isinstance(name, str) else ascii(str(name))
    return text if len(text) <= limit else text[:limit - 3] + "..."


def check_name(name, what="name"):
    """``name`` unchanged if it follows the rule; else ValueError ``"<what> <name> is not
    allowed; allowed: ..."`` (one line: the name shown escaped)."""
    if not is_name(name):
        raise ValueError(f"{what} {shown(name)} is not allowed; allowed: {ALLOWED_NAMES}")
    return name
