r"""The strongest CPU peer a user would write without jaxapf: the closed loop in numpy, vectorised over fields.

A researcher who knows numpy would not loop over fields one at a time (:mod:`jaxapf.bench.oracle`,
numpy + OSQP per field); they would carry the whole batch of fields through the control loop as
arrays. This module is that program, written for speed: one Python loop over control steps, the
fields on the last (contiguous) axis of every array (obstacles ``(M, F)``, states ``(6, F)``,
inputs ``(N, 3, F)``), so sums over obstacles add contiguous rows, and every array in ``dtype``
(float32 by default, no float64 scalar anywhere).

* **APF reference** (SPEC 3-4): the saturated gradient flow over the horizon, the force of
  :func:`jaxapf.bench.oracle.total_force` written out per coordinate with the weight's gradient
  collected into three per-obstacle coefficients (``(ω∇U_rep + U_rep∇ω)`` = ``G r + W((A+B) P v -
  B P v_o)``, see :func:`_repulsion`); padded slots carry ``k_rep = 0`` and contribute exactly zero.
  Moving-obstacle terms are skipped when no obstacle of the batch moves, the clearance's floor when
  no clearance is below ``d_min``, the norm's floor when it does not bind (all exact).
* **MPC**: the engine's algorithm (:func:`jaxapf.control.solve_axes`): the per-axis condensed QP,
  FISTA with the same fixed iteration count, step ``1/L``, momentum sequence
  (:func:`jaxapf.control.mpc._momentum`) and warm start from the shifted previous solution; the
  step is folded into the matrices (``y - (1/L)∇f(y) = (I - Ĥ/L) y - ê/L + (ρ/L) C_vᵀ clip(v)``),
  so an iteration is two matrix products over all ``3F`` axis problems and a few in-place updates.
* **Plant**: the exact double-integrator step.

The per-axis matrices are set up once per configuration (by :func:`jaxapf.control.axis_problem`,
then numpy) and cached, as a user would precompute them.
Matrix products go to BLAS; ``jaxapf bench engine`` times this peer with BLAS pinned to one thread.
``tests/bench/test_vectorised.py`` checks that it reproduces the engine's trajectories (float64: to
rounding).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from ..control.mpc import _momentum
from ..validation import check_choice
from .oracle import _gain_values

__all__ = ["vectorised_rollout", "VECTORISED_METHODS"]

#: Planners the vectorised peer knows (the paper's three, on the double integrator, no filter).
VECTORISED_METHODS: tuple[str, ...] = ("basic", "direction", "direction_velocity")

_TINY = 1e-12  # floor inside every square root (safe_norm), as jaxapf.datatypes.TINY


class _Field:
    """The batch of fields, component-first with fields last, and the gains, all in ``dtype``.

    ``pos``, ``vel`` (3, M, F) obstacle centres and velocities; ``pvel`` = P v_o; ``pz`` (M, F)
    the z row of P (0 for a cylinder); ``reach`` = radius + r_uav; ``half_k_s``, ``neg_k`` =
    σ½k_rep, -k_rep on valid slots, 0 on padded ones (σ the sight's sign, see :func:`_repulsion`);
    ``goal`` (3, F); scalars in ``dtype``.
    """

    def __init__(self, scenarios: Any, gains: dict[str, float], sim: Any, dtype: Any):
        s = dtype
        obs = scenarios.obstacles
        valid = np.asarray(obs.valid, bool).T  # (M, F)
        comp = lambda a: np.ascontiguousarray(np.where(valid[None], np.asarray(a, dtype).transpose(2, 1, 0), 0))  # noqa: E731
        self.pos, self.vel = comp(obs.position), comp(obs.velocity)
        self.pz = np.where(np.asarray(obs.cylinder, bool).T, 0, 1).astype(dtype)
        self.moving = bool(np.any(self.vel))
        self.pvel = self.vel * np.stack([np.ones_like(self.pz), np.ones_like(self.pz), self.pz])
        self.reach = np.where(valid, np.asarray(obs.radius, dtype).T, 0).astype(dtype) + s(sim.vehicle.r_uav)
        self.sign = s(1.0 if sim.planner.convention == "literal" else -1.0)  # sight = sign * r, r = P(p - p_o)
        self.half_k_s = np.where(valid, self.sign * s(0.5) * s(gains["k_rep"]), 0).astype(dtype)
        self.neg_k = np.where(valid, -s(gains["k_rep"]), 0).astype(dtype)
        self.goal = np.ascontiguousarray(np.asarray(scenarios.goal, dtype).T)
        self.start = np.ascontiguousarray(np.asarray(scenarios.start, dtype).T)
        planner = sim.planner
        self.method = planner.method
        self.tiny, self.d_min, self.inv_ds = s(_TINY), s(planner.d_min), s(1.0) / s(gains["d_s"])
        self.eps_v2 = s(planner.eps_v) ** 2
        self.half_gamma, self.k = s(0.5) * s(gains["gamma"]), s(gains["k"])
        self.k_att, self.att_cap = s(gains["k_att"]), None if planner.att_cap is None else s(planner.att_cap)
        self.eta, self.v_max, self.dt = s(gains["eta"]), s(sim.vehicle.v_max), s(sim.episode.dt)
        self.zero, self.one, self.two = s(0), s(1), s(2)
        self.zero_mf = np.zeros_like(self.pz)  # np.maximum against an array is faster than against a scalar


# long: the numpy peer's hot loop, in-place passes over the arrays in one frame, as an expert writes it
def _repulsion(f: _Field, p: np.ndarray, v: np.ndarray, t: Any) -> np.ndarray:
    r"""``Σ_o ∇_p(ω U_rep)`` (3, F) for positions ``p`` and velocities ``v`` (3, F) at time ``t``.

    With ``r = P(p - p_o(t))``, the sight ``s = σ r`` (σ = -1 for ``intent``, +1 for ``literal``),
    ``n = s/|r|``, ``v_n = n·v``, ``c = n·(v - v_o)`` and ``ω = w_dir w_vel``, one obstacle's
    gradient is ``G r + W ((A+B) P v - B P v_o)`` with ``A = ½γ w_vel/|v|_ε``,
    ``B = k (1 - tanh²c) w_dir``, ``W = σ U_rep/|r|`` and ``G = (ω U_rep' - W σ(A v_n + B c))/|r|``
    (``U_rep'`` the derivative along the clearance; ``1/|r|`` in G is 0 where the norm's floor
    binds). σ is folded into ``W`` and the per-field factors, so it costs no pass over the arrays.
    """
    if f.moving:
        r = np.multiply(f.vel, t)
        r += f.pos
        np.subtract(p[:, None], r, out=r)  # r = p - p_o(t), (3, M, F)
    else:
        r = p[:, None] - f.pos
    r[2] *= f.pz  # P drops z for a cylinder
    sq = (r * r).sum(axis=0)
    floor = (sq <= f.tiny).any()  # the safe norm's floor binds only with the UAV at an obstacle's centre
    dist = np.sqrt(np.maximum(sq, f.tiny) if floor else sq)
    inv = np.divide(f.one, dist)
    ginv = inv * (sq > f.tiny) if floor else inv  # ∇|r| = r/|r|, zero below the floor
    d = dist - f.reach  # clearance
    below = d < f.d_min
    slope = None
    if below.any():  # the smooth floor d̃ = d_min²/(2 d_min - d) below d_min, slope d_min²/(2 d_min - d)²
        denom = f.two * f.d_min - d[below]
        low = f.d_min * f.d_min / denom
        d[below] = low
        slope = np.ones_like(d)
        slope[below] = low / denom
    inv_d = np.divide(f.one, d)
    gap = inv_d - f.inv_ds
    np.maximum(gap, f.zero_mf, out=gap)  # 1/d̃ - 1/d_s inside d_s, 0 outside
    coef = f.neg_k * gap  # dU_rep/dd = -k_rep gap / d̃² (times the floor's slope)
    coef *= inv_d
    coef *= inv_d
    if slope is not None:
        coef *= slope
    if f.method == "basic":
        coef *= ginv
        return (r * coef).sum(axis=1)

    w = f.half_k_s * gap  # W = σ U_rep / |r|
    w *= gap
    w *= inv
    inv_speed = f.one / np.sqrt((v * v).sum(axis=0) + f.eps_v2)  # 1/|v|_ε, (F,)
    rv = (r * v[:, None]).sum(axis=0)
    rv *= inv  # σ v_n
    w_dir = rv * (f.sign * f.half_gamma * inv_speed)  # ½γ cos θ
    w_dir += f.one + f.half_gamma
    a_coef = f.half_gamma * inv_speed  # A, (F,) for direction
    if f.method == "direction":
        omega, q = w_dir, rv * a_coef  # σ (A v_n)
        wab = w * a_coef
    else:
        if f.moving:
            c = rv - (r * f.vel).sum(axis=0) * inv  # σ c
        else:
            c = rv
        tc = np.tanh(c)  # σ tanh c
        w_vel = tc * (f.sign * f.k)
        w_vel += f.two
        omega = w_dir * w_vel
        a_coef = w_vel * a_coef  # A
        b_coef = tc * tc
        np.subtract(f.one, b_coef, out=b_coef)
        b_coef *= f.k
        b_coef *= w_dir  # B
        q = a_coef * rv
        c *= b_coef
        q += c  # σ (A v_n + B c)
        wab = a_coef + b_coef
        wab *= w
    g = omega * coef
    q *= w
    g -= q
    g *= ginv  # G
    grad = (r * g).sum(axis=1)
    sab = wab.sum(axis=0)
    grad[0] += sab * v[0]
    grad[1] += sab * v[1]
    grad[2] += (wab * f.pz).sum(axis=0) * v[2]
    if f.moving and f.method != "direction":
        b_coef *= w
        grad -= (f.pvel * b_coef).sum(axis=1)
    return grad


def _reference(f: _Field, x: np.ndarray, t: Any, horizon: int, with_velocity: bool
               ) -> tuple[np.ndarray, np.ndarray | None]:
    """The APF flow from the states ``x`` (6, F) at ``t``: positions (N+1, 3, F) and, when the
    reference carries them, velocities (N+1, 3, F)."""
    pos = np.empty((horizon + 1,) + x[:3].shape, x.dtype)
    vel = np.zeros_like(pos) if with_velocity else None
    p, v = x[:3], x[3:]
    pos[0] = p
    if with_velocity:
        vel[0] = v
    for i in range(horizon):
        e = p - f.goal
        sq = (e * e).sum(axis=0)
        grad = e * np.where(sq > f.tiny, f.k_att, f.zero)
        if f.att_cap is not None:
            dist = np.sqrt(np.maximum(sq, f.tiny))
            grad = np.where(dist > f.att_cap, f.k_att * f.att_cap * e / dist, grad)
        grad += _repulsion(f, p, v, t + x.dtype.type(i) * f.dt)
        u = grad * (-f.eta)
        norm = np.sqrt(np.maximum((u * u).sum(axis=0), f.tiny))
        u *= np.minimum(f.one, f.v_max / norm)
        p = pos[i + 1] = p + f.dt * u
        v = u
        if with_velocity:
            vel[i + 1] = u
    return pos, vel


class _Axes:
    """The per-axis condensed MPC with the FISTA step folded in, as ``dtype`` matrices.

    An iteration works on the buffer ``[x0; y; clip(v)]`` (2N+2, 3, F) of every axis problem:
    ``a1 = [M_v | C_v]`` (N, N+2) gives the predicted velocities ``v_free + C_v y``, and per axis
    ``j`` (one matrix when the three axes have the same weights, as in the engine)
    ``a2 = [I - Ĥ_j/L_j | (ρ/L_j) C_vᵀ]`` (N, 2N) gives ``y - (∇f(y) - ê)/L_j``.
    ``cq`` = ``C_jᵀ Q_aug,j`` (N, 2(N+1)) and ``ct`` = ``ρ C_vᵀ`` make ``ê``; ``m`` (2(N+1), 2) is
    the free response, ``step`` (3, 1) ``1/L_j``.
    """

    def __init__(self, dt: float, mpc: Any, a_max: float, v_max: float, dtype: Any, setup: Any):
        from ..control import axis_problem
        from ..world import discrete_matrices

        prob = axis_problem(mpc, *discrete_matrices(dt, 1, setup))
        as64 = lambda a: np.asarray(a, np.float64)  # noqa: E731
        n = mpc.horizon
        kernel, m, c, q_aug = as64(prob.kernel), as64(prob.m), as64(prob.c), as64(prob.q_aug)
        rho, step = float(prob.v_penalty), 1.0 / as64(prob.lipschitz)
        c_vel = kernel[0, n:]
        self.shared = kernel.shape[0] == 1
        self.a1 = np.concatenate([m[3::2], c_vel], axis=1).astype(dtype)
        self.a2 = [np.concatenate([np.eye(n) - step[j] * kernel[j, :n], step[j] * rho * c_vel.T], axis=1).astype(dtype)
                   for j in range(kernel.shape[0])]
        self.cq = [(c.T * q_aug[j]).astype(dtype) for j in range(kernel.shape[0])]
        self.ct = (rho * c_vel.T).astype(dtype)
        self.m = m.astype(dtype)
        self.step = step.astype(dtype)[:, None]
        self.n = n
        self.betas = [dtype(b) for b in _momentum(mpc.iters)]  # the engine's FISTA coefficients
        self.a_max, self.v_max = dtype(a_max), dtype(v_max)

    def _per_axis(self, mats: list[np.ndarray], a: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``mats[j] @ a[:, j]`` for the three axes of ``a`` (K, 3, F) into ``out`` (R, 3, F)."""
        if self.shared:
            np.matmul(mats[0], a.reshape(a.shape[0], -1), out=out.reshape(out.shape[0], -1))
        else:
            for j in range(3):
                np.matmul(mats[j], a[:, j], out=out[:, j])
        return out

    def solve(self, x: np.ndarray, ref_pos: np.ndarray, ref_vel: np.ndarray | None, warm: np.ndarray
              ) -> np.ndarray:
        """The MPC inputs (N, 3, F) of every field: states ``x`` (6, F), reference (N+1, 3, F),
        warm start (N, 3, F)."""
        n, fields = self.n, x.shape[-1]
        dev = (self.m @ x.reshape(2, -1)).reshape(n + 1, 2, 3, fields)  # M x0 per axis
        v_free = dev[1:, 1].reshape(n, -1)
        b = (self.ct @ v_free).reshape(warm.shape)  # ρ C_vᵀ v_free
        dev[:, 0] -= ref_pos
        if ref_vel is not None:
            dev[:, 1] -= ref_vel
        b += self._per_axis(self.cq, dev.reshape(2 * (n + 1), 3, fields), np.empty_like(warm))  # + e
        b *= -self.step  # -ê/L
        work = np.empty((2 * n + 2,) + warm.shape[1:], warm.dtype)  # [x0; y; clip(v)]
        work[:2] = x.reshape(2, 3, fields)
        y, vel = work[2:n + 2], work[n + 2:]
        u = np.clip(warm, -self.a_max, self.a_max)
        y[...] = u
        u_next, diff = np.empty_like(u), np.empty_like(u)
        for beta in self.betas:
            np.matmul(self.a1, work[:n + 2].reshape(n + 2, -1), out=vel.reshape(n, -1))  # v_free + C_v y
            np.clip(vel, -self.v_max, self.v_max, out=vel)
            self._per_axis(self.a2, work[2:], u_next)  # y - (Ĥ y - ρ C_vᵀ clip(v)) / L
            u_next += b
            np.clip(u_next, -self.a_max, self.a_max, out=u_next)
            np.subtract(u_next, u, out=diff)
            diff *= beta
            np.add(u_next, diff, out=y)
            u, u_next = u_next, u
        return u


@functools.lru_cache(maxsize=8)
def _axes(dt: float, mpc: Any, a_max: float, v_max: float, dtype: Any, setup: Any) -> _Axes:
    """The MPC matrices of a configuration (built in jax's default float ``setup``), set up once
    per configuration, as a user would precompute them."""
    return _Axes(dt, mpc, a_max, v_max, dtype, setup)


def vectorised_rollout(scenarios: Any, gains: Any, sim: Any, mpc: Any, *, dtype: Any = np.float32
                       ) -> dict[str, np.ndarray]:
    """Every field of the batch ``scenarios`` (leading axis F) flown with one gain setting ``gains``.

    Returns ``time`` (T+1,), ``position``/``velocity`` (F, T+1, 3) and ``control`` (F, T, 3) in
    ``dtype``: the loop of :func:`jaxapf.engine.rollout` (APF reference, FISTA MPC with
    ``mpc.iters`` iterations, exact double-integrator step) for all fields at once.

    Raises :class:`~jaxapf.validation.ConfigError` for a planner, filter, plant, sensor, disturbance,
    estimator or traced MPC weights it does not know (it flies the paper's ideal world only).
    """
    known = {"method": VECTORISED_METHODS, "filter": ("none",), "plant": ("double_integrator",), "sensor": ("ideal",),
             "disturbance": ("none",), "estimator": ("none",),
             "mpc_weights": ("static",), "tracking": ("mpc",)}
    for key, names in known.items():
        check_choice(f"sim.{key} (the vectorised numpy peer)", sim.flat()[key], names)
    import jax.numpy as jnp

    dtype = np.dtype(dtype).type
    field = _Field(scenarios, _gain_values(gains), sim, dtype)
    axes = _axes(sim.episode.dt, mpc, sim.vehicle.a_max, sim.vehicle.v_max, dtype, jnp.result_type(float))
    steps, dt, half_dt2 = sim.episode.steps, dtype(sim.episode.dt), dtype(0.5 * sim.episode.dt * sim.episode.dt)
    fields = field.start.shape[-1]
    states = np.zeros((steps + 1, 6, fields), dtype)
    controls = np.empty((steps, 3, fields), dtype)
    states[0, :3] = field.start
    warm = np.zeros((mpc.horizon, 3, fields), dtype)
    for k in range(steps):
        x = states[k]
        ref_pos, ref_vel = _reference(field, x, dtype(k) * dt, mpc.horizon, sim.planner.reference_velocity)
        u = axes.solve(x, ref_pos, ref_vel, warm)
        a = controls[k] = u[0]
        states[k + 1, :3] = x[:3] + dt * x[3:] + half_dt2 * a
        states[k + 1, 3:] = x[3:] + dt * a
        warm[:-1], warm[-1] = u[1:], u[-1]  # shift, repeating the last input
    out = np.ascontiguousarray(states.transpose(2, 0, 1))
    return dict(time=np.arange(steps + 1, dtype=dtype) * dt, position=out[..., :3], velocity=out[..., 3:],
                control=np.ascontiguousarray(controls.transpose(2, 0, 1)))
