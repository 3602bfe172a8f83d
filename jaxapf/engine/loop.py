r"""The closed loop: planner → MPC → safety filter → plant, scanned over an episode.

Each control step ``k`` (time ``t_k = k Δt``), with the components named by ``sim``
(:data:`~jaxapf.engine.components.COMPONENTS`):

0. the sensor (``sim.world.sensor``, :data:`~jaxapf.world.sensing.SENSORS`; ``ideal`` by default) turns
   the truth into what the stack sees: an estimate of ``[p, v]`` and the obstacles as observed.
   Steps 1-3 work with that observation; the plant and the metrics with the truth;
1. the planner (``sim.planner.method``, :data:`~jaxapf.planners.PLANNERS`) maps its state and the
   UAV's ``[p, v]`` to the MPC reference for ``x(k..k+N)``; a potential-field planner rolls its
   saturated gradient flow N steps ahead with the obstacles extrapolated at constant velocity
   (its diagnostics, :meth:`~jaxapf.planners.Planner.diagnostics`, are recorded);
2. a planner that plans its own accelerations (:meth:`~jaxapf.planners.Planner.command`: MPPI,
   the keep-out MPC) has the first of them applied; for every other,
   :func:`~jaxapf.control.mpc.solve_axes` solves the three per-axis condensed box QPs by FISTA,
   warm started from the previous solution shifted by one step, on the plant's linear model (with
   ``sim.planner.tracking = "ideal"``, an ablation, :func:`ideal_tracking` instead: the reference's
   first velocity reached within the step);
3. the safety filter (``sim.planner.filter``, :data:`~jaxapf.control.FILTERS`; ``none`` by default)
   maps the first acceleration to the applied one;
4. the plant (``sim.vehicle.plant``, :data:`~jaxapf.world.PLANTS`; the exact double integrator
   by default) integrates it, under the disturbance (``sim.world.disturbance``,
   :data:`~jaxapf.world.DISTURBANCES`; ``none`` by default) of the step.

:func:`rollout` flies one episode for the fixed ``EpisodeConfig.steps``; termination (goal,
collision) is applied by the metrics' masks, not by the loop. The streaming engine
(:mod:`jaxapf.engine.stream`) flies a batch's episodes with the same control step, stopping each
one when it ends.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Sequence

import jax
import jax.numpy as jnp
from jax import Array

from ..config import MPCConfig, SimConfig
from ..control import axis_problem, shift_warm_start, solve_axes
from ..datatypes import Scenario, Trajectory
from ..gains import Gains
from ..metrics import episode_metrics
from ..validation import ConfigError
from .components import component, component_names, gains_read

__all__ = ["rollout", "rollout_metrics", "closed_loop", "episode_loop", "loop_init", "loop_step", "record_trajectory",
           "ideal_tracking", "check_tracked"]


class ClosedLoop(NamedTuple):
    """The components one ``sim`` names and the MPC's condensed problem: what every control step
    of :func:`rollout` and of the streaming engine (:mod:`jaxapf.engine.stream`) runs."""

    planner: Any
    safety: Any
    plant: Any
    sensor: Any
    disturbance: Any
    estimator: Any
    prob: Any


def closed_loop(sim: SimConfig, mpc: MPCConfig, dtype: Any) -> ClosedLoop:
    """The registered components of ``sim`` and the MPC problem on the plant's linear model (``None``
    with ``sim.mpc_weights = "gains"``: each episode builds its own, :func:`episode_loop`)."""
    parts = {key: component(key, name) for key, name in component_names(sim).items()}
    check_tracked(parts["method"], sim)
    static = sim.planner.mpc_weights == "static"
    return ClosedLoop(parts["method"], parts["filter"], parts["plant"], parts["sensor"], parts["disturbance"],
                      parts["estimator"],
                      axis_problem(mpc, *parts["plant"].linear_model(sim.episode.dt, dtype)) if static else None)


def check_tracked(planner: Any, sim: SimConfig) -> None:
    """A planner that flies its own plan (:meth:`~jaxapf.planners.Planner.command`) has no MPC to weigh or take
    out: ``sim.mpc_weights = "gains"`` or ``sim.tracking = "ideal"`` with it is a :class:`ConfigError`."""
    if not planner.flies_own_plan:
        return
    for field, value, default in (("mpc_weights", sim.planner.mpc_weights, "static"),
                                  ("tracking", sim.planner.tracking, "mpc")):
        if value != default:
            raise ConfigError(f"sim.{field} = {value!r}: planner {sim.planner.method!r} flies its own plan, no MPC "
                              f"tracks it; leave sim.{field} at {default!r}")


def episode_loop(loop: ClosedLoop, gains: Gains, sim: SimConfig, mpc: MPCConfig, dtype: Any) -> ClosedLoop:
    """``loop`` with the MPC problem of an episode flown with ``gains``: the shared one, or with
    ``sim.mpc_weights = "gains"`` the one whose weights these gains scale."""
    if loop.prob is not None:
        return loop
    return loop._replace(prob=axis_problem(mpc, *loop.plant.linear_model(sim.episode.dt, dtype), gains))


def loop_init(loop: ClosedLoop, scenario: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig) -> tuple:
    """The carry of an episode at rest at ``scenario.start``: (plant state, warm start, planner
    state, filter state, sensor state, disturbance state, estimator state)."""
    dtype = scenario.start.dtype
    return (loop.plant.init(scenario.start, gains, sim), jnp.zeros((3, mpc.horizon), dtype),
            loop.planner.init(scenario, gains, sim, mpc.horizon), loop.safety.init(scenario, gains, sim),
            loop.sensor.init(scenario, gains, sim), loop.disturbance.init(scenario, gains, sim),
            loop.estimator.init(scenario, gains, sim))


def loop_step(loop: ClosedLoop, carry: tuple, k: Array, scenario: Scenario, obstacles: Any, gains: Gains,
              sim: SimConfig, mpc: MPCConfig) -> tuple[tuple, tuple[Array, Array, dict[str, Array]]]:
    """Control step ``k`` (a float: ``t_k = k Δt``) of the module docstring; returns the new carry
    and the step's record: the plant's ``[p, v]`` after it, the applied acceleration and the
    components' diagnostics. ``obstacles`` is ``scenario.obstacles.columns()`` (the truth)."""
    state, warm, plan, guard, seen, gust, estimated = carry
    t = k * sim.episode.dt
    step = jnp.round(k).astype(jnp.int32)
    x, observed, seen, sensed = loop.sensor(seen, loop.plant.kinematics(state), step, scenario, obstacles, gains, sim)
    # offset-free tracking: the MPC plans and the filter guards the total acceleration command + d̂
    # (jaxapf.control.estimators); with no estimator nothing of it is compiled in
    d_hat, estimates = loop.estimator(estimated, x, gains, sim) if loop.estimator.active else (None, {})
    x_ref, plan = loop.planner.reference(plan, x, t, scenario.goal, observed, gains, sim, mpc.horizon)
    _check_shape(x_ref, (mpc.horizon + 1, 6), f"planner {sim.planner.method!r}", "its reference x(k..k+N), (N + 1, 6)")
    planned = loop.planner.diagnostics(plan)
    own = loop.planner.command(plan)
    if own is not None:
        u = jnp.zeros((3, mpc.horizon), x.dtype).at[:, 0].set(own)
    elif sim.planner.tracking == "ideal":
        u = ideal_tracking(x, x_ref, sim.episode.dt, mpc.horizon)
    else:
        u = solve_axes(loop.prob, x, x_ref, warm, a_max=sim.vehicle.a_max, v_max=sim.vehicle.v_max,
                       iters=mpc.iters, shift=d_hat)
    accel, guard, filtered = loop.safety(guard, u[:, 0], x, t, observed, gains, sim)
    _check_shape(accel, (3,), f"safety filter {sim.planner.filter!r}", "the acceleration it lets through, (3,)")
    if loop.estimator.active:
        accel = jnp.clip(accel - d_hat, -sim.vehicle.a_max, sim.vehicle.a_max)
        estimated = loop.estimator.advance(x, accel, d_hat)
    push, gust = loop.disturbance(gust, step, scenario, gains, sim)
    state, integrated = loop.plant.step(state, accel, push, gains, sim)
    return ((state, shift_warm_start(u), plan, guard, seen, gust, estimated),
            (loop.plant.kinematics(state), accel, sensed | estimates | planned | filtered | integrated))


def _check_shape(value: Array, shape: tuple[int, ...], who: str, what: str) -> None:
    """While the loop is traced: :class:`ConfigError` in one line where a component (a plugin's, most often)
    returns another shape than the loop reads, which would otherwise broadcast into other episodes."""
    if jnp.shape(value) != shape:
        raise ConfigError(f"{who} returned shape {jnp.shape(value)} where the closed loop reads {what} "
                          "(docs/extending.md)")


def ideal_tracking(x: Array, x_ref: Array, dt: float, horizon: int) -> Array:
    """Inputs (3, N) whose first reaches the reference's first velocity ``(p_1 - p) / Δt`` within the step
    (the acceleration unbounded), the others zero: the MPC taken out of the loop (``sim.planner.tracking``)."""
    accel = ((x_ref[1, :3] - x[:3]) / dt - x[3:]) / dt
    return jnp.zeros((3, horizon), x.dtype).at[:, 0].set(accel)


def record_trajectory(x0: Array, records: tuple, sim: SimConfig) -> Trajectory:
    """The :class:`Trajectory` of an episode from its first sample ``x0 = [p, v]`` (6,) and the
    records (:func:`loop_step`'s, stacked over its ``T`` steps) of its control steps."""
    x, control, extras = records
    states = jnp.concatenate([x0[None], x], axis=0)
    return Trajectory(time=jnp.arange(sim.episode.steps + 1, dtype=x0.dtype) * sim.episode.dt,
                      position=states[:, :3], velocity=states[:, 3:], control=control, extras=extras)


def rollout(scenario: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig, *, remat: bool = False
            ) -> Trajectory:
    """Simulate one episode from rest at ``scenario.start``; returns its :class:`Trajectory`.

    With ``remat`` the control step is wrapped in :func:`jax.checkpoint`: reverse-mode
    differentiation then stores only the scan carry (plant state, warm start, planner, filter,
    sensor and disturbance states) of each step and recomputes the step's reference and FISTA
    iterations on the way back, so the memory of a gradient grows with ``T·(6 + 3N)`` numbers
    instead of ``T·(residuals of one step)``. The forward values are the same either way
    (``jaxapf tune`` measures the trade-off, docs/tune.md).
    """
    dtype = scenario.start.dtype
    gains = gains.only(gains_read(sim)).as_arrays(dtype)  # each component sees what it declared, nothing else
    loop = episode_loop(closed_loop(sim, mpc, dtype), gains, sim, mpc, dtype)
    obstacles = scenario.obstacles.columns()  # once per episode, not once per control step

    def control_step(carry, k):
        return loop_step(loop, carry, k, scenario, obstacles, gains, sim, mpc)

    carry0 = loop_init(loop, scenario, gains, sim, mpc)
    ks = jnp.arange(sim.episode.steps, dtype=dtype)
    body = jax.checkpoint(control_step, prevent_cse=False) if remat else control_step
    _, records = jax.lax.scan(body, carry0, ks)
    return record_trajectory(loop.plant.kinematics(carry0[0]), records, sim)


def rollout_metrics(scenario: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig,
                    metrics: Sequence[str] | None = None) -> dict[str, Array]:
    """The ``metrics`` (default: every registered one) of one episode; the trajectory is not kept."""
    return episode_metrics(rollout(scenario, gains, sim, mpc), scenario, sim, metrics)
