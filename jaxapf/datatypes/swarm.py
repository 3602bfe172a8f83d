r"""A field flown by several UAVs at once, each running the episode's stack (a swarm).

A :class:`Swarm` holds up to ``A`` UAVs (padded like obstacles: ``valid = False`` slots fly but
nobody sees them and no metric counts them), each with its own start and goal, in one obstacle
field. Each UAV flies the stack as in a single-UAV field, seeing the field's obstacles and the
other UAVs; :func:`agent_view` is the :class:`~jaxapf.datatypes.Scenario` UAV ``a`` is flown in,
:func:`neighbours` the other UAVs as obstacles at a control step.

A neighbour is a sphere of radius ``r_uav`` (so its clearance is the distance of the two centres
less ``2 r_uav``) moving at its current velocity: at time ``t_k`` the obstacle slot holds the
centre at ``t = 0`` that puts it at its true position now, ``p_b - v_b t_k``, so a planner that
extrapolates obstacles at constant velocity from ``t = 0`` (every planner does) sees it where it
is and predicts it straight ahead. With ``max_neighbours = K`` (``sim.world``; RVO2's ``maxNeighbors``) a
UAV sees only the ``K`` other UAVs nearest to it at the step (ties to the lower index), in ``K`` slots,
nearest first; without it (0, or ``K >= A - 1``) every other UAV, UAV ``b`` in slot ``b``. Its slot is
flagged ``agent`` (reciprocal planners share the
avoidance with it, :mod:`jaxapf.planners.velocity_obstacle`), and the sensor sees it as it sees any
obstacle, so noise, range, dropout and latency apply to neighbours too (latency by extrapolating
the current state back at its velocity, the constant-velocity model every obstacle follows).

Randomness: UAV 0 uses the field's key, UAV ``a >= 1`` the key folded with ``a``, so each UAV's
noise and escape side are independent of the others' and a one-UAV swarm is the single field.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jax import Array

from ..validation import ConfigError
from .obstacles import ObstacleColumns, Obstacles
from .scenario import Scenario

__all__ = ["Swarm", "agent_view", "neighbours", "with_neighbours", "neighbour_slots"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Swarm:
    """``A`` UAVs in one obstacle field (all leaves arrays, batchable).

    Attributes:
      start: (A, 3) initial positions; every UAV starts at rest.
      goal: (A, 3) goals.
      valid: (A,) True for a UAV, False for a padded slot.
      obstacles: the padded obstacle set the UAVs share.
      kind, key: as :class:`~jaxapf.datatypes.Scenario`'s (the field's kind and key data).
    """

    start: Array
    goal: Array
    valid: Array
    obstacles: Obstacles
    kind: Array | None = None
    key: Array | None = None

    @property
    def agents(self) -> int:
        """``A``, the UAV slots (static: the shape)."""
        return self.start.shape[-2]

    @classmethod
    def of(cls, scenario: Scenario) -> "Swarm":
        """A one-UAV swarm flying ``scenario``: the same episode as ``scenario`` alone."""
        return cls(start=scenario.start[None], goal=scenario.goal[None], valid=jnp.ones((1,), bool),
                   obstacles=scenario.obstacles, kind=scenario.kind, key=scenario.key)


def _key_data(swarm: Swarm, a: Array | int) -> Array:
    data = jax.random.key_data(jax.random.key(0)) if swarm.key is None else swarm.key
    folded = jax.random.key_data(jax.random.fold_in(jax.random.wrap_key_data(data), a))
    return jnp.where(jnp.asarray(a) == 0, data, folded)


def neighbour_slots(agents: int, max_neighbours: int = 0) -> int:
    """The neighbour slots each UAV of a swarm of ``agents`` sees: ``agents`` (UAV ``b`` in slot ``b``,
    itself invalid) with every other UAV, ``max_neighbours`` when fewer (module docstring), none alone."""
    if agents == 1:
        return 0
    return max_neighbours if 0 < max_neighbours < agents - 1 else agents


def with_neighbours(obstacles: Obstacles, slots: int) -> Obstacles:
    """``obstacles`` followed by ``slots`` neighbour slots (invalid, flagged ``agent``), the layout
    every UAV of a swarm sees (:func:`neighbour_slots`); ``slots = 0`` (nobody else): ``obstacles``
    unchanged."""
    if slots == 0:
        return obstacles
    dtype = obstacles.position.dtype
    empty = Obstacles.empty(slots, dtype)
    own = jnp.zeros(obstacles.radius.shape, bool) if obstacles.agent is None else obstacles.agent
    return Obstacles(*(jnp.concatenate([a, b]) for a, b in
                       zip((obstacles.position, obstacles.velocity, obstacles.radius, obstacles.cylinder,
                            obstacles.valid, own),
                           (empty.position, empty.velocity, empty.radius, empty.cylinder, empty.valid,
                            jnp.ones((slots,), bool)))))


def agent_view(swarm: Swarm, a: Array | int, r_uav: float, max_neighbours: int = 0) -> Scenario:
    """The field UAV ``a`` flies: its start and goal, the obstacles with the other UAVs at rest at
    their starts (:func:`with_neighbours`; the ``max_neighbours`` nearest with it), and its own key
    (module docstring)."""
    if jnp.ndim(swarm.start) != 2:
        raise ConfigError(f"agent_view: one swarm is wanted (start of shape (A, 3)), not {jnp.shape(swarm.start)}")
    obstacles = swarm.obstacles
    if swarm.agents > 1:
        still = jnp.zeros_like(swarm.start)
        slots = neighbour_slots(swarm.agents, max_neighbours)
        obstacles = _place(with_neighbours(obstacles, slots), swarm, swarm.start, still, 0.0, a, r_uav, slots)
    return Scenario(start=swarm.start[a], goal=swarm.goal[a], obstacles=obstacles, kind=swarm.kind,
                    key=_key_data(swarm, a))


def _place(obstacles: Obstacles | ObstacleColumns, swarm: Swarm, p: Array, v: Array, t: Array | float,
           a: Array | int, r_uav: float, slots: int):
    """``obstacles`` (laid out by :func:`with_neighbours`) with its last ``slots`` slots holding the UAVs
    at positions ``p`` and velocities ``v`` (A, 3) at time ``t``, UAV ``a`` itself left out: every UAV
    ``b`` in slot ``b``, or with fewer slots than UAVs the nearest to UAV ``a``, nearest first."""
    n = swarm.agents
    others = swarm.valid & (jnp.arange(n) != a)
    centre = p - v * jnp.asarray(t, p.dtype)  # the centre at t = 0 that is at p at time t
    if slots < n:  # the nearest: top_k of -distance² (others only), ties to the lower index
        gap = jnp.sum((p - p[a]) ** 2, axis=-1)
        _, nearest = jax.lax.top_k(jnp.where(others, -gap, -jnp.inf), slots)
        centre, v, others = centre[nearest], v[nearest], others[nearest]
    columns = isinstance(obstacles, ObstacleColumns)
    lay = (lambda x: x.T) if columns else (lambda x: x)  # noqa: E731
    axis = -1 if columns else 0
    put = lambda old, new: jax.lax.dynamic_update_slice_in_dim(old, new, old.shape[axis] - slots, axis)  # noqa: E731
    return dataclasses.replace(obstacles, position=put(obstacles.position, lay(centre)),
                               velocity=put(obstacles.velocity, lay(v)),
                               radius=put(obstacles.radius, jnp.full((slots,), r_uav, p.dtype)),
                               valid=put(obstacles.valid, others))


def neighbours(columns: ObstacleColumns, swarm: Swarm, x: Array, t: Array, a: Array | int,
               r_uav: float, max_neighbours: int = 0) -> ObstacleColumns:
    """The obstacles (component-first, laid out by :func:`with_neighbours`) UAV ``a`` sees at time
    ``t`` when the UAVs' true states are ``x`` (A, 6): the others (the ``max_neighbours`` nearest with
    it) at their positions and velocities."""
    return _place(columns, swarm, x[:, :3], x[:, 3:], t, a, r_uav, neighbour_slots(swarm.agents, max_neighbours))
