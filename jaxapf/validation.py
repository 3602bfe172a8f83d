"""The validation toolkit: every check of a user's value goes through here.

Every check raises :class:`ConfigError` with one line that names where the value sits (a dotted
key such as ``grid.gamma[2]`` or a flag such as ``--seed``) and what is allowed; nothing reaches the
user as a traceback. Configuration classes, spec parsers and the CLI share these functions, so one
kind of mistake always reads the same.
"""

from __future__ import annotations

import os
import stat
import tomllib
from typing import Any, Iterable, Sequence

import numpy as np

__all__ = [
    "ConfigError",
    "MAX_SEED",
    "MAX_FIELDS",
    "MAX_SETTINGS",
    "Interrupted",
    "BoundWarning",
    "describe_range",
    "check_range",
    "check_int",
    "check_choice",
    "check_bool",
    "check_span",
    "check_names",
    "check_table",
    "relocated",
    "first_line",
    "read_toml_file",
]


#: Largest seed (or ``simulate --field``): ``jax.random.key`` keeps 32 bits in float32 runs.
MAX_SEED = 2**32 - 1
#: Most fields per family: field ``i``'s key is ``fold_in(key(seed), i)`` with a 32-bit ``i``, so
#: larger indices would repeat fields; 2^31 keeps every index an int32 too.
MAX_FIELDS = 2**31
#: Most settings a spec may expand to (the grid product times the random samples); each is a
#: Python object, and more than this would not fit a run anyway (sweep specs, tune and
#: compare searches).
MAX_SETTINGS = 100_000


#: Largest spec file read (TOML) [bytes].
MAX_SPEC_BYTES = 16 * 2**20


class ConfigError(ValueError):
    """A configuration value is missing, of the wrong type or outside its allowed range."""


class Interrupted(Exception):
    """The user interrupted a command (Ctrl-C); the message says what was kept and how to go on."""


class BoundWarning(UserWarning):
    """A value is allowed but breaks a property the paper claims (e.g. ``k > 1``: ``ω >= 1`` fails)."""


def describe_range(lo: float | None, hi: float | None, lo_open: bool = False, hi_open: bool = False) -> str:
    """``"a finite number >= 0 and < 1"``: the allowed range in words."""
    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi is not None:
        parts.append(f"{'<' if hi_open else '<='} {hi:g}")
    return "a finite number " + " and ".join(parts) if parts else "a finite number"


def check_range(
    where: str,
    value: Any,
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> np.ndarray:
    """``value`` as a float64 array after checking every entry is finite and in range."""
    allowed = describe_range(lo, hi, lo_open, hi_open)
    if isinstance(value, (bool, np.bool_)):
        raise ConfigError(f"{where} = {value!r} is not numeric; allowed: {allowed}")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"{where} = {value!r} is not numeric; allowed: {allowed}") from None
    bad = ~np.isfinite(arr)
    if lo is not None:
        bad |= (arr <= lo) if lo_open else (arr < lo)
    if hi is not None:
        bad |= (arr >= hi) if hi_open else (arr > hi)
    if np.any(bad):
        shown = arr[bad].ravel()[0] if arr.ndim else arr
        raise ConfigError(f"{where} = {float(shown)!r} is out of range; allowed: {allowed}")
    return arr


def check_int(where: str, value: Any, lo: int, hi: int | None = None) -> int:
    """``value`` as an ``int`` in ``lo … hi`` (booleans are not integers here)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ConfigError(f"{where} = {value!r} must be an integer >= {lo}"
                          + (f" and <= {hi}" if hi is not None else ""))
    if value < lo or (hi is not None and value > hi):
        rng = f">= {lo}" + (f" and <= {hi}" if hi is not None else "")
        raise ConfigError(f"{where} = {value!r} is out of range; allowed: an integer {rng}")
    return int(value)


def did_you_mean(value: Any, choices: Iterable[str]) -> str:
    """`` (did you mean `gamma`?)`` for a misspelled name close to one of ``choices`` (difflib's ratio
    >= 0.7: ``gama``, ``basc``, ``sise``; not ``magic`` for ``basic``), else ``""``."""
    import difflib

    if not isinstance(value, str):
        return ""
    close = difflib.get_close_matches(value, list(choices), n=1, cutoff=0.7)
    return f" (did you mean `{close[0]}`?)" if close else ""


def check_choice(where: str, value: Any, choices: Sequence[str]) -> str:
    """``value`` if it is one of ``choices``."""
    if not isinstance(value, str) or value not in choices:
        raise ConfigError(f"{where} = {value!r} is not allowed{did_you_mean(value, choices)}; "
                          f"choose one of {', '.join(choices)}")
    return value


def check_bool(where: str, value: Any) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ConfigError(f"{where} = {value!r} must be true or false")
    return bool(value)


def check_number(where: str, value: Any, lo: float | None = None, hi: float | None = None, *,
                 lo_open: bool = False) -> float:
    """One finite number in the range (not a boolean, a text or an array)."""
    if isinstance(value, (bool, np.bool_, str, list, tuple, dict, np.ndarray)):
        raise ConfigError(f"{where} = {value!r} must be a number; allowed: {describe_range(lo, hi, lo_open)}")
    return float(check_range(where, value, lo, hi, lo_open=lo_open))


def check_span(where: str, value: Any, lo: float | None = None, hi: float | None = None, *,
               lo_open: bool = False, integer: bool = False) -> tuple:
    """An interval ``(a, b)`` with ``a <= b`` whose ends lie in the range; a single number ``x``
    means ``(x, x)``."""
    ends = tuple(value) if isinstance(value, (list, tuple, np.ndarray)) else (value, value)
    if len(ends) != 2 or any(isinstance(e, (list, tuple, dict, np.ndarray)) for e in ends):
        raise ConfigError(f"{where} = {value!r} must be a number or a pair (lo, hi)")
    if integer:
        a, b = (check_int(where, e, int(lo if lo is not None else 0)) for e in ends)
    else:
        a, b = (float(check_range(where, e, lo, hi, lo_open=lo_open)) for e in ends)
    if a > b:
        raise ConfigError(f"{where} = {value!r} is not an interval; allowed: a pair (lo, hi) with lo <= hi")
    return (a, b)


def check_names(where: str, value: Any, choices: Sequence[str], *, what: str = "name",
                canonical: bool = False) -> tuple[str, ...]:
    """One or more distinct names out of ``choices`` (a single name is allowed), in the order given,
    or in the order of ``choices`` with ``canonical``."""
    names = list(value) if isinstance(value, (list, tuple)) else [value]
    if not names:
        raise ConfigError(f"{where} = {value!r} must list one or more of {', '.join(choices)}")
    for i, name in enumerate(names):
        at = f"{where}[{i}]" if isinstance(value, (list, tuple)) else where
        if not isinstance(name, str) or name not in choices:
            raise ConfigError(f"{at} = {name!r} is not a {what}{did_you_mean(name, choices)}; "
                              f"allowed: {', '.join(choices)}")
    if len(set(names)) != len(names):
        raise ConfigError(f"{where} = {value!r} lists a {what} twice")
    return tuple(c for c in choices if c in names) if canonical else tuple(names)


def check_table(where: str, value: Any, allowed: Iterable[str] | None = None) -> dict[str, Any]:
    """``value`` checked to be a table (``where``: its dotted location, ``""`` for the top level of a
    file) whose keys are all ``allowed``."""
    if not isinstance(value, dict):
        raise ConfigError(f"{where or 'the spec'} must be a table, got {value!r}")
    if allowed is not None:
        allowed = tuple(allowed)
        for key in value:
            if key not in allowed:
                raise ConfigError(f"{where + '.' if where else ''}{key} is not a known key"
                                  f"{did_you_mean(key, allowed)}; allowed: {', '.join(allowed)}")
    return value


def relocated(err: ConfigError, old: str, where: str) -> ConfigError:
    """``err`` with its location ``old`` (how a configuration class names a field) replaced by
    ``where`` (where the value sits in a spec)."""
    message = str(err)
    if message.startswith(old):
        return ConfigError(where + message[len(old):])
    return ConfigError(f"{where}: {message}")


def first_line(err: BaseException) -> str:
    """The first line of an exception's message (its type's name if it has none)."""
    return (str(err).strip().splitlines() or [type(err).__name__])[0]


def read_toml_file(path: str | os.PathLike, what: str = "spec file") -> tuple[dict[str, Any], str]:
    """The table of the TOML file at ``path`` and its text, unvalidated; a file that is missing, a
    directory, not UTF-8 or not TOML is a :class:`ConfigError` naming ``what`` and the path."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO opens at once, and is refused below
    except FileNotFoundError:
        raise ConfigError(f"{what} {str(path)!r} does not exist") from None
    except OSError as err:
        raise ConfigError(f"{what} {str(path)!r} cannot be read: {err.strerror or first_line(err)}") from None
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        if stat.S_ISDIR(mode):
            raise ConfigError(f"{what} {str(path)!r} is a directory")
        raise ConfigError(f"{what} {str(path)!r} is not a regular file (a device or a pipe); give a TOML file")
    with open(fd, "rb") as fh:
        raw = fh.read(MAX_SPEC_BYTES + 1)
    if len(raw) > MAX_SPEC_BYTES:
        raise ConfigError(f"{what} {str(path)!r} is larger than {MAX_SPEC_BYTES // 2**20} MiB; a spec is a short text")
    try:
        text = raw.decode()
        return tomllib.loads(text), text
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ConfigError(f"{what} {str(path)!r} is not valid TOML: {err}") from None
    except RecursionError:  # tomllib reads nested arrays and tables recursively
        raise ConfigError(f"{what} {str(path)!r} nests arrays or tables too deeply to read") from None
