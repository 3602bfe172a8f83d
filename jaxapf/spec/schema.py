"""The schema every spec file is read with: ``jaxapf sweep``'s, ``tune``'s and ``compare``'s.

A spec is a :class:`Table` of :class:`Key` s. A key is a reader ``(where, value) -> value`` that
returns the value normalised or raises a one-line :class:`~jaxapf.validation.ConfigError` naming
``where`` (the dotted place in the file, ``train.learning_rate``), and a default, which is read as if
the file gave it. Reading a table refuses unknown keys (listing the allowed ones) and missing required
ones (saying what to add), then reads every key in declaration order; a :class:`Table` is itself a
reader, so tables nest. The readers the three specs share are here (numbers, names, seeds, the spec's
name, gain grids); those of setting values (``[sim]``, ``[gains]``) and of ``[scenario.params]`` are
the sweep spec's (:mod:`jaxapf.sweep.spec`), which tune and compare specs read with. What holds
between keys (a test seed apart from the selection seeds) is checked by each spec's parser after
reading.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from typing import Any, Callable, Mapping, Sequence

from ..validation import (
    MAX_SEED,
    MAX_SETTINGS,
    ConfigError,
    check_bool,
    check_choice,
    check_int,
    check_names,
    check_number,
    check_table,
)

__all__ = ["Key", "Table", "REQUIRED", "OMIT", "given", "integer", "number", "choice", "boolean", "names", "SEED",
           "spec_name", "value_grid"]

Reader = Callable[[str, Any], Any]

#: A key the spec must give.
REQUIRED = object()
#: A key that, absent, is absent from what the table reads (no default).
OMIT = object()


@dataclasses.dataclass(frozen=True)
class Key:
    """One key of a table: its reader, its default (a value as a file gives it, read like one;
    :data:`REQUIRED`; or :data:`OMIT`), and for a required key what the message of its absence advises
    (``add [test] with families and fields``)."""

    read: Reader
    default: Any = OMIT
    missing: str = ""


@dataclasses.dataclass(frozen=True)
class Table:
    """A table of :class:`Key` s by name (their order: the order of reading and of the allowed keys
    an unknown key's message lists). Calling it reads a table found at ``where`` (``""``: the file)."""

    keys: Mapping[str, Key]

    def __call__(self, where: str, value: Any) -> dict[str, Any]:
        table = check_table(where, value, tuple(self.keys))
        out = {}
        for name, key in self.keys.items():
            at = f"{where}.{name}" if where else name
            if name in table:
                out[name] = key.read(at, table[name])
            elif key.default is REQUIRED:
                raise ConfigError(f"{at} is missing" + (f"; {key.missing}" if key.missing else ""))
            elif key.default is not OMIT:
                out[name] = key.read(at, key.default)
        return out


def given(where: str, value: Any) -> Any:
    """The value as the file gives it: read later by the spec's parser, once what it depends on is known."""
    return value


def integer(lo: int, hi: int | None = None) -> Reader:
    """An integer in ``[lo, hi]``."""
    return lambda where, value: check_int(where, value, lo, hi)


def number(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False, inf: bool = False) -> Reader:
    """A number (not a boolean) at least ``lo`` (above it with ``lo_open``) and at most ``hi``, as a
    float; ``inf``: also ``inf``."""
    def read(where: str, value: Any) -> float:
        if inf and isinstance(value, float) and value == math.inf:
            return value
        return check_number(where, value, lo, hi, lo_open=lo_open)
    return read


def choice(choices: Sequence[str]) -> Reader:
    """One of ``choices``."""
    return lambda where, value: check_choice(where, value, choices)


def boolean(where: str, value: Any) -> bool:
    """``true`` or ``false``."""
    return check_bool(where, value)


def names(choices: Sequence[str], what: str = "name", *, canonical: bool = False) -> Reader:
    """Distinct names out of ``choices`` (:func:`~jaxapf.validation.check_names`)."""
    return lambda where, value: check_names(where, value, choices, what=what, canonical=canonical)


#: A seed of a generator: an integer in ``[0, 2**32 - 1]``.
SEED = integer(0, MAX_SEED)

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


#: Longest spec ``name``: it names files and folders (``runs/compare-NAME``, ``runs/NAME.parquet``), whose names
#: most file systems cap at 255 bytes.
MAX_NAME = 128


def spec_name(hint: str = "") -> Reader:
    """The spec's ``name``: up to :data:`MAX_NAME` letters, digits, ``_``, ``.`` and ``-`` (it names outputs);
    ``hint`` says which."""
    def read(where: str, value: Any) -> str:
        if not isinstance(value, str) or not _NAME.fullmatch(value):
            shown = (f"{value[:40]!r}… ({len(value):,} characters)" if isinstance(value, str) and len(value) > 40
                     else repr(value))
            raise ConfigError(f"{where} = {shown} must be a string of letters, digits, '_', '.', '-'"
                              + (f" ({hint})" if hint else ""))
        if len(value) > MAX_NAME:
            raise ConfigError(f"{where} = {value[:40]!r}… is {len(value):,} characters long; at most {MAX_NAME} "
                              "(it names files and folders)")
        return value
    return read


def value_grid(read: Callable[[str, str, Any], Any], *, keys: Sequence[str] | None = None,
               check_key: Callable[[str, str], Any] | None = None, empty: str) -> Reader:
    """A table ``{key = [values, ...]}`` (keys out of ``keys``, or accepted by ``check_key(where,
    key)``), each value read by ``read(where, key, value)`` and none repeated, whose product is at
    most :data:`~jaxapf.validation.MAX_SETTINGS` settings: the grids of sweep, tune and compare specs.
    ``empty``: the message for an empty table."""
    def read_grid(where: str, value: Any) -> tuple[tuple[str, tuple], ...]:
        table = check_table(where, value, keys)
        if not table:
            raise ConfigError(empty)
        grid = []
        for key, values in table.items():
            at = f"{where}.{key}"
            if check_key is not None:
                check_key(where, key)
            if not isinstance(values, list):
                raise ConfigError(f"{at} = {values!r} must be a list of values")
            if not values:
                raise ConfigError(f"{at} is empty; give at least one value")
            if len(values) > MAX_SETTINGS:
                raise ConfigError(f"{at} has {len(values):,} values; at most {MAX_SETTINGS:,} are allowed")
            read_values = tuple(read(f"{at}[{i}]", key, v) for i, v in enumerate(values))
            seen = set()
            for i, v in enumerate(read_values):
                text = json.dumps(v)
                if text in seen:
                    raise ConfigError(f"{at}[{i}] = {values[i]!r} repeats an earlier value")
                seen.add(text)
            grid.append((key, read_values))
        count = math.prod(len(v) for _, v in grid)
        if count > MAX_SETTINGS:
            raise ConfigError(f"{where} expands to {count:,} settings; at most {MAX_SETTINGS:,} are allowed")
        return tuple(grid)
    return read_grid
