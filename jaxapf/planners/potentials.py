r"""Attractive and weighted repulsive potentials (paper section 3, SPEC 3), and their forces.

Attractive potential, optionally conic beyond ``att_cap``:

.. math::  U_{att}(p) = \tfrac12 k_{att} \lVert p - g\rVert^2

Classical repulsive potential of one obstacle with clearance ``d`` (paper eq. 13):

.. math::  U_{rep}(d) = \tfrac12 k_{rep} (1/d - 1/d_s)^2 \ \text{for } d \le d_s, \ 0 \text{ otherwise}

with ``d`` floored smoothly at ``d_min > 0`` (:func:`floored_clearance`). The weighted potential
is :math:`U^*_{rep} = \omega U_{rep}` (paper eq. 14 and 20) with a weight ω of
:mod:`jaxapf.planners.weights`, named by ``method`` (``basic``, ``direction``,
``direction_velocity``, or any registered weight).

Forces are ``-jax.grad`` of the total potential with respect to the UAV position ``p`` (v, p_o, v_o
held fixed), so the weighted force is :math:`-(\omega\nabla U_{rep} + U_{rep}\nabla\omega)`.

Gains are passed by name (``k_rep``, ``d_s`` and the weight's own, e.g. ``gamma``, ``k``); every
function accepts float32 and float64 and is ``jit``/``vmap``/``grad``-compatible.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from jax import Array

from ..config import CONVENTIONS
from ..datatypes import ObstacleColumns, Obstacles, safe_norm
from ..gains import Gains
from ..validation import ConfigError, check_choice
from .base import PLANNERS
from .sight import Sight, line_of_sight, norm
from .weights import Weight, direction_weight, velocity_weight

__all__ = [
    "D_MIN",
    "EPS_V",
    "attractive_potential",
    "floored_clearance",
    "repulsive_potential",
    "direction_weight",
    "velocity_weight",
    "weight",
    "weight_bounds",
    "weighted_repulsive_potential",
    "repulsive_force",
    "total_potential",
    "total_force",
]

#: Default floor on the clearance inside U_rep [m] (PlannerConfig.d_min).
D_MIN = 0.05
#: Default regulariser of |v| in cos θ [m/s] (PlannerConfig.eps_v).
EPS_V = 1e-3


def attractive_potential(p: Array, goal: Array, k_att: Array, att_cap: float | None = None) -> Array:
    r"""``½ k_att |p - g|²``; with ``att_cap = ρ_c`` it is conic beyond ``ρ_c``:
    :math:`k_{att}(\rho_c |p-g| - \rho_c^2/2)` (continuous value and gradient at ``ρ_c``)."""
    dist = safe_norm(p - goal)
    quad = 0.5 * k_att * dist**2
    if att_cap is None:
        return quad
    return jnp.where(dist <= att_cap, quad, k_att * (att_cap * dist - 0.5 * att_cap**2))


def floored_clearance(d: Array, d_min: float = D_MIN) -> Array:
    r"""Clearance floored at ``d_min`` so ``1/d`` stays finite, but with a gradient that never vanishes.

    .. math:: \tilde d = d \ \text{for } d \ge d_{min}, \qquad
              \tilde d = d_{min}^2 / (2 d_{min} - d) \ \text{for } d < d_{min}

    The floor is C¹ at ``d_min`` (value ``d_min``, slope 1), stays positive for any penetration
    depth and keeps decreasing with ``d``, so inside an obstacle the repulsion still points out
    (a hard ``max(d, d_min)`` would switch the force off exactly when it is needed most).
    """
    below = d_min * d_min / (2.0 * d_min - jnp.minimum(d, d_min))
    return jnp.where(d >= d_min, d, below)


def repulsive_potential(d: Array, k_rep: Array, d_s: Array, d_min: float = D_MIN) -> Array:
    r"""Classical repulsive potential (paper eq. 13) of clearance ``d``, floored by
    :func:`floored_clearance` at ``d_min``."""
    d = floored_clearance(d, d_min)
    inside = d <= d_s
    # Evaluate on a safe value outside so that the unselected branch has a finite gradient.
    gap = jnp.where(inside, 1.0 / d - 1.0 / d_s, 0.0)
    return 0.5 * k_rep * gap**2


def _weight(method: str | Weight) -> Weight:
    """``method`` itself, or the weight of the potential-field planner registered as ``method``."""
    if isinstance(method, Weight):
        return method
    weight = getattr(PLANNERS.get(method, "method"), "weight", None)
    if not isinstance(weight, Weight):
        raise ConfigError(f"method = {method!r} is not a potential-field planner (no weight ω); choose one of "
                          + ", ".join(n for n, p in PLANNERS.items() if isinstance(getattr(p, "weight", None), Weight)))
    return weight


def weight(p: Array, v: Array, p_o: Array, v_o: Array, *, method: str | Weight, convention: str,
           cylinder: Array | bool = False, eps_v: float = EPS_V, goal: Array | None = None, **gains: Array) -> Array:
    """The weight ω of one obstacle for ``method`` under ``convention`` (gains by name, e.g.
    ``gamma=1.0, k=0.5``).

    ``p``, ``v``, ``p_o``, ``v_o`` are (3,) vectors; ``p_o``, ``v_o`` may also be component-first
    ``(3, M)`` arrays of M obstacles (``cylinder`` (M,)), giving ω of each, shape (M,).
    """
    check_choice("convention", convention, CONVENTIONS)
    sight = Sight(line_of_sight(p, p_o, cylinder), v, v_o, p, goal)
    return _weight(method)(sight, Gains.unchecked(gains), convention=convention, eps_v=eps_v)


def weight_bounds(method: str | Weight, **gains: Array) -> tuple[Array, Array]:
    """True (min, max) of ω over all geometries: (1, 1+γ) for ``direction``; (2 - k, (1+γ)(2+k))
    for ``direction_velocity`` when k <= 2 (for k > 2 the minimum (1+γ)(2-k) is negative)."""
    return _weight(method).bounds(Gains.unchecked(gains))


def _repulsion(p: Array, v: Array, p_o: Array, v_o: Array, radius: Array | float, cylinder: Array | bool,
               gains: Any, method: str | Weight, convention: str, d_min: float, eps_v: float,
               goal: Array | None) -> Array:
    """``ω · U_rep(d)`` of the obstacle(s) at ``p_o`` (see :func:`weighted_repulsive_potential`)."""
    sight = line_of_sight(p, p_o, cylinder)
    d = norm(sight) - radius
    w = _weight(method)(Sight(sight, v, v_o, p, goal, d), gains, convention=convention, eps_v=eps_v)
    if jnp.size(w) != 1 and jnp.shape(w) != jnp.shape(d):  # broadcast, ω of one obstacle would weigh another's
        name = method if isinstance(method, str) else type(method).__name__
        raise ConfigError(f"the weight ω of {name!r} returned shape {jnp.shape(w)}, not {jnp.shape(d)}: one ω per "
                          "obstacle (or one for all), as docs/extending.md ('A repulsive weight ω') says")
    return w * repulsive_potential(d, gains.k_rep, gains.d_s, d_min)


def weighted_repulsive_potential(
    p: Array,
    v: Array,
    p_o: Array,
    v_o: Array,
    *,
    k_rep: Array,
    d_s: Array,
    method: str | Weight = "direction_velocity",
    convention: str = "intent",
    radius: Array | float = 0.0,
    cylinder: Array | bool = False,
    d_min: float = D_MIN,
    eps_v: float = EPS_V,
    goal: Array | None = None,
    **gains: Array,
) -> Array:
    r"""U*_rep = ω · U_rep(d) of one obstacle (paper eq. 14, 20).

    Args:
      p, v: UAV position and velocity (3,).
      p_o, v_o: obstacle centre and velocity (3,), or component-first ``(3, M)`` for M obstacles
        at once (then ``radius``, ``cylinder`` are (M,) and the result is (M,)).
      k_rep, d_s: repulsive gain and influence distance (paper eq. 13).
      method: the weight ω, by name or as a :class:`~jaxapf.planners.weights.Weight`.
      radius: obstacle radius plus UAV radius; the clearance is ``d = |P(p - p_o)| - radius``.
      cylinder: vertical cylinder (distance ignores z) instead of a sphere.
      d_min: floor on ``d`` before the division.
      eps_v: regulariser of ``|v|`` in cos θ.
      goal: the goal, for weights that read it.
      gains: the weight's gains by name (``gamma``, ``k`` for ``direction_velocity``).
    """
    check_choice("convention", convention, CONVENTIONS)
    return _repulsion(p, v, p_o, v_o, radius, cylinder, Gains.unchecked({"k_rep": k_rep, "d_s": d_s, **gains}),
                      method, convention, d_min, eps_v, goal)


def repulsive_force(p: Array, v: Array, p_o: Array, v_o: Array, **kwargs: Any) -> Array:
    r"""F*_rep = -∇_p U*_rep (paper eq. 21) by ``jax.grad``; same keywords as
    :func:`weighted_repulsive_potential`. Shape (3,)."""
    return -jax.grad(weighted_repulsive_potential)(p, v, p_o, v_o, **kwargs)


def total_potential(
    p: Array,
    v: Array,
    t: Array | float,
    goal: Array,
    obstacles: Obstacles | ObstacleColumns,
    gains: Gains,
    *,
    method: str | Weight,
    convention: str,
    r_uav: float,
    d_min: float = D_MIN,
    eps_v: float = EPS_V,
    att_cap: float | None = None,
) -> Array:
    """U_att + Σ_o U*_rep over the valid obstacles, with obstacles at their time-``t`` positions
    (``p_o + v_o t``; ``obstacles`` in either layout).

    Padded slots contribute exactly zero (their term is masked with ``where``, whose gradient
    is exactly zero too).
    """
    cols = obstacles.columns()
    u_rep = _repulsion(p, v, cols.position + cols.velocity * t, cols.velocity, cols.radius + r_uav, cols.cylinder,
                       gains, method, convention, d_min, eps_v, goal)
    u_rep = jnp.where(cols.valid, u_rep, 0.0)
    return attractive_potential(p, goal, gains.k_att, att_cap) + jnp.sum(u_rep)


def total_force(p: Array, v: Array, t: Array | float, goal: Array, obstacles: Obstacles | ObstacleColumns,
                gains: Gains, **kwargs: Any) -> Array:
    """-∇_p of :func:`total_potential` (3,), by :func:`jax.grad`."""
    return -jax.grad(total_potential)(p, v, t, goal, obstacles, gains, **kwargs)
