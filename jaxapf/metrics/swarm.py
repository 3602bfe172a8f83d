r"""The metrics of a swarm episode: every UAV's outcome, the swarm's, and how they met each other.

A swarm episode (:func:`~jaxapf.engine.swarm.swarm_rollout`) is ``A`` trajectories on one time grid
(:mod:`jaxapf.metrics.episode`'s). Per UAV ``a`` (valid slots only):

- ``c^{ab}_i``: the swept clearance of UAVs ``a`` and ``b`` over interval ``i``, both moving linearly
  (the closest approach of their relative motion) less ``2 r_uav``;
- its obstacle collision ``o_a`` (the single-UAV rule against the field's obstacles), its goal
  index ``g_a``; a pair collides on interval ``i`` iff ``c^{ab}_i < 0`` while neither has hit an
  obstacle (``i < o_a, o_b``: a crashed UAV's later flight is not physics); ``k_a`` = its first
  such interval + 1 (``T + 1``: never). A UAV at its goal hovers there and still counts;
- ``success_a``: ``g_a <= T`` and ``g_a < min(o_a, k_a)``; its end ``e_a = min(g_a, o_a, k_a, T)``;
  the swarm's end ``E = max_a e_a`` (the streaming engine stops a swarm when every UAV has ended).

Metrics (one scalar each per episode):

- ``at_goal``: the fraction of UAVs that succeed; ``swarm_success``: all of them do.
- ``agent_collision``: some pair collides (before ``E``); ``obstacle_collision``: some UAV hits an obstacle
  before reaching its goal.
- ``min_agent_clearance``: the smallest ``c^{ab}_i`` over pairs and intervals ``i < E`` while
  neither has hit an obstacle (+inf for one UAV).
- ``deadlock``: some window of ``n`` samples (``n·dt >= t_stall``, as ``stalled``) in ``0..E`` in
  which at least one UAV is still on its way (not yet at its goal, not crashed) and every such UAV
  gets less than ``d_progress`` closer to its goal: nobody makes progress while goals remain.
- ``makespan``: the last arrival time if every UAV succeeds, else NaN;
  ``mean_time_to_goal``: the mean arrival time of those that succeed (NaN if none).
- ``arrival_fairness``: Jain's index ``(Σ s_a)² / (n Σ s_a²)`` of the arrived UAVs' slowdowns
  ``s_a = t_a / |g_a - start_a|`` (seconds per metre of straight line), in ``(0, 1]``, 1 when every
  UAV is held up alike; NaN if none arrives.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from ..config import SimConfig
from ..datatypes import Scenario, Trajectory
from ..datatypes.obstacles import TINY
from ..datatypes.swarm import Swarm
from .context import EpisodeContext, stall_samples

__all__ = ["pair_clearance", "swarm_metrics", "SWARM_METRICS"]

#: The metrics :func:`swarm_metrics` returns, in order.
SWARM_METRICS = ("at_goal", "swarm_success", "agent_collision", "obstacle_collision", "min_agent_clearance",
                 "deadlock", "makespan", "mean_time_to_goal", "arrival_fairness")


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


def swarm_metrics(traj: Trajectory, swarm: Swarm, sim: SimConfig) -> dict[str, Array]:
    """:data:`SWARM_METRICS` of one swarm episode (``traj`` with a leading UAV axis)."""
    steps, dt = traj.control.shape[-2], sim.episode.dt

    def own(t: Trajectory, start: Array, goal: Array) -> tuple[Array, Array, Array]:
        ctx = EpisodeContext(t, Scenario(start=start, goal=goal, obstacles=swarm.obstacles), sim)
        return ctx.end["goal_index"], ctx.end["collision_index"], ctx.goal_distance
    goal_index, obstacle_index, distance = jax.vmap(own)(traj, swarm.start, swarm.goal)  # (A,), (A,), (A, T+1)
    # one interval at a time (lax.map), keeping per interval only what the metrics need: which UAVs
    # hit another (T, A) and the closest pair (T,), so memory grows with A² per step, not per episode
    p = jnp.moveaxis(traj.position, 0, 1)  # (T+1, A, 3)

    def interval(args: tuple[Array, Array, Array]) -> tuple[Array, Array]:
        p0, p1, i = args
        c = _interval_pairs(p0, p1, swarm.valid, sim.vehicle.r_uav)
        intact = (i < obstacle_index)[:, None] & (i < obstacle_index)[None, :]
        return jnp.any((c < 0) & intact, axis=-1), jnp.min(jnp.where(intact, c, jnp.inf))
    hit, closest = jax.lax.map(interval, (p[:-1], p[1:], jnp.arange(steps)))  # (T, A), (T,)
    agent_index = jnp.where(jnp.any(hit, axis=0), jnp.argmax(hit, axis=0), steps).astype(jnp.int32) + 1
    success = swarm.valid & (goal_index <= steps) & (goal_index < jnp.minimum(obstacle_index, agent_index))
    end = jnp.minimum(jnp.minimum(goal_index, jnp.minimum(obstacle_index, agent_index)), steps)
    last = jnp.max(jnp.where(swarm.valid, end, 0))
    count = jnp.maximum(jnp.sum(swarm.valid), 1)
    arrival = goal_index.astype(traj.position.dtype) * dt
    arrived = jnp.sum(success)
    mean_time = jnp.where(arrived > 0, jnp.sum(jnp.where(success, arrival, 0.0)) / jnp.maximum(arrived, 1), jnp.nan)
    straight = jnp.linalg.norm(swarm.goal - swarm.start, axis=-1)
    slowdown = jnp.where(success, arrival / jnp.maximum(straight, TINY), 0.0)
    jain = jnp.sum(slowdown) ** 2 / (jnp.maximum(arrived, 1) * jnp.maximum(jnp.sum(slowdown ** 2), TINY))
    # deadlock: a window of n samples in 0..E in which everybody still on the way gets nowhere
    n = stall_samples(sim)
    windows = max(steps + 2 - n, 0)  # window starts i with i + n - 1 <= T (none in an episode shorter than n)
    first = jnp.arange(windows)
    on_way = (swarm.valid[None] & (first[:, None] < goal_index[None]) & (first[:, None] < obstacle_index[None])
              & (first[:, None] < agent_index[None]))  # (W, A)
    progress = (distance[:, :windows] - distance[:, n - 1:n - 1 + windows]).T  # (W, A)
    stuck = jnp.any(on_way, axis=1) & jnp.all(~on_way | (progress < sim.metrics.d_progress), axis=1)
    stuck = stuck & (first + n - 1 <= last)
    return {
        "at_goal": jnp.sum(success) / count,
        "swarm_success": jnp.all(success | ~swarm.valid),
        "agent_collision": jnp.any(swarm.valid & (agent_index <= last)),
        "obstacle_collision": jnp.any(swarm.valid & (obstacle_index <= steps) & (obstacle_index <= goal_index)),
        "min_agent_clearance": jnp.min(jnp.where(jnp.arange(steps) < last, closest, jnp.inf)),
        "deadlock": jnp.any(stuck),
        "makespan": jnp.where(jnp.all(success | ~swarm.valid), jnp.max(jnp.where(success, arrival, 0.0)), jnp.nan),
        "mean_time_to_goal": mean_time,
        "arrival_fairness": jnp.where(arrived > 0, jain, jnp.nan),
    }
