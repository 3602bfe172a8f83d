r"""A swarm's closed loop: every UAV of a :class:`~jaxapf.datatypes.swarm.Swarm` flies the episode's stack.

Each control step ``k``, all UAVs at once (a ``vmap`` over them inside the ``lax.scan`` over time):
the UAVs' true states ``x`` (A, 6) place every UAV in the others' obstacle sets
(:func:`~jaxapf.datatypes.swarm.neighbours`), then each UAV runs :func:`~jaxapf.engine.loop.loop_step`
-- sensor, planner, MPC, filter, plant -- on its own carry, exactly as a single UAV does. The
interaction is ``O(A²)`` per step: each UAV's planner, filter and sensor see ``M + A`` obstacle
slots (``M + K`` with ``sim.world.max_neighbours = K``: the nearest ``K`` only). A one-UAV swarm is
:func:`~jaxapf.engine.loop.rollout` itself (the same program, bit for bit).
:func:`evaluate_swarms` flies every (gain setting, swarm field) pair of a batch in one compiled call
(fixed-length episodes) and returns the swarm metrics (:mod:`jaxapf.metrics.swarm`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from ..config import MPCConfig, SimConfig
from ..datatypes import Trajectory
from ..datatypes.swarm import Swarm, agent_view, neighbours
from ..gains import Gains
from ..metrics.swarm import swarm_metrics
from .batch import fixed_batches, program, settings_read
from .components import gains_read
from .loop import closed_loop, episode_loop, loop_init, loop_step, record_trajectory, rollout

__all__ = ["swarm_rollout", "evaluate_swarms"]


def swarm_rollout(swarm: Swarm, gains: Gains, sim: SimConfig, mpc: MPCConfig, *, remat: bool = False) -> Trajectory:
    """Simulate every UAV of ``swarm`` from rest at its start; returns their trajectories, a
    :class:`~jaxapf.datatypes.Trajectory` with a leading UAV axis (A, ...) on every leaf."""
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

    def control_step(carry, k):
        x = jax.vmap(loop.plant.kinematics)(carry[0])  # the truth of every UAV, (A, 6)
        t = k * sim.episode.dt

        def one(c, view, cols, a):
            seen = neighbours(cols, swarm, x, t, a, r_uav, near)
            return loop_step(loop, c, k, view, seen, gains, sim, mpc)
        return jax.vmap(one)(carry, views, columns, ids)

    carry0 = jax.vmap(lambda view: loop_init(loop, view, gains, sim, mpc))(views)
    body = jax.checkpoint(control_step, prevent_cse=False) if remat else control_step
    _, records = jax.lax.scan(body, carry0, jnp.arange(sim.episode.steps, dtype=dtype))
    x0 = jax.vmap(loop.plant.kinematics)(carry0[0])
    return jax.vmap(lambda x, r: record_trajectory(x, r, sim), in_axes=(0, 1))(x0, records)


@program(static_argnames=("sim", "mpc", "width", "metrics"))
def evaluate_swarms(swarms: Swarm, gains: Gains, sim: SimConfig, mpc: MPCConfig, width: int | None = None,
                    metrics: tuple[str, ...] | None = None) -> dict[str, Array]:
    """The swarm ``metrics`` (default: all of :data:`~jaxapf.metrics.swarm.SWARM_METRICS`) of every
    (setting, field) pair: arrays (G, F). ``swarms``: F fields (leading axis F); ``gains``: G settings
    (leading axis G on every array leaf; scalars are shared). The G·F swarm episodes run in the
    fixed-length engine (:func:`~jaxapf.engine.batch.fixed_batches`), ``width`` of them vmapped
    together (default: all)."""
    n_gains, gains = settings_read(gains, sim)
    width = n_gains * swarms.start.shape[0] if width is None else width
    return fixed_batches(lambda s, g: swarm_metrics(swarm_rollout(s, g, sim, mpc), s, sim, metrics), swarms, gains,
                         n_gains, width)
