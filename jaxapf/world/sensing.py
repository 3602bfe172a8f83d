r"""Sensing: what the avoidance stack knows of the world, between the world and the planner.

Every control step a :class:`Sensor` turns the truth (the plant's ``[p, v]``, the obstacles) into
the *observation* the planner, the MPC and the safety filter work with: an estimate of the UAV's
state and the obstacles as they are seen. The plant and the metrics always use the truth.

``ideal`` (:class:`Ideal`, the default) passes the truth on, instantly: the paper's assumption and
today's numbers bit for bit. ``noisy`` (:class:`NoisySensor`) is the imperfect sensor, every level
a traced gain (a grid over σ is one ``vmap``); at its defaults it reproduces ``ideal``.

Randomness comes from the field's key (:func:`~jaxapf.datatypes.episode_key`) folded with a purpose
and the step, never from the method or the gains, so settings compared on a field see the same noise
(common random numbers).
"""

from __future__ import annotations

import abc
import dataclasses
from typing import TYPE_CHECKING, Any, ClassVar

import jax
import jax.numpy as jnp
from jax import Array

from ..datatypes import ObstacleColumns, episode_key
from ..gains import GainSpec
from ..metrics import Metric
from ..planners.sight import line_of_sight, norm
from ..registry import Registry
from ..stage import DECLARE, Stage

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..datatypes import Scenario
    from ..gains import Gains

__all__ = ["Sensor", "Ideal", "NoisySensor", "SENSORS", "register_sensor", "delay_line"]


class Sensor(Stage, abc.ABC):
    """Maps the truth to what the stack sees (a :class:`~jaxapf.stage.Stage`: gains, ``init``)."""

    @abc.abstractmethod
    def __call__(self, state: Any, x: Array, k: Array, scenario: "Scenario", obstacles: ObstacleColumns,
                 gains: "Gains", sim: "SimConfig") -> tuple[Array, ObstacleColumns, Any, dict[str, Array]]:
        """``(estimate of [p, v] (6,), observed obstacles, next state, diagnostics)`` at control step
        ``k`` (an integer) from the true state ``x`` (6,) and the true ``obstacles`` (at t = 0,
        component-first). The observed obstacles are in the same form: a planner extrapolates them
        at their (observed) velocity from ``t = 0`` as it does the truth."""

    def delay(self, gains: "Gains", sim: "SimConfig") -> Array:
        """How many control steps old the obstacle measurements are (the swarm engine hands each UAV the
        others' true states of that age); none by default."""
        return jnp.zeros((), jnp.int32)


@dataclasses.dataclass(frozen=True)
class Ideal(Sensor):
    """Perfect, instant knowledge of the UAV and of every obstacle (the paper's assumption)."""

    def __call__(self, state: Any, x: Array, k: Array, scenario: Any, obstacles: ObstacleColumns, gains: Any,
                 sim: Any) -> tuple[Array, ObstacleColumns, Any, dict[str, Array]]:
        return x, obstacles, state, {}


def delay_line(history: Array, x: Array, delay: Array) -> tuple[Array, Array]:
    """``(history, then)``: the last ``L + 1`` values (leading axis) with ``x`` the newest, and the one
    ``delay`` steps old: the memory behind a latency (the noisy sensor's own positions, the swarm
    engine's UAV states)."""
    history = jnp.concatenate([history[1:], x[None]], axis=0)
    return history, jax.lax.dynamic_index_in_dim(history, history.shape[0] - 1 - delay, keepdims=False)


def _surface_distance(p: Array, centres: Array, obstacles: ObstacleColumns, r_uav: float) -> Array:
    """Clearance (M,) of the UAV at ``p`` (3,) to the obstacles centred at ``centres`` (3, M) (SPEC 2)."""
    return norm(line_of_sight(p, centres, obstacles.cylinder)) - obstacles.radius - r_uav


@dataclasses.dataclass(frozen=True)
class NoisySensor(Sensor):
    r"""Noise, limited range, latency and dropout on the obstacles, noise on the UAV's own state.

    At control step ``k`` (time ``t_k``) with latency ``d = clip(round(latency/dt), 0, max_latency)``
    steps, the stack sees the measurement of step ``j = k - d``:

    * each obstacle's centre at ``t_j`` plus Gaussian noise of ``sigma_obs_p`` per coordinate; its
      velocity plus noise of ``sigma_obs_v`` (``velocity_estimate = "measured"``), or the finite
      difference ``(z_j - z_{j-1}) / dt`` of two consecutive noisy positions (``"differenced"``);
    * an obstacle is *detected* iff its clearance from the UAV's true position at ``t_j`` is at most
      ``sense_range`` and the measurement is not dropped (probability ``dropout``, independent per
      obstacle and step);
    * the stack treats a detection as current: it extrapolates the measured centre at the measured
      velocity from ``t_k`` on. An obstacle not detected at a step coasts on its last detection (a
      track at constant velocity); one never detected is unknown to the stack.

    The UAV's own estimate is ``[p + σ_p ξ, v + σ_v ξ']`` (``sigma_self_p``, ``sigma_self_v``), with no
    latency. Before the episode (``j < 0``) the world is extrapolated back at constant velocity and
    the UAV was at rest at its start, so the latency is exactly ``d`` steps from the first step on.

    Diagnostics: ``unseen_near`` (int32), the valid obstacles whose true clearance is at most
    ``sim.metrics.d_sense`` and which the step's measurement did not detect.
    """

    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric.flagged_steps("unseen_steps", "unseen_near", per_step=False,
                             doc="obstacle-steps with an obstacle within d_sense not detected by the sensor (0 for the "
                                 "ideal one)"),
    )
    gains: ClassVar[tuple[GainSpec, ...]] = (
        GainSpec("sigma_obs_p", 0.0, low=0.0, unit="m", symbol="σ_o", tunable=False,
                 doc="standard deviation of each coordinate of an obstacle's measured centre"),
        GainSpec("sigma_obs_v", 0.0, low=0.0, unit="m/s", symbol="σ_ov", tunable=False,
                 doc="standard deviation of each component of an obstacle's measured velocity"),
        GainSpec("sigma_self_p", 0.0, low=0.0, unit="m", symbol="σ_p", tunable=False,
                 doc="standard deviation of each coordinate of the UAV's position estimate"),
        GainSpec("sigma_self_v", 0.0, low=0.0, unit="m/s", symbol="σ_v", tunable=False,
                 doc="standard deviation of each component of the UAV's velocity estimate"),
        GainSpec("sense_range", 1e4, low=0.0, low_open=True, unit="m", symbol="r_s", tunable=False,
                 doc="clearance beyond which an obstacle is not detected (default: beyond every field)"),
        GainSpec("latency", 0.0, low=0.0, unit="s", symbol="τ_d", tunable=False,
                 doc="age of the obstacle measurements the stack sees, rounded to control steps"),
        GainSpec("dropout", 0.0, low=0.0, high=1.0, symbol="p_drop", tunable=False,
                 doc="probability that an obstacle's measurement is lost at a step"),
    )

    def init(self, scenario: "Scenario", gains: "Gains", sim: "SimConfig") -> dict[str, Array]:
        obstacles = scenario.obstacles.columns()
        history = jnp.broadcast_to(scenario.start, (sim.world.max_latency + 1, 3))
        state = {"history": history, "position": obstacles.position, "velocity": jnp.zeros_like(obstacles.velocity),
                 "seen": jnp.zeros_like(obstacles.valid)}
        if sim.world.velocity_estimate == "differenced":
            # the latency is fixed for an episode, so step k measures j = k - d and the previous raw
            # position noise is carried from step to step (one draw per step); before step 0: j = -d - 1
            first = -self.delay(gains, sim) - 1
            state["last_noise"] = self._noise(scenario, first, obstacles.position.shape)[0]
        return state

    def delay(self, gains: "Gains", sim: "SimConfig") -> Array:
        """The latency in control steps, ``clip(round(latency/dt), 0, max_latency)``."""
        return jnp.clip(jnp.round(gains.latency / sim.episode.dt), 0, sim.world.max_latency).astype(jnp.int32)

    @staticmethod
    def _noise(scenario: "Scenario", j: Array, shape: tuple[int, int]) -> tuple[Array, Array, Array]:
        """Position noise, velocity noise (3, M) and the dropout uniforms (M,) of measurement ``j``."""
        key = episode_key(scenario, "sensing", j)
        normal_key, drop_key = jax.random.split(key)
        noise = jax.random.normal(normal_key, (2,) + shape, scenario.start.dtype)
        return noise[0], noise[1], jax.random.uniform(drop_key, shape[1:], scenario.start.dtype)

    def __call__(self, state: dict[str, Array], x: Array, k: Array, scenario: "Scenario",
                 obstacles: ObstacleColumns, gains: "Gains", sim: "SimConfig"
                 ) -> tuple[Array, ObstacleColumns, dict[str, Array], dict[str, Array]]:
        dt = sim.episode.dt
        d = self.delay(gains, sim)
        history, uav_then = delay_line(state["history"], x[:3], d)  # positions of steps k-L..k; of step k-d
        j = k - d
        t_k = k.astype(x.dtype) * dt
        lag = -d.astype(x.dtype) * dt  # t_j - t_k
        shape = obstacles.position.shape
        noise_p, noise_v, drop = self._noise(scenario, j, shape)
        carried = {}
        if sim.world.velocity_estimate == "differenced":
            noise_v = (noise_p - state["last_noise"]) * (gains.sigma_obs_p / dt)
            carried = {"last_noise": noise_p}
        else:
            noise_v = noise_v * gains.sigma_obs_v
        noise_p = noise_p * gains.sigma_obs_p
        # the measured centre z_j = c(t_j) + noise, seen as current: extrapolated from t_k at the measured
        # velocity v + noise_v, so its centre at t = 0 reads c(0) + v (t_j - t_k) + noise_p - noise_v t_k
        # (with no noise and no latency exactly the truth, bit for bit)
        position = obstacles.position + obstacles.velocity * lag + noise_p - noise_v * t_k
        velocity = obstacles.velocity + noise_v
        truth_then = obstacles.position + obstacles.velocity * (t_k + lag)
        in_range = _surface_distance(uav_then, truth_then, obstacles, sim.vehicle.r_uav) <= gains.sense_range
        detected = obstacles.valid & in_range & ~(drop < gains.dropout)
        position = jnp.where(detected, position, state["position"])
        velocity = jnp.where(detected, velocity, state["velocity"])
        seen = state["seen"] | detected
        own = jax.random.normal(episode_key(scenario, "self_sensing", k), (6,), x.dtype)
        estimate = x + own * jnp.repeat(jnp.stack([gains.sigma_self_p, gains.sigma_self_v]), 3).astype(x.dtype)
        truth_now = obstacles.position + obstacles.velocity * t_k
        near = _surface_distance(x[:3], truth_now, obstacles, sim.vehicle.r_uav) <= sim.metrics.d_sense
        unseen = jnp.sum(obstacles.valid & near & ~detected).astype(jnp.int32)
        observed = dataclasses.replace(obstacles, position=position, velocity=velocity, valid=obstacles.valid & seen)
        next_state = {"history": history, "position": position, "velocity": velocity, "seen": seen, **carried}
        return estimate, observed, next_state, {"unseen_near": unseen}


#: Registered sensing models: the values of ``sensor`` (default ``ideal``).
SENSORS: Registry[Sensor] = Registry("sensor", on_register=DECLARE,
                                     role="what the stack sees of the world")


def register_sensor(name: str, sensor: Sensor, *, replace: bool = False) -> Sensor:
    """Register ``sensor`` as ``sensor = name`` and declare its gains."""
    return SENSORS.register(name, sensor, replace=replace)


register_sensor("ideal", Ideal())
register_sensor("noisy", NoisySensor())
