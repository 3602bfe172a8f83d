"""The toolkit of family builders: a field's random numbers and its obstacles in the local frame.

Local frame: start at the origin, goal at ``(L, 0)``, x along the start–goal line, y to its left;
xy only (obstacles live in the plane of flight and move horizontally).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

__all__ = ["Draws", "Layout", "CUP_SIZE", "static", "fit", "cup", "scatter", "with_motion"]

#: Cylinders in a concave cup (paper_static and the trap kind ``concave``).
CUP_SIZE = 5


class Draws:
    """A field's random numbers, handed out in order from one block of uniforms in [0, 1).

    One ``jax.random.uniform`` call per field instead of one per quantity: every threefry call
    site adds a noticeable fraction of a second of XLA compile time on CPU, while the block's size
    costs nothing. The block holds ``draws[0] + draws[1] · max_obstacles`` numbers
    (:attr:`~jaxapf.scenarios.base.FamilyParams.draws`); asking for more is a programming error
    caught while tracing.
    """

    def __init__(self, u: Array) -> None:
        self._u = u
        self._used = 0

    def uniform(self, span: tuple, shape: tuple[int, ...] = ()) -> Array:
        """Uniform in ``[lo, hi)``; exactly ``lo`` when ``lo == hi``."""
        n = math.prod(shape)
        if self._used + n > self._u.shape[0]:
            raise RuntimeError(f"scenario draw budget of {self._u.shape[0]} numbers exceeded; raise the "
                               "family's FamilyParams.draws")
        u = self._u[self._used:self._used + n].reshape(shape)
        self._used += n
        lo, hi = span
        return lo + (hi - lo) * u

    def integers(self, lo: int, hi: int, shape: tuple[int, ...] = ()) -> Array:
        """Uniform in the integers ``lo … hi``."""
        return jnp.minimum(jnp.floor(self.uniform((lo, hi + 1), shape)), hi).astype(int)

    def signs(self, shape: tuple[int, ...]) -> Array:
        """±1 with equal probability."""
        return jnp.where(self.uniform((0.0, 1.0), shape) < 0.5, 1.0, -1.0)

    def directions(self, n: int) -> Array:
        """``n`` horizontal unit vectors (n, 2) in uniformly random directions."""
        phi = self.uniform((0.0, 2.0 * math.pi), (n,))
        return jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1)


class Layout(NamedTuple):
    """Obstacles in the local frame, any number K of rows."""

    xy: Array  # (K, 2) centres at t = 0
    vxy: Array  # (K, 2) velocities
    radius: Array  # (K,)
    valid: Array  # (K,) bool


def static(xy: Array, radius: Array) -> Layout:
    """Static obstacles, all valid."""
    return Layout(xy, jnp.zeros_like(xy), radius, jnp.ones(radius.shape, bool))


def fit(layout: Layout, size: int) -> Layout:
    """Exactly ``size`` rows: cut, or followed by invalid rows of zeros. Only rows that are
    invalid are ever cut (parameter validation makes ``max_obstacles`` hold every valid row)."""
    extra = max(size - layout.radius.shape[0], 0)
    return Layout(*(jnp.concatenate([a[:size], jnp.zeros((extra,) + a.shape[1:], a.dtype)]) for a in layout))


def cup(mid_x: Array, y: Array, cup_radius: Array | float, radius: Array | float) -> Layout:
    """``CUP_SIZE`` cylinders of ``radius`` evenly on a half circle of ``cup_radius`` whose open
    side faces the start (angles -90°…90° from +x); the cup spans ``mid_x ± cup_radius/2`` in x."""
    angles = jnp.linspace(-0.5 * math.pi, 0.5 * math.pi, CUP_SIZE, dtype=mid_x.dtype)
    centre_x = mid_x - 0.5 * cup_radius
    xy = jnp.stack([centre_x + cup_radius * jnp.cos(angles), y + cup_radius * jnp.sin(angles)], axis=-1)
    return static(xy, jnp.full((CUP_SIZE,), radius, mid_x.dtype))


def scatter(d: Draws, size: int, count: Array | int, length: Array, width: float,
            radius: tuple[float, float]) -> Layout:
    """``size`` rows, the first ``count`` valid: centres uniform in ``[0, L] × [-w/2, w/2]``, radii
    uniform in ``radius``, at rest."""
    x = d.uniform((0.0, length), (size,))
    y = d.uniform((-0.5 * width, 0.5 * width), (size,))
    xy = jnp.stack([x, y], axis=-1)
    return Layout(xy, jnp.zeros_like(xy), d.uniform(radius, (size,)), jnp.arange(size) < count)


def with_motion(layout: Layout, d: Draws, speed: tuple[float, float], moving: Array) -> Layout:
    """``layout`` whose rows where ``moving`` get random horizontal velocities (speed uniform)."""
    n = layout.radius.shape[0]
    vxy = d.directions(n) * d.uniform(speed, (n, 1))
    return layout._replace(vxy=jnp.where(moving[:, None], vxy, 0.0))
