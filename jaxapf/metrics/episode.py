r"""The episode's own metrics (SPEC 6): every one is defined here, once, and registered.

An episode is a fixed-length scan of ``T`` control steps; termination (goal, collision) is applied
here by masking, so every episode of a batch has the same shape and every function below is pure,
``jit``-able (with ``sim`` static) and ``vmap``-able over a batch of trajectories and scenarios.

Time grid
---------
Samples ``i = 0..T`` at ``t_i = i·dt`` (``traj.time``); interval ``i = [t_i, t_{i+1}]``,
``i = 0..T-1``, carries the control ``a_i = traj.control[i]``. Obstacles move at constant velocity,
``centre(t) = position + velocity·t``. ``c_i`` is the swept (segment) clearance of interval ``i``,
the minimum over valid obstacles of :func:`~jaxapf.datatypes.segment_clearance`
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

Metrics (one scalar each, in registration order)
----------------------------------------------------------
- ``success``: ``goal_index <= T`` and ``goal_index < collision_index``.
- ``collision``: ``collision_index <= T`` and ``collision_index <= goal_index``.
- ``min_clearance``: min of ``c_i`` over valid intervals (+inf with no valid obstacle); if
  ``e == 0`` the sample clearance at ``i = 0`` instead.
- ``time_to_goal``: ``goal_index·dt`` if ``success``, else NaN (the only NaN any metric produces).
- ``path_length``: ``Σ_{valid i} |p_{i+1} - p_i|``.
- ``path_ratio``: ``path_length / |g - start|`` (``start`` = ``scenario.start``). Degenerate
  ``start == goal``: ``0/0 := 1`` and ``x/0 := +inf`` for ``x > 0`` (never NaN).
- ``stalled``: some run of ``n`` consecutive valid samples ``i .. i+n-1``, each with speed
  ``|v| < v_stall`` and ``|p - g| > r_goal``, has ``n·dt >= t_stall`` and makes no progress:
  ``|p_i - g| - |p_{i+n-1} - g| < d_progress``. ``n = ceil(t_stall/dt)`` with a relative tolerance
  of 1e-9 on the quotient, so ``t_stall = 3, dt = 0.1`` needs exactly 30 samples. The progress
  condition keeps a slow final approach that still closes in (a small attraction gain near the
  goal) from counting as the local-minimum signature.
- ``final_distance``: ``|p_e - g|``.
- ``control_effort``: ``Σ_{valid i} |a_i|²·dt`` (the rectangle rule of ``∫|a|² dt``, exact for
  piecewise-constant control).
- ``jerk_rms``: ``j_i = (a_{i+1} - a_i)/dt`` for consecutive valid intervals (``i + 1 <= e - 1``),
  ``sqrt(mean_i |j_i|²)``; 0 with fewer than two valid intervals.
- ``max_velocity_excess``: ``max`` over valid samples and axes of ``max(|v_{i,axis}| - v_max, 0)``.
- ``time_near``: ``dt`` × number of valid intervals with ``c_i < d_safe`` while closing in: the
  sample clearance to the nearest obstacle falls over the interval, ``n_{i+1} < n_i`` with
  ``n_i = min_o d_{i,o}``, or the closest approach lies inside it, ``c_i < min(n_i, n_{i+1})``. A UAV
  hovering still near an obstacle (a stall) accumulates nothing; one approaching or passing does.
- ``min_ttc``: min over valid samples and valid obstacles of :func:`time_to_collision`
  ``(p_i, v_i, obstacles, t_i, r_uav)``.
- ``spl`` (success weighted by path length, Anderson et al. 2018, "On Evaluation of Embodied
  Navigation Agents", arXiv:1807.06757): ``success · L / max(path_length, L)`` with ``L = |g - start|``,
  the straight-line distance (a lower bound of the shortest collision-free path, so ``spl`` can only
  understate an agent's efficiency). In [0, 1]; 1 for a straight successful flight, 0 for a failure;
  degenerate ``L = 0``: ``success`` if the path length is 0, else 0.
- ``steps``: ``e`` (int32).
- ``accel_error_rms``: ``sqrt(mean_i |(v_{i+1} - v_i)/dt - a_i|²)`` over valid intervals: the applied
  command against the acceleration the plant realised (a plant's lag, a disturbance); 0 with no
  valid interval. The double integrator in calm air realises its command (up to rounding).
- ``position_error_max``: ``max_i |p_{i+1} - (p_i + v_i dt + a_i dt²/2)|`` over valid intervals: how
  far one step of the plant lands from where the MPC's model puts it; 0 with no valid interval.

A component that records what only it knows (a filter's infeasible steps, a plant's tilt, a
sensor's missed obstacles) owns the metric that reads it: registering the component registers the
metric (``metrics`` of :class:`~jaxapf.control.CBF`, :class:`~jaxapf.world.Quadrotor`,
:class:`~jaxapf.world.NoisySensor`, :class:`~jaxapf.planners.VelocityObstacle`).

Efficiency metrics (``time_to_goal``, ``path_ratio``, ``control_effort``, ``jerk_rms``, ``min_ttc``)
are registered as meaningful only on successful episodes (``Metric.on_success``): a collision cuts a
path short and an early stall looks "efficient", so reports compare them on the pairs where both
settings succeed. ``min_ttc`` is larger in stalled episodes than in successful ones for that reason.

Dtypes: ``success``, ``collision``, ``stalled`` are bool, ``steps`` is int32, all others have the
trajectory's floating dtype.

Every metric reads the shared quantities of one :class:`EpisodeContext` (the swept clearance, the
episode end, the valid masks), which are computed once per trace whatever metrics ask for them.
"""

from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp
from jax import Array

from ..config import SimConfig
from ..datatypes import Scenario, Trajectory, clearance
from .base import METRICS, Metric, compute_metrics, register_metric
from .context import EpisodeContext, clearance_history, masked_min, ratio, stall_samples, time_to_collision

__all__ = ["episode_metrics"]


# --------------------------------------------------------------------------------------------
# the metrics (SPEC 6), in column order
# --------------------------------------------------------------------------------------------


def _min_clearance(ctx: EpisodeContext) -> Array:
    traj, obstacles = ctx.traj, ctx.scenario.obstacles
    first_sample = jnp.min(clearance(traj.position[0], obstacles, traj.time[0], ctx.sim.vehicle.r_uav))
    return jnp.where(ctx.end_index == 0, first_sample, masked_min(ctx.swept, ctx.interval_valid))


def _stalled(ctx: EpisodeContext) -> Array:
    speed = jnp.linalg.norm(ctx.traj.velocity, axis=-1)
    mask = ctx.sample_valid & (speed < ctx.sim.metrics.v_stall) & (ctx.goal_distance > ctx.sim.episode.r_goal)
    n, samples = stall_samples(ctx.sim), mask.shape[-1]
    if n > samples:
        return jnp.zeros((), bool)
    count = jnp.cumsum(jnp.concatenate([jnp.zeros(1, jnp.int32), mask.astype(jnp.int32)]))
    slow = count[n:] - count[:-n] == n  # the n samples from each start are all slow and away
    progress = ctx.goal_distance[: samples - n + 1] - ctx.goal_distance[n - 1:]
    return jnp.any(slow & (progress < ctx.sim.metrics.d_progress))


def _control_effort(ctx: EpisodeContext) -> Array:
    effort = jnp.sum(ctx.traj.control * ctx.traj.control, axis=-1) * ctx.dt
    return jnp.sum(jnp.where(ctx.interval_valid, effort, 0.0))


def _jerk_rms(ctx: EpisodeContext) -> Array:
    """RMS of ``(a_{i+1} - a_i)/dt`` over consecutive valid intervals; 0 if there are fewer than two."""
    control, e = ctx.traj.control, ctx.end_index
    jerk = (control[1:] - control[:-1]) / ctx.dt  # (T-1, 3)
    pair_valid = jnp.arange(jerk.shape[0]) + 2 <= e
    total = jnp.sum(jnp.where(pair_valid, jnp.sum(jerk * jerk, axis=-1), 0.0))
    count = jnp.maximum(e - 1, 0)
    return jnp.where(count > 0, jnp.sqrt(total / jnp.maximum(count, 1)), 0.0)


def _max_velocity_excess(ctx: EpisodeContext) -> Array:
    excess = jnp.max(jnp.maximum(jnp.abs(ctx.traj.velocity) - ctx.sim.vehicle.v_max, 0.0), axis=-1)
    return jnp.max(jnp.where(ctx.sample_valid, excess, 0.0))


def _min_ttc(ctx: EpisodeContext) -> Array:
    traj = ctx.traj
    ttc = jax.vmap(time_to_collision, in_axes=(0, 0, None, 0, None))(
        traj.position, traj.velocity, ctx.scenario.obstacles, traj.time, ctx.sim.vehicle.r_uav)
    return masked_min(jnp.min(ttc, axis=-1), ctx.sample_valid)


def _spl(ctx: EpisodeContext) -> Array:
    """``success · L / max(path_length, L)`` (module docstring); ``0/0 := 1`` for a degenerate L = 0."""
    efficiency = 1.0 / ratio(jnp.maximum(ctx.path_length, ctx.straight), ctx.straight)
    return jnp.where(ctx.success, efficiency, 0.0)


def _step_errors(ctx: EpisodeContext) -> tuple[Array, Array]:
    """Per interval: the realised minus the applied acceleration (T, 3), and where one step lands
    against the double integrator's prediction (T, 3)."""
    p, v, a, dt = ctx.traj.position, ctx.traj.velocity, ctx.traj.control, ctx.dt
    return (v[1:] - v[:-1]) / dt - a, p[1:] - (p[:-1] + v[:-1] * dt + 0.5 * dt * dt * a)


def _accel_error_rms(ctx: EpisodeContext) -> Array:
    error = jnp.sum(_step_errors(ctx)[0] ** 2, axis=-1)
    count = jnp.sum(ctx.interval_valid)
    return jnp.sqrt(jnp.sum(jnp.where(ctx.interval_valid, error, 0.0)) / jnp.maximum(count, 1))


def _position_error_max(ctx: EpisodeContext) -> Array:
    error = jnp.linalg.norm(_step_errors(ctx)[1], axis=-1)
    return jnp.max(jnp.where(ctx.interval_valid, error, 0.0))


def _time_near(ctx: EpisodeContext) -> Array:
    nearest = jnp.min(clearance_history(ctx.traj, ctx.scenario, ctx.sim), axis=-1)  # (T+1,)
    closing = (nearest[1:] < nearest[:-1]) | (ctx.swept < jnp.minimum(nearest[1:], nearest[:-1]))
    return ctx.dt * jnp.sum(ctx.interval_valid & (ctx.swept < ctx.sim.metrics.d_safe) & closing)


for _metric in (
    Metric("success", lambda ctx: ctx.success, dtype="bool", kind="rate", higher_is_better=True, report=True,
           margin=0.02, doc="goal reached within r_goal before t_max with no collision"),
    Metric("collision", lambda ctx: ctx.collision, dtype="bool", kind="rate", higher_is_better=False, report=True,
           margin=0.02, doc="the swept clearance fell below 0"),
    Metric("min_clearance", _min_clearance, unit="m", higher_is_better=True, report=True, margin=0.05,
           doc="smallest swept clearance to any obstacle"),
    Metric("time_to_goal", lambda ctx: ctx.time_to_goal, unit="s", higher_is_better=False, on_success=True,
           report=True, margin=0.5, per_step=True, doc="time of the first sample within r_goal of the goal"),
    Metric("path_length", lambda ctx: ctx.path_length, unit="m", doc="length of the flown path"),
    Metric("path_ratio", lambda ctx: ratio(ctx.path_length, ctx.straight), higher_is_better=False,
           on_success=True, report=True, margin=0.02, doc="path length over the straight start-goal distance"),
    Metric("stalled", _stalled, dtype="bool", kind="rate", higher_is_better=False, report=True, margin=0.02,
           doc="slower than v_stall for t_stall, away from the goal and not closing in: a local minimum"),
    Metric("final_distance", lambda ctx: ctx.goal_distance[ctx.end_index], unit="m", higher_is_better=False,
           margin=0.1, doc="distance to the goal at the episode's end"),
    Metric("control_effort", _control_effort, unit="m²/s³", higher_is_better=False, on_success=True, report=True,
           margin=0.5, doc="∫|a|² dt"),
    Metric("jerk_rms", _jerk_rms, unit="m/s³", higher_is_better=False, on_success=True, report=True, margin=0.25,
           doc="RMS of the jerk between consecutive controls"),
    Metric("max_velocity_excess", _max_velocity_excess, unit="m/s", higher_is_better=False, margin=0.05,
           doc="largest per-axis speed above v_max"),
    Metric("time_near", _time_near, unit="s", higher_is_better=False, margin=0.5,
           per_step=True, doc="time closing in on an obstacle within d_safe"),
    Metric("min_ttc", _min_ttc, unit="s", higher_is_better=True, on_success=True, margin=0.25,
           doc="smallest time to collision under constant relative velocity"),
    Metric("spl", _spl, higher_is_better=True, report=True, margin=0.02,
           doc="success weighted by path length, S·L/max(path, L) (Anderson et al. 2018)"),
    Metric("steps", lambda ctx: ctx.end_index, dtype="int32", kind="count", per_step=True,
           doc="steps until the episode ended"),
    Metric("accel_error_rms", _accel_error_rms, unit="m/s²", higher_is_better=False, margin=0.1,
           doc="RMS of the realised minus the applied acceleration"),
    Metric("position_error_max", _position_error_max, unit="m", higher_is_better=False, margin=0.01,
           doc="largest one-step miss of the plant against the MPC's double-integrator prediction"),
):
    register_metric(_metric)


def episode_metrics(traj: Trajectory, scenario: Scenario, sim: SimConfig,
                    names: Sequence[str] | None = None) -> dict[str, Array]:
    """The metrics ``names`` (default: every registered one) of one episode (module docstring).

    Args:
      traj: one episode of ``T`` steps (no batch axes; ``vmap`` for batches).
      scenario: the field it was flown in.
      sim: static settings.

    Returns:
      ``{name: scalar}`` in the order of ``names``.
    """
    names = METRICS.names() if names is None else names
    # XLA fuses nothing across this barrier, so the metrics' arithmetic is not merged into that of
    # the program which produced the trajectory (the rounding of a whole program can still differ
    # between the fixed-length and the streaming engine, docs/performance.md)
    traj, scenario = jax.lax.optimization_barrier((traj, scenario))
    return compute_metrics(EpisodeContext(traj, scenario, sim), names, traj.position.dtype)
