r"""Swarm families: fields flown by ``A`` UAVs at once (:class:`~jaxapf.datatypes.swarm.Swarm`).

Every swarm field is built like a single-UAV one (:mod:`jaxapf.scenarios.families`): one block of
uniforms from the field's key, a local layout turned by a heading about the origin; then every UAV's
start and goal move by a uniform offset in ``±jitter`` per horizontal coordinate (breaking a formation's
exact symmetry), and every obstacle closer than ``start_margin`` (``goal_margin``) to some UAV's start
(goal) is dropped. A field is the same whatever batch computes it. The four families, ``circle_swap``,
``crossing_flows``, ``formation_gap`` and ``swarm_clutter``, are described on their parameter classes;
:func:`agents_solvable` tells which fields are solvable UAV by UAV (docs/scenarios.md).
"""

from __future__ import annotations

import dataclasses
import math
from functools import partial
from typing import Any, Callable, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..datatypes import Obstacles
from ..datatypes.swarm import Swarm
from ..registry import Registry
from ..validation import ConfigError
from .base import FamilyParams, checked_params, integer, number, span
from .generate import _to_world, first_rows, padded_indices
from .layout import Draws, Layout, fit, scatter, with_motion

__all__ = ["SwarmParams", "CircleSwapParams", "CrossingFlowsParams", "FormationGapParams", "SwarmClutterParams",
           "SWARM_FAMILIES", "swarm_params", "make_swarm", "make_swarms", "agents_solvable"]


@dataclasses.dataclass(frozen=True)
class SwarmParams(FamilyParams):
    """Parameters every swarm family has, beyond :class:`~jaxapf.scenarios.FamilyParams`'s.

    Attributes:
      agents: UAVs per field, ``A`` (static; 1–256).
      jitter: each start and goal moved by a uniform offset in ``±jitter`` per horizontal coordinate [m]
        (default 0.1 m).
    """

    family = "swarm"
    #: Uniforms per UAV in a field's block (beyond ``draws``).
    agent_draws: ClassVar[int] = 6
    CHECKS = FamilyParams.CHECKS | {"agents": integer(1, 256), "jitter": number(0.0)}
    UNITS = FamilyParams.UNITS | {"agents": "", "jitter": "m"}

    agents: int = 8
    jitter: float = 0.1
    max_obstacles: int = 1
    goal_margin: float = 0.5
    t_max: float = 40.0

    def draw_count(self) -> int:
        per_field, per_slot = self.draws
        return per_field + per_slot * self.max_obstacles + self.agent_draws * self.agents


@dataclasses.dataclass(frozen=True)
class CircleSwapParams(SwarmParams):
    """``circle_swap``, RVO2's standard first test: ``agents`` UAVs evenly on a circle of diameter ``distance``
    (12–16 m; a random rotation), each flying to the antipodal point, so every path crosses the centre at
    about the same time; a circle too small for its UAVs (neighbours closer than ``2 r_uav`` plus the
    jitter: from 43 UAVs on at 12 m) grows until they fit. No obstacles."""

    family = "circle_swap"
    distance: tuple[float, float] = (12.0, 16.0)


@dataclasses.dataclass(frozen=True)
class CrossingFlowsParams(SwarmParams):
    """``crossing_flows``: ``groups`` (2–4) flows of ``agents / groups`` UAVs abreast (``spacing`` 1.5 m
    apart; ``agents`` a multiple of ``groups``) entering a common square from the directions 0°, 90°, 180°,
    270° (the first ``groups``), each flying straight through it to ``distance`` beyond its start; each UAV
    starts up to ``stagger`` (2 m) further back. A flow too wide for the square (``(agents/groups - 1)·
    spacing/2 + stagger + √2 r_uav + 2 jitter > distance/2``) starts that far from the centre instead and
    flies twice that, so no two UAVs of perpendicular flows start or end inside each other. No obstacles."""

    family = "crossing_flows"
    CHECKS = SwarmParams.CHECKS | {"groups": integer(2, 4), "spacing": number(0.0, lo_open=True),
                                   "stagger": number(0.0)}
    UNITS = SwarmParams.UNITS | {"groups": "", "spacing": "m", "stagger": "m"}

    groups: int = 2
    spacing: float = 1.5
    stagger: float = 2.0
    distance: tuple[float, float] = (16.0, 20.0)

    def _check(self, where: str) -> None:
        if self.agents % self.groups:
            raise ConfigError(f"{where}.agents = {self.agents} must be a multiple of groups = {self.groups}")


@dataclasses.dataclass(frozen=True)
class FormationGapParams(SwarmParams):
    """``formation_gap``: ``agents`` UAVs in a formation ``columns`` abreast (``spacing`` apart; ``agents`` a
    multiple of ``columns``) flying ``distance`` (20–24 m) through a gap of width ``gap`` (3–5 m, centre
    offset up to ``offset``) in a wall of ``max_obstacles`` (24) touching cylinders of radius
    ``wall_radius`` (0.5 m) across the middle of the run; the goals keep the formation. The gap is wider
    than a UAV (``gap > 2 r_uav``, checked), so the formation can pass in single file."""

    family = "formation_gap"
    CHECKS = SwarmParams.CHECKS | {"columns": integer(1), "spacing": number(0.0, lo_open=True),
                                   "gap": span(0.0, lo_open=True), "offset": number(0.0),
                                   "wall_radius": number(0.0, lo_open=True)}
    UNITS = SwarmParams.UNITS | {"columns": "", "spacing": "m", "gap": "m", "offset": "m", "wall_radius": "m"}

    columns: int = 4
    spacing: float = 1.5
    gap: tuple[float, float] = (3.0, 5.0)
    offset: float = 1.0
    wall_radius: float = 0.5
    max_obstacles: int = 24
    distance: tuple[float, float] = (20.0, 24.0)

    def _check(self, where: str) -> None:
        if self.agents % self.columns:
            raise ConfigError(f"{where}.agents = {self.agents} must be a multiple of columns = {self.columns}")
        if self.gap[0] <= 2 * self.r_uav:
            raise ConfigError(f"{where}.gap = {list(self.gap)} must be wider than the UAV (2 r_uav = "
                              f"{2 * self.r_uav} m)")


@dataclasses.dataclass(frozen=True)
class SwarmClutterParams(SwarmParams):
    """``swarm_clutter``: ``agents`` UAVs abreast (``spacing`` apart) flying across a forest (``density`` per
    100 m² of the run's corridor, ``agents · spacing + corridor_margin`` wide (4 m), radius 0.5–1.0 m),
    each to the goal of its mirror image (UAV ``i`` to the column of UAV ``A - 1 - i``), so every pair of
    paths crosses; a ``moving`` share of the obstacles drifts at ``speed``."""

    family = "swarm_clutter"
    CHECKS = SwarmParams.CHECKS | {"spacing": number(0.0, lo_open=True), "density": number(0.0),
                                   "radius": span(0.0, lo_open=True), "moving": number(0.0, 1.0),
                                   "speed": span(0.0), "corridor_margin": number(0.0)}
    UNITS = SwarmParams.UNITS | {"spacing": "m", "density": "1/m²", "radius": "m", "moving": "", "speed": "m/s",
                                 "corridor_margin": "m"}

    spacing: float = 1.5
    density: float = 3.0
    radius: tuple[float, float] = (0.5, 1.0)
    moving: float = 0.5
    speed: tuple[float, float] = (0.2, 1.0)
    max_obstacles: int = 24
    distance: tuple[float, float] = (20.0, 24.0)
    t_max: float = 60.0
    corridor_margin: float = 4.0


class SwarmLayout(NamedTuple):
    """A swarm field in its local frame: starts and goals (A, 2), the obstacles, the kind."""

    start: Array
    goal: Array
    obstacles: Layout


def _abreast(n: int, spacing: float, dtype: Any) -> Array:
    """``n`` lateral offsets ``spacing`` apart, centred on 0."""
    return (jnp.arange(n, dtype=dtype) - 0.5 * (n - 1)) * spacing


def _no_obstacles(size: int, dtype: Any) -> Layout:
    return Layout(jnp.zeros((size, 2), dtype), jnp.zeros((size, 2), dtype), jnp.zeros((size,), dtype),
                  jnp.zeros((size,), bool))


def _circle(d: Draws, p: CircleSwapParams, length: Array) -> SwarmLayout:
    # the agents' directions: one random rotation (trig of one number per field) of A fixed unit
    # vectors, so that no vectorised trig over the batch's agents rounds with the batch's size
    turn = d.uniform((0.0, 2 * math.pi))
    fixed = 2 * np.pi * np.arange(p.agents) / p.agents
    c, s = jnp.cos(turn), jnp.sin(turn)
    cos, sin = jnp.asarray(np.cos(fixed), length.dtype), jnp.asarray(np.sin(fixed), length.dtype)
    # a circle too small for its UAVs grows until neighbours are 2 r_uav apart whatever the jitter
    length = jnp.maximum(length, (2.0 * p.r_uav + 2.0 * math.sqrt(2.0) * p.jitter) / math.sin(math.pi / p.agents)
                         if p.agents > 1 else 0.0)
    ring = 0.5 * length * jnp.stack([c * cos - s * sin, s * cos + c * sin], axis=-1)
    return SwarmLayout(ring, -ring, _no_obstacles(p.max_obstacles, length.dtype))


def _flows(d: Draws, p: CrossingFlowsParams, length: Array) -> SwarmLayout:
    per = p.agents // p.groups
    lateral = jnp.tile(_abreast(per, p.spacing, length.dtype), p.groups)
    quarter = np.repeat(np.arange(p.groups), per)  # the flows' directions: k · 90°
    along = jnp.asarray(np.stack([[1, 0], [0, 1], [-1, 0], [0, -1]])[quarter], length.dtype)
    left = jnp.stack([-along[:, 1], along[:, 0]], -1)
    # half the run; at least so far that perpendicular flows' starts, and their staggered goals, keep
    # 2 r_uav apart at the corners whatever the jitter (wide flows of many UAVs push the square out)
    half = 0.5 * (per - 1) * p.spacing + p.stagger + math.sqrt(2.0) * p.r_uav + 2.0 * p.jitter
    base = jnp.maximum(0.5 * length, half)
    back = base + d.uniform((0.0, p.stagger), (p.agents,))
    start = -back[:, None] * along + lateral[:, None] * left
    goal = start + 2.0 * base * along
    return SwarmLayout(start, goal, _no_obstacles(p.max_obstacles, length.dtype))


def _formation(d: Draws, p: FormationGapParams, length: Array) -> SwarmLayout:
    rows = p.agents // p.columns
    lateral = jnp.tile(_abreast(p.columns, p.spacing, length.dtype), rows)
    back = jnp.repeat(jnp.arange(rows, dtype=length.dtype) * p.spacing, p.columns)
    start = jnp.stack([-back, lateral], -1)
    goal = start + jnp.stack([length, jnp.zeros_like(length)])
    gap, centre = d.uniform(p.gap), d.uniform((-p.offset, p.offset))
    # the wall: touching cylinders outward from each side of the gap, half of them on each side
    half = p.max_obstacles // 2
    steps = p.wall_radius + 2 * p.wall_radius * jnp.arange(half, dtype=length.dtype)
    y = jnp.concatenate([centre + 0.5 * gap + steps, centre - 0.5 * gap - steps])
    n = y.shape[0]
    wall = Layout(jnp.stack([jnp.full((n,), 0.5 * length), y], -1), jnp.zeros((n, 2), length.dtype),
                  jnp.full((n,), p.wall_radius, length.dtype), jnp.ones((n,), bool))
    return SwarmLayout(start, goal, fit(wall, p.max_obstacles))


def _clutter(d: Draws, p: SwarmClutterParams, length: Array) -> SwarmLayout:
    lateral = _abreast(p.agents, p.spacing, length.dtype)
    start = jnp.stack([jnp.zeros_like(lateral), lateral], -1)
    goal = jnp.stack([jnp.full_like(lateral, length), lateral[::-1]], -1)
    width = p.agents * p.spacing + p.corridor_margin
    count = jnp.minimum(jnp.round(p.density * length * width / 100.0), p.max_obstacles)
    forest = scatter(d, p.max_obstacles, count, length, width, p.radius)
    moving = d.uniform((0.0, 1.0), (p.max_obstacles,)) < p.moving
    return SwarmLayout(start, goal, with_motion(forest, d, p.speed, moving & forest.valid))


@dataclasses.dataclass(frozen=True)
class SwarmFamily:
    """A registered swarm family: its parameters and its builder ``build(draws, params, L) -> SwarmLayout``."""

    params: type[SwarmParams]
    build: Callable[..., SwarmLayout]
    description: str = ""

    @property
    def name(self) -> str:
        return self.params.family

    @property
    def kinds(self) -> tuple[str, ...]:
        """The kinds of field it draws: one, its name (a sweep's ``kind`` column)."""
        return (self.name,)


#: Registered swarm families.
SWARM_FAMILIES: Registry[SwarmFamily] = Registry("swarm family", describe=lambda f: f.description,
                                                 listed_as="swarm-families")


def register_swarm_family(params: type[SwarmParams], build: Callable[..., SwarmLayout], *, description: str = ""
                          ) -> SwarmFamily:
    """Register the swarm family ``params.family`` with its builder."""
    return SWARM_FAMILIES.register(params.family, SwarmFamily(params, build, description))


def swarm_params(family: str, **overrides: Any) -> SwarmParams:
    """The default parameters of swarm ``family`` with ``overrides`` (validated, one-line errors)."""
    return checked_params(SWARM_FAMILIES.get(family, "scenario.family").params, family, overrides)


def _far(obstacles: Obstacles, points: Array, reach: Array) -> Array:
    """Whether every obstacle keeps its centre at least ``reach`` (M,) from every point (A, 3), in xy for a
    cylinder (written out elementwise: the same in any batch)."""
    dx = obstacles.position[:, None, 0] - points[None, :, 0]
    dy = obstacles.position[:, None, 1] - points[None, :, 1]
    dz = jnp.where(obstacles.cylinder[:, None], 0.0, obstacles.position[:, None, 2] - points[None, :, 2])
    return jnp.all(dx * dx + dy * dy + dz * dz >= (reach * reach)[:, None], axis=1)


def make_swarm(key: Array, params: SwarmParams) -> Swarm:
    """One field of swarm family ``params.family`` from ``key`` (module docstring)."""
    d = Draws(jax.random.uniform(key, (params.draw_count(),), jnp.result_type(float)))
    length = d.uniform(params.distance)
    heading = jnp.deg2rad(d.uniform(params.heading))
    local = SWARM_FAMILIES.get(params.family).build(d, params, length)
    shake = d.uniform((-params.jitter, params.jitter), (2, params.agents, 2))
    start = _to_world(local.start + shake[0], heading, params.altitude)
    goal = _to_world(local.goal + shake[1], heading, params.altitude)
    lay = local.obstacles
    obstacles = Obstacles(position=_to_world(lay.xy, heading, params.altitude),
                          velocity=_to_world(lay.vxy, heading, 0.0), radius=lay.radius,
                          cylinder=jnp.full(lay.valid.shape, params.shape == "cylinder"), valid=lay.valid)
    reach = obstacles.radius + params.r_uav
    keep = (obstacles.valid & _far(obstacles, start, reach + params.start_margin)
            & _far(obstacles, goal, reach + params.goal_margin))
    obstacles = Obstacles(position=jnp.where(keep[:, None], obstacles.position, 1e6),
                          velocity=jnp.where(keep[:, None], obstacles.velocity, 0.0),
                          radius=jnp.where(keep, obstacles.radius, 0.0), cylinder=obstacles.cylinder & keep,
                          valid=keep)
    return Swarm(start=start, goal=goal, valid=jnp.ones((params.agents,), bool), obstacles=obstacles,
                 kind=jnp.zeros((), jnp.int32), key=jax.random.key_data(key))


def make_swarms(seed: int, params: SwarmParams, fields: int | Array) -> Swarm:
    """A batch of swarm fields: field ``i`` is ``make_swarm(field_key(seed, i), params)``
    (:func:`~jaxapf.scenarios.field_key`), the same in any batch (``fields``: a count or an array of
    field indices)."""
    indices = jnp.arange(fields) if isinstance(fields, int) else jnp.asarray(fields)
    return first_rows(_build(jax.random.key(seed), padded_indices(indices), params), indices.shape[0])


@partial(jax.jit, static_argnames="params")
def _build(base: Array, indices: Array, params: SwarmParams) -> Swarm:
    return jax.vmap(lambda i: make_swarm(jax.random.fold_in(base, i), params))(indices)

register_swarm_family(CircleSwapParams, _circle, description="UAVs on a circle swapping to the antipodal points "
                                                             "(RVO2's circle); no obstacles")
register_swarm_family(CrossingFlowsParams, _flows, description="2-4 flows of UAVs abreast crossing a common square "
                                                               "at right angles; no obstacles")
register_swarm_family(FormationGapParams, _formation, description="a formation flying through a 3-5 m gap in a wall")
register_swarm_family(SwarmClutterParams, _clutter, description="UAVs abreast crossing a forest of static and "
                                                                "drifting cylinders to mirrored goals")


def agents_solvable(swarms: Swarm, **oracle: Any) -> np.ndarray:
    """Whether each UAV of each field could reach its goal alone among the field's obstacles: a bool array
    of shape (..., A) (padded slots: True), by :func:`~jaxapf.scenarios.solvable` (whose keyword
    arguments ``oracle`` passes on: ``r_uav``, ``v_max``, ``t_max``, ...). A necessary condition only: the
    UAVs may still block each other, and flying them one at a time need not fit in ``t_max``."""
    from ..datatypes import Scenario
    from .solvability import solvable

    start = np.asarray(swarms.start)
    lead, agents = start.ndim - 2, start.shape[-2]  # the fields' batch axes, the UAV axis after them
    o = swarms.obstacles
    alone = Obstacles(*(np.repeat(np.expand_dims(np.asarray(x), lead), agents, axis=lead)
                        for x in (o.position, o.velocity, o.radius, o.cylinder, o.valid)))
    return solvable(Scenario(start=start, goal=np.asarray(swarms.goal), obstacles=alone), **oracle) | ~np.asarray(
        swarms.valid)
