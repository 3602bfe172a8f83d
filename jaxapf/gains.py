"""Declared gains and the :class:`Gains` pytree: every traced number of a setting.

A component (a planner's weight, the APF flow, a safety filter, a plant, a world model) declares
the numbers it reads as :class:`GainSpec` objects: name, default, allowed range, unit. Declared
gains are collected in :data:`GAINS` and become, with no edit elsewhere, keys of :class:`Gains`,
sweep grid keys, ``--NAME`` flags of the CLI, ``--gains`` TOML keys and tunable parameters of
``jaxapf tune``.

:class:`Gains` maps every declared name to a value and is a pytree whose every leaf is numeric
(MJX's rule: a field is a leaf iff it is an array), so a grid of gain settings is one ``vmap`` over
a batched ``Gains``; changing a gain never recompiles. Constructing one validates what the caller
gave, before anything is traced, with :class:`~jaxapf.validation.ConfigError` naming the gain and
its allowed range.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from typing import Any, Collection, Iterator, Mapping

import jax
import numpy as np

from .registry import Registry, loop_rank
from .validation import BoundWarning, ConfigError, check_range, check_table, describe_range, read_toml_file

__all__ = ["GainSpec", "GAINS", "declare_gains", "declare_entry_gains", "Gains", "UndeclaredGain", "validate_gains",
           "gains_from_mapping", "load_gains", "read_gains_file", "check_gain_name", "setting_count",
           "gain_shape", "setting_shape"]


@dataclasses.dataclass(frozen=True)
class GainSpec:
    """One traced number a component reads.

    Attributes:
      name: key in :class:`Gains`, sweep specs and CLI flags (``--name``, ``_`` as ``-``).
      default: value when a setting does not name it.
      low, high, low_open, high_open: allowed range (``None``: unbounded).
      unit: unit in brackets for help texts and reports (``"m"``), ``""`` for none.
      symbol: short label for figures and tables (``"γ"``), default the name.
      doc: one line of what it does.
      tunable: ``jaxapf tune`` may learn it.
      tune_high: upper end of the map ``jaxapf tune`` learns it through (a bounded sigmoid instead
        of the softplus of an unbounded gain), e.g. the paper's bound ``k <= 1``.
      warn_above, warning: values above ``warn_above`` are allowed but break a property the
        paper claims; they raise :class:`~jaxapf.validation.BoundWarning` with ``warning``.
      shape: the shape of one setting's value: ``()`` for a number; an array-valued gain (a network's
        parameters, :mod:`jaxapf.planners.learned`) has a shape, a tuple of numbers as its default, the
        range applying to every entry; it is set by ``--gains`` files and ``jaxapf tune``, not by grids or
        flags.
    """

    name: str
    default: float | tuple[float, ...]
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    unit: str = ""
    symbol: str = ""
    doc: str = ""
    tunable: bool = True
    tune_high: float | None = None
    warn_above: float | None = None
    warning: str = ""
    shape: tuple[int, ...] = ()

    @property
    def label(self) -> str:
        return self.symbol or self.name

    @property
    def tuning_high(self) -> float | None:
        """The upper end of the range a search tunes the gain over: ``tune_high`` within the allowed ``high``
        (``None``: unbounded)."""
        highs = [h for h in (self.tune_high, self.high) if h is not None]
        return min(highs) if highs else None

    def range_text(self) -> str:
        """The allowed range in words, with the unit."""
        return describe_range(self.low, self.high, self.low_open, self.high_open) + (
            f" [{self.unit}]" if self.unit else "")

    @property
    def value(self) -> float | np.ndarray:
        """The default as a setting's value: a float, or a float64 array of :attr:`shape`."""
        return np.asarray(self.default, np.float64).reshape(self.shape) if self.shape else self.default

    def check(self, where: str, value: Any) -> np.ndarray:
        """``value`` as float64 after the range check; warns (:class:`BoundWarning`) above ``warn_above``.
        An array-valued gain's value must end in its :attr:`shape`."""
        arr = check_range(where, value, self.low, self.high, lo_open=self.low_open, hi_open=self.high_open)
        if self.shape and arr.shape[arr.ndim - len(self.shape):] != self.shape:
            raise ConfigError(f"{where} has shape {arr.shape}; this gain holds {_shape_text(self.shape)} numbers")
        if np.any(np.abs(arr) > _FLOAT32_MAX):
            raise ConfigError(f"{where} = {value!r} is too large: gains are computed in float32, whose largest "
                              f"value is {_FLOAT32_MAX:.3g}")
        if self.warn_above is not None and np.any(arr > self.warn_above):
            warnings.warn(f"{where} > {self.warn_above:g}: {self.warning}", BoundWarning, stacklevel=4)
        return arr


#: The largest float32: a gain beyond it would silently become inf.
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def _shape_text(shape: tuple[int, ...]) -> str:
    return " x ".join(f"{n:,}" for n in shape)


def _describe(spec: GainSpec) -> str:
    unit = f" [{spec.unit}]" if spec.unit else ""
    allowed = describe_range(spec.low, spec.high, spec.low_open, spec.high_open)
    tuned = "tunable (jaxapf tune)" if spec.tunable else "not tuned"
    default = f"{_shape_text(spec.shape)} numbers, set by --gains files" if spec.shape else f"default {spec.default:g}"
    return f"{spec.doc}{unit}; {default}; {allowed}; {tuned}"


def gain_shape(name: str) -> tuple[int, ...]:
    """The shape of one setting's value of gain ``name`` (``()`` for a number or an undeclared name)."""
    return GAINS.get(name).shape if name in GAINS else ()


def setting_shape(name: str, value: Any) -> tuple[int, ...]:
    """The settings axes of ``value`` of gain ``name``: its leading axes before the gain's own shape
    (``()`` for one setting, ``(G,)`` for a batch)."""
    shape = np.shape(value)
    return shape[:len(shape) - len(gain_shape(name))]


#: Where each declared gain is listed (:func:`jaxapf.registry.loop_rank` of the first kind declaring it).
_RANK: dict[str, int] = {}

#: Every declared gain, by the kind of component declaring it (:data:`jaxapf.registry.LOOP`), then in
#: declaration order: the order of :class:`Gains` leaves, of a sweep's gain columns and of what
#: ``jaxapf tune`` learns, whichever module was imported first.
GAINS: Registry[GainSpec] = Registry("gain", describe=_describe, rank=_RANK.__getitem__)


def declare_gains(*specs: GainSpec, kind: str | None = None) -> tuple[GainSpec, ...]:
    """Declare ``specs``, read by a component of ``kind`` (``"planner"``, ...; None: no component kind);
    a gain declared twice must be declared the same way. Returns them."""
    for spec in specs:
        if spec.name in GAINS and GAINS.get(spec.name) != spec:
            raise ConfigError(f"gain {spec.name!r} is declared already with another range or default: "
                              f"{GAINS.get(spec.name)}")
        spec.check(f"gain {spec.name!r} default", spec.value)
        _RANK[spec.name] = min(_RANK.get(spec.name, loop_rank(kind)), loop_rank(kind))
        GAINS.register(spec.name, spec)
    return specs


def declare_entry_gains(entry: Any, registry: Registry) -> None:
    """What a component registry does with a new entry: declare the gains it reads (``entry.gains``)."""
    declare_gains(*entry.gains, kind=registry.what)


def _is_user_value(x: Any) -> bool:
    """A value a user handed in (number, sequence, numpy or concrete JAX array), as opposed to what
    JAX puts into a pytree while tracing (tracers, ``ShapeDtypeStruct``s): only user values are
    validated."""
    if isinstance(x, jax.core.Tracer):
        return False
    return isinstance(x, (int, float, str, list, tuple, np.ndarray, np.generic, jax.Array))


def check_gain_name(where: str, name: str) -> GainSpec:
    """The declaration of gain ``name``; :class:`ConfigError` ``"where.name is not a gain"`` otherwise."""
    if name not in GAINS:
        raise ConfigError(f"{where}.{name} is not a gain; allowed: {', '.join(GAINS.names())}")
    return GAINS.get(name)


def gain_key(prefix: str, name: str) -> str:
    """Where a gain's value sits, for messages: ``gains.k_rep`` in a spec, ``--k-rep`` on the command
    line (``prefix`` ``"--"``)."""
    return f"--{name.replace('_', '-')}" if prefix == "--" else f"{prefix}.{name}"


def validate_gains(values: Mapping[str, Any], *, prefix: str = "gains") -> None:
    """Range-check every value of ``values`` (names must be declared gains)."""
    for name, value in values.items():
        spec = check_gain_name(prefix, name)
        if _is_user_value(value):
            spec.check(gain_key(prefix, name), value)


def _lists_as_arrays(values: Mapping[str, Any]) -> dict[str, Any]:
    """Lists and tuples of numbers as float64 arrays: a list would be a pytree node, not a leaf, and
    a batch of settings must be one leaf per gain."""
    return {k: np.asarray(v, np.float64) if isinstance(v, (list, tuple)) else v for k, v in values.items()}


class UndeclaredGain(AttributeError, ConfigError):
    """A gain read that the setting does not hold: an ``AttributeError`` (attribute access), and a
    :class:`ConfigError`, so that the command line says it in one line."""


@jax.tree_util.register_pytree_node_class
class Gains(Mapping[str, Any]):
    """A value (scalar or batched array) for every declared gain: ``Gains(gamma=2.0)`` takes the
    declared defaults for the others. Read as ``gains.gamma`` or ``gains["gamma"]``.

    Leaves are in declaration order (:data:`GAINS`). Only values the caller hands in are
    validated; pytree operations (``vmap``, ``grad``, ``tree_map``) rebuild a ``Gains`` without
    checks.
    """

    __slots__ = ("_values",)

    def __init__(self, **values: Any) -> None:
        validate_gains(values)
        values = _lists_as_arrays(values)
        merged = {name: values[name] if name in values else spec.value for name, spec in GAINS.items()}
        object.__setattr__(self, "_values", merged)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """Every declared gain."""
        return GAINS.names()

    # --- mapping ----------------------------------------------------------------------------

    def __getitem__(self, name: str) -> Any:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __getattr__(self, name: str) -> Any:
        values = object.__getattribute__(self, "_values")
        try:
            return values[name]
        except KeyError:
            raise UndeclaredGain(f"no gain {name!r} here (misspelled, or not declared by the component that reads "
                                 f"it: docs/extending.md, 'Gains'); gains: {', '.join(values)}") from None

    def __setattr__(self, name: str, value: Any) -> None:
        raise dataclasses.FrozenInstanceError(f"Gains are immutable; use .replace({name}=...)")

    def _key(self) -> tuple:
        """The values as a hashable tuple (numpy arrays by dtype, shape and bytes)."""
        return tuple((k, (v.dtype.str, v.shape, v.tobytes()) if isinstance(v, np.ndarray) else v)
                     for k, v in self._values.items())

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Gains) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __repr__(self) -> str:
        return "Gains(" + ", ".join(f"{k}={v!r}" for k, v in self._values.items()) + ")"

    # --- pytree -------------------------------------------------------------------------------

    def tree_flatten(self) -> tuple[list[Any], tuple[str, ...]]:
        return list(self._values.values()), tuple(self._values)

    @classmethod
    def tree_unflatten(cls, names: tuple[str, ...], leaves: list[Any]) -> "Gains":
        return cls.unchecked(dict(zip(names, leaves)))

    @classmethod
    def unchecked(cls, values: Mapping[str, Any]) -> "Gains":
        """Gains holding exactly ``values``: no defaults added, nothing validated (traced values, and
        the functional API of :mod:`jaxapf.planners.potentials`, which takes gains by name)."""
        gains = object.__new__(cls)
        object.__setattr__(gains, "_values", dict(values))
        return gains

    # --- batches of settings -----------------------------------------------------------------

    @classmethod
    def grid(cls, **axes: Any) -> "Gains":
        """Every combination of ``axes`` (the cartesian product, last key varying fastest, as a
        sweep spec's ``[grid]``): ``Gains.grid(gamma=[0, 1, 2], k=[0, 0.5])`` is 6 settings,
        ``(0, 0), (0, 0.5), (1, 0), ...``. Gains not named keep their defaults."""
        import itertools

        arrays = {}
        for name, values in axes.items():
            spec = check_gain_name("Gains.grid", name)
            if spec.shape:
                raise ConfigError(f"Gains.grid: {name} holds {_shape_text(spec.shape)} numbers and is not a grid axis; "
                                  "give it to Gains(...) or a --gains file")
            arr = np.asarray(values, dtype=np.float64) if _is_user_value(values) else None
            if arr is None or arr.ndim != 1 or arr.size == 0:
                raise ConfigError(f"Gains.grid: {name} = {values!r} must be a non-empty list of numbers")
            spec.check(gain_key("Gains.grid", name), arr)
            arrays[name] = arr
        columns = dict(zip(arrays, np.array(list(itertools.product(*arrays.values())), np.float64).T))
        return cls.unchecked({name: columns.get(name, spec.value) for name, spec in GAINS.items()})

    @classmethod
    def paired(cls, **values: Any) -> "Gains":
        """Settings whose ``i``-th takes the ``i``-th value of every list (no product):
        ``Gains.paired(gamma=[0, 3], k=[0, 1])`` is 2 settings, ``(0, 0)`` and ``(3, 1)``: the same as
        ``Gains(gamma=[0, 3], k=[0, 1])``, which also pairs, but checked here for lists of equal lengths."""
        gains = cls(**values)
        setting_count(gains, "Gains.paired")
        return gains

    # --- helpers ------------------------------------------------------------------------------

    def replace(self, **changes: Any) -> "Gains":
        """The same gains with ``changes`` (validated where they are user values)."""
        validate_gains(changes)
        changes = _lists_as_arrays(changes)
        return Gains.unchecked({k: changes.get(k, v) for k, v in self._values.items()})

    def only(self, names: Collection[str]) -> "Gains":
        """The gains of ``names`` alone (in declaration order): what the components of a setting read
        (:func:`jaxapf.engine.gains_read`); a component reading another one fails while it is traced."""
        return Gains.unchecked({k: v for k, v in self._values.items() if k in names})

    def as_arrays(self, dtype: Any = None) -> "Gains":
        """The same gains as ``jnp`` arrays of ``dtype`` (default: JAX's default float)."""
        import jax.numpy as jnp

        dtype = dtype or jnp.result_type(float)
        return jax.tree_util.tree_map(lambda g: jnp.asarray(g, dtype), self)

    def floats(self) -> dict[str, float | list[float]]:
        """One setting's gains as plain numbers (JSON and TOML): floats, lists of floats for an array-valued
        gain."""
        return {k: np.asarray(v, np.float64).tolist() if gain_shape(k) else float(np.asarray(v))
                for k, v in self._values.items()}


def setting_count(gains: Gains, where: str = "gains") -> int:
    """The number of settings ``G`` a (batched) :class:`Gains` holds: the common length of its leaves'
    settings axis (:func:`setting_shape`; 1 if no leaf has one). Leaves of other lengths or shapes raise
    :class:`ConfigError` (one line): values are paired, not combined (:meth:`Gains.grid` combines)."""
    lengths: dict[str, int] = {}
    for name, value in gains.items():
        shape = setting_shape(name, value)
        if len(shape) > 1:
            raise ConfigError(f"{where}: {name} has shape {np.shape(value)}; a gain is a number or a 1-D list of "
                              "settings")
        if shape:
            lengths[name] = shape[0]
    if len(set(lengths.values())) > 1:
        listed = ", ".join(f"{k} {n}" for k, n in lengths.items())
        raise ConfigError(f"{where}: the gains have different numbers of values ({listed}); settings pair the i-th "
                          "values, so give every list the same length, or use Gains.grid(...) for every combination")
    if 0 in lengths.values():
        raise ConfigError(f"{where}: {next(k for k, n in lengths.items() if n == 0)} is empty; give at least one value")
    return next(iter(lengths.values()), 1)


def gains_from_mapping(mapping: Mapping[str, Any], where: str = "gains", base: Gains | None = None) -> Gains:
    """:class:`Gains` from ``{name: number}`` on top of ``base`` (default: the declared defaults);
    an unknown name or a value that is not a number raises :class:`ConfigError` naming ``where.name``."""
    values = {name: _number(where, name, value) for name, value in mapping.items()}
    validate_gains(values, prefix=where)
    base = base or Gains()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BoundWarning)  # already warned above, under `where`
        return base.replace(**values)


def _number(where: str, name: str, value: Any) -> float | list[float]:
    """``value`` of gain ``name`` as a float, or a list of floats of the gain's shape (unchecked range)."""
    spec = check_gain_name(where, name)
    if spec.shape:
        ok = isinstance(value, list) and all(not isinstance(v, bool) and isinstance(v, (int, float)) for v in value)
        if not ok or np.shape(value) != spec.shape:
            shown = f"a list of {len(value)}" if isinstance(value, list) else repr(value)
            raise ConfigError(f"{gain_key(where, name)} = {shown} must be a list of {_shape_text(spec.shape)} numbers")
        return [float(v) for v in value]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{gain_key(where, name)} = {value!r} must be a number")
    return float(value)


def load_gains(path: str | os.PathLike, base: Gains | None = None) -> Gains:
    """Gains from a TOML file (:func:`read_gains_file`) on top of ``base`` (default: the declared defaults)."""
    values = read_gains_file(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BoundWarning)  # read_gains_file warned, naming the file
        return (base or Gains()).replace(**values)


def read_gains_file(path: str | os.PathLike) -> dict[str, float | list[float]]:
    """The gains a TOML file names, checked: a ``[gains]`` table, or gain keys at the top level (the
    fragment ``jaxapf tune`` writes), not both."""
    data, _ = read_toml_file(path, "gains file")
    if "gains" in data:
        extra = sorted(set(data) - {"gains"})
        if extra:
            raise ConfigError(f"gains file {str(path)!r}: {extra[0]} sits next to the [gains] table; put every gain "
                              "inside [gains] (or write them all at the top level)")
        table = check_table(f"{path}:gains", data["gains"])
    else:
        table = data
    gains_from_mapping(table, where=f"{path}:gains")  # checks names, types and ranges
    return {k: _number(f"{path}:gains", k, v) for k, v in table.items()}
