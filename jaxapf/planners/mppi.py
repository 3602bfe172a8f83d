r"""Model predictive path integral control (MPPI, Williams et al. 2017), registered as ``mppi``.

Every control step ``K = sim.mppi_samples`` perturbed acceleration sequences around the last plan (shifted
by one step) are rolled out through the double integrator with the obstacles predicted, scored, and
averaged with the weights ``exp(-S/λ)``; the plan's first acceleration is flown, no MPC tracks it. The
noise comes from the field's key (purpose ``"mppi"``), so every method flies the same world, and the plan
is differentiable in every cost weight (``jaxapf tune``). The cost, the defaults and where it differs
from the published implementations: docs/spec.md, "model predictive path integral control".
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
from jax import Array

from ..datatypes import ObstacleColumns, Obstacles, safe_norm
from ..datatypes.obstacles import project
from ..datatypes.scenario import episode_key
from ..gains import GainSpec
from .base import Planner, reference_states, register_planner, shifted

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..gains import Gains

__all__ = ["MPPI", "MPPI_GAINS", "mppi_costs", "mppi_update", "rollout_positions"]

MPPI_LAMBDA = GainSpec("mppi_lambda", 1.0, low=0.0, low_open=True, symbol="λ",
                       doc="MPPI: temperature of the sample weights exp(-S/λ); smaller follows the best sample")
MPPI_SIGMA = GainSpec("mppi_sigma", 1.0, low=0.0, low_open=True, unit="m/s²", symbol="σ",
                      doc="MPPI: standard deviation of the sampled accelerations' perturbation, per axis and step")
MPPI_GOAL = GainSpec("mppi_goal", 1.0, low=0.0, unit="1/m", doc="MPPI: cost of each metre from the goal, per step")
MPPI_OBSTACLE = GainSpec("mppi_obstacle", 20.0, low=0.0,
                         doc="MPPI: cost of closing within mppi_d of an obstacle, (1 - c/d)² per step")
MPPI_D = GainSpec("mppi_d", 1.0, low=0.0, low_open=True, unit="m",
                  doc="MPPI: clearance below which an obstacle costs")
MPPI_COLLISION = GainSpec("mppi_collision", 1000.0, low=0.0, doc="MPPI: cost of each step inside an obstacle")
MPPI_SPEED = GainSpec("mppi_speed", 10.0, low=0.0, unit="s²/m²",
                      doc="MPPI: cost of the speed above v_max, squared per axis and step")
MPPI_EFFORT = GainSpec("mppi_effort", 0.01, low=0.0, unit="s⁴/m²", doc="MPPI: cost of |a|² per step")
MPPI_GAINS = (MPPI_LAMBDA, MPPI_SIGMA, MPPI_GOAL, MPPI_OBSTACLE, MPPI_D, MPPI_COLLISION, MPPI_SPEED, MPPI_EFFORT)


def rollout_positions(x: Array, controls: Array, dt: float) -> tuple[Array, Array]:
    """Positions and velocities (..., N, 3) after each of the accelerations ``controls`` (..., N, 3),
    from ``x = [p, v]``, by the exact double integrator (paper eq. 7)."""
    v = x[3:] + dt * jnp.cumsum(controls, axis=-2)
    v_before = v - dt * controls
    p = x[:3] + jnp.cumsum(dt * v_before + 0.5 * dt * dt * controls, axis=-2)
    return p, v


def _clearances(p: Array, t: Array, obstacles: ObstacleColumns, dt: float, r_uav: float) -> Array:
    """Surface clearance (..., N, M) of positions ``p`` (..., N, 3) at times ``t + (1..N) Δt`` to each
    obstacle, predicted at constant velocity (``P`` of §2 drops z for a cylinder); padded slots are far (+1e6)."""
    n = p.shape[-2]
    times = t + dt * jnp.arange(1, n + 1, dtype=p.dtype)
    centres = obstacles.position.T[None] + obstacles.velocity.T[None] * times[:, None, None]  # (N, M, 3)
    rel = project(p[..., :, None, :] - centres, obstacles.cylinder)  # (..., N, M, 3)
    c = safe_norm(rel) - obstacles.radius - r_uav
    return jnp.where(obstacles.valid, c, 1e6)


def mppi_costs(u: Array, noise: Array, x: Array, t: Array, goal: Array, obstacles: ObstacleColumns,
               gains: "Gains", sim: "SimConfig") -> tuple[Array, Array]:
    """The costs ``S_k`` (K,) of the perturbed sequences and their effective noise (K, N, 3) (module
    docstring, steps 1–3)."""
    a_max, dt = sim.vehicle.a_max, sim.episode.dt
    samples = jnp.clip(u + noise, -a_max, a_max)
    eps = samples - u
    p, v = rollout_positions(x, samples, dt)
    c = _clearances(p, t, obstacles, dt, sim.vehicle.r_uav)
    goal_cost = gains.mppi_goal * jnp.sum(safe_norm(p - goal), axis=-1)
    near = gains.mppi_obstacle * jnp.sum(jnp.square(jnp.maximum(0.0, 1.0 - c / gains.mppi_d)), axis=(-2, -1))
    hit = gains.mppi_collision * jnp.sum((c < 0.0).astype(p.dtype), axis=(-2, -1))
    speed = gains.mppi_speed * jnp.sum(jnp.square(jnp.maximum(0.0, jnp.abs(v) - sim.vehicle.v_max)), axis=(-2, -1))
    effort = gains.mppi_effort * jnp.sum(samples * samples, axis=(-2, -1))
    control = gains.mppi_lambda / (gains.mppi_sigma**2) * jnp.sum(u * eps, axis=(-2, -1))
    return goal_cost + near + hit + speed + effort + control, eps


def mppi_update(u: Array, noise: Array, x: Array, t: Array, goal: Array, obstacles: ObstacleColumns,
                gains: "Gains", sim: "SimConfig") -> tuple[Array, Array]:
    """``U*`` (N, 3) from the nominal ``u`` and the noise draws (K, N, 3) (module docstring, step 4), and
    the lowest sample cost."""
    costs, eps = mppi_costs(u, noise, x, t, goal, obstacles, gains, sim)
    best = jnp.min(costs)
    weights = jax.nn.softmax(-(costs - jax.lax.stop_gradient(best)) / gains.mppi_lambda)
    return u + jnp.tensordot(weights, eps, axes=1), best


@dataclasses.dataclass(frozen=True)
class MPPI(Planner):
    """model predictive path integral control (MPPI, Williams et al. 2017): the weighted mean of sampled plans

    (module docstring) The state carries the plan ``U*``, the field's key for the noise and the step.
    """

    color: str | None = "tab:olive"
    linestyle: str | None = "-"

    @property
    def gains(self) -> tuple[GainSpec, ...]:
        return MPPI_GAINS

    @property
    def reads(self) -> tuple[str, ...]:
        return ("mppi_samples", "reference_velocity")

    def init(self, scenario: Any, gains: "Gains", sim: "SimConfig", horizon: int) -> tuple[Array, Array, Array]:
        """Hover as the first plan, the field's ``"mppi"`` key and step 0."""
        dtype = scenario.start.dtype
        key = jax.random.key_data(episode_key(scenario, "mppi"))
        return jnp.zeros((horizon, 3), dtype), key, jnp.zeros((), jnp.int32)

    def reference(self, state: Any, x: Array, t: Array, goal: Array, obstacles: Obstacles | ObstacleColumns,
                  gains: "Gains", sim: "SimConfig", horizon: int) -> tuple[Array, Any]:
        """``U*`` rolled out from ``x`` (module docstring), from the last plan shifted by one step; the state
        becomes ``U*``."""
        last, key, step = state
        u = shifted(last)
        draw = jax.random.fold_in(jax.random.wrap_key_data(key), step)
        noise = gains.mppi_sigma * jax.random.normal(draw, (sim.planner.mppi_samples, horizon, 3), x.dtype)
        plan, _ = mppi_update(u, noise, x, t, goal, obstacles.columns(), gains, sim)
        p, v = rollout_positions(x, plan, sim.episode.dt)
        return reference_states(x, p, v, sim), (plan, key, step + 1)

    def command(self, state: Any) -> Array:
        """``U*``'s first acceleration."""
        return state[0][0]


register_planner("mppi", MPPI())
