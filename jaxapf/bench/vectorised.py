r"""The strongest CPU peer a user would write without jaxapf: the closed loop in numpy, vectorised over fields.

A researcher who knows numpy would not loop over fields one at a time (:mod:`jaxapf.bench.oracle`,
numpy + OSQP per field); they would carry the whole batch of fields through the control loop as
arrays. This module is that program: one Python loop over control steps, inside it the APF
reference flow over ``(fields, obstacles)`` arrays (the oracle's formulas, which broadcast over
leading axes), and the engine's MPC algorithm -- the per-axis condensed QP solved by FISTA with the
same fixed iteration count, step ``1/L`` and momentum sequence, warm-started from the shifted
previous solution -- as numpy matrix products over ``(fields, 3 axes, N)``. Same algorithm, same
iteration counts, float32 by default: what differs from :func:`jaxapf.rollout.evaluate` is only
numpy instead of XLA. The per-axis matrices are set up once per run (by
:func:`jaxapf.control.axis_problem`, then plain numpy), as a user would precompute them.

``tests/bench/test_vectorised.py`` checks that it reproduces the engine's trajectories (float64:
to rounding), and ``jaxapf bench engine --vectorised-fields F`` times it against the engine
interleaved in one process.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..control.mpc import _momentum
from ..validation import check_choice
from .oracle import _gain_values, apf_reference

__all__ = ["vectorised_rollout", "VECTORISED_METHODS"]

#: Planners the vectorised peer knows (the paper's three, on the double integrator, no filter).
VECTORISED_METHODS: tuple[str, ...] = ("basic", "direction", "direction_velocity")


def _field_arrays(scenarios: Any, dtype) -> dict[str, np.ndarray]:
    """The batch of fields as numpy arrays with a leading field axis (obstacles (F, M, ...))."""
    obs = scenarios.obstacles
    cylinder = np.asarray(obs.cylinder, bool)
    proj = np.ones(cylinder.shape + (3,), dtype)
    proj[cylinder, 2] = 0.0
    return dict(start=np.asarray(scenarios.start, dtype), goal=np.asarray(scenarios.goal, dtype),
                position=np.asarray(obs.position, dtype), velocity=np.asarray(obs.velocity, dtype),
                radius=np.asarray(obs.radius, dtype), valid=np.asarray(obs.valid, bool), proj=proj)


def _axis_matrices(sim: Any, mpc: Any, dtype) -> dict[str, np.ndarray]:
    """The per-axis condensed MPC (prediction, weights, FISTA kernel, Lipschitz constants) as numpy."""
    import jax.numpy as jnp

    from ..control import axis_problem
    from ..dynamics import discrete_matrices

    prob = axis_problem(mpc, *discrete_matrices(sim.episode.dt, 1, jnp.result_type(float)))
    m, c = np.asarray(prob.m, dtype), np.asarray(prob.c, dtype)
    return dict(m=m, c=c, q_aug=np.asarray(prob.q_aug, dtype), kernel=np.asarray(prob.kernel, dtype),
                step=(1.0 / np.asarray(prob.lipschitz, np.float64)).astype(dtype)[:, None],
                rho=dtype(prob.v_penalty), m_vel=m[3::2], c_vel=c[3::2])


def _solve_axes(mats: dict, x: np.ndarray, x_ref: np.ndarray, warm: np.ndarray, *, a_max: float, v_max: float,
                betas: list[float]) -> np.ndarray:
    """The three per-axis MPC QPs of every field by FISTA; ``x`` (F, 6), ``x_ref`` (F, N+1, 6),
    ``warm`` (F, 3, N); returns the inputs (F, 3, N)."""
    n = warm.shape[-1]
    x0 = np.stack([x[:, :3], x[:, 3:]], axis=-1)  # (F, 3, 2): (p_j, v_j)
    ref = np.stack([x_ref[..., :3], x_ref[..., 3:]], axis=-1).transpose(0, 2, 1, 3).reshape(x.shape[0], 3, -1)
    e = (mats["q_aug"] * (x0 @ mats["m"].T - ref)) @ mats["c"]  # Cᵀ Q_aug (M x0 - X_ref), (F, 3, N)
    v_free = x0 @ mats["m_vel"].T  # (F, 3, N)
    rho, c_vel, kernel = mats["rho"], mats["c_vel"], mats["kernel"]
    e_hat = e + rho * (v_free @ c_vel)
    shared = kernel.shape[0] == 1
    u = np.clip(warm, -a_max, a_max)
    y = u
    for beta in betas:
        stacked = y @ kernel[0].T if shared else np.einsum("amn,fan->fam", kernel, y)
        grad = stacked[..., :n] + e_hat - rho * (np.clip(v_free + stacked[..., n:], -v_max, v_max) @ c_vel)
        u_next = np.clip(y - mats["step"] * grad, -a_max, a_max)
        y = u_next + u_next.dtype.type(beta) * (u_next - u)
        u = u_next
    return u


def vectorised_rollout(scenarios: Any, gains: Any, sim: Any, mpc: Any, *, dtype: Any = np.float32
                       ) -> dict[str, np.ndarray]:
    """Every field of the batch ``scenarios`` (leading axis F) flown with one gain setting ``gains``.

    Returns ``time`` (T+1,), ``position``/``velocity`` (F, T+1, 3) and ``control`` (F, T, 3) in
    ``dtype``: the loop of :func:`jaxapf.rollout.rollout` (APF reference, FISTA MPC with
    ``mpc.iters`` iterations, exact double-integrator step) for all fields at once.

    Raises :class:`~jaxapf.validation.ConfigError` for a planner, filter or plant it does not know.
    """
    known = {"method": VECTORISED_METHODS, "filter": ("none",), "plant": ("double_integrator",)}
    for key, names in known.items():
        check_choice(f"sim.{key} (the vectorised numpy peer)", sim.flat()[key], names)
    dtype = np.dtype(dtype).type
    arrays = _field_arrays(scenarios, dtype)
    g = _gain_values(gains)
    mats = _axis_matrices(sim, mpc, dtype)
    betas = [float(b) for b in _momentum(mpc.iters)]  # the engine's FISTA coefficients
    steps, dt = sim.episode.steps, dtype(sim.episode.dt)
    fields = arrays["start"].shape[0]
    x = np.concatenate([arrays["start"], np.zeros((fields, 3), dtype)], axis=1)
    states = np.zeros((fields, steps + 1, 6), dtype)
    controls = np.zeros((fields, steps, 3), dtype)
    warm = np.zeros((fields, 3, mpc.horizon), dtype)
    states[:, 0] = x
    for k in range(steps):
        x_ref = apf_reference(x, dtype(k) * dt, arrays, g, sim, mpc.horizon)
        u = _solve_axes(mats, x, x_ref, warm, a_max=sim.vehicle.a_max, v_max=sim.vehicle.v_max, betas=betas)
        a = u[..., 0]
        p, v = x[:, :3], x[:, 3:]
        x = np.concatenate([p + dt * v + dtype(0.5) * dt * dt * a, v + dt * a], axis=1)
        warm = np.concatenate([u[..., 1:], u[..., -1:]], axis=-1)
        states[:, k + 1] = x
        controls[:, k] = a
    return dict(time=np.arange(steps + 1, dtype=dtype) * dt, position=states[..., :3], velocity=states[..., 3:],
                control=controls)
