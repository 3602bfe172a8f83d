r"""The metrics of a swarm episode: every UAV's outcome, the swarm's, and how they met each other.

A swarm episode (:func:`~jaxapf.engine.swarm.swarm_rollout`) is ``A`` trajectories on one time grid. Its
metrics: ``at_goal`` and ``swarm_success``, ``agent_collision`` and ``obstacle_collision``,
``min_agent_clearance``, ``deadlock``, ``makespan`` and ``mean_time_to_goal``, and ``arrival_fairness``
(Jain's index of the arrivals' slowdowns); a swarm's rows also hold every component's per-step
diagnostic count summed over the UAVs (:func:`swarm_metric_names`). Their exact definitions (a pair's
swept clearance, when a pair collides, each UAV's end and the swarm's): docs/spec.md, "Beyond the paper:
swarms".

Each is a :class:`~jaxapf.metrics.Metric` of :data:`SWARM_METRICS` whose function reads the
:class:`SwarmContext`, which computes every shared quantity once (as
:class:`~jaxapf.metrics.EpisodeContext` does for one UAV); the pair clearances are taken one
interval at a time, so the working memory grows with ``A²`` per step, not per episode.
"""

from __future__ import annotations

import functools
from typing import Sequence

import jax
import jax.numpy as jnp
from jax import Array

from ..config import SimConfig
from ..datatypes import Scenario, Trajectory
from ..datatypes.obstacles import TINY
from ..datatypes.swarm import Swarm
from ..registry import Registry
from ..validation import ConfigError
from .base import METRICS, SWARM_NAMES, Metric, _describe
from .context import EpisodeContext, stall_samples

__all__ = ["SwarmContext", "SWARM_METRICS", "pair_clearance", "swarm_metrics", "swarm_metric_names", "agent_outcomes"]


def _interval_pairs(p0: Array, p1: Array, valid: Array, r_uav: float) -> Array:
    """``c^{ab}`` (A, A) of one interval from positions ``p0`` to ``p1`` (A, 3)."""
    r0 = p0[:, None] - p0[None, :]
    delta = (p1[:, None] - p1[None, :]) - r0
    dd = jnp.sum(delta * delta, axis=-1)
    s = jnp.clip(-jnp.sum(r0 * delta, axis=-1) / jnp.maximum(dd, TINY), 0.0, 1.0)
    closest = r0 + s[..., None] * delta
    c = jnp.sqrt(jnp.maximum(jnp.sum(closest * closest, axis=-1), TINY)) - 2 * r_uav
    pair = valid[:, None] & valid[None, :] & ~jnp.eye(valid.shape[0], dtype=bool)
    return jnp.where(pair, c, jnp.inf)


def pair_clearance(position: Array, valid: Array, r_uav: float) -> Array:
    """``c^{ab}_i`` (T, A, A) of positions (A, T+1, 3): the swept clearance of every pair over every
    interval (module docstring); +inf on the diagonal and for padded slots."""
    p = jnp.moveaxis(position, 0, 1)  # (T+1, A, 3)
    return jax.vmap(lambda p0, p1: _interval_pairs(p0, p1, valid, r_uav))(p[:-1], p[1:])


class SwarmContext:
    """One swarm episode (``traj`` with a leading UAV axis) and what its metrics share, each computed once."""

    def __init__(self, traj: Trajectory, swarm: Swarm, sim: SimConfig) -> None:
        self.traj, self.swarm, self.sim = traj, swarm, sim
        self.steps, self.dt = traj.control.shape[-2], sim.episode.dt

    @functools.cached_property
    def own(self) -> tuple[Array, Array, Array]:
        """Per UAV: ``g_a``, ``o_a`` (A,) and the distance to its goal (A, T+1), by the single-UAV rules."""
        def one(t: Trajectory, start: Array, goal: Array) -> tuple[Array, Array, Array]:
            ctx = EpisodeContext(t, Scenario(start=start, goal=goal, obstacles=self.swarm.obstacles), self.sim)
            return ctx.end["goal_index"], ctx.end["collision_index"], ctx.goal_distance
        return jax.vmap(one)(self.traj, self.swarm.start, self.swarm.goal)

    @functools.cached_property
    def pairs(self) -> tuple[Array, Array]:
        """Per interval: which UAVs hit another while neither has hit an obstacle (T, A), and the closest
        such pair (T,); one interval at a time."""
        obstacle_index = self.own[1]
        p = jnp.moveaxis(self.traj.position, 0, 1)  # (T+1, A, 3)

        def interval(args: tuple[Array, Array, Array]) -> tuple[Array, Array]:
            p0, p1, i = args
            c = _interval_pairs(p0, p1, self.swarm.valid, self.sim.vehicle.r_uav)
            intact = (i < obstacle_index)[:, None] & (i < obstacle_index)[None, :]
            return jnp.any((c < 0) & intact, axis=-1), jnp.min(jnp.where(intact, c, jnp.inf))
        return jax.lax.map(interval, (p[:-1], p[1:], jnp.arange(self.steps)))

    @functools.cached_property
    def agent_index(self) -> Array:
        """``k_a`` (A,): the first interval on which UAV ``a`` hits another, + 1 (``T + 1``: never)."""
        hit = self.pairs[0]
        return jnp.where(jnp.any(hit, axis=0), jnp.argmax(hit, axis=0), self.steps).astype(jnp.int32) + 1

    @functools.cached_property
    def success(self) -> Array:
        goal_index, obstacle_index, _ = self.own
        return self.swarm.valid & (goal_index <= self.steps) & (goal_index < jnp.minimum(obstacle_index,
                                                                                          self.agent_index))

    @functools.cached_property
    def ends(self) -> Array:
        """``e_a = min(g_a, o_a, k_a, T)`` (A,): each UAV's end."""
        goal_index, obstacle_index, _ = self.own
        return jnp.minimum(jnp.minimum(goal_index, jnp.minimum(obstacle_index, self.agent_index)), self.steps)

    @functools.cached_property
    def last(self) -> Array:
        """``E``: the last UAV's end."""
        return jnp.max(jnp.where(self.swarm.valid, self.ends, 0))

    @functools.cached_property
    def arrival(self) -> Array:
        """Arrival times (A,) [s] of the UAVs that succeed, 0 for the others."""
        return jnp.where(self.success, self.own[0].astype(self.traj.position.dtype) * self.dt, 0.0)

    @property
    def arrived(self) -> Array:
        return jnp.sum(self.success)

    def extra(self, name: str) -> Array:
        """The per-step diagnostic ``name`` the UAVs' components record, summed over every UAV's intervals
        before its end (0 if the stack records no ``name``)."""
        values = self.traj.extras.get(name)
        if values is None:
            return jnp.zeros((), jnp.int32)
        before = jnp.arange(self.steps)[None] < self.ends[:, None]
        return jnp.sum(jnp.where(before & self.swarm.valid[:, None], values, 0))


def _deadlock(ctx: SwarmContext) -> Array:
    goal_index, obstacle_index, distance = ctx.own
    n, steps, valid = stall_samples(ctx.sim), ctx.steps, ctx.swarm.valid
    windows = max(steps + 2 - n, 0)  # window starts i with i + n - 1 <= T (none in an episode shorter than n)
    first = jnp.arange(windows)
    on_way = (valid[None] & (first[:, None] < goal_index[None]) & (first[:, None] < obstacle_index[None])
              & (first[:, None] < ctx.agent_index[None]))  # (W, A)
    progress = (distance[:, :windows] - distance[:, n - 1:n - 1 + windows]).T  # (W, A)
    stuck = jnp.any(on_way, axis=1) & jnp.all(~on_way | (progress < ctx.sim.metrics.d_progress), axis=1)
    return jnp.any(stuck & (first + n - 1 <= ctx.last))


def _fairness(ctx: SwarmContext) -> Array:
    straight = jnp.linalg.norm(ctx.swarm.goal - ctx.swarm.start, axis=-1)
    slowdown = ctx.arrival / jnp.maximum(straight, TINY)
    jain = jnp.sum(slowdown) ** 2 / (jnp.maximum(ctx.arrived, 1) * jnp.maximum(jnp.sum(slowdown ** 2), TINY))
    return jnp.where(ctx.arrived > 0, jain, jnp.nan)


def _obstacle_collision(ctx: SwarmContext) -> Array:
    goal_index, obstacle_index, _ = ctx.own
    return jnp.any(ctx.swarm.valid & (obstacle_index <= ctx.steps) & (obstacle_index <= goal_index))


def _mean_time(ctx: SwarmContext) -> Array:
    return jnp.where(ctx.arrived > 0, jnp.sum(ctx.arrival) / jnp.maximum(ctx.arrived, 1), jnp.nan)


#: The swarm metrics, in column order (module docstring for their definitions).
SWARM_METRICS: Registry[Metric] = Registry("swarm metric", describe=_describe, listed_as="swarm-metrics")
for _metric in (
    Metric("at_goal", lambda c: jnp.sum(c.success) / jnp.maximum(jnp.sum(c.swarm.valid), 1), higher_is_better=True,
           report=True, margin=0.02, doc="fraction of the swarm's UAVs that reach their goals"),
    Metric("swarm_success", lambda c: jnp.all(c.success | ~c.swarm.valid), dtype="bool", kind="rate",
           higher_is_better=True, report=True, margin=0.02, doc="every UAV reaches its goal"),
    Metric("agent_collision", lambda c: jnp.any(c.swarm.valid & (c.agent_index <= c.last)), dtype="bool",
           kind="rate", higher_is_better=False, report=True, margin=0.02, doc="two UAVs collide"),
    Metric("obstacle_collision", _obstacle_collision, dtype="bool", kind="rate", higher_is_better=False, report=True,
           margin=0.02, doc="a UAV hits an obstacle before its goal"),
    Metric("min_agent_clearance", lambda c: jnp.min(jnp.where(jnp.arange(c.steps) < c.last, c.pairs[1], jnp.inf)),
           unit="m", higher_is_better=True, report=True, margin=0.05,
           doc="closest approach between two UAVs (swept, surface to surface)"),
    Metric("deadlock", _deadlock, dtype="bool", kind="rate", higher_is_better=False, report=True, margin=0.02,
           doc="for t_stall no UAV still on its way gets d_progress closer to its goal"),
    Metric("makespan", lambda c: jnp.where(jnp.all(c.success | ~c.swarm.valid), jnp.max(c.arrival), jnp.nan),
           unit="s", higher_is_better=False, on_success=True, report=True, margin=0.5, per_step=True,
           doc="time until the last UAV is at its goal (every UAV arriving)"),
    Metric("mean_time_to_goal", _mean_time, unit="s", higher_is_better=False, margin=0.5, per_step=True,
           doc="mean arrival time of the UAVs that arrive"),
    Metric("arrival_fairness", _fairness, higher_is_better=True, margin=0.02,
           doc="Jain's index of the arrived UAVs' slowdowns (s per m of straight line)"),
):
    if _metric.name in METRICS:
        raise ConfigError(f"swarm metric {_metric.name!r} is a single-UAV metric's name")
    SWARM_NAMES.add(_metric.name)
    SWARM_METRICS.register(_metric.name, _metric)


def agent_outcomes(traj: Trajectory, swarm: Swarm, sim: SimConfig) -> dict[str, Array]:
    """Each UAV's outcome (A,) in one swarm episode (module docstring): ``end`` (``e_a``), ``success``,
    ``obstacle_index`` (``o_a``, ``T + 1``: never) and ``agent_index`` (``k_a``), sample indices."""
    ctx = SwarmContext(traj, swarm, sim)
    return {"end": ctx.ends, "success": ctx.success, "obstacle_index": ctx.own[1], "agent_index": ctx.agent_index}


def swarm_metric_names() -> tuple[str, ...]:
    """A swarm's columns: :data:`SWARM_METRICS`, then the registered components' counts of a per-step
    diagnostic (the metrics with a ``flag``), each summed over the UAVs (module docstring)."""
    return SWARM_METRICS.names() + tuple(n for n, m in METRICS.items() if m.flag is not None)


def _swarm_metric(name: str) -> Metric:
    if name in SWARM_METRICS:
        return SWARM_METRICS.get(name)
    if name in METRICS and METRICS.get(name).flag is not None:
        return METRICS.get(name)
    raise ConfigError(f"swarm metric = {name!r} is not a swarm's metric; choose one of "
                      f"{', '.join(swarm_metric_names())}")


def swarm_metrics(traj: Trajectory, swarm: Swarm, sim: SimConfig, names: Sequence[str] | None = None
                  ) -> dict[str, Array]:
    """The swarm metrics ``names`` (default: all, :func:`swarm_metric_names`) of one swarm episode."""
    ctx = SwarmContext(traj, swarm, sim)
    dtype = traj.position.dtype
    metrics = {n: _swarm_metric(n) for n in (swarm_metric_names() if names is None else names)}
    return {n: m.cast(m.fn(ctx), dtype) for n, m in metrics.items()}
