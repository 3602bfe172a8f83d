r"""Attractive and direction/velocity-weighted repulsive potentials (paper section 3, SPEC 3).

Attractive potential, optionally conic beyond ``att_cap``:

.. math::  U_{att}(p) = \tfrac12 k_{att} \lVert p - g\rVert^2

Classical repulsive potential of one obstacle with clearance ``d`` (paper eq. 13):

.. math::  U_{rep}(d) = \tfrac12 k_{rep} (1/d - 1/d_s)^2 \ \text{for } d \le d_s, \ 0 \text{ otherwise}

with ``d`` floored smoothly at ``d_min > 0`` (:func:`floored_clearance`). The weighted potential is :math:`U^*_{rep} = \omega U_{rep}`
(paper eq. 14 and 20) with

=====================  =====================================================
method                 weight ω
=====================  =====================================================
``basic``              1
``direction``          :math:`1 + \gamma (1 + \cos\theta)/2`            (eq. 15)
``direction_velocity`` :math:`[1 + \gamma (1 + \cos\theta)/2]\,(2 + k \tanh c)`  (eq. 19)
=====================  =====================================================

Forces are ``-jax.grad`` of the total potential with respect to the UAV position ``p`` (v, p_o, v_o
held fixed), so the weighted force is :math:`-(\omega\nabla U_{rep} + U_{rep}\nabla\omega)`.

Sign conventions (SPEC 3): let ``s = P(p_o - p)`` be the line of sight from the UAV to the
obstacle (``P`` drops z for a cylinder). ``intent`` uses
:math:`\cos\theta = v\cdot s/(|v|_\epsilon |s|)`, :math:`c = (v - v_o)\cdot s/|s|` (closing speed, > 0
when the gap shrinks), which matches the paper's prose. ``literal`` uses the paper's printed
:math:`r_e = p - p_o = -s`: :math:`\cos\theta = v\cdot r_e/(|v|_\epsilon |r_e|)`, :math:`c = G =
(v - v_o)\cdot r_e/|r_e|`. :math:`|v|_\epsilon = \sqrt{|v|^2 + \epsilon^2}`.

The paper's bound ``1 <= ω <= (1+γ)(2+k)`` holds above; below, the true minimum of the
``direction_velocity`` weight is ``2 - k`` (< 1 for k > 1, negative for k > 2).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from jax import Array

from .config import CONVENTIONS, METHODS, check_choice
from .obstacles import TINY, ObstacleColumns, Obstacles, safe_norm

__all__ = [
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

#: Default floor on the clearance inside U_rep [m] (SimConfig.d_min).
D_MIN = 0.05
#: Default regulariser of |v| in cos θ [m/s] (SimConfig.eps_v).
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


def direction_weight(cos_theta: Array, gamma: Array) -> Array:
    r"""ω(θ) = 1 + γ (1 + cos θ) / 2 (paper eq. 15); in [1, 1 + γ] for γ >= 0."""
    return 1.0 + gamma * 0.5 * (1.0 + cos_theta)


def velocity_weight(c: Array, k: Array) -> Array:
    r"""The relative-velocity factor 2 + k tanh(c) of paper eq. 19; in [2 - k, 2 + k]."""
    return 2.0 + k * jnp.tanh(c)


def _dot(a: Any, b: Any) -> Array:
    """Dot product of two component-first vectors (their leading axis of size 3 is x, y, z; any
    trailing axes broadcast). Written out so that XLA fuses it with its neighbours."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _norm(a: Any) -> Array:
    """Component-first :func:`~jaxapf.obstacles.safe_norm`."""
    return jnp.sqrt(jnp.maximum(_dot(a, a), TINY))


def _line_of_sight(p: Array, p_o: Array, cylinder: Array | bool) -> tuple[Array, Array, Array]:
    """``s = P(p_o - p)`` component by component (``P`` drops z for a cylinder).

    The difference is taken as one vector operation (``p`` broadcast along the obstacle axes of
    ``p_o``) before it is split into components: ``∇_p`` then reaches ``p`` as a single sum over
    the obstacles of a (3, M) cotangent, which XLA:CPU fuses with the per-obstacle backward pass
    into one vectorised reduction; indexing ``p`` per component would instead give three sums and
    more per-obstacle kernels (``jaxapf bench --kernels``: lone elementwise kernels run one element
    at a time; the whole closed loop ran a median 1.14x faster this way, README "Speed").
    """
    p = jnp.asarray(p)
    s = p_o - jnp.reshape(p, p.shape + (1,) * (jnp.ndim(p_o) - p.ndim))
    return s[0], s[1], jnp.where(cylinder, 0.0, s[2])


def _weight(v: Array, v_o: Array, sight: Any, *, gamma: Array, k: Array, method: str, convention: str,
            eps_v: float) -> Array:
    """ω of the obstacle(s) seen along ``sight`` (component-first); see :func:`weight`."""
    if method == "basic":
        return jnp.ones((), jnp.result_type(v))
    if convention == "literal":
        sight = tuple(-c for c in sight)  # r_e = p - p_o, the paper's printed definition
    dist = _norm(sight)
    speed = jnp.sqrt(_dot(v, v) + eps_v**2)
    w = direction_weight(_dot(v, sight) / (dist * speed), gamma)
    if method == "direction":
        return w
    closing = tuple(a - b for a, b in zip(v, v_o))
    return w * velocity_weight(_dot(closing, sight) / dist, k)


def weight(
    p: Array,
    v: Array,
    p_o: Array,
    v_o: Array,
    *,
    gamma: Array,
    k: Array,
    method: str,
    convention: str,
    cylinder: Array | bool = False,
    eps_v: float = EPS_V,
) -> Array:
    """The weight ω of one obstacle for ``method`` under ``convention`` (see module docstring).

    ``p``, ``v``, ``p_o``, ``v_o`` are (3,) vectors; ``p_o``, ``v_o`` may also be component-first
    ``(3, M)`` arrays of M obstacles (``cylinder`` (M,)), giving ω of each, shape (M,).
    """
    return _weight(v, v_o, _line_of_sight(p, p_o, cylinder), gamma=gamma, k=k, method=method,
                   convention=convention, eps_v=eps_v)


def weight_bounds(gamma: Array, k: Array, method: str) -> tuple[Array, Array]:
    """True (min, max) of ω over all geometries: (1, 1+γ) for ``direction``; (2 - k, (1+γ)(2+k))
    for ``direction_velocity`` when k <= 2 (for k > 2 the minimum (1+γ)(2-k) is negative)."""
    if method == "basic":
        return jnp.ones(()), jnp.ones(())
    if method == "direction":
        return jnp.ones_like(gamma), 1.0 + gamma
    lo = jnp.where(k <= 2.0, 2.0 - k, (1.0 + gamma) * (2.0 - k))
    return lo, (1.0 + gamma) * (2.0 + k)


def _check_static(method: str, convention: str) -> None:
    check_choice("method", method, METHODS)
    check_choice("convention", convention, CONVENTIONS)


def weighted_repulsive_potential(
    p: Array,
    v: Array,
    p_o: Array,
    v_o: Array,
    *,
    k_rep: Array,
    d_s: Array,
    gamma: Array,
    k: Array,
    method: str = "direction_velocity",
    convention: str = "intent",
    radius: Array | float = 0.0,
    cylinder: Array | bool = False,
    d_min: float = D_MIN,
    eps_v: float = EPS_V,
) -> Array:
    r"""U*_rep = ω · U_rep(d) of one obstacle (paper eq. 14, 20).

    Args:
      p, v: UAV position and velocity (3,).
      p_o, v_o: obstacle centre and velocity (3,), or component-first ``(3, M)`` for M obstacles
        at once (then ``radius``, ``cylinder`` are (M,) and the result is (M,)).
      radius: obstacle radius plus UAV radius; the clearance is ``d = |P(p - p_o)| - radius``.
      cylinder: vertical cylinder (distance ignores z) instead of a sphere.
      d_min: floor on ``d`` before the division.
      eps_v: regulariser of ``|v|`` in cos θ.
    """
    _check_static(method, convention)
    sight = _line_of_sight(p, p_o, cylinder)
    d = _norm(sight) - radius
    w = _weight(v, v_o, sight, gamma=gamma, k=k, method=method, convention=convention, eps_v=eps_v)
    return w * repulsive_potential(d, k_rep, d_s, d_min)


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
    gains: Any,
    *,
    method: str,
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
    u_rep = weighted_repulsive_potential(
        p, v, cols.position + cols.velocity * t, cols.velocity, k_rep=gains.k_rep, d_s=gains.d_s,
        gamma=gains.gamma, k=gains.k, method=method, convention=convention,
        radius=cols.radius + r_uav, cylinder=cols.cylinder, d_min=d_min, eps_v=eps_v,
    )
    u_rep = jnp.where(cols.valid, u_rep, 0.0)
    return attractive_potential(p, goal, gains.k_att, att_cap) + jnp.sum(u_rep)


def total_force(p: Array, v: Array, t: Array | float, goal: Array, obstacles: Obstacles | ObstacleColumns,
                gains: Any, **kwargs: Any) -> Array:
    """-∇_p of :func:`total_potential` (3,), by :func:`jax.grad`."""
    return -jax.grad(total_potential)(p, v, t, goal, obstacles, gains, **kwargs)
