r"""MPC with every obstacle kept out over its horizon (the family of MPC-CBF), registered as ``keepout_mpc``.

Every control step one QP over the double integrator's accelerations: a goal-seeking reference, the
box, and at every horizon step a keep-out row per obstacle slot, linearised at the last plan (the
obstacles predicted), with one shared slack at an exact penalty so the QP always answers; steps that
need the slack are counted (``kmpc_infeasible_steps``). ``qpax``'s interior point method with a fixed
iteration count solves it batched; the plan's first acceleration is flown. The QP, its gains and where
it differs from MPC-CBF: docs/spec.md, "MPC with the obstacles kept out over the horizon".
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import jax.numpy as jnp
from jax import Array

from ..datatypes import ObstacleColumns, Obstacles, safe_norm
from ..gains import GainSpec
from ..metrics.base import Metric
from .apf import ETA, K_ATT, preferred_velocity
from .base import Planner, reference_states, register_planner, shifted
from .mppi import rollout_positions

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..gains import Gains

__all__ = ["KeepoutMPC", "KMPC_GAINS", "keepout_qp", "solve", "ITERATIONS", "TOLERANCE", "SLACK_LINEAR",
           "SLACK_QUADRATIC"]

KMPC_Q = GainSpec("kmpc_q", 1.0, low=0.0, low_open=True, unit="1/m²",
                  doc="keep-out MPC: weight of the distance to the goal-seeking reference, per step")
KMPC_QV = GainSpec("kmpc_qv", 0.1, low=0.0, unit="s²/m²",
                   doc="keep-out MPC: weight of the velocity's distance to the preferred velocity, per step")
KMPC_R = GainSpec("kmpc_r", 0.05, low=0.0, low_open=True, unit="s⁴/m²",
                  doc="keep-out MPC: weight of the acceleration, per step")
KMPC_MARGIN = GainSpec("kmpc_margin", 0.2, low=0.0, unit="m",
                       doc="keep-out MPC: margin added to the combined radius ρ_o + r_uav")
KMPC_GAINS = (KMPC_Q, KMPC_QV, KMPC_R, KMPC_MARGIN)
#: Interior-point iterations per QP, and the slack [m] above which a step counts as infeasible.
ITERATIONS = 20
TOLERANCE = 1e-3
#: Weights of the slack s [m] the keep-out rows may borrow: SLACK_LINEAR s + SLACK_QUADRATIC s².
SLACK_LINEAR = 1e3
SLACK_QUADRATIC = 1e4


def _prediction(horizon: int, dt: float, dtype) -> tuple[Array, Array]:
    """``S_p``, ``S_v`` (N, N): position and velocity after step ``i`` from the accelerations,
    ``p_i = p + iΔt v + Σ_j S_p[i, j] a_j``, ``v_i = v + Σ_j S_v[i, j] a_j``."""
    i = jnp.arange(1, horizon + 1, dtype=dtype)[:, None]
    j = jnp.arange(horizon, dtype=dtype)[None, :]
    before = j < i
    return jnp.where(before, (i - j - 0.5) * dt * dt, 0.0), jnp.where(before, dt, 0.0)


def keepout_qp(x: Array, t: Array, preferred: Array, last: Array, obstacles: ObstacleColumns, gains: "Gains",
               sim: "SimConfig", horizon: int) -> tuple[Array, Array, Array, Array]:
    """``(H, e, G, h)`` of the step's QP ``min ½ zᵀ H z + eᵀ z s.t. G z <= h`` over ``z = (U, s)`` (3N + 1,):
    the accelerations stacked step by step and the keep-out rows' slack (module docstring); ``last`` (N, 3):
    the positions the keep-out rows are linearised at. The rows: N·M keep-out rows (step-major), the box
    on ``U`` (upper, then lower), ``s >= 0``."""
    dtype = x.dtype
    dt = sim.episode.dt
    sp, sv = _prediction(horizon, dt, dtype)
    eye3 = jnp.eye(3, dtype=dtype)
    big_p, big_v = jnp.kron(sp, eye3), jnp.kron(sv, eye3)  # (3N, 3N)
    steps = jnp.arange(1, horizon + 1, dtype=dtype)[:, None]
    free_p = x[:3] + steps * dt * x[3:]  # positions without acceleration (N, 3)
    target = x[:3] + steps * dt * preferred
    d_p = (free_p - target).reshape(-1)
    d_v = jnp.broadcast_to(x[3:] - preferred, (horizon, 3)).reshape(-1)
    n_u = 3 * horizon
    hess = 2.0 * (gains.kmpc_q * big_p.T @ big_p + gains.kmpc_qv * big_v.T @ big_v
                  + gains.kmpc_r * jnp.eye(n_u, dtype=dtype))
    lin = 2.0 * (gains.kmpc_q * big_p.T @ d_p + gains.kmpc_qv * big_v.T @ d_v)
    # keep-out rows: n·(p_i - c_o(t_i)) >= R_o, n the unit vector from c_o(t_i) to last_i (z dropped for cylinders)
    times = t + dt * steps[:, 0]
    centres = obstacles.position.T[None] + obstacles.velocity.T[None] * times[:, None, None]  # (N, M, 3)
    keep_z = jnp.where(obstacles.cylinder, 0.0, 1.0).astype(dtype)
    flat = jnp.stack([jnp.ones_like(keep_z), jnp.ones_like(keep_z), keep_z], axis=-1)  # (M, 3)
    away = (last[:, None, :] - centres) * flat
    normal = away / safe_norm(away)[..., None]
    radius = obstacles.radius + sim.vehicle.r_uav + gains.kmpc_margin
    rhs = radius + jnp.sum(normal * (centres - free_p[:, None, :]), axis=-1)  # n·(S_p U)_i >= rhs, (N, M)
    rows = jnp.einsum("nmk,nkj->nmj", normal, big_p.reshape(horizon, 3, n_u))  # (N, M, 3N)
    valid = obstacles.valid[None, :]
    rows = jnp.where(valid[..., None], rows, 0.0).reshape(-1, n_u)
    rhs = jnp.where(valid, rhs, -1.0).reshape(-1)
    # the slack s >= 0 every keep-out row may borrow (exact penalty): the QP is always feasible
    a_max = sim.vehicle.a_max
    box = jnp.eye(n_u + 1, dtype=dtype)[:n_u]
    slack = jnp.zeros(n_u + 1, dtype).at[-1].set(-1.0)
    keep = jnp.concatenate([-rows, jnp.full((rows.shape[0], 1), -1.0, dtype)], axis=1)
    g = jnp.concatenate([keep, box, -box, slack[None]])
    h = jnp.concatenate([-rhs, jnp.full(2 * n_u, a_max, dtype), jnp.zeros(1, dtype)])
    hess = jnp.zeros((n_u + 1, n_u + 1), dtype).at[:n_u, :n_u].set(hess).at[-1, -1].set(2.0 * SLACK_QUADRATIC)
    lin = jnp.concatenate([lin, jnp.full(1, SLACK_LINEAR, dtype)])
    return hess, lin, g, h


def solve(hess: Array, lin: Array, g: Array, h: Array) -> Array:
    """The QP's answer ``z`` by :data:`ITERATIONS` interior-point iterations."""
    import qpax

    n = lin.shape[0]
    return qpax.solve_qp(hess, lin, jnp.zeros((0, n), lin.dtype), jnp.zeros((0,), lin.dtype), g, h,
                         solver_tol=0.0, max_iter=ITERATIONS)[0]


@dataclasses.dataclass(frozen=True)
class KeepoutMPC(Planner):
    """MPC keeping every obstacle out at every horizon step (linearised keep-out constraints, one SCP step)

    (module docstring) The state: the plan flown (accelerations and positions), and whether this step's QP
    was infeasible.
    """

    color: str | None = "tab:cyan"
    linestyle: str | None = "-"
    # Two CPU devices running this program at once stall inside XLA's CPU runtime (every thread idle,
    # a result never ready; jax 0.10.2: 128 fields, vmap width 64, 2 devices; never on one device, at
    # width 8, or with the devices' blocks run one after another), so they run one after another.
    concurrent_cpu_devices = False
    metrics = (Metric.flagged_steps("kmpc_infeasible_steps", "kmpc_infeasible",
                                    "control steps at which no plan kept every obstacle out over the horizon (the "
                                    "plan intruding least was flown; 0 for other planners)"),)

    @property
    def gains(self) -> tuple[GainSpec, ...]:
        return (*KMPC_GAINS, K_ATT, ETA)

    @property
    def reads(self) -> tuple[str, ...]:
        return ("att_cap", "reference_velocity")

    def init(self, scenario: Any, gains: "Gains", sim: "SimConfig", horizon: int) -> tuple[Array, Array, Array]:
        """Hover as the last plan, at the start."""
        start = scenario.start
        return (jnp.zeros((horizon, 3), start.dtype), jnp.broadcast_to(start, (horizon, 3)),
                jnp.zeros((), bool))

    def diagnostics(self, state: Any) -> dict[str, Array]:
        return {"kmpc_infeasible": state[2]}

    def step_qp(self, state: Any, x: Array, t: Array, goal: Array, obstacles: ObstacleColumns, gains: "Gains",
                sim: "SimConfig", horizon: int) -> tuple[Array, Array, Array, Array]:
        """The QP (:func:`keepout_qp`) of the step from ``x`` at ``t``: the preferred velocity towards ``goal``,
        the keep-out rows linearised at the last plan's positions shifted by one step."""
        return keepout_qp(x, t, preferred_velocity(x, goal, gains, sim), shifted(state[1]), obstacles, gains, sim,
                          horizon)

    def reference(self, state: Any, x: Array, t: Array, goal: Array, obstacles: Obstacles | ObstacleColumns,
                  gains: "Gains", sim: "SimConfig", horizon: int) -> tuple[Array, Any]:
        """The plan's positions (module docstring); the state becomes the plan flown and its positions."""
        controls = state[0]
        z = solve(*self.step_qp(state, x, t, goal, obstacles.columns(), gains, sim, horizon))
        answered = jnp.all(jnp.isfinite(z))
        plan = jnp.where(answered, jnp.clip(z[:-1].reshape(horizon, 3), -sim.vehicle.a_max, sim.vehicle.a_max),
                         shifted(controls))
        p, v = rollout_positions(x, plan, sim.episode.dt)
        return reference_states(x, p, v, sim), (plan, p, ~answered | (z[-1] > TOLERANCE))

    def command(self, state: Any) -> Array:
        """The plan's first acceleration."""
        return state[0][0]


register_planner("keepout_mpc", KeepoutMPC())
