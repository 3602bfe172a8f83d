r"""The closed loop: planner → MPC → safety filter → plant, scanned over an episode.

The nesting follows gymnax: one episode is a ``lax.scan`` over time (:func:`rollout`); a batch
of fields is a ``vmap`` over scenarios; a population of gain settings is a ``vmap`` over
:class:`~jaxapf.gains.Gains` (:func:`evaluate`). Static configuration (:class:`SimConfig`,
:class:`MPCConfig`) is compiled in; gains are traced, so a whole gain grid over many fields is
one compiled call.

Each control step ``k`` (time ``t_k = k Δt``), with the components named by ``sim``
(:data:`~jaxapf.components.COMPONENTS`):

0. the sensor (``sim.world.sensor``, :data:`~jaxapf.sensing.SENSORS`; ``ideal`` by default) turns
   the truth into what the stack sees: an estimate of ``[p, v]`` and the obstacles as observed.
   Steps 1-3 work with that observation; the plant and the metrics with the truth;
1. the planner (``sim.planner.method``, :data:`~jaxapf.planners.PLANNERS`) maps its state and the
   UAV's ``[p, v]`` to the MPC reference for ``x(k..k+N)``; a potential-field planner rolls its
   saturated gradient flow N steps ahead with the obstacles extrapolated at constant velocity
   (its diagnostics, :meth:`~jaxapf.planners.Planner.diagnostics`, are recorded);
2. :func:`~jaxapf.control.mpc.solve_axes` solves the three per-axis condensed box QPs by FISTA,
   warm started from the previous solution shifted by one step, on the plant's linear model;
3. the safety filter (``sim.planner.filter``, :data:`~jaxapf.control.FILTERS`; ``none`` by default)
   maps the first acceleration to the applied one;
4. the plant (``sim.vehicle.plant``, :data:`~jaxapf.dynamics.PLANTS`; the exact double integrator
   by default) integrates it, under the disturbance (``sim.world.disturbance``,
   :data:`~jaxapf.dynamics.DISTURBANCES`; ``none`` by default) of the step.

:func:`rollout` flies one episode for the fixed ``EpisodeConfig.steps``; termination (goal,
collision) is applied by the metrics' masks, not by the loop. :func:`evaluate` streams a batch's
episodes with the same control step (:mod:`jaxapf.stream`), stopping each one when it ends.
"""

from __future__ import annotations

from functools import partial
from typing import Any, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .components import COMPONENTS, components_read_gains
from .config import MPCConfig, SimConfig
from .control import axis_problem, shift_warm_start, solve_axes
from .datatypes import Scenario, Trajectory
from .gains import Gains, setting_count
from .metrics import METRICS, episode_metrics

__all__ = ["rollout", "gains_read", "rollout_metrics", "evaluate", "evaluate_program", "episode_index", "default_width",
           "CPU_WIDTH", "ACCELERATOR_WIDTH", "XLA_OPTIONS"]


def component_names(sim: SimConfig) -> dict[str, str]:
    """``{key: name}`` of the components ``sim`` names (:data:`~jaxapf.components.COMPONENTS`)."""
    flat = sim.flat()
    return {key: flat[key] for key in COMPONENTS}


def gains_read(sim: SimConfig) -> frozenset[str]:
    """The gains a :func:`rollout` with ``sim`` reads: those its planner, safety filter, plant, sensor
    and disturbance declare. Settings that agree on these fly the same episodes (a sweep runs them
    once)."""
    return components_read_gains(component_names(sim))


class ClosedLoop(NamedTuple):
    """The components one ``sim`` names and the MPC's condensed problem: what every control step
    of :func:`rollout` and of the streaming engine (:mod:`jaxapf.stream`) runs."""

    planner: Any
    safety: Any
    plant: Any
    sensor: Any
    disturbance: Any
    prob: Any


def closed_loop(sim: SimConfig, mpc: MPCConfig, dtype: Any) -> ClosedLoop:
    """The registered components of ``sim`` and the MPC problem on the plant's linear model."""
    parts = {key: COMPONENTS[key].get(name, f"sim.{key}") for key, name in component_names(sim).items()}
    return ClosedLoop(parts["method"], parts["filter"], parts["plant"], parts["sensor"], parts["disturbance"],
                      axis_problem(mpc, *parts["plant"].linear_model(sim.episode.dt, dtype)))


def loop_init(loop: ClosedLoop, scenario: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig) -> tuple:
    """The carry of an episode at rest at ``scenario.start``: (plant state, warm start, planner
    state, filter state, sensor state, disturbance state)."""
    dtype = scenario.start.dtype
    return (loop.plant.init(scenario.start, gains, sim), jnp.zeros((3, mpc.horizon), dtype),
            loop.planner.init(scenario, gains, sim, mpc.horizon), loop.safety.init(scenario, gains, sim),
            loop.sensor.init(scenario, gains, sim), loop.disturbance.init(scenario, gains, sim))


def loop_step(loop: ClosedLoop, carry: tuple, k: Array, scenario: Scenario, obstacles: Any, gains: Gains,
              sim: SimConfig, mpc: MPCConfig) -> tuple[tuple, tuple[Array, Array, dict[str, Array]]]:
    """Control step ``k`` (a float: ``t_k = k Δt``) of the module docstring; returns the new carry
    and the step's record: the plant's ``[p, v]`` after it, the applied acceleration and the
    components' diagnostics. ``obstacles`` is ``scenario.obstacles.columns()`` (the truth)."""
    state, warm, plan, guard, seen, gust = carry
    t = k * sim.episode.dt
    step = jnp.round(k).astype(jnp.int32)
    x, observed, seen, sensed = loop.sensor(seen, loop.plant.kinematics(state), step, scenario, obstacles, gains, sim)
    x_ref, plan = loop.planner.reference(plan, x, t, scenario.goal, observed, gains, sim, mpc.horizon)
    planned = loop.planner.diagnostics(plan)
    u = solve_axes(loop.prob, x, x_ref, warm, a_max=sim.vehicle.a_max, v_max=sim.vehicle.v_max, iters=mpc.iters)
    accel, guard, filtered = loop.safety(guard, u[:, 0], x, t, observed, gains, sim)
    push, gust = loop.disturbance(gust, step, scenario, gains, sim)
    state, integrated = loop.plant.step(state, accel, push, gains, sim)
    return ((state, shift_warm_start(u), plan, guard, seen, gust),
            (loop.plant.kinematics(state), accel, sensed | planned | filtered | integrated))


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
    gains = gains.as_arrays(dtype)
    loop = closed_loop(sim, mpc, dtype)
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


#: Episodes vmapped together (the vmap width) on CPU: wide enough that every step's kernels run
#: over long contiguous rows (``jaxapf bench engine --width`` measures other widths).
CPU_WIDTH = 1024
#: Episodes vmapped together on accelerators, where wide batches pay.
ACCELERATOR_WIDTH = 4096


#: XLA options of every compiled closed loop (CPU only; other backends ignore them):
#:
#: * ``xla_cpu_experimental_ynn_fusion_type = ""``: jaxlib 0.10 hands reductions and small matrix
#:   products on CPU to YNNPACK kernels, which run the APF's sums over obstacles and xyz several
#:   times slower than XLA's own fused loops (``jaxapf bench``: the engine took about twice as long);
#:   the empty list switches YNNPACK fusions off.
#: * ``xla_cpu_use_fusion_emitters = False``: XLA's classic loop emitter instead of the newer
#:   fusion emitters. On a lone elementwise kernel the fusion emitters are the faster ones
#:   (``benchmarks/kernels.py``), but the closed loop's kernels are large fusions of the APF's
#:   forward and backward pass over ``(fields, obstacles)``, which the fusion emitters compile
#:   into slower code: the whole closed loop runs about 1.1-1.2x faster with the classic one
#:   (``benchmarks/xla_options.py --xla-option xla_cpu_use_fusion_emitters=true`` compiles one
#:   lowering both ways and times them interleaved; docs/performance.md).
#: * ``xla_cpu_copy_insertion_use_region_analysis = True``: XLA's copy insertion analyses the
#:   loops' regions, so FISTA's ``lax.scan`` keeps one copy of its carry per iteration instead of
#:   three; the same arithmetic, about 1.07x faster (median of five ``benchmarks/xla_options.py``
#:   runs, docs/performance.md).
XLA_OPTIONS = {
    "xla_cpu_experimental_ynn_fusion_type": "",
    "xla_cpu_use_fusion_emitters": False,
    "xla_cpu_copy_insertion_use_region_analysis": True,
}


def default_width(episodes: int | None = None) -> int:
    """The vmap width for the default backend; for a batch of fewer ``episodes``, the smallest power
    of two that holds them (so a small batch is not padded to a wide batch)."""
    width = CPU_WIDTH if jax.default_backend() == "cpu" else ACCELERATOR_WIDTH
    return width if episodes is None else min(width, 1 << (max(episodes, 1) - 1).bit_length())


def episode_index(total: int, width: int) -> np.ndarray:
    """Episodes ``0 … total-1`` of a (setting, field) grid (episode ``e = g·F + f``: setting
    ``e // F``, field ``e % F``), padded with episode 0 to a whole number of ``width``-wide batches;
    callers drop the padding."""
    index = np.zeros(-(-total // width) * width, np.int64)
    index[:total] = np.arange(total)
    return index


@partial(jax.jit, static_argnames=("sim", "mpc", "width", "metrics", "streaming"), compiler_options=XLA_OPTIONS)
def evaluate_program(scenarios: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig, width: int,
                     metrics: tuple[str, ...], streaming: bool = True) -> dict[str, Array]:
    """The compiled program behind :func:`evaluate`, every static argument explicit (for
    ``evaluate_program.lower(...)``)."""
    from .stream import stream_metrics, stream_slots

    n_gains = max((jnp.shape(x)[0] for x in jax.tree_util.tree_leaves(gains) if jnp.ndim(x)), default=1)
    gains = jax.tree_util.tree_map(lambda x: x if jnp.ndim(x) else jnp.full((n_gains,), x), gains)
    n_fields = scenarios.start.shape[0]
    total = n_gains * n_fields
    if streaming:
        return stream_metrics(scenarios, gains, sim, mpc, stream_slots(total, width), metrics)
    width = min(width, total)
    index = episode_index(total, width)
    padded = index.shape[0]
    flat = (
        jax.tree_util.tree_map(lambda x: x[index % n_fields], scenarios),
        jax.tree_util.tree_map(lambda x: jnp.asarray(x)[index // n_fields], gains),
    )
    batches = jax.tree_util.tree_map(lambda x: x.reshape((padded // width, width) + x.shape[1:]), flat)
    episodes = jax.vmap(lambda s, g: rollout_metrics(s, g, sim, mpc, metrics))
    values = jax.lax.map(lambda c: episodes(*c), batches)
    return jax.tree_util.tree_map(lambda m: m.reshape((padded,) + m.shape[2:])[:total].reshape(
        (n_gains, n_fields) + m.shape[2:]), values)


def evaluate(scenarios: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig, width: int | None = None,
             metrics: Sequence[str] | None = None, *, streaming: bool = True) -> dict[str, Array]:
    """Metrics of every (gain setting, field) pair: arrays of shape (G, F), in one compiled call.

    The G·F episodes ``e = g·F + f`` form one queue. By default they are streamed
    (:mod:`jaxapf.stream`): a few hundred slots fly them side by side and each slot takes the next
    episode when its own ends, so no step is simulated after an episode is over. With
    ``streaming=False`` (the fixed-length engine) the queue is padded to a multiple of ``width``
    and run as a ``lax.map`` over batches of ``width`` vmapped episodes of ``T`` steps each. Both
    give the same numbers, and neither depends on G, F or the batch an episode ran in.

    Args:
      scenarios: a batch of F fields (leading axis F on every leaf).
      gains: a batch of G gain settings (leading axis G on every array leaf; a scalar leaf, e.g. a
        gain left at its default, is shared by all G settings): ``Gains(gamma=[...], k=[...])`` or
        :meth:`~jaxapf.gains.Gains.paired` pairs the lists, :meth:`~jaxapf.gains.Gains.grid` takes
        every combination. Lists of different lengths raise :class:`~jaxapf.validation.ConfigError`.
      width: the vmap width (static; ``None``: :func:`default_width`); the streaming engine flies
        at most this many episodes side by side.
      metrics: the metrics to compute (default: every registered one, :data:`~jaxapf.metrics.METRICS`).
      streaming: stop each episode when it ends (default) instead of flying all ``T`` steps.
    """
    setting_count(gains, "evaluate: gains")  # one line for lists of different lengths, which would not pair
    names = METRICS.names() if metrics is None else tuple(metrics)
    return evaluate_program(scenarios, gains, sim, mpc, default_width() if width is None else width, names, streaming)
