"""Validated configuration: planner gains, MPC settings and simulation settings.

Pytree rule (as in MJX): a field is a pytree leaf iff it holds an array. :class:`Gains` is a
pytree whose every field is numeric, so a grid of gain settings is one ``vmap`` over a batched
``Gains``. :class:`SimConfig` and :class:`MPCConfig` are frozen, hashable and passed as static
arguments; changing one of them triggers a recompile, changing a gain never does.

Every constructor validates its values *before* anything is traced and raises
:class:`ConfigError` naming the field and its allowed range.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from typing import Any, Literal

import jax
import numpy as np

__all__ = [
    "METHODS",
    "CONVENTIONS",
    "ConfigError",
    "BoundWarning",
    "Gains",
    "MPCConfig",
    "SimConfig",
    "gains_from_mapping",
    "load_gains",
]

METHODS = ("basic", "direction", "direction_velocity")
CONVENTIONS = ("intent", "literal")

Method = Literal["basic", "direction", "direction_velocity"]
Convention = Literal["intent", "literal"]


class ConfigError(ValueError):
    """A configuration value is missing, of the wrong type or outside its allowed range."""


class BoundWarning(UserWarning):
    """``k > 1``: the paper's lower bound ``ω >= 1`` no longer holds (the minimum is ``2 - k``)."""


# --------------------------------------------------------------------------------------------
# range checking helpers
# --------------------------------------------------------------------------------------------


def _describe(lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
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
    """Return ``value`` as a float64 array after checking every entry is finite and in range.

    Raises :class:`ConfigError` naming ``where`` and the allowed range otherwise.
    """
    allowed = _describe(lo, hi, lo_open, hi_open)
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


def check_choice(where: str, value: Any, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise ConfigError(f"{where} = {value!r} is not allowed; choose one of {', '.join(choices)}")
    return value


def check_int(where: str, value: Any, lo: int, hi: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ConfigError(f"{where} = {value!r} must be an integer >= {lo}")
    if value < lo or (hi is not None and value > hi):
        rng = f">= {lo}" + (f" and <= {hi}" if hi is not None else "")
        raise ConfigError(f"{where} = {value!r} is out of range; allowed: an integer {rng}")
    return int(value)


def _axis_weight(where: str, value: Any) -> tuple[float, float, float]:
    """A per-axis weight: a number (same on x, y, z) or a 3-sequence, each >= 0."""
    arr = check_range(where, value, 0.0)
    if arr.ndim == 0:
        arr = np.repeat(arr, 3)
    if arr.shape != (3,):
        raise ConfigError(f"{where} must be a number or 3 numbers (x, y, z); got shape {arr.shape}")
    return tuple(float(a) for a in arr)


def _is_user_value(x: Any) -> bool:
    """A leaf a user handed in (number, string, sequence, numpy or concrete JAX array), as opposed
    to what JAX itself puts into a pytree when it rebuilds one (tracers, ``ArgInfo`` or shape
    structs under ``.lower``, ``None``/sentinels): only user values are validated."""
    if isinstance(x, jax.core.Tracer):
        return False
    return isinstance(x, (int, float, str, list, tuple, np.ndarray, np.generic, jax.Array))


# --------------------------------------------------------------------------------------------
# Gains: numeric, traced, vmappable
# --------------------------------------------------------------------------------------------

_GAIN_RANGES: dict[str, tuple[float, bool]] = {
    # name: (lower bound, lower bound is open)
    "gamma": (0.0, False),
    "k": (0.0, False),
    "k_rep": (0.0, True),
    "d_s": (0.0, True),
    "k_att": (0.0, True),
    "eta": (0.0, True),
}


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Gains:
    r"""Planner gains; every field is a pytree leaf (scalar or batched array).

    Attributes:
      gamma: direction gain γ >= 0 in ω(θ) = 1 + γ(1 + cos θ)/2 (paper eq. 15).
      k: relative-velocity gain k >= 0 in (2 + k tanh c) (paper eq. 19). ``k > 1`` breaks the
        paper's lower bound ω >= 1 (warns, see SPEC 3).
      k_rep: repulsive gain > 0 (paper eq. 13).
      d_s: influence distance > 0 [m] (paper eq. 13).
      k_att: attractive gain > 0, U_att = ½ k_att |p - g|².
      eta: step gain > 0 [m/s per unit force] of the reference gradient flow u = η F.
    """

    gamma: Any = 1.0
    k: Any = 0.5
    k_rep: Any = 10.0
    d_s: Any = 4.0
    k_att: Any = 1.0
    eta: Any = 0.5

    def __post_init__(self) -> None:
        # Pytree unflattening (vmap, grad) passes tracers or placeholders: only validate
        # values a user handed in.
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        if all(_is_user_value(v) for v in values.values()):
            validate_gains(values)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))

    def as_arrays(self, dtype: Any = None) -> "Gains":
        """The same gains as ``jnp`` arrays of ``dtype`` (default: JAX's default float)."""
        import jax.numpy as jnp

        dtype = dtype or jnp.result_type(float)
        return Gains(**{n: jnp.asarray(getattr(self, n), dtype) for n in self.names()})

    def replace(self, **changes: Any) -> "Gains":
        return dataclasses.replace(self, **changes)


def validate_gains(values: dict[str, Any], *, prefix: str = "gains") -> None:
    for name, (lo, lo_open) in _GAIN_RANGES.items():
        check_range(f"{prefix}.{name}", values[name], lo, lo_open=lo_open)
    if np.any(np.asarray(values["k"], dtype=np.float64) > 1.0):
        warnings.warn(
            f"{prefix}.k > 1: the paper's bound ω >= 1 fails (min ω = 2 - k < 1); "
            "for k >= 2 a receding obstacle's 'repulsion' becomes attraction",
            BoundWarning,
            stacklevel=4,
        )


# --------------------------------------------------------------------------------------------
# Static configuration
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class MPCConfig:
    r"""Box-constrained condensed MPC (paper eq. 8–12, SPEC 4). Static: hashable, compiled in.

    Attributes:
      horizon: prediction horizon N >= 1 (also the number of APF prediction points).
      iters: fixed FISTA iteration count >= 1.
      q_pos, q_vel: stage weights on predicted position / velocity, per axis (number or 3-tuple).
      f_pos, f_vel: terminal weights on x(k+N), per axis.
      r: input weight on every acceleration, per axis (> 0 keeps H positive definite).
      v_penalty: weight ρ >= 0 of the smooth convex penalty ½ρ Σ max(|v_i| - v_max, 0)² on the
        predicted velocities (the paper's velocity limit, kept inside the box-QP loop).
    """

    horizon: int = 20
    iters: int = 30
    q_pos: Any = 1.0
    q_vel: Any = 0.05
    f_pos: Any = 5.0
    f_vel: Any = 0.5
    r: Any = 0.05
    v_penalty: float = 10.0

    def __post_init__(self) -> None:
        check_int("mpc.horizon", self.horizon, 1, 500)
        check_int("mpc.iters", self.iters, 1, 10_000)
        for name in ("q_pos", "q_vel", "f_pos", "f_vel"):
            object.__setattr__(self, name, _axis_weight(f"mpc.{name}", getattr(self, name)))
        r = _axis_weight("mpc.r", self.r)
        if min(r) <= 0:
            raise ConfigError(f"mpc.r = {min(r)!r} is out of range; allowed: a finite number > 0")
        object.__setattr__(self, "r", r)
        object.__setattr__(self, "v_penalty", float(check_range("mpc.v_penalty", self.v_penalty, 0.0)))


@dataclasses.dataclass(frozen=True)
class SimConfig:
    r"""Episode, vehicle, potential and metric settings. Static: hashable, compiled in.

    Attributes:
      method: ``basic`` | ``direction`` | ``direction_velocity`` (SPEC 3).
      convention: ``intent`` (default, matches the paper's prose) | ``literal`` (the paper's
        formulas as printed), SPEC 3.
      dt: control / integration step [s] > 0.
      t_max: episode length [s] > 0 (``steps = round(t_max / dt)``).
      a_max: per-axis acceleration limit [m/s²] > 0 (hard box of the MPC).
      v_max: per-axis velocity limit [m/s] > 0 (MPC penalty; also the norm cap of the reference).
      r_uav: UAV sphere radius [m] >= 0.
      r_goal: goal tolerance [m] > 0.
      d_min: floor [m] > 0 on the clearance inside the repulsive potential (no inf/NaN).
      eps_v: regulariser [m/s] > 0 of |v| in cos θ: a hovering UAV has cos θ = 0.
      v_stall, t_stall: stall = speed below ``v_stall`` for at least ``t_stall`` seconds while
        farther than ``r_goal`` from the goal.
      d_safe: clearance [m] below which time counts as ``time_near``.
      att_cap: distance [m] beyond which the attractive potential turns conic (linear in
        distance); ``None`` (default) keeps it quadratic everywhere.
      reference_velocity: use the flow velocities u_i as the MPC velocity reference instead of
        the paper's zero (off by default).
    """

    method: Method = "direction_velocity"
    convention: Convention = "intent"
    dt: float = 0.1
    t_max: float = 60.0
    a_max: float = 3.0
    v_max: float = 2.0
    r_uav: float = 0.3
    r_goal: float = 0.5
    d_min: float = 0.05
    eps_v: float = 1e-3
    v_stall: float = 0.1
    t_stall: float = 3.0
    d_safe: float = 1.0
    att_cap: float | None = None
    reference_velocity: bool = False

    def __post_init__(self) -> None:
        check_choice("sim.method", self.method, METHODS)
        check_choice("sim.convention", self.convention, CONVENTIONS)
        positive = ("dt", "t_max", "a_max", "v_max", "r_goal", "d_min", "eps_v", "v_stall", "t_stall")
        for name in positive:
            object.__setattr__(self, name, float(check_range(f"sim.{name}", getattr(self, name), 0.0, lo_open=True)))
        for name in ("r_uav", "d_safe"):
            object.__setattr__(self, name, float(check_range(f"sim.{name}", getattr(self, name), 0.0)))
        if self.att_cap is not None:
            object.__setattr__(self, "att_cap", float(check_range("sim.att_cap", self.att_cap, 0.0, lo_open=True)))
        if not isinstance(self.reference_velocity, bool):
            raise ConfigError(f"sim.reference_velocity = {self.reference_velocity!r} must be true or false")
        if self.t_max / self.dt < 1:
            raise ConfigError(f"sim.t_max = {self.t_max!r} must be at least one step (sim.dt = {self.dt!r})")
        check_int("sim.steps", self.steps, 1, 10_000_000)

    @property
    def steps(self) -> int:
        """Number of control steps T of an episode."""
        return int(round(self.t_max / self.dt))

    def replace(self, **changes: Any) -> "SimConfig":
        return dataclasses.replace(self, **changes)


def gains_from_mapping(mapping: dict[str, Any], where: str = "gains", base: Gains | None = None) -> Gains:
    """:class:`Gains` from a mapping of gain names to numbers, on top of ``base`` (defaults).

    Unknown keys raise :class:`ConfigError` naming the key and listing the allowed ones.
    """
    unknown = sorted(set(mapping) - set(Gains.names()))
    if unknown:
        raise ConfigError(f"{where}.{unknown[0]} is not a gain; allowed: {', '.join(Gains.names())}")
    for name, value in mapping.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}.{name} = {value!r} must be a number")
    base = base or Gains()
    values = {n: getattr(base, n) for n in Gains.names()} | {k: float(v) for k, v in mapping.items()}
    validate_gains(values, prefix=where)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BoundWarning)  # already warned above, under `where`
        return Gains(**values)


def load_gains(path: str | os.PathLike, base: Gains | None = None) -> Gains:
    """Gains from a TOML file: either a ``[gains]`` table or gain keys at the top level
    (the fragment written by ``jaxapf tune``)."""
    import tomllib

    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"gains file {str(path)!r} does not exist") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"gains file {str(path)!r} is not valid TOML: {err}") from None
    table = data.get("gains", data)
    if not isinstance(table, dict):
        raise ConfigError(f"gains file {str(path)!r}: [gains] must be a table")
    return gains_from_mapping(table, where=f"{path}:gains", base=base)
