r"""The point of a polytope in R³ (within a box or a ball) nearest a given point, exactly.

Both the CBF safety filter (accelerations within the MPC's box) and the velocity-obstacle planner
(velocities within the speed ball) solve

.. math:: x^* = \arg\min_x \tfrac12 |x - x_0|^2 \quad\text{s.t.}\quad g_j\cdot x \ge b_j\;\forall j,
          \quad x \in S, \qquad S = \{|x_i| \le L\} \text{ or } \{|x| \le L\}.

The minimiser is a projection onto a convex set in R³, so at most three constraints are active at
it (linearly independent ones; the ball counts as one). :func:`nearest_feasible` forms the
candidate of every active set -- for planes only, ``x = x_0 + G_Sᵀ (G_S G_Sᵀ)⁻¹ (b_S - G_S x_0)``;
with the sphere ``|x| = L`` active, ``x_0`` scaled onto it, the point of a plane's circle on the
sphere nearest ``x_0``, or the two points where two planes' line meets the sphere -- and returns
the feasible candidate nearest ``x_0``. The work is fixed (``O(K³)`` candidates for ``K`` rows), so
it vmaps, and it differentiates almost everywhere (through the selected candidate). Iterative
alternatives measured before this one (a first-order dual method with 60-400 iterations, ADMM with
30-100) missed an independent QP solver by up to 0.5 on narrow feasible wedges.

When no candidate is feasible, the constraints and ``S`` cannot all hold: the candidate in ``S``
with the smallest violation of the rows (nearest ``x_0`` among equals) is returned with that
violation.
"""

from __future__ import annotations

import itertools
from functools import cache
from typing import Literal

import jax.numpy as jnp
import numpy as np
from jax import Array

from .datatypes import safe_norm
from .datatypes.obstacles import TINY

__all__ = ["nearest_feasible"]

@cache
def _subsets(count: int, largest: int) -> tuple[np.ndarray, ...]:
    """Index arrays of every subset of 1 .. ``largest`` of ``count`` rows."""
    return tuple(np.asarray(list(itertools.combinations(range(count), k)), np.int32).reshape(-1, k)
                 for k in range(1, largest + 1))


def _step(gs: Array, rhs: Array) -> tuple[Array, Array]:
    """The least-norm ``d`` with ``G d = rhs``, ``d = Gᵀ (G Gᵀ)⁻¹ rhs``, for a batch of ``k`` <= 3
    rows ``G`` (C, k, 3), and whether they are independent (``det(G Gᵀ) > 1e-9``; the others get
    a finite dummy). Written out rather than by LAPACK, which inside a wide vmap is slow and, on
    XLA:CPU at 512 episodes, stalled: ``det(G Gᵀ) = |g_0 × g_1|²`` for two rows (no cancellation)
    and ``d = G⁻¹ rhs`` by the cross products of the rows for three."""
    k = gs.shape[1]
    if k == 1:
        det = jnp.sum(gs[:, 0] * gs[:, 0], axis=1)
    elif k == 2:
        normal = jnp.cross(gs[:, 0], gs[:, 1])
        det = jnp.sum(normal * normal, axis=1)
    else:
        columns = jnp.stack([jnp.cross(gs[:, 1], gs[:, 2]), jnp.cross(gs[:, 2], gs[:, 0]),
                             jnp.cross(gs[:, 0], gs[:, 1])], axis=1)  # column j of det(G) G⁻¹, as row j
        det_g = jnp.sum(gs[:, 0] * columns[:, 0], axis=1)
        det = det_g * det_g
    regular = det > 1e-9
    if k == 1:
        mu = rhs / jnp.where(regular, det, 1.0)[:, None]
    elif k == 2:
        a = gs @ jnp.swapaxes(gs, 1, 2)
        adjugate_rhs = jnp.stack([a[:, 1, 1] * rhs[:, 0] - a[:, 0, 1] * rhs[:, 1],
                                  a[:, 0, 0] * rhs[:, 1] - a[:, 1, 0] * rhs[:, 0]], axis=1)
        mu = adjugate_rhs / jnp.where(regular, det, 1.0)[:, None]
    else:
        return jnp.einsum("cjd,cj->cd", columns, rhs) / jnp.where(regular, det_g, 1.0)[:, None], regular
    return jnp.einsum("ckd,ck->cd", gs, mu), regular


def _plane_candidates(x0: Array, rows: Array, bounds: Array, usable: Array, largest: int) -> tuple[Array, Array]:
    """Projections of ``x0`` onto every intersection of 1 .. ``largest`` of the planes
    ``rows·x = bounds`` (``C, 3``), and whether each is regular."""
    candidates, ok = [], []
    for index in _subsets(rows.shape[0], largest):
        gs, bs = rows[index], bounds[index]  # (C, k, 3), (C, k)
        step, regular = _step(gs, bs - gs @ x0)
        candidates.append(x0 + step)
        ok.append(regular & jnp.all(usable[index], axis=1))
    return jnp.concatenate(candidates), jnp.concatenate(ok)


def _sphere_candidates(x0: Array, rows: Array, bounds: Array, usable: Array, radius: float) -> tuple[Array, Array]:
    """Candidates with the sphere ``|x| = radius`` active: alone, with one plane (the nearest point
    of their circle), with two planes (both points of their line on the sphere)."""
    r2 = radius * radius
    scale = radius / safe_norm(x0)
    alone = (x0 * scale)[None]
    # one plane n·x = b (|n| = 1): circle centre b n, radius sqrt(L² - b²)
    n, b = rows, bounds
    centre = b[:, None] * n
    along = x0[None] - (n @ x0)[:, None] * n  # x0 projected into the plane, from the centre b n
    along_len = safe_norm(along)
    circle_r = jnp.sqrt(jnp.maximum(r2 - b * b, TINY))
    one = centre + (circle_r / along_len)[:, None] * along
    one_ok = usable & (b * b < r2)
    # two planes: the line c + s e, c its point nearest the origin, e = n1 × n2
    (pairs,) = _subsets(rows.shape[0], 2)[1:]
    n1, n2 = rows[pairs[:, 0]], rows[pairs[:, 1]]
    e = jnp.cross(n1, n2)
    e2 = jnp.sum(e * e, axis=1)
    regular = (e2 > 1e-9) & usable[pairs[:, 0]] & usable[pairs[:, 1]]
    gs = rows[pairs]
    c = _step(gs, bounds[pairs])[0]
    disc = r2 - jnp.sum(c * c, axis=1)
    step = jnp.sqrt(jnp.maximum(disc, TINY) / jnp.maximum(e2, TINY))[:, None] * e
    two_ok = regular & (disc > 0.0)
    candidates = jnp.concatenate([alone, one, c + step, c - step])
    ok = jnp.concatenate([jnp.ones((1,), bool), one_ok, two_ok, two_ok])
    return candidates, ok


def nearest_feasible(x0: Array, g: Array, b: Array, limit: float | Array,
                     region: Literal["box", "ball"]) -> tuple[Array, Array]:
    """``argmin ½|x - x0|²`` s.t. ``g x >= b`` (rows (M, 3) of unit length; zero rows ignored) and
    ``x`` in the box ``|x_i| <= limit`` or the ball ``|x| <= limit``; returns ``(x, largest
    violation of the rows)`` (module docstring)."""
    usable_rows = jnp.any(g != 0, axis=1)
    if region == "box":
        eye = jnp.eye(3, dtype=x0.dtype)
        rows = jnp.concatenate([g, eye, -eye])  # the rows, then x_i >= -L and -x_i >= -L
        bounds = jnp.concatenate([b, jnp.full((6,), -limit, x0.dtype)])
        usable = jnp.concatenate([usable_rows, jnp.ones((6,), bool)])
        cand, ok = _plane_candidates(x0, rows, bounds, usable, 3)
    elif region == "ball":
        planes, planes_ok = _plane_candidates(x0, g, b, usable_rows, 3)
        sphere, sphere_ok = _sphere_candidates(x0, g, b, usable_rows, limit)
        cand, ok = jnp.concatenate([planes, sphere]), jnp.concatenate([planes_ok, sphere_ok])
    else:
        raise ValueError(f"region must be 'box' or 'ball', not {region!r}")
    cand, ok = jnp.concatenate([x0[None], cand]), jnp.concatenate([jnp.ones((1,), bool), ok])
    slack = 1e-6 * (1.0 + limit)
    if region == "box":
        inside = ok & jnp.all(jnp.abs(cand) <= limit + slack, axis=1)
    else:
        inside = ok & (jnp.sum(cand * cand, axis=1) <= (limit + slack) ** 2)
    violation = jnp.max(jnp.where(usable_rows[None], b[None] - cand @ g.T, 0.0), axis=1, initial=0.0)
    distance = jnp.sum((cand - x0) ** 2, axis=1)
    feasible = inside & (violation <= slack)
    # feasible candidates first, nearest x0; otherwise the least violating one inside the region
    key = jnp.where(feasible, distance, jnp.where(inside, 1e6 + 1e3 * violation + distance, jnp.inf))
    best = jnp.argmin(key)
    x = cand[best]
    if region == "box":
        x = jnp.clip(x, -limit, limit)
    else:
        x = x * jnp.minimum(1.0, limit / safe_norm(x))
    return x, violation[best]
