r"""Obstacle fields and their geometry (SPEC 2).

An obstacle field holds a fixed maximum number ``M`` of obstacles; unused slots have
``valid = False`` and contribute exactly nothing (zero potential, zero force, +inf clearance).

Clearance (surface distance) of the UAV sphere to an obstacle is

.. math::  d = \lVert P (p - p_o) \rVert - \rho - r_{uav},

where ``P`` drops z for a vertical cylinder of infinite height and is the identity for a sphere.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jax import Array

__all__ = [
    "Obstacles",
    "ObstacleColumns",
    "project",
    "safe_norm",
    "obstacles_at",
    "clearance",
    "segment_clearance",
    "TINY",
]

#: Offset added inside square roots so that norms stay differentiable at zero.
TINY = 1e-12


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Obstacles:
    """A padded set of ``M`` obstacles (leading axis ``M``; extra leading axes for batches).

    Attributes:
      position: (M, 3) centre at t = 0 [m].
      velocity: (M, 3) constant velocity [m/s].
      radius: (M,) radius ρ [m].
      cylinder: (M,) True for a vertical cylinder of infinite height, False for a sphere.
      valid: (M,) True for a real obstacle, False for a padded slot.
      agent: (M,) True for another UAV running the same stack (a swarm's neighbour,
        :mod:`jaxapf.datatypes.swarm`), which a reciprocal planner shares the avoidance with; ``None``
        (no leaf) where no obstacle is one, as in every single-UAV field.
    """

    position: Array
    velocity: Array
    radius: Array
    cylinder: Array
    valid: Array
    agent: Array | None = None

    @property
    def size(self) -> int:
        return self.radius.shape[-1]

    @classmethod
    def empty(cls, size: int, dtype=jnp.float32) -> "Obstacles":
        """``size`` padded (invalid) slots, parked far away."""
        return cls(
            position=jnp.full((size, 3), 1e6, dtype),
            velocity=jnp.zeros((size, 3), dtype),
            radius=jnp.zeros((size,), dtype),
            cylinder=jnp.zeros((size,), bool),
            valid=jnp.zeros((size,), bool),
        )

    def padded(self, size: int) -> "Obstacles":
        """These obstacles followed by padded slots (:meth:`empty`) up to ``size`` slots, on every batch of
        the leading axes (families of one sweep sharing one program, :class:`~jaxapf.engine.policy.Policy`)."""
        extra = size - self.size
        if extra <= 0:
            return self
        lead = self.radius.shape[:-1]
        empty = Obstacles.empty(extra, self.position.dtype)
        empty = dataclasses.replace(empty, agent=None if self.agent is None else jnp.zeros((extra,), bool))

        def pad(leaf: Array, fill: Array) -> Array:
            return jnp.concatenate([leaf, jnp.broadcast_to(fill, lead + fill.shape)], axis=len(lead))
        return jax.tree_util.tree_map(pad, self, empty)

    def columns(self) -> "ObstacleColumns":
        """The same obstacles with component-first vectors (see :class:`ObstacleColumns`)."""
        first = lambda a: jnp.moveaxis(a, -1, -2)  # noqa: E731  (..., M, 3) -> (..., 3, M)
        return ObstacleColumns(position=first(self.position), velocity=first(self.velocity),
                               radius=self.radius, cylinder=self.cylinder, valid=self.valid, agent=self.agent)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ObstacleColumns:
    """:class:`Obstacles` with component-first vectors: ``position``, ``velocity`` (3, M), the rest (M,).

    The force evaluation works on whole rows of M obstacles per component (x, y, z), which XLA
    fuses into a few contiguous loops; the closed loop converts a field once per episode
    (:meth:`Obstacles.columns`) instead of once per prediction point. Functions that take either
    layout call ``.columns()`` on what they get (a no-op here).
    """

    position: Array
    velocity: Array
    radius: Array
    cylinder: Array
    valid: Array
    agent: Array | None = None

    def columns(self) -> "ObstacleColumns":
        """Already component-first: itself."""
        return self


def project(r: Array, cylinder: Array) -> Array:
    """``P r``: drop the z component of ``r`` (..., 3) where ``cylinder`` is True."""
    keep_z = jnp.where(cylinder, 0.0, 1.0).astype(r.dtype)
    return r * jnp.stack([jnp.ones_like(keep_z), jnp.ones_like(keep_z), keep_z], axis=-1)


def safe_norm(r: Array, axis: int = -1) -> Array:
    """Euclidean norm whose gradient is finite (zero) at ``r = 0``."""
    sq = jnp.sum(r * r, axis=axis)
    return jnp.sqrt(jnp.maximum(sq, TINY))


def obstacles_at(obstacles: Obstacles, t: Array | float) -> Array:
    """Obstacle centres (M, 3) at time ``t`` under constant velocity."""
    return obstacles.position + obstacles.velocity * t


def clearance(p: Array, obstacles: Obstacles, t: Array | float, r_uav: float) -> Array:
    """Clearance (M,) of the UAV at ``p`` to each obstacle at time ``t``; +inf for padded slots."""
    rel = project(p - obstacles_at(obstacles, t), obstacles.cylinder)
    d = safe_norm(rel) - obstacles.radius - r_uav
    return jnp.where(obstacles.valid, d, jnp.inf)


def segment_clearance(
    p0: Array, p1: Array, obstacles: Obstacles, t0: Array | float, t1: Array | float, r_uav: float
) -> Array:
    r"""Smallest clearance (M,) over the step from ``(p0, t0)`` to ``(p1, t1)``.

    Both UAV and obstacles move linearly between the two samples, so the relative position is
    :math:`r(s) = r_0 + s (r_1 - r_0)`, :math:`s \in [0, 1]`; the closest approach is at
    :math:`s^* = \mathrm{clip}(-r_0\cdot\delta / \lVert\delta\rVert^2, 0, 1)` with
    :math:`\delta = r_1 - r_0` (after the cylinder projection ``P``). This catches a fast crossing
    that tunnels through an obstacle between two samples.
    """
    r0 = project(p0 - obstacles_at(obstacles, t0), obstacles.cylinder)
    r1 = project(p1 - obstacles_at(obstacles, t1), obstacles.cylinder)
    delta = r1 - r0
    dd = jnp.sum(delta * delta, axis=-1)
    s = jnp.clip(-jnp.sum(r0 * delta, axis=-1) / jnp.maximum(dd, TINY), 0.0, 1.0)
    closest = r0 + s[..., None] * delta
    d = safe_norm(closest) - obstacles.radius - r_uav
    return jnp.where(obstacles.valid, d, jnp.inf)
