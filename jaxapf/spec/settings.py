"""One setting's value, the language every spec shares: which keys a setting has (the declared gains, the
static settings of :class:`~jaxapf.config.SimConfig` and :class:`~jaxapf.config.MPCConfig`), what each
takes, tables of them (``[sim]``, ``[gains]``), the MPC weights a spec traces, and sampling ranges."""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from ..config import MPC_KEYS, SIM_KEYS, MPCConfig, SimConfig
from ..engine.components import COMPONENTS
from ..gains import GAINS, Gains
from ..validation import BoundWarning, ConfigError, check_table, relocated

__all__ = ["AXIS_WEIGHT_KEYS", "check_value", "setting_values", "sim_configs", "traced_weights", "RandomRange",
           "parse_range"]

#: MPC weights that take a number (same on x, y, z) or 3 numbers.
AXIS_WEIGHT_KEYS: frozenset[str] = frozenset({"q_pos", "q_vel", "f_pos", "f_vel", "r"})


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _kind(key: str) -> str:
    """What a setting key takes: ``number``, ``integer``, ``text``, ``boolean`` or ``weight``."""
    if key in GAINS:
        return "numbers" if GAINS.get(key).shape else "number"
    if key in AXIS_WEIGHT_KEYS:
        return "weight"
    default = SimConfig().flat()[key] if key in SIM_KEYS else getattr(MPCConfig(), key)
    if isinstance(default, bool):
        return "boolean"
    if isinstance(default, int):
        return "integer"
    if isinstance(default, str):
        return "text"
    return "number"  # floats, and att_cap (default None: off)


_KIND_TEXT = {
    "number": "a number",
    "integer": "an integer",
    "text": "a string",
    "boolean": "true or false",
    "weight": "a number or a list of 3 numbers (x, y, z)",
    "numbers": "a list of numbers",
}


def _type_ok(kind: str, value: Any) -> bool:
    if kind == "number":
        return _is_number(value)
    if kind == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "text":
        return isinstance(value, str)
    if kind == "boolean":
        return isinstance(value, bool)
    if kind == "numbers":
        return isinstance(value, list) and all(map(_is_number, value))
    return _is_number(value) or (isinstance(value, list) and len(value) == 3 and all(map(_is_number, value)))


def check_value(where: str, key: str, value: Any) -> Any:
    """Type- and range-check one value of setting ``key`` found at ``where`` in the spec; returns it
    normalised (gains and other numbers as float, weights as float or a 3-tuple of floats, an array-valued
    gain as a tuple of floats)."""
    kind = _kind(key)
    if not _type_ok(kind, value):
        raise ConfigError(f"{where} = {value!r} must be {_KIND_TEXT[kind]}")
    if kind == "number":
        value = float(value)
    elif kind == "weight":
        value = tuple(float(v) for v in value) if isinstance(value, list) else float(value)
    elif kind == "numbers":  # an array-valued gain, as a tuple (a setting's values are hashable)
        value = tuple(float(v) for v in value)
    if key in COMPONENTS:
        COMPONENTS[key].get(value, where)
    owner, prefix = ((Gains, "gains") if key in GAINS
                     else (SimConfig.from_flat, "sim") if key in SIM_KEYS else (MPCConfig, "mpc"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", BoundWarning)
        try:
            owner(**{key: value})
        except ConfigError as err:
            raise relocated(err, f"{prefix}.{key}", where) from None
    for w in caught:  # re-issued naming the spec's key (k > 1)
        message = str(w.message).removeprefix(f"{prefix}.{key}")
        warnings.warn(f"{where} = {value!r}{message}", BoundWarning, stacklevel=2)
    return value


def setting_values(keys: Sequence[str]) -> Callable[[str, Any], dict[str, Any]]:
    """A table of setting values (``[sim]``, ``[gains]``) out of ``keys``, each checked by
    :func:`check_value`: the values it gives (a reader of :mod:`jaxapf.spec.schema`)."""
    def read(where: str, value: Any) -> dict[str, Any]:
        table = check_table(where, value, keys)
        return {key: check_value(f"{where}.{key}", key, v) for key, v in table.items()}
    return read


def sim_configs(values: Mapping[str, Any], scaled: Iterable[str] = (), where: str = "sim"
                ) -> tuple[SimConfig, MPCConfig]:
    """The :class:`SimConfig` and :class:`MPCConfig` of ``[sim]`` values (the rest at their defaults).
    If ``scaled`` (the MPC weight scales a spec sets to something other than 1, or varies:
    :func:`~jaxapf.control.scales_set`) is not empty, the MPC's weights come from the gains
    (``mpc_weights = "gains"``); ``mpc_weights = "static"`` beside one is refused."""
    sim = traced_weights({k: v for k, v in values.items() if k in SIM_KEYS}, scaled, where)
    return SimConfig.from_flat(sim), MPCConfig(**{k: v for k, v in values.items() if k in MPC_KEYS})


def traced_weights(sim: Mapping[str, Any], scaled: Iterable[str], where: str = "sim") -> dict[str, Any]:
    """``[sim]`` values with ``mpc_weights = "gains"`` if ``scaled`` (MPC weight scales a spec sets away
    from 1 or varies) is not empty; ``mpc_weights = "static"`` beside one is refused in one line."""
    sim, scales = dict(sim), sorted(scaled)
    if scales:
        if sim.get("mpc_weights", "gains") != "gains":
            raise ConfigError(f"{where}.mpc_weights = {sim['mpc_weights']!r} compiles the MPC's weights in, but the "
                              f"spec sets {scales[0]}, which only mpc_weights = \"gains\" reads")
        sim["mpc_weights"] = "gains"
    return sim


@dataclasses.dataclass(frozen=True)
class RandomRange:
    """Range of one sampled gain: uniform on ``[low, high]``, or log-uniform with ``log``."""

    low: float
    high: float
    log: bool = False

    def sample(self, u: np.ndarray) -> np.ndarray:
        """Map uniforms ``u`` in (0, 1) to the range (float64)."""
        if self.log:
            a, b = np.log(self.low), np.log(self.high)
            return np.exp(a + u * (b - a))
        return self.low + u * (self.high - self.low)


def parse_range(where: str, key: str, value: Any) -> RandomRange:
    """A sampling range of gain ``key`` at ``where``: ``[lo, hi]`` (uniform) or ``{range = [lo, hi],
    log = true}`` (log-uniform, lo > 0)."""
    log = False
    if isinstance(value, dict):
        table = check_table(where, value, ("range", "log"))
        if "range" not in table:
            raise ConfigError(f"{where}.range is missing; write {{range = [lo, hi]}} "
                              "or {range = [lo, hi], log = true}")
        log = table.get("log", False)
        if not isinstance(log, bool):
            raise ConfigError(f"{where}.log = {log!r} must be true or false")
        where, value = f"{where}.range", table["range"]
    if not isinstance(value, list) or len(value) != 2:
        raise ConfigError(f"{where} = {value!r} must be a range [lo, hi] or a table {{range = [lo, hi], log = true}}")
    low, high = (check_value(f"{where}[{i}]", key, v) for i, v in enumerate(value))
    if low > high:
        raise ConfigError(f"{where} = {value!r} is not a range; allowed: [lo, hi] with lo <= hi")
    if log and low <= 0:
        raise ConfigError(f"{where}[0] = {low!r} is out of range; allowed: > 0 for a log range")
    return RandomRange(low, high, log)
