r"""Per-episode metrics (SPEC 6): every metric is defined here, once.

An episode is a fixed-length scan of ``T`` control steps; termination (goal, collision) is applied
here by masking, so every episode of a batch has the same shape and every function below is pure,
``jit``-able (with ``sim`` static) and ``vmap``-able over a batch of trajectories and scenarios.

Time grid
---------
Samples ``i = 0..T`` at ``t_i = i·dt`` (``traj.time``); interval ``i = [t_i, t_{i+1}]``,
``i = 0..T-1``, carries the control ``a_i = traj.control[i]``. Obstacles move at constant velocity,
``centre(t) = position + velocity·t``. ``c_i`` is the swept (segment) clearance of interval ``i``,
the minimum over valid obstacles of :func:`~jaxapf.obstacles.segment_clearance`
``(p_i, p_{i+1}, obstacles, t_i, t_{i+1}, r_uav)`` (relative motion linear on the interval, closest
approach, cylinder projection), +inf if the field has no valid obstacle.

Episode end
-----------
- interval ``i`` collides iff ``c_i < 0``;
  ``collision_index`` = (first colliding interval) + 1, or ``T + 1`` ("never");
- ``goal_index`` = first sample ``i`` with ``|p_i - g| <= r_goal``, or ``T + 1`` ("never");
- ``e = end_index = min(goal_index, collision_index, T)``.

Valid samples are ``0..e``, valid intervals ``0..e-1``. When the goal is reached at the very
sample that ends a colliding interval (``collision_index == goal_index``) the collision wins.

Metrics (one scalar each, in the order of :data:`METRICS`)
----------------------------------------------------------
- ``success``: ``goal_index <= T`` and ``goal_index < collision_index``.
- ``collision``: ``collision_index <= T`` and ``collision_index <= goal_index``.
- ``min_clearance``: min of ``c_i`` over valid intervals (+inf with no valid obstacle); if
  ``e == 0`` the sample clearance at ``i = 0`` instead.
- ``time_to_goal``: ``goal_index·dt`` if ``success``, else NaN (the only NaN any metric produces).
- ``path_length``: ``Σ_{valid i} |p_{i+1} - p_i|``.
- ``path_ratio``: ``path_length / |g - start|`` (``start`` = ``scenario.start``). Degenerate
  ``start == goal``: ``0/0 := 1`` and ``x/0 := +inf`` for ``x > 0`` (never NaN).
- ``stalled``: some run of ``n`` consecutive valid samples, each with speed ``|v_i| < v_stall`` and
  ``|p_i - g| > r_goal``, has ``n·dt >= t_stall``. Evaluated as ``n >= ceil(t_stall/dt)`` with a
  relative tolerance of 1e-9 on the quotient, so ``t_stall = 3, dt = 0.1`` needs exactly 30 samples.
- ``final_distance``: ``|p_e - g|``.
- ``control_effort``: ``Σ_{valid i} |a_i|²·dt`` (the rectangle rule of ``∫|a|² dt``, exact for
  piecewise-constant control).
- ``jerk_rms``: ``j_i = (a_{i+1} - a_i)/dt`` for consecutive valid intervals (``i + 1 <= e - 1``),
  ``sqrt(mean_i |j_i|²)``; 0 with fewer than two valid intervals.
- ``max_velocity_excess``: ``max`` over valid samples and axes of ``max(|v_{i,axis}| - v_max, 0)``.
- ``time_near``: ``dt`` × number of valid intervals with ``c_i < d_safe``.
- ``min_ttc``: min over valid samples and valid obstacles of :func:`time_to_collision`
  ``(p_i, v_i, obstacles, t_i, r_uav)``.
- ``score`` (BARN): ``success · t_opt / clip(time_to_goal, 2 t_opt, 8 t_opt)`` with
  ``t_opt = |g - start| / v_max``; 0 if not ``success``. Degenerate ``t_opt = 0`` takes the limit
  ``t_opt → 0⁺`` at fixed ``time_to_goal``: 1/2 if ``time_to_goal = 0``, else 1/8.
- ``steps``: ``e`` (int32).

Dtypes: ``success``, ``collision``, ``stalled`` are bool, ``steps`` is int32, all others have the
trajectory's floating dtype.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax import Array

from .config import SimConfig
from .obstacles import Obstacles, Scenario, clearance, obstacles_at, project, segment_clearance
from .trajectory import Trajectory

__all__ = [
    "METRICS",
    "episode_metrics",
    "episode_end",
    "clearance_history",
    "interval_clearance",
    "time_to_collision",
]

#: Metric names, in column order.
METRICS: tuple[str, ...] = (
    "success",
    "collision",
    "min_clearance",
    "time_to_goal",
    "path_length",
    "path_ratio",
    "stalled",
    "final_distance",
    "control_effort",
    "jerk_rms",
    "max_velocity_excess",
    "time_near",
    "min_ttc",
    "score",
    "steps",
)


# --------------------------------------------------------------------------------------------
# geometry along the trajectory
# --------------------------------------------------------------------------------------------


def clearance_history(traj: Trajectory, scenario: Scenario, sim: SimConfig) -> Array:
    """Clearance (T+1, M) of every sample to every obstacle; +inf for padded slots."""
    per_sample = jax.vmap(clearance, in_axes=(0, None, 0, None))
    return per_sample(traj.position, scenario.obstacles, traj.time, sim.r_uav)


def interval_clearance(traj: Trajectory, scenario: Scenario, sim: SimConfig) -> Array:
    """Swept clearance (T, M) of every interval to every obstacle; +inf for padded slots."""
    per_interval = jax.vmap(segment_clearance, in_axes=(0, 0, None, 0, 0, None))
    p, t = traj.position, traj.time
    return per_interval(p[:-1], p[1:], scenario.obstacles, t[:-1], t[1:], sim.r_uav)


def time_to_collision(p: Array, v: Array, obstacles: Obstacles, t: Array | float, r_uav: float) -> Array:
    r"""Time to collision (M,) under constant relative velocity, from the state ``(p, v)`` at time ``t``.

    With ``r = P(p - centre(t))``, ``w = P(v - v_o)`` (``P`` drops z for a cylinder) and
    ``R = ρ + r_uav``, the result is the smallest ``τ >= 0`` with ``|r + w τ| = R``: 0 if already
    overlapping (``|r| <= R``), +inf if the gap is not closing (``w·r >= 0``), if the line of
    relative motion misses the obstacle, or for a padded slot.

    The smaller root of ``|w|² τ² + 2 (w·r) τ + (|r|² - R²) = 0`` is computed in the cancellation
    free form ``τ = (|r|² - R²) / (-(w·r) + sqrt((w·r)² - |w|²(|r|² - R²)))``.
    """
    r = project(p - obstacles_at(obstacles, t), obstacles.cylinder)
    w = project(v - obstacles.velocity, obstacles.cylinder)
    big_r = obstacles.radius + r_uav
    gap = jnp.sum(r * r, axis=-1) - big_r * big_r  # > 0 iff not overlapping
    closing = jnp.sum(w * r, axis=-1)  # < 0 iff the gap shrinks
    disc = closing * closing - jnp.sum(w * w, axis=-1) * gap
    hits = (closing < 0) & (disc >= 0)
    denom = jnp.where(hits, -closing + jnp.sqrt(jnp.maximum(disc, 0.0)), 1.0)
    tau = jnp.where(hits, gap / denom, jnp.inf)
    tau = jnp.where(gap <= 0, 0.0, tau)
    return jnp.where(obstacles.valid, tau, jnp.inf).astype(p.dtype)


# --------------------------------------------------------------------------------------------
# episode end and masks
# --------------------------------------------------------------------------------------------


def _first_index(mask: Array, never: int) -> Array:
    """Index (int32) of the first True entry of ``mask``, ``never`` if there is none."""
    return jnp.where(jnp.any(mask), jnp.argmax(mask), never).astype(jnp.int32)


def _goal_distance(traj: Trajectory, scenario: Scenario) -> Array:
    """Distance (T+1,) of every sample to the goal."""
    return jnp.linalg.norm(traj.position - scenario.goal, axis=-1)


def _end(min_interval_clearance: Array, goal_distance: Array, sim: SimConfig) -> dict[str, Array]:
    """Episode-end indices from the (T,) swept clearance and the (T+1,) goal distance."""
    steps = min_interval_clearance.shape[-1]
    collision_index = _first_index(min_interval_clearance < 0, steps) + 1  # "never" -> T + 1
    goal_index = _first_index(goal_distance <= sim.r_goal, steps + 1)
    end_index = jnp.minimum(jnp.minimum(goal_index, collision_index), steps).astype(jnp.int32)
    return {"goal_index": goal_index, "collision_index": collision_index, "end_index": end_index}


def episode_end(traj: Trajectory, scenario: Scenario, sim: SimConfig) -> dict[str, Array]:
    """``goal_index``, ``collision_index`` and ``end_index`` (int32 sample indices; ``T + 1`` = never)."""
    min_c = jnp.min(interval_clearance(traj, scenario, sim), axis=-1)
    return _end(min_c, _goal_distance(traj, scenario), sim)


# --------------------------------------------------------------------------------------------
# individual metrics (masked reductions)
# --------------------------------------------------------------------------------------------


def _masked_min(x: Array, mask: Array) -> Array:
    return jnp.min(jnp.where(mask, x, jnp.inf))


def _longest_run(mask: Array) -> Array:
    """Length (int32) of the longest run of consecutive True entries of a 1-D ``mask``."""
    idx = jnp.arange(mask.shape[-1], dtype=jnp.int32)
    last_false = jax.lax.cummax(jnp.where(mask, -1, idx), axis=0)
    return jnp.max(idx - last_false)


def _stall_samples(sim: SimConfig) -> int:
    """Smallest number of samples ``n`` with ``n·dt >= t_stall`` (1e-9 relative tolerance)."""
    return max(1, math.ceil(sim.t_stall / sim.dt * (1.0 - 1e-9)))


def _jerk_rms(control: Array, end_index: Array, dt: float) -> Array:
    """RMS of ``(a_{i+1} - a_i)/dt`` over consecutive valid intervals; 0 if there are fewer than two."""
    jerk = (control[1:] - control[:-1]) / dt  # (T-1, 3)
    pair_valid = jnp.arange(jerk.shape[0]) + 2 <= end_index
    total = jnp.sum(jnp.where(pair_valid, jnp.sum(jerk * jerk, axis=-1), 0.0))
    count = jnp.maximum(end_index - 1, 0)
    return jnp.where(count > 0, jnp.sqrt(total / jnp.maximum(count, 1)), 0.0)


def _ratio(num: Array, den: Array) -> Array:
    """``num / den`` for ``num, den >= 0`` with ``0/0 := 1`` and ``x/0 := +inf``."""
    safe = jnp.where(den > 0, den, 1.0)
    return jnp.where(den > 0, num / safe, jnp.where(num > 0, jnp.inf, 1.0))


def _score(success: Array, time_to_goal: Array, t_opt: Array) -> Array:
    """BARN score ``success · t_opt / clip(t, 2 t_opt, 8 t_opt)`` written as ``1 / clip(t/t_opt, 2, 8)``."""
    t = jnp.where(success, time_to_goal, 0.0)
    safe = jnp.where(t_opt > 0, t_opt, 1.0)
    rel = jnp.where(t_opt > 0, t / safe, jnp.where(t > 0, jnp.inf, 0.0))
    return jnp.where(success, 1.0 / jnp.clip(rel, 2.0, 8.0), 0.0)


def episode_metrics(traj: Trajectory, scenario: Scenario, sim: SimConfig) -> dict[str, Array]:
    """Every metric of SPEC 6 (definitions in the module docstring) for one episode.

    Args:
      traj: one episode of ``T`` steps (no batch axes; ``vmap`` for batches).
      scenario: the field it was flown in.
      sim: static settings (``dt``, ``v_max``, ``r_uav``, ``r_goal``, ``v_stall``, ``t_stall``,
        ``d_safe``).

    Returns:
      ``{name: scalar}`` for every name of :data:`METRICS`, in that order.
    """
    dtype = traj.position.dtype
    steps = traj.control.shape[-2]
    dt = sim.dt
    obstacles = scenario.obstacles

    swept = jnp.min(interval_clearance(traj, scenario, sim), axis=-1)  # (T,)
    goal_distance = _goal_distance(traj, scenario)  # (T+1,)
    end = _end(swept, goal_distance, sim)
    goal_index, collision_index, e = end["goal_index"], end["collision_index"], end["end_index"]
    sample_valid = jnp.arange(steps + 1) <= e
    interval_valid = jnp.arange(steps) < e

    success = (goal_index <= steps) & (goal_index < collision_index)
    collision = (collision_index <= steps) & (collision_index <= goal_index)

    first_sample = jnp.min(clearance(traj.position[0], obstacles, traj.time[0], sim.r_uav))
    min_clearance = jnp.where(e == 0, first_sample, _masked_min(swept, interval_valid))

    time_to_goal = jnp.where(success, goal_index * dt, jnp.nan)

    step_length = jnp.linalg.norm(traj.position[1:] - traj.position[:-1], axis=-1)
    path_length = jnp.sum(jnp.where(interval_valid, step_length, 0.0))
    straight = jnp.linalg.norm(scenario.goal - scenario.start)
    path_ratio = _ratio(path_length, straight)

    speed = jnp.linalg.norm(traj.velocity, axis=-1)
    stall_mask = sample_valid & (speed < sim.v_stall) & (goal_distance > sim.r_goal)
    stalled = _longest_run(stall_mask) >= _stall_samples(sim)

    final_distance = goal_distance[e]

    effort = jnp.sum(traj.control * traj.control, axis=-1) * dt
    control_effort = jnp.sum(jnp.where(interval_valid, effort, 0.0))

    jerk_rms = _jerk_rms(traj.control, e, dt)

    excess = jnp.max(jnp.maximum(jnp.abs(traj.velocity) - sim.v_max, 0.0), axis=-1)
    max_velocity_excess = jnp.max(jnp.where(sample_valid, excess, 0.0))

    time_near = dt * jnp.sum(interval_valid & (swept < sim.d_safe))

    ttc = jax.vmap(time_to_collision, in_axes=(0, 0, None, 0, None))(
        traj.position, traj.velocity, obstacles, traj.time, sim.r_uav)
    min_ttc = _masked_min(jnp.min(ttc, axis=-1), sample_valid)

    score = _score(success, time_to_goal, straight / sim.v_max)

    values = {
        "success": success,
        "collision": collision,
        "min_clearance": min_clearance,
        "time_to_goal": time_to_goal,
        "path_length": path_length,
        "path_ratio": path_ratio,
        "stalled": stalled,
        "final_distance": final_distance,
        "control_effort": control_effort,
        "jerk_rms": jerk_rms,
        "max_velocity_excess": max_velocity_excess,
        "time_near": time_near,
        "min_ttc": min_ttc,
        "score": score,
        "steps": e,
    }
    flags = {"success", "collision", "stalled"}
    return {
        name: (values[name].astype(bool) if name in flags
               else e.astype(jnp.int32) if name == "steps"
               else jnp.asarray(values[name]).astype(dtype))
        for name in METRICS
    }
