"""An episode and the quantities its metrics share (SPEC 6): swept clearance, episode end, masks.

The time grid and the episode-end rules are defined in :mod:`jaxapf.metrics.episode`'s docstring;
:class:`EpisodeContext` computes each shared quantity once per trace, whatever metrics ask for it.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
from jax import Array

from ..config import SimConfig
from ..datatypes import Obstacles, Scenario, Trajectory, clearance, obstacles_at, project, segment_clearance

__all__ = ["EpisodeContext", "episode_end", "END_MARGIN", "certainly_ended", "certainly_at_goal", "clearance_history",
           "interval_clearance", "time_to_collision", "masked_min", "stall_samples", "ratio"]


# --------------------------------------------------------------------------------------------
# geometry along the trajectory
# --------------------------------------------------------------------------------------------


def clearance_history(traj: Trajectory, scenario: Scenario, sim: SimConfig) -> Array:
    """Clearance (T+1, M) of every sample to every obstacle; +inf for padded slots."""
    per_sample = jax.vmap(clearance, in_axes=(0, None, 0, None))
    return per_sample(traj.position, scenario.obstacles, traj.time, sim.vehicle.r_uav)


def interval_clearance(traj: Trajectory, scenario: Scenario, sim: SimConfig) -> Array:
    """Swept clearance (T, M) of every interval to every obstacle; +inf for padded slots."""
    per_interval = jax.vmap(segment_clearance, in_axes=(0, 0, None, 0, 0, None))
    p, t = traj.position, traj.time
    return per_interval(p[:-1], p[1:], scenario.obstacles, t[:-1], t[1:], sim.vehicle.r_uav)


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
    goal_index = _first_index(goal_distance <= sim.episode.r_goal, steps + 1)
    end_index = jnp.minimum(jnp.minimum(goal_index, collision_index), steps).astype(jnp.int32)
    return {"goal_index": goal_index, "collision_index": collision_index, "end_index": end_index}


def episode_end(traj: Trajectory, scenario: Scenario, sim: SimConfig) -> dict[str, Array]:
    """``goal_index``, ``collision_index`` and ``end_index`` (int32 sample indices; ``T + 1`` = never)."""
    min_c = jnp.min(interval_clearance(traj, scenario, sim), axis=-1)
    return _end(min_c, _goal_distance(traj, scenario), sim)


#: How far past an end rule a sample must be for :func:`certainly_ended` [m]: far above the few
#: ulps by which two compiled programs may round the same clearance or goal distance apart.
END_MARGIN = 1e-3


def certainly_at_goal(p: Array, scenario: Scenario, sim: SimConfig) -> Array:
    """Whether the sample ``p`` is within ``r_goal - END_MARGIN`` of the goal (see :func:`certainly_ended`)."""
    return jnp.linalg.norm(p - scenario.goal) <= sim.episode.r_goal - END_MARGIN


def certainly_ended(p0: Array, p1: Array, t0: Array, scenario: Scenario, sim: SimConfig) -> Array:
    """Whether the interval from sample ``p0`` (time ``t0``) to the next sample ``p1`` certainly ends
    the episode: its swept clearance is below ``-END_MARGIN`` (a collision) or ``p1`` is within
    ``r_goal - END_MARGIN`` of the goal. The episode-end rules of :func:`episode_end` then hold at
    this sample or an earlier one whatever program rounds them, so the samples flown so far decide
    every metric. The streaming engine (:mod:`jaxapf.engine.stream`) evaluates it after each step."""
    swept = jnp.min(segment_clearance(p0, p1, scenario.obstacles, t0, t0 + sim.episode.dt, sim.vehicle.r_uav))
    return (swept < -END_MARGIN) | certainly_at_goal(p1, scenario, sim)


def masked_min(x: Array, mask: Array) -> Array:
    return jnp.min(jnp.where(mask, x, jnp.inf))


def stall_samples(sim: SimConfig) -> int:
    """Smallest number of samples ``n`` with ``n·dt >= t_stall`` (1e-9 relative tolerance)."""
    return max(1, math.ceil(sim.metrics.t_stall / sim.episode.dt * (1.0 - 1e-9)))


def ratio(num: Array, den: Array) -> Array:
    """``num / den`` for ``num, den >= 0`` with ``0/0 := 1`` and ``x/0 := +inf``."""
    safe = jnp.where(den > 0, den, 1.0)
    return jnp.where(den > 0, num / safe, jnp.where(num > 0, jnp.inf, 1.0))


class EpisodeContext:
    """One episode and the quantities its metrics share, each computed once (on first use).

    Attributes:
      traj, scenario, sim: the episode, its field and its static settings.
    """

    def __init__(self, traj: Trajectory, scenario: Scenario, sim: SimConfig) -> None:
        self.traj, self.scenario, self.sim = traj, scenario, sim
        self.steps = traj.control.shape[-2]
        self.dt = sim.episode.dt

    @functools.cached_property
    def swept(self) -> Array:
        """``c_i``: swept clearance (T,) of every interval to the nearest valid obstacle."""
        return jnp.min(interval_clearance(self.traj, self.scenario, self.sim), axis=-1)

    @functools.cached_property
    def goal_distance(self) -> Array:
        """Distance (T+1,) of every sample to the goal."""
        return _goal_distance(self.traj, self.scenario)

    @functools.cached_property
    def end(self) -> dict[str, Array]:
        """``goal_index``, ``collision_index``, ``end_index`` (module docstring)."""
        return _end(self.swept, self.goal_distance, self.sim)

    @property
    def end_index(self) -> Array:
        """``e``: the last valid sample."""
        return self.end["end_index"]

    @functools.cached_property
    def sample_valid(self) -> Array:
        return jnp.arange(self.steps + 1) <= self.end_index

    @functools.cached_property
    def interval_valid(self) -> Array:
        return jnp.arange(self.steps) < self.end_index

    def extra(self, name: str, reduce=jnp.sum) -> Array:
        """``reduce`` (sum, max) of the per-step diagnostic ``name`` a component records in the
        trajectory's ``extras``, over the valid intervals (0 where they hold none); 0 if the episode's
        components record no ``name``."""
        values = self.traj.extras.get(name)
        if values is None:
            return jnp.zeros((), self.traj.position.dtype)
        return reduce(jnp.where(self.interval_valid, values, 0))

    @functools.cached_property
    def success(self) -> Array:
        return (self.end["goal_index"] <= self.steps) & (self.end["goal_index"] < self.end["collision_index"])

    @functools.cached_property
    def collision(self) -> Array:
        return (self.end["collision_index"] <= self.steps) & (self.end["collision_index"] <= self.end["goal_index"])

    @functools.cached_property
    def time_to_goal(self) -> Array:
        return jnp.where(self.success, self.end["goal_index"] * self.dt, jnp.nan)

    @functools.cached_property
    def straight(self) -> Array:
        """``|g - start|``: the straight-line distance."""
        return jnp.linalg.norm(self.scenario.goal - self.scenario.start)

    @functools.cached_property
    def path_length(self) -> Array:
        p = self.traj.position
        step_length = jnp.linalg.norm(p[1:] - p[:-1], axis=-1)
        return jnp.sum(jnp.where(self.interval_valid, step_length, 0.0))
