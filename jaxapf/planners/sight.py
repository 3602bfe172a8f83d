"""The line of sight from the UAV to its obstacles, component by component.

The force evaluation works on whole rows of M obstacles per component (x, y, z): ``p_o`` and
``v_o`` are component-first ``(3, M)`` arrays (:class:`~jaxapf.datatypes.ObstacleColumns`), and
vectors are tuples or arrays whose leading axis of size 3 is x, y, z. Dot products are written out
so that XLA fuses them with their neighbours.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax.numpy as jnp
from jax import Array

from ..datatypes.obstacles import TINY

__all__ = ["Sight", "dot", "norm", "line_of_sight"]


def dot(a: Any, b: Any) -> Array:
    """Dot product of two component-first vectors (any trailing axes broadcast)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def norm(a: Any) -> Array:
    """Component-first :func:`~jaxapf.datatypes.safe_norm` (gradient zero at the origin)."""
    return jnp.sqrt(jnp.maximum(dot(a, a), TINY))


def line_of_sight(p: Array, p_o: Array, cylinder: Array | bool) -> tuple[Array, Array, Array]:
    """``s = P(p_o - p)`` component by component (``P`` drops z for a cylinder).

    The difference is taken as one vector operation (``p`` broadcast along the obstacle axes of
    ``p_o``) before it is split into components: ``∇_p`` then reaches ``p`` as a single sum over
    the obstacles of a (3, M) cotangent, which XLA:CPU fuses with the per-obstacle backward pass
    into one vectorised reduction; indexing ``p`` per component would instead give three sums and
    more per-obstacle kernels (the whole closed loop ran a median 1.14x faster this way,
    docs/performance.md).
    """
    p = jnp.asarray(p)
    s = p_o - jnp.reshape(p, p.shape + (1,) * (jnp.ndim(p_o) - p.ndim))
    return s[0], s[1], jnp.where(cylinder, 0.0, s[2])


class Sight(NamedTuple):
    """What a weight ω sees of its obstacle(s).

    Attributes:
      s: line of sight ``P(p_o - p)`` from the UAV to each obstacle, as 3 component arrays.
      v: UAV velocity (3,).
      v_o: obstacle velocity, component-first (3,) or (3, M).
      p: UAV position (3,).
      goal: the goal (3,), or ``None`` where no goal is known (a single obstacle's potential).
      clearance: the clearance ``d = |s| - radius`` to each obstacle's surface, or ``None`` where the
        radius is not known (a weight then reads ``|s|``).
    """

    s: tuple[Array, Array, Array]
    v: Array
    v_o: Array
    p: Array
    goal: Array | None = None
    clearance: Array | None = None
