"""The numpy + OSQP oracle: the same closed loop, written again the way a researcher without jaxapf would.

One scenario at a time, a Python loop over control steps, numpy for the potentials and the reference
flow, the MPC's QP solved by OSQP to tight tolerance; nothing of the JAX implementation is imported. It
is the correctness oracle of ``tests/bench/test_oracle.py`` and the per-field peer of ``jaxapf bench
engine``; it knows the paper's three planners on the double integrator with no safety filter and refuses
anything else. Its choices (analytic forces, the velocity penalty as slacks, OSQP set up once per
episode): docs/testing.md, "The numpy + OSQP oracle".
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from ..validation import check_choice

__all__ = [
    "oracle_rollout",
    "total_potential",
    "total_force",
    "apf_reference",
    "CondensedMPC",
    "require_osqp",
]

_TINY = 1e-12  # floor inside every square root (safe_norm), as jaxapf.datatypes.obstacles.TINY


def require_osqp():
    """Import and return :mod:`osqp`, or raise an :class:`ImportError` saying how to install it."""
    try:
        import osqp
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError(
            "the numpy + OSQP oracle needs the OSQP solver, which is not installed; "
            'install it with:  pip install "jaxapf[bench]"'
        ) from err
    return osqp


# --------------------------------------------------------------------------------------------
# scenario and gains as plain numpy
# --------------------------------------------------------------------------------------------


def _scenario_arrays(scenario: Any) -> dict[str, np.ndarray]:
    """The scenario as float64/bool numpy arrays, plus ``proj`` = diag(P) per obstacle (M, 3)."""
    obs = scenario.obstacles
    cylinder = np.asarray(obs.cylinder, bool).reshape(-1)
    proj = np.ones((cylinder.size, 3))
    proj[cylinder, 2] = 0.0
    return dict(
        start=np.asarray(scenario.start, np.float64).reshape(3),
        goal=np.asarray(scenario.goal, np.float64).reshape(3),
        position=np.asarray(obs.position, np.float64).reshape(-1, 3),
        velocity=np.asarray(obs.velocity, np.float64).reshape(-1, 3),
        radius=np.asarray(obs.radius, np.float64).reshape(-1),
        cylinder=cylinder,
        valid=np.asarray(obs.valid, bool).reshape(-1),
        proj=proj,
    )


def _valid_only(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The same field without its padded slots (they contribute exactly zero anyway)."""
    keep = arrays["valid"]
    return {k: (v[keep] if k in ("position", "velocity", "radius", "cylinder", "valid", "proj") else v)
            for k, v in arrays.items()}


def _gain_values(gains: Any) -> dict[str, float]:
    names = ("gamma", "k", "k_rep", "d_s", "k_att", "eta")
    out = {}
    for name in names:
        value = np.asarray(gains[name], np.float64)
        if value.ndim != 0:
            raise ValueError(f"oracle_rollout takes one gain setting; gains.{name} has shape {value.shape}")
        out[name] = float(value)
    return out


# --------------------------------------------------------------------------------------------
# potentials and forces (SPEC 3), vectorised over the obstacles of one field and over any
# leading batch axes (p (..., 3), obstacle arrays (..., M, ...)): the per-field oracle calls them
# with none, the vectorised peer (jaxapf.bench.vectorised) with one axis of fields
# --------------------------------------------------------------------------------------------


def _safe_norm(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(|r|_safe, active)`` over the last axis; ``active`` is False where the floor binds."""
    sq = (r * r).sum(axis=-1)
    return np.sqrt(np.maximum(sq, _TINY)), sq > _TINY


def _floored(d: np.ndarray, d_min: float) -> tuple[np.ndarray, np.ndarray]:
    """Smooth clearance floor and its derivative: ``d`` above ``d_min``, ``d_min²/(2 d_min - d)`` below."""
    below = d < d_min
    denom = 2.0 * d_min - np.minimum(d, d_min)
    value = np.where(below, d_min * d_min / denom, d)
    slope = np.where(below, d_min * d_min / denom**2, 1.0)
    return value, slope


def _rep_terms(p, v, t, arrays, gains, sim):
    """Per-obstacle ``U_rep`` (..., M), ``∇U_rep`` (..., M, 3), ``ω`` (..., M), ``∇ω`` (..., M, 3);
    masked by the caller."""
    centres = arrays["position"] + arrays["velocity"] * t
    proj = arrays["proj"]  # diag(P): drops z for a cylinder

    # clearance d = |P(p - p_o)| - rho - r_uav and its gradient P r/|r| = r/|r| (r is projected)
    r = proj * (p[..., None, :] - centres)
    dist, active = _safe_norm(r)
    d = dist - arrays["radius"] - sim.vehicle.r_uav
    grad_d = np.where(active[..., None], r / dist[..., None], 0.0)  # safe_norm's gradient vanishes below its floor

    # U_rep = ½ k_rep (1/d̃ - 1/d_s)² for d̃ <= d_s, d̃ the floored clearance
    d_fl, slope = _floored(d, sim.planner.d_min)
    inside = d_fl <= gains["d_s"]
    gap = np.where(inside, 1.0 / d_fl - 1.0 / gains["d_s"], 0.0)
    u_rep = 0.5 * gains["k_rep"] * gap * gap
    grad_u = (-gains["k_rep"] * gap / (d_fl * d_fl) * slope)[..., None] * grad_d

    if sim.planner.method == "basic":
        return u_rep, grad_u, np.ones_like(u_rep), np.zeros_like(grad_u)

    # line of sight s = σ P (p_o - p), n = s/|s|;  ∇_p (a·n) = -σ P (a - (a·n) n)/|s| for fixed a
    sigma = 1.0 if sim.planner.convention == "intent" else -1.0
    sight = (-sigma) * r  # r = P (p - p_o)
    s_norm, s_active = _safe_norm(sight)
    n = sight / s_norm[..., None]
    scale = (-sigma / s_norm)[..., None] * proj

    def grad_dot(a, a_dot_n):  # a (..., M, 3), a_dot_n (..., M)
        tangential = a - a_dot_n[..., None] * n * s_active[..., None]
        return scale * tangential

    v_m = v[..., None, :]  # the vehicle's velocity against every obstacle
    speed = np.sqrt((v * v).sum(axis=-1) + sim.planner.eps_v**2)[..., None]
    v_n = (n * v_m).sum(axis=-1)
    cos_theta = v_n / speed
    half_gamma = 0.5 * gains["gamma"]
    w_dir = 1.0 + half_gamma * (1.0 + cos_theta)
    grad_w_dir = (half_gamma / speed)[..., None] * grad_dot(v_m, v_n)
    if sim.planner.method == "direction":
        return u_rep, grad_u, w_dir, grad_w_dir

    rel = v_m - arrays["velocity"]
    c = (rel * n).sum(axis=-1)
    tc = np.tanh(c)
    w_vel = 2.0 + gains["k"] * tc
    grad_w_vel = (gains["k"] * (1.0 - tc * tc))[..., None] * grad_dot(rel, c)
    omega = w_dir * w_vel
    grad_omega = grad_w_dir * w_vel[..., None] + w_dir[..., None] * grad_w_vel
    return u_rep, grad_u, omega, grad_omega


def _attractive(p, goal, k_att, att_cap):
    """``U_att`` (...) and ``∇U_att`` (..., 3): quadratic, linear beyond ``att_cap`` (if set)."""
    e = p - goal
    dist, active = _safe_norm(e)
    u = 0.5 * k_att * dist**2
    grad = np.where(active[..., None], k_att * e, 0.0)
    if att_cap is None:
        return u, grad
    far = dist > att_cap
    return (np.where(far, k_att * (att_cap * dist - 0.5 * att_cap**2), u),
            np.where(far[..., None], k_att * att_cap * e / dist[..., None], grad))


def total_potential(p: np.ndarray, v: np.ndarray, t: float, arrays: dict, gains: dict, sim: Any) -> float:
    """``U_att + Σ_o ω U_rep`` at ``p`` (numpy; ``arrays``/``gains`` as built by :func:`oracle_rollout`)."""
    u_att, _ = _attractive(p, arrays["goal"], gains["k_att"], sim.planner.att_cap)
    u_rep, _, omega, _ = _rep_terms(p, v, t, arrays, gains, sim)
    return u_att + np.sum(np.where(arrays["valid"], omega * u_rep, 0.0), axis=-1)


def total_force(p: np.ndarray, v: np.ndarray, t: float, arrays: dict, gains: dict, sim: Any) -> np.ndarray:
    """Analytic ``-∇_p`` of :func:`total_potential`: ``-∇U_att - Σ_o (ω ∇U_rep + U_rep ∇ω)``."""
    _, grad_att = _attractive(p, arrays["goal"], gains["k_att"], sim.planner.att_cap)
    u_rep, grad_u, omega, grad_omega = _rep_terms(p, v, t, arrays, gains, sim)
    per_obstacle = omega[..., None] * grad_u + u_rep[..., None] * grad_omega
    per_obstacle = np.where(arrays["valid"][..., None], per_obstacle, 0.0)
    return -(grad_att + np.sum(per_obstacle, axis=-2))


# --------------------------------------------------------------------------------------------
# APF reference (SPEC 4)
# --------------------------------------------------------------------------------------------


def _saturate(u: np.ndarray, limit: float) -> np.ndarray:
    norm, _ = _safe_norm(u)
    return u * np.minimum(1.0, limit / norm)[..., None]


def apf_reference(x: np.ndarray, t: float, arrays: dict, gains: dict, sim: Any, horizon: int) -> np.ndarray:
    """Reference states (..., N+1, 6) for ``x(k..k+N)`` (``x`` (..., 6)): the saturated gradient
    flow from ``x`` at ``t``, obstacles extrapolated at constant velocity, zero velocity reference
    (or the flow velocities with ``sim.planner.reference_velocity``)."""
    p, v = x[..., :3], x[..., 3:]
    positions, velocities = [p], [v]
    for i in range(horizon):
        force = total_force(p, v, t + i * sim.episode.dt, arrays, gains, sim)
        u = _saturate(gains["eta"] * force, sim.vehicle.v_max)
        p, v = p + sim.episode.dt * u, u
        positions.append(p)
        velocities.append(u)
    ref = np.zeros(x.shape[:-1] + (horizon + 1, 6), x.dtype)
    ref[..., :3] = np.stack(positions, axis=-2)
    if sim.planner.reference_velocity:
        ref[..., 3:] = np.stack(velocities, axis=-2)
    return ref


# --------------------------------------------------------------------------------------------
# condensed MPC solved by OSQP (SPEC 4)
# --------------------------------------------------------------------------------------------


def _axis3(value) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, np.float64), (3,)).astype(np.float64)


class CondensedMPC:
    """The full 3N-variable condensed MPC QP of one episode, set up once in OSQP.

    Decision vector ``z = [U; s]`` with ``U = [a(k); …; a(k+N-1)]`` (3N) and the velocity slacks
    ``s`` (3N, one per predicted velocity component of ``v(k+1..k+N)``; absent when ρ = 0).
    """

    def __init__(self, mpc: Any, sim: Any, *, eps: float = 1e-7, max_iter: int = 50_000):
        osqp = require_osqp()
        n, dt = mpc.horizon, sim.episode.dt
        self.horizon, self.a_max, self.v_max, self.rho = n, sim.vehicle.a_max, sim.vehicle.v_max, float(mpc.v_penalty)

        eye3, zero3 = np.eye(3), np.zeros((3, 3))
        a = np.block([[eye3, dt * eye3], [zero3, eye3]])
        b = np.vstack([0.5 * dt * dt * eye3, dt * eye3])
        powers = [np.eye(6)]
        for _ in range(n):
            powers.append(a @ powers[-1])
        self.big_m = np.vstack(powers)  # (6(N+1), 6)
        c = np.zeros((6 * (n + 1), 3 * n))
        for i in range(1, n + 1):
            for j in range(i):
                c[6 * i:6 * i + 6, 3 * j:3 * j + 3] = powers[i - 1 - j] @ b
        self.c = c
        q = np.concatenate([_axis3(mpc.q_pos), _axis3(mpc.q_vel)])
        f = np.concatenate([_axis3(mpc.f_pos), _axis3(mpc.f_vel)])
        self.q_aug = np.concatenate([np.zeros(6), np.tile(q, n - 1), f])
        r_aug = np.tile(_axis3(mpc.r), n)
        self.h = c.T @ (self.q_aug[:, None] * c) + np.diag(r_aug)
        vel_rows = np.concatenate([np.arange(6 * i + 3, 6 * i + 6) for i in range(1, n + 1)])
        self.c_v, self.m_v = c[vel_rows], self.big_m[vel_rows]

        nu = 3 * n
        if self.rho > 0:
            p_mat = sp.block_diag([sp.csc_matrix(self.h), self.rho * sp.identity(nu)], format="csc")
            i_u, i_s, c_v = sp.identity(nu), sp.identity(nu), sp.csc_matrix(self.c_v)
            zero = sp.csc_matrix((nu, nu))
            a_mat = sp.bmat([[i_u, zero], [zero, i_s], [c_v, -i_s], [c_v, i_s]], format="csc")
        else:
            p_mat = sp.csc_matrix(self.h)
            a_mat = sp.identity(nu, format="csc")
        self.n_var = p_mat.shape[0]
        lo, hi = self._bounds(np.zeros(6))
        # OSQP >= 1.0 calls the polishing switch "polishing"; 0.6.x called it "polish".
        major = _osqp_major(osqp)
        polish_key = "polishing" if major >= 1 else "polish"
        # OSQP >= 1.0 warns unless told whether to raise; we check the status ourselves.
        self._solve_kwargs = {"raise_error": False} if major >= 1 else {}
        self.solver = osqp.OSQP()
        self.solver.setup(
            sp.triu(p_mat, format="csc"), np.zeros(self.n_var), a_mat, lo, hi,
            eps_abs=eps, eps_rel=eps, max_iter=max_iter, verbose=False, **{polish_key: True},
        )
        self.iterations = 0  # OSQP iterations summed over the solves
        self.solves = 0
        self.unpolished = 0  # solves whose polishing failed (solution then accurate to ~eps only)

    def _bounds(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nu = 3 * self.horizon
        box_lo, box_hi = np.full(nu, -self.a_max), np.full(nu, self.a_max)
        if self.rho == 0:
            return box_lo, box_hi
        v_free = self.m_v @ x0
        inf = np.full(nu, np.inf)
        lo = np.concatenate([box_lo, np.zeros(nu), -inf, -self.v_max - v_free])
        hi = np.concatenate([box_hi, inf, self.v_max - v_free, inf])
        return lo, hi

    def linear_term(self, x0: np.ndarray, x_ref: np.ndarray) -> np.ndarray:
        """``E = Cᵀ Q_aug (M x0 - X_ref)`` (3N,)."""
        return self.c.T @ (self.q_aug * (self.big_m @ x0 - x_ref.reshape(-1)))

    def solve(self, x0: np.ndarray, x_ref: np.ndarray) -> np.ndarray:
        """The optimal input sequence (N, 3) for state ``x0`` (6,) and reference ``x_ref`` (N+1, 6)."""
        q = np.zeros(self.n_var)
        q[: 3 * self.horizon] = self.linear_term(x0, x_ref)
        lo, hi = self._bounds(x0)
        self.solver.update(q=q, l=lo, u=hi)
        res = self.solver.solve(**self._solve_kwargs)
        status = str(res.info.status).lower()
        if "solved" not in status or "inaccurate" in status:
            raise RuntimeError(f"OSQP did not solve the MPC QP: {res.info.status}")
        self.iterations += int(res.info.iter)
        self.solves += 1
        self.unpolished += int(getattr(res.info, "status_polish", 1) != 1)
        u = np.clip(np.asarray(res.x[: 3 * self.horizon]), -self.a_max, self.a_max)
        return u.reshape(self.horizon, 3)


def _osqp_major(osqp) -> int:
    try:
        return int(str(osqp.__version__).split(".")[0])
    except (AttributeError, ValueError):  # pragma: no cover
        return 1


# --------------------------------------------------------------------------------------------
# the closed loop
# --------------------------------------------------------------------------------------------


def oracle_rollout(scenario: Any, gains: Any, sim: Any, mpc: Any, *, eps: float = 1e-7) -> dict[str, np.ndarray]:
    """Simulate one episode with numpy + OSQP, exactly the loop of :func:`jaxapf.engine.rollout`.

    Each step ``k`` (``t_k = k Δt``): APF reference from the current state, MPC QP solved by OSQP,
    first acceleration applied, plant stepped exactly (double integrator, piecewise-constant a).

    Args:
      scenario: one :class:`~jaxapf.datatypes.Scenario` (no batch axis); leaves are converted with
        ``np.asarray`` to float64.
      gains: one :class:`~jaxapf.gains.Gains` setting (scalar leaves).
      sim, mpc: :class:`~jaxapf.config.SimConfig`, :class:`~jaxapf.config.MPCConfig`
        (``mpc.iters`` is ignored: OSQP solves each QP to tolerance ``eps``).
      eps: OSQP's ``eps_abs`` and ``eps_rel`` (solution polishing is on).

    Returns:
      ``time`` (T+1,), ``position`` (T+1, 3), ``velocity`` (T+1, 3), ``control`` (T, 3), float64.

    Raises:
      ImportError: OSQP is not installed (``pip install "jaxapf[bench]"``).
      ConfigError: a planner, filter, plant, sensor, disturbance, estimator or traced MPC weights the oracle
        does not know.
    """
    require_osqp()
    known = {"method": ("basic", "direction", "direction_velocity"), "filter": ("none",),
             "plant": ("double_integrator",), "sensor": ("ideal",), "disturbance": ("none",), "estimator": ("none",),
             "mpc_weights": ("static",), "tracking": ("mpc",)}
    for key, names in known.items():
        check_choice(f"sim.{key} (the numpy + OSQP oracle)", sim.flat()[key], names)
    # Padded slots contribute exactly zero (see total_force's mask), so drop them up front.
    arrays = _valid_only(_scenario_arrays(scenario))
    g = _gain_values(gains)
    qp = CondensedMPC(mpc, sim, eps=eps)
    steps, dt = sim.episode.steps, sim.episode.dt

    x = np.concatenate([arrays["start"], np.zeros(3)])
    states = np.zeros((steps + 1, 6))
    controls = np.zeros((steps, 3))
    states[0] = x
    for k in range(steps):
        t = k * dt
        x_ref = apf_reference(x, t, arrays, g, sim, mpc.horizon)
        a = qp.solve(x, x_ref)[0]
        p, v = x[:3], x[3:]
        x = np.concatenate([p + dt * v + 0.5 * dt * dt * a, v + dt * a])
        states[k + 1] = x
        controls[k] = a
    return dict(
        time=np.arange(steps + 1, dtype=np.float64) * dt,
        position=states[:, :3],
        velocity=states[:, 3:],
        control=controls,
    )
