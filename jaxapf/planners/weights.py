r"""Repulsive weights ω (paper eq. 14–20): a factor on each obstacle's repulsive potential.

``Basic`` (ω = 1), ``Direction`` (eq. 15) and ``DirectionVelocity`` (eq. 19, the paper's proposal), read
under either sign convention (``intent``, ``literal``); :class:`Normalised` divides a weight by its value
abeam at zero closing speed, so only the weighting's shape differs from ``basic``; :class:`Chosen` flies
several weights in one compiled program, each episode the one its gains choose. The force is ``-∇_p`` of
``ω U_rep`` (:mod:`jaxapf.planners.potentials`), so a weight that depends on ``p`` adds its sideways term
by itself. A new weight is a subclass of :class:`Weight`, flown by registering ``APF(weight)``. The
formulas, the conventions and why equal gains compare strengths: docs/spec.md §3.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, ClassVar

import jax.numpy as jnp
from jax import Array

from ..gains import GainSpec
from ..validation import ConfigError
from .sight import Sight, dot, norm

__all__ = ["GAMMA", "K", "CHOICE", "Weight", "Basic", "Direction", "DirectionVelocity", "Normalised", "Chosen",
           "reference_sight", "direction_weight", "velocity_weight"]

GAMMA = GainSpec("gamma", 1.0, low=0.0, symbol="γ",
                 doc="direction gain γ in ω(θ) = 1 + γ(1 + cos θ)/2 (paper eq. 15)")
K = GainSpec("k", 0.5, low=0.0, tune_high=1.0, warn_above=1.0,
             doc="relative-velocity gain k in (2 + k tanh c) (paper eq. 19)",
             warning="the paper's bound ω >= 1 fails (min ω = 2 - k < 1); for k >= 2 a receding obstacle's "
                     "'repulsion' becomes attraction")

#: Which weight of a :class:`Chosen` an episode flies: the position of its method among the program's
#: (set by the sweep that fuses them, never by a spec; not declared, so no spec, flag or column sees it).
CHOICE = GainSpec("weight_choice", 0.0, low=0.0, tunable=False,
                  doc="which weight of a fused program an episode flies (its method's position)")


def direction_weight(cos_theta: Array, gamma: Array) -> Array:
    r"""ω(θ) = 1 + γ (1 + cos θ) / 2 (paper eq. 15); in [1, 1 + γ] for γ >= 0."""
    return 1.0 + gamma * 0.5 * (1.0 + cos_theta)


def velocity_weight(c: Array, k: Array) -> Array:
    r"""The relative-velocity factor 2 + k tanh(c) of paper eq. 19; in [2 - k, 2 + k]."""
    return 2.0 + k * jnp.tanh(c)


class Weight(abc.ABC):
    """ω of each obstacle: a pure function of what it sees (:class:`~jaxapf.planners.sight.Sight`)
    and the gains. Subclasses are frozen dataclasses.

    Attributes:
      gains: the gains it reads (declared when it is registered).
      uses_convention: whether it reads ``convention`` (SPEC 3).
    """

    gains: ClassVar[tuple[GainSpec, ...]] = ()
    uses_convention: ClassVar[bool] = False

    @abc.abstractmethod
    def __call__(self, sight: Sight, gains: Any, *, convention: str, eps_v: float) -> Array:
        """ω per obstacle, broadcasting against the line of sight's components (a scalar is fine)."""

    def bounds(self, gains: Any) -> tuple[Array, Array]:
        """The true (min, max) of ω over all geometries, where the weight states them."""
        raise ConfigError(f"the weight {type(self).__name__} does not state its bounds")

    def reference(self, gains: Any, *, convention: str = "intent", eps_v: float = 1e-3) -> Array:
        """ω at the reference condition: an obstacle abeam (θ = 90°) with zero closing speed
        (:func:`reference_sight`). A weight that reads more than the relative geometry (e.g. the
        goal) overrides this."""
        return self(reference_sight(jnp.result_type(float)), gains, convention=convention, eps_v=eps_v)


def reference_sight(dtype: Any) -> Sight:
    """A UAV moving at 1 m/s along y, an obstacle 1 m away along x moving with it: θ = 90°, c = 0."""
    one, zero = jnp.ones((), dtype), jnp.zeros((), dtype)
    v = jnp.stack([zero, one, zero])
    return Sight(s=(one, zero, zero), v=v, v_o=v, p=jnp.zeros(3, dtype))


def _direction(sight: Sight, gamma: Array, convention: str, eps_v: float) -> tuple[Array, tuple, Array]:
    """ω(θ) and the oriented line of sight with its length (shared by the direction weights)."""
    s = tuple(-c for c in sight.s) if convention == "literal" else sight.s  # r_e = p - p_o, as printed
    dist = norm(s)
    speed = jnp.sqrt(dot(sight.v, sight.v) + eps_v**2)
    return direction_weight(dot(sight.v, s) / (dist * speed), gamma), s, dist


@dataclasses.dataclass(frozen=True)
class Basic(Weight):
    """ω = 1: the classical potential (paper eq. 13)."""

    def __call__(self, sight: Sight, gains: Any, *, convention: str, eps_v: float) -> Array:
        return jnp.ones((), jnp.result_type(sight.v))

    def bounds(self, gains: Any) -> tuple[Array, Array]:
        return jnp.ones(()), jnp.ones(())


@dataclasses.dataclass(frozen=True)
class Direction(Weight):
    """ω = 1 + γ(1 + cos θ)/2: obstacles ahead weigh more (paper eq. 15)."""

    gains = (GAMMA,)
    uses_convention = True

    def __call__(self, sight: Sight, gains: Any, *, convention: str, eps_v: float) -> Array:
        return _direction(sight, gains.gamma, convention, eps_v)[0]

    def bounds(self, gains: Any) -> tuple[Array, Array]:
        return jnp.ones_like(gains.gamma), 1.0 + gains.gamma


@dataclasses.dataclass(frozen=True)
class DirectionVelocity(Weight):
    """ω = [1 + γ(1 + cos θ)/2](2 + k tanh c): ahead and closing weigh more (paper eq. 19)."""

    gains = (GAMMA, K)
    uses_convention = True

    def __call__(self, sight: Sight, gains: Any, *, convention: str, eps_v: float) -> Array:
        w, s, dist = _direction(sight, gains.gamma, convention, eps_v)
        closing = tuple(a - b for a, b in zip(sight.v, sight.v_o))
        return w * velocity_weight(dot(closing, s) / dist, gains.k)

    def bounds(self, gains: Any) -> tuple[Array, Array]:
        gamma, k = gains.gamma, gains.k
        lo = jnp.where(k <= 2.0, 2.0 - k, (1.0 + gamma) * (2.0 - k))
        return lo, (1.0 + gamma) * (2.0 + k)


@dataclasses.dataclass(frozen=True)
class Normalised(Weight):
    """ω / ω_ref: the inner weight divided by its value at the reference condition (θ = 90°, zero
    closing speed), so it is 1 there whatever the gains (module docstring)."""

    inner: Weight

    @property
    def gains(self) -> tuple[GainSpec, ...]:  # type: ignore[override]
        return self.inner.gains

    @property
    def uses_convention(self) -> bool:  # type: ignore[override]
        return self.inner.uses_convention

    def __call__(self, sight: Sight, gains: Any, *, convention: str, eps_v: float) -> Array:
        ref = self.inner.reference(gains, convention=convention, eps_v=eps_v)
        return self.inner(sight, gains, convention=convention, eps_v=eps_v) / ref

    def bounds(self, gains: Any) -> tuple[Array, Array]:
        lo, hi = self.inner.bounds(gains)
        ref = self.inner.reference(gains)
        return lo / ref, hi / ref


@dataclasses.dataclass(frozen=True)
class Chosen(Weight):
    """One of ``weights``, chosen per episode by the gain ``weight_choice`` (:data:`CHOICE`: 0 the first):
    methods that differ only in their weight fly one compiled program (the accelerator policy,
    :mod:`jaxapf.engine.policy`). Every weight is computed and the chosen one selected, so the chosen
    weight's value and gradient are its own."""

    weights: tuple[Weight, ...]

    @property
    def gains(self) -> tuple[GainSpec, ...]:  # type: ignore[override]
        return tuple({g.name: g for w in self.weights for g in w.gains}.values()) + (CHOICE,)

    @property
    def uses_convention(self) -> bool:  # type: ignore[override]
        return any(w.uses_convention for w in self.weights)

    def _select(self, gains: Any, values: list[Any]) -> Any:
        out = values[-1]
        for i in range(len(values) - 2, -1, -1):
            out = jnp.where(gains[CHOICE.name] == i, values[i], out)
        return out

    def __call__(self, sight: Sight, gains: Any, *, convention: str, eps_v: float) -> Array:
        return self._select(gains, [w(sight, gains, convention=convention, eps_v=eps_v) for w in self.weights])

    def bounds(self, gains: Any) -> tuple[Array, Array]:
        lows, highs = zip(*(w.bounds(gains) for w in self.weights))
        return self._select(gains, list(lows)), self._select(gains, list(highs))
