r"""The episode's own metrics (docs/spec.md, section 6): every one defined here, once, and registered.

An episode is a fixed-length scan; the goal and a collision end it by masking, so every episode of a
batch has the same shape and each metric is pure, ``jit``-able and ``vmap``-able. Every metric reads
the shared quantities of one :class:`EpisodeContext` (the swept clearance, the episode's end, the valid
masks), computed once per trace whatever metrics ask for them. The exact definitions (time grid,
episode end, each metric's formula) are docs/spec.md's "Exact definitions".

A component that records what only it knows (a filter's infeasible steps, a plant's tilt, a
sensor's missed obstacles) owns the metric that reads it: registering the component registers the
metric (``metrics`` of :class:`~jaxapf.control.CBF`, :class:`~jaxapf.world.Quadrotor`,
:class:`~jaxapf.world.NoisySensor`, :class:`~jaxapf.planners.VelocityObstacle`).

Efficiency metrics (``time_to_goal``, ``path_ratio``, ``control_effort``, ``jerk_rms``, ``min_ttc``)
are meaningful only on successful episodes (``Metric.on_success``): reports compare them on the pairs
where both settings succeed. ``success``, ``collision``, ``stalled`` are bool, ``steps`` is int32, all
others have the trajectory's floating dtype.
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


def _invalid(ctx: EpisodeContext) -> Array:
    """Whether a state or an applied control turned non-finite (NaN or ±inf) before the episode ended."""
    traj = ctx.traj
    state = jnp.isfinite(traj.position).all(-1) & jnp.isfinite(traj.velocity).all(-1)
    control = jnp.isfinite(traj.control).all(-1)
    return jnp.any(ctx.sample_valid & ~state) | jnp.any(ctx.interval_valid & ~control)


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
    Metric("invalid", _invalid, dtype="bool", kind="rate", higher_is_better=False,
           doc="the state or the control turned non-finite before the episode ended (a component's output was "
               "not a number): an outcome of its own, never a success, a collision or a stall"),
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
