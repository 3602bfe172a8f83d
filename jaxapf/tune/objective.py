"""The smooth training objective of ``jaxapf tune`` and the reparametrisation of the gains.

The surrogate loss ``J = w_c C + w_p P + w_e E`` of one episode (soft collision, time-integrated goal
distance, control effort; differentiable, no episode-end mask) and the map from unconstrained reals to
gains inside their declared ranges. Both are defined exactly in docs/tune.md ("Objective",
"Reparametrisation").
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..config import SimConfig
from ..datatypes import Scenario, Trajectory, safe_norm
from ..gains import GAINS, Gains, check_gain_name
from ..metrics import clearance_history
from ..validation import ConfigError, check_range

__all__ = [
    "TERMS",
    "OPEN_FLOOR",
    "Objective",
    "smooth_min",
    "surrogate_terms",
    "surrogate_loss",
    "Reparam",
]

#: Names of the surrogate terms, in the order of the loss.
TERMS: tuple[str, ...] = ("soft_collision", "progress", "effort")

#: Added to the lower end of a gain whose range is open there (e.g. ``k_rep > 0``).
OPEN_FLOOR = 1e-3


@dataclasses.dataclass(frozen=True)
class Objective:
    r"""Weights and smoothing of the surrogate loss (static: hashable, compiled in).

    Attributes:
      w_collision: weight ``w_c >= 0`` of the soft collision term ``C`` [m·s].
      w_progress: weight ``w_p >= 0`` of the progress term ``P`` [s].
      w_effort: weight ``w_e >= 0`` of the control effort ``E`` [m²/s³].
      tau: smoothing length ``τ > 0`` [m] of both the soft minimum and the soft hinge.
      d_safe: safety margin ``d_safe >= 0`` [m] on the clearance (default 0.3 m: the UAV radius;
        a larger margin also penalises hovering at a goal placed near an obstacle, as in the
        ``trap`` kind ``gnron``).
    """

    w_collision: float = 10.0
    w_progress: float = 1.0
    w_effort: float = 0.01
    tau: float = 0.1
    d_safe: float = 0.3

    def __post_init__(self) -> None:
        for name in ("w_collision", "w_progress", "w_effort", "d_safe"):
            object.__setattr__(self, name, float(check_range(f"objective.{name}", getattr(self, name), 0.0)))
        object.__setattr__(self, "tau", float(check_range("objective.tau", self.tau, 0.0, lo_open=True)))

    def weights(self) -> tuple[float, ...]:
        """The weights in the order of :data:`TERMS`."""
        return (self.w_collision, self.w_progress, self.w_effort)


def smooth_min(x: Array, valid: Array, tau: float) -> Array:
    r"""``-τ log Σ_{valid} exp(-x/τ)`` over the last axis: a smooth lower bound of the minimum over
    the ``valid`` entries, within ``τ log(#valid)`` of it; +inf if none is valid. Invalid entries
    contribute exactly nothing (whatever their value)."""
    x = jnp.where(valid, x, 0.0)
    return -tau * jax.nn.logsumexp(-x / tau, axis=-1, b=valid.astype(x.dtype))


def surrogate_terms(traj: Trajectory, scenario: Scenario, sim: SimConfig, objective: Objective) -> dict[str, Array]:
    """The terms ``C``, ``P``, ``E`` of the module docstring for one episode (scalars, keyed by
    :data:`TERMS`: ``soft_collision``, ``progress``, ``effort``)."""
    dt, tau = sim.episode.dt, objective.tau
    clear = clearance_history(traj, scenario, sim)[1:]  # (T, M), +inf on padded slots
    soft = smooth_min(clear, scenario.obstacles.valid, tau)
    hinge = tau * jax.nn.softplus((objective.d_safe - soft) / tau)
    length = jnp.maximum(jnp.linalg.norm(scenario.goal - scenario.start), sim.episode.r_goal)
    distance = safe_norm(traj.position[1:] - scenario.goal)
    return {
        "soft_collision": dt * jnp.sum(hinge),
        "progress": dt * jnp.sum(distance) / length,
        "effort": dt * jnp.sum(traj.control * traj.control),
    }


def surrogate_loss(terms: Mapping[str, Array], objective: Objective) -> Array:
    """``J = w_c C + w_p P + w_e E`` from :func:`surrogate_terms` (any common batch shape)."""
    return sum(w * terms[name] for name, w in zip(TERMS, objective.weights()))


# --------------------------------------------------------------------------------------------
# reparametrisation
# --------------------------------------------------------------------------------------------


def flatten_theta(theta: Mapping[str, Any], names: tuple[str, ...], lead: int = 0) -> Array:
    """θ's entries as one vector of coordinates (after ``lead`` batch axes), ``names`` in order: what the
    perturbed gradient estimators perturb and CMA-ES searches (a number is one coordinate, a network many)."""
    return jnp.concatenate([jnp.reshape(theta[n], jnp.shape(theta[n])[:lead] + (-1,)) for n in names], axis=-1)


def unflatten_theta(flat: Array, shapes: Mapping[str, tuple[int, ...]], names: tuple[str, ...]) -> dict[str, Array]:
    """The inverse of :func:`flatten_theta`: each name's coordinates of ``flat`` (after its batch axes) in its
    shape."""
    out, at, lead = {}, 0, flat.shape[:-1]
    for n in names:
        size = math.prod(shapes[n])
        out[n] = flat[..., at:at + size].reshape(lead + tuple(shapes[n]))
        at += size
    return out


def _softplus_inverse(y: float) -> float:
    """``θ`` with ``softplus(θ) = y > 0``: ``y + log(-expm1(-y))`` (stable for large and small y)."""
    return y + math.log(-math.expm1(-y))


@dataclasses.dataclass(frozen=True)
class Reparam:
    r"""Map between unconstrained parameters ``θ`` (a dict ``{gain name: scalar}`` over
    ``names``) and :class:`~jaxapf.gains.Gains` (module docstring). Gains not in ``names`` stay at
    ``base``.

    Attributes:
      names: the tuned gains, declared tunable gains, in declaration order.
      base: the gains the untuned entries keep (and the tuned ones start from).
      upper: ``(gain, b)`` pairs overriding the upper end ``b`` of a gain's map (``inf``: unbounded).
    """

    names: tuple[str, ...]
    base: Gains
    upper: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        for name in self.names:
            spec = check_gain_name("tune.params", name)
            if not spec.tunable:
                raise ConfigError(f"tune.params: {name!r} is not a tunable gain")
        if not self.names or len(set(self.names)) != len(self.names):
            raise ConfigError(f"tune.params = {list(self.names)!r} must list one or more distinct gains")
        object.__setattr__(self, "names", tuple(n for n in GAINS.names() if n in self.names))
        upper = []
        for name, value in self.upper:
            check_gain_name("tune.upper", name)
            if value != math.inf:
                value = float(check_range(f"tune.upper.{name}", value))
            upper.append((name, value))
        object.__setattr__(self, "upper", tuple(upper))
        for name in self.names:
            low, high = self.bounds(name)
            if high is not None and (low is None or high <= low):
                raise ConfigError(f"tune.upper.{name} = {high!r} must lie above the gain's lower end {low!r}")

    def bounds(self, name: str) -> tuple[float | None, float | None]:
        """``(a, b)``: the lower end and the tuning upper end (``None``: unbounded) of gain ``name``."""
        spec = GAINS.get(name)
        high = dict(self.upper).get(name)
        if high is None or high == math.inf:
            high = spec.high if high == math.inf else spec.tuning_high
        elif spec.high is not None:
            high = min(high, spec.high)
        return spec.low, high

    def _floor(self, name: str) -> float:
        spec = GAINS.get(name)
        return spec.low + (OPEN_FLOOR if spec.low_open else 0.0)

    def gains(self, theta: Mapping[str, Array]) -> Gains:
        """The gains of ``θ`` (differentiable; always inside their allowed ranges)."""
        values = {}
        for name in self.names:
            low, high = self.bounds(name)
            if high is not None:
                value = (high - low) * jax.nn.sigmoid(theta[name])
                values[name] = low + value if low else value
            elif low is not None:
                values[name] = self._floor(name) + jax.nn.softplus(theta[name])
            else:
                values[name] = theta[name]
        return self.base.replace(**values)

    def theta(self, gains: Gains, dtype=None) -> dict[str, Array]:
        """The ``θ`` of ``gains`` (the inverse of :meth:`gains` on the tuned entries).

        Raises :class:`ConfigError` if a tuned gain lies outside the open image of its map (e.g.
        ``k`` not strictly inside ``(0, upper)``, ``γ = 0``), where no finite ``θ`` reaches it.
        """
        dtype = dtype or jnp.result_type(float)
        return {n: jnp.asarray(np.vectorize(lambda v, n=n: self._theta(n, float(v)), otypes=[np.float64])(
            np.asarray(gains[n], np.float64)), dtype) for n in self.names}

    def _theta(self, name: str, value: float) -> float:
        """θ of one number of gain ``name`` (an array-valued gain's entries one by one)."""
        low, high = self.bounds(name)
        if high is not None:
            if not low < value < high:
                raise ConfigError(f"init.{name} = {value!r} must lie strictly inside ({low:g}, {high:g}) to be "
                                  f"tuned ({name} = {low:g} + ({high:g} - {low:g})·sigmoid(θ))")
            u = (value - low) / (high - low)
            return math.log(u / (1.0 - u))
        if low is not None:
            floor = self._floor(name)
            if not value > floor:
                raise ConfigError(f"init.{name} = {value!r} must be > {floor:g} to be tuned "
                                  f"({name} = {floor:g} + softplus(θ))")
            return _softplus_inverse(value - floor)
        return value

    def flatten(self, theta: Mapping[str, Any]) -> np.ndarray:
        """θ as one float64 vector, the gains in :attr:`names` order (what CMA-ES searches)."""
        return np.asarray(flatten_theta(theta, self.names), np.float64)

    def unflatten(self, x: Any, dtype: Any = None) -> dict[str, Array]:
        """The inverse of :meth:`flatten`: θ of a vector ``x``, each gain in its shape."""
        return unflatten_theta(jnp.asarray(x, dtype or jnp.float32), {n: GAINS.get(n).shape for n in self.names},
                               self.names)
