r"""A swarm's closed loop: every UAV of a :class:`~jaxapf.datatypes.swarm.Swarm` flies the episode's stack.

Each control step ``k``, all UAVs at once (a ``vmap`` over them inside the ``lax.scan`` over time):
the UAVs' true states ``x`` (A, 6) place every UAV in the others' obstacle sets
(:func:`~jaxapf.datatypes.swarm.neighbours`), then each UAV runs :func:`~jaxapf.engine.loop.loop_step`
-- sensor, planner, MPC, filter, plant -- on its own carry, exactly as a single UAV does. The
interaction is ``O(A²)`` per step: each UAV's planner, filter and sensor see ``M + A`` obstacle
slots (``M + K`` with ``sim.world.max_neighbours = K``: the nearest ``K`` only). A one-UAV swarm is
:func:`~jaxapf.engine.loop.rollout` itself (the same program, bit for bit).
:func:`evaluate_swarms` flies every (gain setting, swarm field) pair of a batch in one compiled call
and returns the swarm metrics (:mod:`jaxapf.metrics.swarm`): streamed by default
(:func:`swarm_episodes` in :mod:`jaxapf.engine.stream`: a swarm ends when every UAV has ended), or
in fixed-length episodes.
"""

from __future__ import annotations

from typing import Any, Sequence

import jax
import jax.numpy as jnp
from jax import Array

from ..config import MPCConfig, SimConfig
from ..datatypes import Scenario, Trajectory
from ..datatypes.swarm import Swarm, agent_view, neighbours
from ..gains import Gains
from ..metrics.context import certainly_at_goal, certainly_ended
from ..metrics.swarm import swarm_metric_names, swarm_metrics
from ..validation import ConfigError
from ..world.sensing import delay_line
from .batch import fixed_batches, program, settings_read
from .components import gains_read
from .loop import closed_loop, episode_loop, loop_init, loop_step, record_trajectory, rollout
from .stream import EpisodeKind, stream_metrics, stream_slots

__all__ = ["swarm_rollout", "evaluate_swarms", "swarm_episodes"]


def check_neighbours(sim: SimConfig) -> None:
    """Refuse ``max_neighbours`` with a sensor other than ``ideal``: the nearest neighbours are re-picked
    into the slots every step, and a sensor that remembers each slot (dropout, latency, range) would
    carry one UAV's reading into another's slot."""
    if sim.world.max_neighbours and sim.world.sensor != "ideal":
        raise ConfigError(f"sim.max_neighbours = {sim.world.max_neighbours} needs sensor = \"ideal\" (the nearest "
                          f"UAVs change slots every step, and sensor = \"{sim.world.sensor}\" remembers each slot); "
                          "use max_neighbours = 0 (every UAV, each in its own slot) with it")


def at_rest(swarm: Swarm, sim: SimConfig) -> Array:
    """The UAVs' states before the episode, as the others' sensors remember them: at rest at their
    starts, ``sim.world.max_latency + 1`` steps of them (L+1, A, 6)."""
    x = jnp.concatenate([swarm.start, jnp.zeros_like(swarm.start)], axis=-1)
    return jnp.broadcast_to(x, (sim.world.max_latency + 1,) + x.shape)


def remember(history: Array, x: Array, k: Array, delay: Array, dt: float) -> tuple[Array, Array, Array]:
    """``(history, then, t_j)``: the last L+1 true states of every UAV with ``x`` (A, 6), those of step
    ``j = k - delay`` and its time. What a UAV's sensor measures of the others with latency is their
    true past state (placed at ``t_j`` by :func:`~jaxapf.datatypes.swarm.neighbours`); with no latency,
    their states now."""
    history, then = delay_line(history, x, delay)
    return history, then, (k - delay).astype(x.dtype) * dt


def swarm_rollout(swarm: Swarm, gains: Gains, sim: SimConfig, mpc: MPCConfig, *, remat: bool = False) -> Trajectory:
    """Simulate every UAV of ``swarm`` from rest at its start; returns their trajectories, a
    :class:`~jaxapf.datatypes.Trajectory` with a leading UAV axis (A, ...) on every leaf."""
    check_neighbours(sim)
    r_uav = sim.vehicle.r_uav
    if swarm.agents == 1:  # nobody else to see: today's single-UAV program
        return jax.tree_util.tree_map(lambda x: x[None], rollout(agent_view(swarm, 0, r_uav), gains, sim, mpc,
                                                                  remat=remat))
    dtype = swarm.start.dtype
    gains = gains.only(gains_read(sim)).as_arrays(dtype)
    loop = episode_loop(closed_loop(sim, mpc, dtype), gains, sim, mpc, dtype)
    ids = jnp.arange(swarm.agents)
    near = sim.world.max_neighbours
    views = jax.vmap(lambda a: agent_view(swarm, a, r_uav, near))(ids)
    columns = jax.vmap(lambda v: v.obstacles.columns())(views)
    delay = loop.sensor.delay(gains, sim)

    def control_step(carry, k):
        agents, history = carry
        x = jax.vmap(loop.plant.kinematics)(agents[0])  # the truth of every UAV, (A, 6)
        history, then, t = remember(history, x, k, delay, sim.episode.dt)

        def one(c, view, cols, a):
            seen = neighbours(cols, swarm, then, t, a, r_uav, near)
            return loop_step(loop, c, k, view, seen, gains, sim, mpc)
        agents, record = jax.vmap(one)(agents, views, columns, ids)
        return (agents, history), record

    carry0 = jax.vmap(lambda view: loop_init(loop, view, gains, sim, mpc))(views)
    body = jax.checkpoint(control_step, prevent_cse=False) if remat else control_step
    _, records = jax.lax.scan(body, (carry0, at_rest(swarm, sim)), jnp.arange(sim.episode.steps, dtype=dtype))
    x0 = jax.vmap(loop.plant.kinematics)(carry0[0])
    return jax.vmap(lambda x, r: record_trajectory(x, r, sim), in_axes=(0, 1))(x0, records)


def swarm_episodes(sim: SimConfig, mpc: MPCConfig, dtype: Any, metrics: Sequence[str] | None) -> EpisodeKind:
    """A swarm per slot of the streaming engine (:class:`~jaxapf.engine.stream.EpisodeKind`): the control
    step of :func:`swarm_rollout`, every UAV at once; a UAV has ended once
    :func:`~jaxapf.metrics.context.certainly_ended` fires against the field's obstacles (a collision
    between two UAVs ends nobody here: the swarm flies on, and the metrics find it in the records), and
    the swarm once every UAV has; measured by :func:`~jaxapf.metrics.swarm.swarm_metrics`."""
    check_neighbours(sim)
    loop = closed_loop(sim, mpc, dtype)
    r_uav, near, dt = sim.vehicle.r_uav, sim.world.max_neighbours, sim.episode.dt

    def alone(swarm: Swarm) -> Scenario:
        """Each UAV's start and goal among the field's obstacles (leading axis A)."""
        return Scenario(start=swarm.start, goal=swarm.goal,
                        obstacles=jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (swarm.agents,) + x.shape),
                                                         swarm.obstacles))

    def start(swarm: Swarm, g: Gains) -> dict[str, Any]:
        ids = jnp.arange(swarm.agents)
        views = jax.vmap(lambda a: agent_view(swarm, a, r_uav, near))(ids)
        carry = jax.vmap(lambda view: loop_init(loop, view, g, sim, mpc))(views)
        own = {} if loop.prob is not None else {"prob": episode_loop(loop, g, sim, mpc, dtype).prob}
        done = ~swarm.valid | jax.vmap(lambda p, s: certainly_at_goal(p, s, sim))(swarm.start, alone(swarm))
        return {**own, "swarm": swarm, "views": views, "columns": jax.vmap(lambda v: v.obstacles.columns())(views),
                "gains": g, "carry": carry, "k": jnp.zeros((), jnp.int32), "done": done, "ended": jnp.all(done),
                "x0": jax.vmap(loop.plant.kinematics)(carry[0]), "history": at_rest(swarm, sim),
                "delay": loop.sensor.delay(g, sim)}

    def step(slot: dict[str, Any]) -> tuple[dict[str, Any], tuple]:
        swarm, k = slot["swarm"], slot["k"]
        flown = loop if loop.prob is not None else loop._replace(prob=slot["prob"])
        x = jax.vmap(loop.plant.kinematics)(slot["carry"][0])
        t = k.astype(dtype) * dt
        history, then, t_j = remember(slot["history"], x, k, slot["delay"], dt)

        def one(c, view, cols, a):
            seen = cols if swarm.agents == 1 else neighbours(cols, swarm, then, t_j, a, r_uav, near)
            return loop_step(flown, c, k.astype(dtype), view, seen, slot["gains"], sim, mpc)
        carry, record = jax.vmap(one)(slot["carry"], slot["views"], slot["columns"], jnp.arange(swarm.agents))
        hit = jax.vmap(lambda p0, p1, s: certainly_ended(p0, p1, t, s, sim))(x[:, :3], record[0][:, :3], alone(swarm))
        done = slot["done"] | hit
        return {**slot, "carry": carry, "k": k + 1, "done": done, "ended": jnp.all(done), "history": history}, record

    def measure(x0: Array, record: tuple, swarm: Swarm) -> dict[str, Array]:
        traj = jax.vmap(lambda x, r: record_trajectory(x, r, sim), in_axes=(0, 1))(x0, record)
        return swarm_metrics(traj, swarm, sim, metrics)

    return EpisodeKind(start, step, measure)


@program(static_argnames=("sim", "mpc", "width", "metrics", "streaming", "refill"))
def evaluate_swarms(swarms: Swarm, gains: Gains, sim: SimConfig, mpc: MPCConfig, width: int | None = None,
                    metrics: tuple[str, ...] | None = None, streaming: bool = True,
                    refill: bool = True) -> dict[str, Array]:
    """The swarm ``metrics`` (default: all, :func:`~jaxapf.metrics.swarm.swarm_metric_names`) of every
    (setting, field) pair: arrays (G, F). ``swarms``: F fields (leading axis F); ``gains``: G settings
    (leading axis G on every array leaf; scalars are shared). The G·F swarm episodes are streamed
    (:mod:`jaxapf.engine.stream`: a swarm stops when every UAV has ended; at most ``width`` flown side
    by side; ``refill`` as in :func:`~jaxapf.engine.stream.stream_slots`), or with ``streaming=False`` run in
    the fixed-length engine (:func:`~jaxapf.engine.batch.fixed_batches`, ``width`` vmapped together). ``width``
    default: all."""
    n_gains, gains = settings_read(gains, sim)
    total = n_gains * swarms.start.shape[0]
    width = total if width is None else width
    names = swarm_metric_names() if metrics is None else metrics
    if streaming:
        return stream_metrics(swarms, gains, sim, mpc, stream_slots(total, width, refill), names, swarm_episodes)
    return fixed_batches(lambda s, g: swarm_metrics(swarm_rollout(s, g, sim, mpc), s, sim, names), swarms, gains,
                         n_gains, width)
