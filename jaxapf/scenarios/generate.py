"""Fields as pure functions of a PRNG key and a family's parameters (SPEC 5).

Every field is built the same way: the start–goal distance ``L`` and heading ψ are drawn, the
family's builder lays out its obstacles in the local frame (:mod:`jaxapf.scenarios.layout`), and
the layout is rotated into the world frame, padded to ``max_obstacles`` slots and passed through
:func:`clear_endpoints`. Keys: field ``i`` of seed ``s`` is :func:`field_key` ``= fold_in(key(s), i)``,
and a field is bit-identical whatever batch it is computed in.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..datatypes import Obstacles, Scenario, project
from ..validation import ConfigError, check_int
from .base import FAMILIES, FamilyParams
from .layout import Draws, Layout, fit

__all__ = ["field_key", "clear_endpoints", "make_scenario", "make_scenarios"]

#: Where padded slots are parked [m] (matches :meth:`Obstacles.empty`).
_PARK = 1e6
#: :func:`clear_endpoints` pushes to ``margin + _PUSH_SLACK`` [m] so that float rounding of the
#: moved centre can never leave it below ``margin``.
_PUSH_SLACK = 1e-3


def field_key(seed: int, field_index: int | Array) -> Array:
    """The key of field ``field_index`` of ``seed``: ``fold_in(jax.random.key(seed), field_index)``."""
    return jax.random.fold_in(jax.random.key(seed), field_index)


def _park(obstacles: Obstacles) -> Obstacles:
    """Invalid slots parked at ``1e6`` with radius 0, velocity 0, sphere flag."""
    valid = obstacles.valid
    return Obstacles(
        position=jnp.where(valid[:, None], obstacles.position, _PARK),
        velocity=jnp.where(valid[:, None], obstacles.velocity, 0.0),
        radius=jnp.where(valid, obstacles.radius, 0.0),
        cylinder=obstacles.cylinder & valid,
        valid=valid,
    )


def _sq_norm(r: Array) -> Array:
    """``|r|²`` over the last axis (3), written out: XLA's CPU reductions round differently for
    different batch sizes, and a field must not depend on the batch it is computed in."""
    return r[..., 0] * r[..., 0] + r[..., 1] * r[..., 1] + r[..., 2] * r[..., 2]


def clear_endpoints(obstacles: Obstacles, start: Array, goal: Array, r_uav: float | Array,
                    start_margin: float | Array, goal_margin: float | Array) -> Obstacles:
    """Keep ``start`` at least ``start_margin`` and ``goal`` at least ``goal_margin`` clear (UAV
    clearance, t = 0) of every obstacle.

    Deterministic: an obstacle whose clearance from the start is below ``start_margin`` is moved
    radially away from the start (in xy for a cylinder, in 3-D for a sphere) until its clearance is
    ``start_margin`` (plus 1 mm against rounding); then the same for the goal and ``goal_margin``.
    After two such passes an obstacle that still violates either end (possible only when start and
    goal are closer than an obstacle's diameter plus margins) is marked invalid. An obstacle centred exactly on an end
    is moved perpendicular to the start–goal line (to its left). Invalid slots come back parked.
    """
    along = goal - start
    left = jnp.stack([-along[1], along[0], jnp.zeros_like(along[0])])
    left_sq = _sq_norm(left)
    unit_y = jnp.array([0.0, 1.0, 0.0], left.dtype)
    fallback = jnp.where(left_sq > 0, left / jnp.sqrt(jnp.where(left_sq > 0, left_sq, 1.0)), unit_y)
    reach = obstacles.radius + r_uav  # + margin: the centre distance at which the clearance is the margin

    def distance(position: Array, point: Array) -> tuple[Array, Array]:
        rel = project(position - point, obstacles.cylinder)
        return rel, jnp.sqrt(_sq_norm(rel))

    def push(position: Array, point: Array, margin: float | Array) -> Array:
        need = reach + margin
        rel, dist = distance(position, point)
        direction = jnp.where((dist > 0)[:, None], rel / jnp.where(dist > 0, dist, 1.0)[:, None], fallback)
        move = jnp.where(obstacles.valid & (dist < need), need + _PUSH_SLACK - dist, 0.0)
        return position + direction * move[:, None]

    position = obstacles.position
    for _ in range(2):
        position = push(push(position, start, start_margin), goal, goal_margin)
    ok = (distance(position, start)[1] >= reach + start_margin) & (distance(position, goal)[1] >= reach + goal_margin)
    return _park(dataclasses.replace(obstacles, position=position, valid=obstacles.valid & ok))


def _to_world(xy: Array, heading: Array, z: float) -> Array:
    """Local ``(..., 2)`` rotated by ``heading`` about z, with height ``z``: ``(..., 3)``."""
    c, s = jnp.cos(heading), jnp.sin(heading)
    x, y = xy[..., 0], xy[..., 1]
    return jnp.stack([c * x - s * y, s * x + c * y, jnp.full_like(x, z)], axis=-1)


def _local_field(u: Array, params: FamilyParams) -> tuple[Array, Array, Layout, Array]:
    """Start–goal distance L, heading ψ [rad], the local layout (``max_obstacles`` rows) and the kind
    (int32 index into the family's kinds) from a field's block of uniforms ``u``."""
    d = Draws(u)
    length = d.uniform(params.distance)
    heading = jnp.deg2rad(d.uniform(params.heading))
    layout, kind = FAMILIES.get(params.family).build(d, params, length)
    return length, heading, fit(layout, params.max_obstacles), jnp.asarray(kind, jnp.int32)


def _place(key: Array, length: Array, heading: Array, layout: Layout, kind: Array, altitude: Array, r_uav: Array,
           start_margin: Array, goal_margin: Array, cylinder: Array) -> Scenario:
    """The field in the world frame, with clear endpoints; ``key`` is the field key's data."""
    zero = jnp.zeros_like(length)
    start = jnp.stack([zero, zero, zero + altitude])
    goal = _to_world(jnp.stack([length, zero]), heading, altitude)
    obstacles = Obstacles(
        position=_to_world(layout.xy, heading, altitude),
        velocity=_to_world(layout.vxy, heading, 0.0),
        radius=layout.radius,
        cylinder=jnp.broadcast_to(cylinder, layout.valid.shape),
        valid=layout.valid,
    )
    return Scenario(start, goal, clear_endpoints(obstacles, start, goal, r_uav, start_margin, goal_margin),
                    kind, key)


def _placement(params: FamilyParams) -> tuple[float, float, float, float, bool]:
    """The arguments of :func:`_place` taken from ``params`` (traced, so they do not recompile)."""
    return params.altitude, params.r_uav, params.start_margin, params.goal_margin, params.shape == "cylinder"


def _stage_boundary(local: tuple, params: FamilyParams) -> tuple[tuple, tuple]:
    """The local field and the placement arguments behind an optimisation barrier, so that XLA
    neither fuses across the two stages nor folds the placement constants: a field then rounds
    the same whether the stages are compiled separately (:func:`make_scenarios`) or together
    (either function under a caller's ``jit``)."""
    return jax.lax.optimization_barrier((local, _placement(params)))


def _draw_count(params: FamilyParams) -> int:
    """Size of a field's block of uniforms (see :class:`Draws`)."""
    per_field, per_slot = params.draws
    return per_field + per_slot * params.max_obstacles


def _uniforms(key: Array, size: int) -> Array:
    return jax.random.uniform(key, (size,), jnp.result_type(float))


def make_scenario(key: Array, params: FamilyParams) -> Scenario:
    """One field of ``params.family`` from ``key``: a pure function of both (``params`` is static
    under ``jit``; ``vmap`` over keys gives a batch).

    Floats have JAX's default float dtype (float32, or float64 under ``jax_enable_x64``); the
    obstacle set has exactly ``params.max_obstacles`` slots.
    """
    local, placement = _stage_boundary(_local_field(_uniforms(key, _draw_count(params)), params), params)
    return _place(jax.random.key_data(key), *local, *placement)


# make_scenarios runs make_scenario as three compiled, batched stages so that the parts that do
# not depend on the family (the random block; world frame + clear_endpoints) compile once per
# shape and are shared by all families with the same max_obstacles.


@partial(jax.jit, static_argnames="size")
def _draw_batch(base_key: Array, indices: Array, size: int) -> tuple[Array, Array]:
    """The fields' key data and blocks of uniforms."""
    keys = jax.vmap(lambda i: jax.random.fold_in(base_key, i))(indices)
    return jax.random.key_data(keys), jax.vmap(lambda k: _uniforms(k, size))(keys)


@partial(jax.jit, static_argnames="params")
def _local_batch(u: Array, params: FamilyParams) -> tuple[Array, Array, Layout, Array]:
    return jax.vmap(lambda row: _local_field(row, params))(u)


_place_batch = jax.jit(jax.vmap(_place, in_axes=(0, 0, 0, 0, 0, None, None, None, None, None)))


def make_scenarios(seed: int | Array, params: FamilyParams, fields: int | Array) -> Scenario:
    """A batch of fields (leading axis on every leaf): field ``i`` is
    ``make_scenario(field_key(seed, i), params)``.

    ``fields`` is a count ``n`` (fields ``0 … n-1``) or a 1-D integer array of field indices.
    A field is bit-identical whatever batch it is computed in (so a sweep split into chunks yields
    exactly the fields of the whole sweep, and ``simulate`` on field ``i`` sees the field the
    sweep saw) and whether or not this call or :func:`make_scenario` runs inside a caller's
    ``jit``. (Only op-by-op evaluation of :func:`make_scenario` without ``jit`` may differ in the
    last bit: nothing is fused there.)
    """
    if isinstance(fields, (int, np.integer)) and not isinstance(fields, bool):
        indices = jnp.arange(check_int("scenario.fields", fields, 0))
    else:
        indices = jnp.asarray(fields)
        if indices.ndim != 1 or not jnp.issubdtype(indices.dtype, jnp.integer):
            raise ConfigError(f"scenario.fields must be a count or a 1-D integer array of field indices; "
                              f"got {indices.dtype} of shape {indices.shape}")
    padded = padded_indices(indices)
    keys, u = _draw_batch(jax.random.key(seed), padded, _draw_count(params))
    local, placement = _stage_boundary(_local_batch(u, params), params)
    return first_rows(_place_batch(keys, *local, *placement), indices.shape[0])


def padded_indices(indices: Array) -> Array:
    """``indices`` padded (with its first index) to the next power of two, at least 8: a family's
    generation compiles once per such size instead of once per field count (a field does not depend on
    its batch, so the padding changes none)."""
    n = int(indices.shape[0])
    size = max(8, 1 << max(n - 1, 0).bit_length())
    return indices if n == size else jnp.concatenate([indices, jnp.full((size - n,), indices[0] if n else 0,
                                                                         indices.dtype)])


def first_rows(batch: Any, n: int) -> Any:
    """The first ``n`` rows of every leaf of a batched pytree."""
    return jax.tree_util.tree_map(lambda x: x if x.shape[0] == n else x[:n], batch)
