r"""The point of a polytope in R³ (within a box or a ball) nearest a given point, exactly
(:func:`nearest_feasible`): the CBF safety filters' accelerations within the MPC's box and the velocity
obstacles' velocities within the speed ball. Fixed work (every active set of up to three rows), so it
vmaps and differentiates almost everywhere; infeasible problems get RVO2's least-violation point; among
many rows a few are solved at a time and the answer certified (constraint generation). The derivation
and why it is exact: docs/spec.md, section 4, "The exact projection".
"""

from __future__ import annotations

import itertools
from functools import cache, partial
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .datatypes import safe_norm
from .datatypes.obstacles import TINY
from .metrics.base import Metric

__all__ = ["nearest_feasible", "projection_metrics", "INFEASIBLE_TOL"]

#: A problem counts as infeasible (the CBF filter's ``cbf_infeasible``, the velocity obstacles'
#: ``vo_infeasible``) when the returned point misses some unit-scaled row by more than this.
INFEASIBLE_TOL = 1e-3


def projection_metrics(prefix: str, rows: str, region: str, absent: str) -> tuple[Metric, Metric]:
    """The two counts of a component that projects every step: ``{prefix}_infeasible_steps``, the steps
    at which its ``rows`` and the ``region`` could not all hold (its flag ``{prefix}_infeasible``), and
    ``{prefix}_truncated_steps``, those whose answer was not certified exact with ``sim.projection_rows``
    rows at a time (``{prefix}_truncated``). ``absent``: their value for a stack without the component."""
    return (Metric.flagged_steps(f"{prefix}_infeasible_steps", f"{prefix}_infeasible",
                                 f"control steps at which {rows} and {region} could not all hold ({absent})"),
            Metric.flagged_steps(f"{prefix}_truncated_steps", f"{prefix}_truncated",
                                 f"control steps at which one of {rows} left out (sim.projection_rows) is violated at "
                                 "the answer by more than the kept ones: not certified the exact projection (0 with "
                                 "every row kept)"))


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


def _least_violation(g: Array, b: Array, usable_rows: Array, limit: float | Array,
                     region: Literal["box", "ball"]) -> Array:
    """``t* = min over x in S of max_j (b_j - g_j·x)`` over the usable rows (module docstring), exactly;
    ``-inf`` without usable rows."""
    dtype = g.dtype
    if region == "box":
        eye = jnp.eye(3, dtype=dtype)
        rows = jnp.concatenate([g, eye, -eye])
        bounds = jnp.concatenate([b, jnp.full((6,), -limit, dtype)])
        usable = jnp.concatenate([usable_rows, jnp.ones((6,), bool)])
        shifts = jnp.concatenate([jnp.ones_like(b), jnp.zeros((6,), dtype)])  # r: 1 for a row, 0 for a face
    else:
        rows, bounds, usable, shifts = g, b, usable_rows, jnp.ones_like(b)
    candidates, scored = [], []
    (triples,) = _subsets(rows.shape[0], 3)[2:]
    if triples.shape[0]:
        # the line x_T(t) = p + t d of every independent triple T, its lowest t by the ratio test
        gs = rows[triples]
        p, regular = _step(gs, bounds[triples])
        d = -_step(gs, shifts[triples])[0]
        alpha = p @ rows.T - bounds[None]  # slack of every constraint at t = 0
        beta = d @ rows.T + shifts[None]  # its rate in t
        member = np.zeros((triples.shape[0], rows.shape[0]), bool)
        member[np.arange(triples.shape[0])[:, None], triples] = True
        bounding = (beta > 1e-6) & usable[None] & ~member
        lowest = jnp.where(bounding, -alpha / jnp.where(bounding, beta, 1.0), -jnp.inf)
        t_line = jnp.max(lowest, axis=1)
        t_line = jnp.where(jnp.isfinite(t_line), t_line, 0.0)
        line = p + t_line[:, None] * d
        # its largest violation b_j - g_j·x = -alpha_j - t (beta_j - 1) over the usable rows
        score = jnp.max(jnp.where(usable_rows[None], -alpha[:, :g.shape[0]] - t_line[:, None]
                                  * (beta[:, :g.shape[0]] - 1.0), -jnp.inf), axis=1)
        scored.append((line, score, regular & jnp.all(usable[triples], axis=1)))
    if region == "ball":
        n_rows = g.shape[0]
        candidates.append((limit * _unit(g)[0], usable_rows))  # one row active: L g_j
        (pairs,) = _subsets(n_rows, 2)[1:]
        if pairs.shape[0]:
            # two rows at equal violation: the plane (g_i - g_j)·x = b_i - b_j, farthest along g_i on the sphere
            gi = g[pairs[:, 0]]
            n, length = _unit(gi - g[pairs[:, 1]])
            c = (b[pairs[:, 0]] - b[pairs[:, 1]]) / length
            along = gi - jnp.sum(gi * n, axis=1, keepdims=True) * n
            circle = jnp.sqrt(jnp.maximum(limit * limit - c * c, TINY))
            point = c[:, None] * n + (circle / safe_norm(along))[:, None] * along
            candidates.append((point, (length > 1e-6) & (c * c < limit * limit)
                               & usable_rows[pairs[:, 0]] & usable_rows[pairs[:, 1]]))
        (triples,) = _subsets(n_rows, 3)[2:]
        if triples.shape[0]:
            # three rows at equal violation: the line of two difference planes, where it meets the sphere
            gi, bi = g[triples[:, :1]], b[triples[:, :1]]
            planes, offsets = gi - g[triples[:, 1:]], bi - b[triples[:, 1:]]  # (C, 2, 3), (C, 2)
            e = jnp.cross(planes[:, 0], planes[:, 1])
            e2 = jnp.sum(e * e, axis=1)
            c, regular = _step(planes, offsets)
            disc = limit * limit - jnp.sum(c * c, axis=1)
            step = jnp.sqrt(jnp.maximum(disc, TINY) / jnp.maximum(e2, TINY))[:, None] * e
            ok = regular & (disc > 0.0) & jnp.all(usable_rows[triples], axis=1)
            candidates += [(c + step, ok), (c - step, ok)]
    scored += [(x, jnp.max(jnp.where(usable_rows[None], b[None] - x @ g.T, -jnp.inf), axis=1), ok)
               for x, ok in candidates]
    if not scored:
        return jnp.asarray(-jnp.inf, dtype)
    points = jnp.concatenate([x for x, _, _ in scored])
    score = jnp.concatenate([v for _, v, _ in scored])
    ok = jnp.concatenate([k for _, _, k in scored])
    slack = 1e-6 * (1.0 + limit)
    if region == "box":
        ok &= jnp.all(jnp.abs(points) <= limit + slack, axis=1)
    else:
        ok &= jnp.sum(points * points, axis=1) <= (limit + slack) ** 2
    return jnp.min(jnp.where(ok, score, jnp.inf))


def _unit(a: Array) -> tuple[Array, Array]:
    """``(a / |a|, |a|)`` along the last axis, finite at ``a = 0``."""
    length = safe_norm(a)
    return a / length[..., None], length


def _nearest(x0: Array, g: Array, b: Array, usable_rows: Array, limit: float | Array,
             region: Literal["box", "ball"]) -> Array:
    """The feasible candidate nearest ``x0``; the least violating one in the region if none is."""
    if region == "box":
        eye = jnp.eye(3, dtype=x0.dtype)
        rows = jnp.concatenate([g, eye, -eye])  # the rows, then x_i >= -L and -x_i >= -L
        bounds = jnp.concatenate([b, jnp.full((6,), -limit, x0.dtype)])
        usable = jnp.concatenate([usable_rows, jnp.ones((6,), bool)])
        cand, ok = _plane_candidates(x0, rows, bounds, usable, 3)
    else:
        planes, planes_ok = _plane_candidates(x0, g, b, usable_rows, 3)
        sphere, sphere_ok = _sphere_candidates(x0, g, b, usable_rows, limit)
        cand, ok = jnp.concatenate([planes, sphere]), jnp.concatenate([planes_ok, sphere_ok])
    cand, ok = jnp.concatenate([x0[None], cand]), jnp.concatenate([jnp.ones((1,), bool), ok])
    slack = 1e-6 * (1.0 + limit)
    if region == "box":
        inside = ok & jnp.all(jnp.abs(cand) <= limit + slack, axis=1)
    else:
        inside = ok & (jnp.sum(cand * cand, axis=1) <= (limit + slack) ** 2)
    violation = jnp.max(jnp.where(usable_rows[None], b[None] - cand @ g.T, 0.0), axis=1, initial=0.0)
    distance = jnp.sum((cand - x0) ** 2, axis=1)
    feasible = inside & (violation <= slack)
    # feasible candidates first, nearest x0; otherwise (rounding only) the least violating one inside
    key = jnp.where(feasible, distance, jnp.where(inside, 1e6 + 1e3 * violation + distance, jnp.inf))
    x = cand[jnp.argmin(key)]
    if region == "box":
        return jnp.clip(x, -limit, limit)
    return x * jnp.minimum(1.0, limit / safe_norm(x))


def _solve(x0: Array, g: Array, b: Array, usable_rows: Array, limit: float | Array,
           region: Literal["box", "ball"]) -> Array:
    """The answer of :func:`nearest_feasible` with the rows ``g, b`` (every one of them)."""
    least = _least_violation(g, b, usable_rows, limit, region)
    level = jnp.where(least > 0.0, least + 4e-6 * (1.0 + limit), 0.0)
    return _nearest(x0, g, jnp.where(usable_rows, b - level, b), usable_rows, limit, region)


def nearest_feasible(x0: Array, g: Array, b: Array, limit: float | Array, region: Literal["box", "ball"],
                     rows: int = 0, rounds: int = 8) -> tuple[Array, Array, Array]:
    """``argmin ½|x - x0|²`` s.t. ``g x >= b`` (rows (M, 3) of unit length; zero rows ignored) and
    ``x`` in the box ``|x_i| <= limit`` or the ball ``|x| <= limit``; if they cannot all hold, the
    point nearest ``x0`` among those of least largest violation (module docstring).

    ``rows`` (0: all): solve with ``rows`` rows at a time, ``O(rows⁴)`` work instead of ``O(M⁴)``. The
    first are those that can bind soonest in the region (largest ``b_j + limit·‖g_j‖``, 1-norm for the
    box). While a row left out is violated at the answer by more than the kept ones (beyond
    ``1e-6 (1 + limit)``), the next solve keeps the rows active at it and fills the other places with
    the most violated rows, up to ``rounds`` solves (constraint generation), then once with twice the
    rows if still needed (module docstring). Whether the answer is certified the full problem's is
    returned; its derivative is the solve's with the rows kept.

    Returns ``(x, largest violation of all rows at x, exact)``; ``exact`` is True without ``rows``."""
    if region not in ("box", "ball"):
        raise ValueError(f"region must be 'box' or 'ball', not {region!r}")
    if rounds < 1:
        raise ValueError(f"rounds must be at least 1, not {rounds}")
    usable_rows = jnp.any(g != 0, axis=1)
    if not 0 < rows < g.shape[0]:
        x = _solve(x0, g, b, usable_rows, limit, region)
        return x, jnp.max(jnp.where(usable_rows, b - g @ x, 0.0), initial=0.0), jnp.ones((), bool)
    slack = 1e-6 * (1.0 + limit)
    fixed_g, fixed_b, fixed_x0 = jax.lax.stop_gradient((g, b, x0))  # the rows are chosen, not differentiated

    def kept(index: Array) -> Array:
        return jnp.zeros(b.shape, bool).at[index].set(True)

    def standing(x: Array, index: Array) -> tuple[Array, Array, Array]:
        """Every row's violation at ``x``, the kept rows active there, and whether ``x`` is certified."""
        v = jnp.where(usable_rows, fixed_b - fixed_g @ x, -jnp.inf)
        worst = jnp.maximum(jnp.max(jnp.where(kept(index), v, -jnp.inf)), 0.0)
        return v, kept(index) & (v >= worst - slack), jnp.max(v) <= worst + slack

    def solve_round(carry: tuple) -> tuple:
        count, index, _, _, _, _ = carry
        x = _solve(fixed_x0, fixed_g[index], fixed_b[index], usable_rows[index], limit, region)
        v, active, certified = standing(x, index)
        # the next rows: those active at the answer (so the next answer is worse), then the most violated
        following = jax.lax.top_k(jnp.where(active, jnp.inf, v), rows)[1]
        return count + 1, jnp.where(certified, index, following), index, x, v, certified

    reach = jnp.sum(jnp.abs(fixed_g), axis=1) if region == "box" else safe_norm(fixed_g)
    first = jax.lax.top_k(jnp.where(usable_rows, fixed_b + limit * reach, -jnp.inf), rows)[1]
    start = (jnp.zeros((), jnp.int32), first, first, fixed_x0, jnp.zeros(b.shape, b.dtype), jnp.zeros((), bool))
    _, _, index, x, v, certified = jax.lax.while_loop(lambda c: ~c[5] & (c[0] < rounds), solve_round, start)

    def wider(carry: tuple) -> tuple:
        # float32 rounding on a thin wedge can make a relaxation miss its minimiser and the rounds cycle:
        # solve once with twice the rows (the last ones and as many most violated), keep the rows of
        # largest value at that answer (its active ones first) and solve with them; where only the wider
        # answer is certified (a sliver of a feasible set the kept rows' float32 solve misses), it is the one
        index, _, v, _, _ = carry
        both = jax.lax.top_k(jnp.where(kept(index), jnp.inf, v), min(2 * rows, g.shape[0]))[1]
        wide = _solve(fixed_x0, fixed_g[both], fixed_b[both], usable_rows[both], limit, region)
        v_wide, _, wide_certified = standing(wide, both)
        index = jax.lax.top_k(v_wide, rows)[1]
        x = _solve(fixed_x0, fixed_g[index], fixed_b[index], usable_rows[index], limit, region)
        certified = standing(x, index)[2]
        return index, jnp.where(certified | ~wide_certified, x, wide), v, True, certified | wide_certified

    index, x, _, _, certified = jax.lax.while_loop(lambda c: ~c[3], wider, (index, x, v, certified, certified))
    x = _kept_rows(region, x, x0, g[index], b[index], usable_rows[index], jnp.asarray(limit, x0.dtype))
    violation = jnp.max(jnp.where(usable_rows, b - g @ x, 0.0), initial=0.0)
    return x, violation, certified


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def _kept_rows(region: Literal["box", "ball"], answer: Array, x0: Array, g: Array, b: Array, usable_rows: Array,
               limit: Array) -> Array:
    """``answer`` (chosen without gradients), differentiated as the solve with the kept rows ``g, b``: the
    common step solves once, and only a derivative pays for a second solve."""
    return answer


@_kept_rows.defjvp
def _kept_rows_jvp(region: Literal["box", "ball"], primals: tuple, tangents: tuple) -> tuple[Array, Array]:
    answer, x0, g, b, usable_rows, limit = primals
    _, dx0, dg, db, _, dlimit = tangents
    tangent = jax.jvp(lambda *a: _solve(*a[:3], usable_rows, a[3], region), (x0, g, b, limit),
                      (dx0, dg, db, dlimit))[1]
    return answer, tangent
