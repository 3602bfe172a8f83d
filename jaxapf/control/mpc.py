r"""Condensed box-constrained MPC solved by accelerated projected gradient (paper eq. 8–12, SPEC 4).

The prediction and cost matrices of the condensed QP (:func:`prediction_matrices`, :func:`condensed_qp`),
FISTA with a fixed iteration count and a warm start (:func:`fista`, :func:`solve_box_qp`), and the closed
loop's solver: with diagonal per-axis weights the double integrator's 3N-dimensional problem is three
N-dimensional ones (:class:`AxisProblem`, :func:`solve_axes`), the velocity limit a smooth convex penalty
so the feasible set stays the acceleration box. The derivation: docs/spec.md §4.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..config import MPCConfig
from ..gains import GainSpec, declare_gains
from ..world.double_integrator import discrete_matrices

__all__ = [
    "MPC_GAINS",
    "scales_set",
    "prediction_matrices",
    "augmented_weights",
    "condensed_hessian",
    "condensed_linear",
    "condensed_qp",
    "fista",
    "solve_box_qp",
    "AxisProblem",
    "axis_problem",
    "solve_axes",
    "shift_warm_start",
]


_SCALED = "with sim.mpc_weights = gains"
#: Traced scales of the MPC's weights, read with ``sim.mpc_weights = "gains"`` (:func:`axis_problem`):
#: the weight of :class:`MPCConfig` times its scale; 1 leaves the weight as it is.
MPC_GAINS: tuple[GainSpec, ...] = declare_gains(
    GainSpec("mpc_pos", 1.0, low=0.0, symbol="s_p", doc=f"MPC: scale of the stage position weight q_pos ({_SCALED})"),
    GainSpec("mpc_vel", 1.0, low=0.0, symbol="s_v", doc=f"MPC: scale of the stage velocity weight q_vel ({_SCALED})"),
    GainSpec("mpc_terminal", 1.0, low=0.0, symbol="s_f",
             doc=f"MPC: scale of the terminal weights f_pos and f_vel ({_SCALED})"),
    GainSpec("mpc_input", 1.0, low=0.0, low_open=True, symbol="s_r",
             doc=f"MPC: scale of the input weight r ({_SCALED})"),
    GainSpec("mpc_speed", 1.0, low=0.0, symbol="s_ρ",
             doc=f"MPC: scale of the velocity-limit penalty v_penalty ({_SCALED})"),
)


def scales_set(values: Any, varied: Any = ()) -> tuple[str, ...]:
    """The :data:`MPC_GAINS` that ``values`` (gain name -> a value or a sequence of values) sets to
    something other than 1, or that ``varied`` names (sampled or tuned: any value): the scales that need
    ``sim.mpc_weights = "gains"`` (a scale of 1 leaves its weight as it is, so a gains file that lists
    every gain at its default does not switch the mode)."""
    varied = set(varied)
    return tuple(g.name for g in MPC_GAINS if g.name in varied or (
        g.name in values and np.any(np.asarray(values[g.name], np.float64) != 1.0)))


def prediction_matrices(a: Array, b: Array, horizon: int) -> tuple[Array, Array]:
    """``(M, C)`` of paper eq. 8 for ``x(k+1) = a x(k) + b u(k)``.

    Shapes: ``M`` (n(N+1), n), ``C`` (n(N+1), m N); block row ``i`` predicts ``x(k+i)``.
    """
    n, m = b.shape
    powers = [jnp.eye(n, dtype=a.dtype)]
    for _ in range(horizon):
        powers.append(a @ powers[-1])
    big_m = jnp.concatenate(powers, axis=0)
    zero = jnp.zeros((n, m), a.dtype)
    rows = [
        jnp.concatenate([powers[i - 1 - j] @ b if j < i else zero for j in range(horizon)], axis=1)
        for i in range(horizon + 1)
    ]
    return big_m, jnp.concatenate(rows, axis=0)


def augmented_weights(q: Array, f: Array, horizon: int) -> Array:
    """Diagonal of ``Q_aug = blkdiag(0, Q, …, Q, F)`` for state weights ``q`` and terminal ``f`` (n,)."""
    q, f = jnp.asarray(q), jnp.asarray(f)
    return jnp.concatenate([jnp.zeros_like(q), jnp.tile(q, horizon - 1), f])


def condensed_hessian(c: Array, q_aug: Array, r_aug: Array) -> Array:
    """``H = Cᵀ Q_aug C + R_aug`` (paper eq. 11) for diagonal ``Q_aug``, ``R_aug`` given as vectors."""
    return c.T @ (q_aug[:, None] * c) + jnp.diag(r_aug)


def condensed_linear(m: Array, c: Array, q_aug: Array, x0: Array, x_ref: Array) -> Array:
    """``E = Cᵀ Q_aug (M x0 - X_ref)`` with ``x_ref`` of shape (N+1, n) (paper eq. 11)."""
    return c.T @ (q_aug * (m @ x0 - x_ref.reshape(-1)))


def condensed_qp(
    x0: Array,
    x_ref: Array,
    *,
    dt: float,
    horizon: int,
    q_pos,
    q_vel,
    f_pos,
    f_vel,
    r,
) -> tuple[Array, Array]:
    """``(H, E)`` of the full 3-axis condensed MPC QP (paper eq. 8–12).

    Args:
      x0: (6,) current state ``[p, v]``.
      x_ref: (horizon+1, 6) reference for ``x(k..k+N)``.
      q_pos, q_vel: stage weights on x(k+1..k+N-1) (scalar or per axis).
      f_pos, f_vel: terminal weights on x(k+N) (scalar or per axis).
      r: input weight (scalar or per axis).

    Returns:
      ``H`` (3N, 3N) and ``E`` (3N,) for ``U = [a(k); a(k+1); …]``, ``a = (a_x, a_y, a_z)``.
    """
    dtype = jnp.result_type(x0, x_ref)
    axes = lambda w: jnp.broadcast_to(jnp.asarray(w, dtype), (3,))  # noqa: E731
    a, b = discrete_matrices(dt, 3, dtype)
    big_m, c = prediction_matrices(a, b, horizon)
    q_aug = augmented_weights(
        jnp.concatenate([axes(q_pos), axes(q_vel)]), jnp.concatenate([axes(f_pos), axes(f_vel)]), horizon
    )
    r_aug = jnp.tile(axes(r), horizon)
    return condensed_hessian(c, q_aug, r_aug), condensed_linear(big_m, c, q_aug, x0, x_ref)


def _momentum(iters: int) -> np.ndarray:
    """FISTA extrapolation coefficients (t_k - 1)/t_{k+1}; data independent, so precomputed."""
    t, out = 1.0, []
    for _ in range(iters):
        t_next = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
        out.append((t - 1.0) / t_next)
        t = t_next
    return np.asarray(out)


def fista(grad: Callable[[Array], Array], init: Array, lower: Array | float, upper: Array | float, *,
          step: Array, iters: int) -> Array:
    r"""FISTA with constant step: minimise a smooth convex ``f`` (gradient ``grad``) over a box.

    .. math:: U_{j+1} = \Pi_{box}(Y_j - \text{step}\,\nabla f(Y_j)), \quad
              Y_{j+1} = U_{j+1} + \tfrac{t_j - 1}{t_{j+1}} (U_{j+1} - U_j)

    for a fixed ``iters`` (a ``lax.scan``, so it vmaps and reverse-differentiates; the projection's
    derivative is that of ``clip``). ``init`` is projected onto the box first; ``step`` must be at
    most ``1/L`` for the Lipschitz constant ``L`` of ``grad`` (it may be an array broadcasting
    against ``init``, e.g. one step per row).
    """
    u0 = jnp.clip(init, lower, upper)

    def body(carry, beta):
        u, y = carry
        u_next = jnp.clip(y - step * grad(y), lower, upper)
        return (u_next, u_next + beta * (u_next - u)), None

    betas = jnp.asarray(_momentum(iters), init.dtype)
    (u, _), _ = jax.lax.scan(body, (u0, u0), betas)
    return u


def solve_box_qp(
    h: Array,
    e: Array,
    lower: Array | float,
    upper: Array | float,
    *,
    iters: int,
    init: Array | None = None,
    lipschitz: Array | None = None,
) -> Array:
    r"""Minimise ``½ Uᵀ H U + Eᵀ U`` s.t. ``lower <= U <= upper`` by :func:`fista` (paper eq. 12).

    Args:
      h: (n, n) symmetric positive (semi)definite.
      e: (n,) linear term.
      lower, upper: box bounds, broadcastable to (n,).
      iters: fixed number of iterations.
      init: warm start (n,); zero by default.
      lipschitz: ``L``; default ``λ_max(H)``.
    """
    if lipschitz is None:
        lipschitz = jnp.linalg.eigvalsh(h)[-1]
    init = jnp.zeros_like(e) if init is None else init
    return fista(lambda y: h @ y + e, init, lower, upper, step=1.0 / lipschitz, iters=iters)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class AxisProblem:
    r"""The state-independent part of the per-axis MPC QPs (built once per episode).

    Per axis ``j`` the smooth objective is
    :math:`f_j(u) = \tfrac12 u^\top H_j u + e_j^\top u + \tfrac12\rho\sum_i \max(|v_i| - v_{max}, 0)^2`
    with predicted velocities :math:`v = v_{free} + C_v u`, whose gradient is

    .. math:: \nabla f_j(u) = \hat H_j u + \hat e_j - \rho C_v^\top \mathrm{clip}(v, \pm v_{max}),
              \quad \hat H_j = H_j + \rho C_v^\top C_v, \quad \hat e_j = e_j + \rho C_v^\top v_{free}

    so one product with the stacked ``[Ĥ_j; C_v]`` and one with ``C_vᵀ`` make a FISTA step.

    Attributes:
      m: (2(N+1), 2) prediction of the free response of one axis.
      c: (2(N+1), N) forced response of one axis.
      q_aug: (3, 2(N+1)) diagonal of ``Q_aug`` per axis.
      h: (3, N, N) Hessian ``H_j`` per axis.
      kernel: ``[Ĥ_j; C_v]`` stacked, (A, 2N, N): A = 1 when the three axes have the same weights
        (one matrix product serves all three), else A = 3.
      lipschitz: (3,) ``λ_max(H_j) + ρ λ_max(C_vᵀ C_v)`` per axis.
      v_penalty: ρ.
    """

    m: Array
    c: Array
    q_aug: Array
    h: Array
    kernel: Array
    lipschitz: Array
    v_penalty: Array


def axis_problem(mpc: MPCConfig, a: Array, b: Array, gains: Any = None) -> AxisProblem:
    """Per-axis condensed matrices for :class:`MPCConfig` ``mpc`` and the model ``x(k+1) = a x(k) + b u(k)``
    of one axis on ``(p, v)`` (a (2, 2), b (2, 1): the plant's
    :meth:`~jaxapf.world.Plant.linear_model`, the double integrator by default). With ``gains`` (a
    :class:`~jaxapf.gains.Gains` holding :data:`MPC_GAINS`) each weight is scaled by its traced gain."""
    n = mpc.horizon
    dtype = a.dtype
    big_m, c = prediction_matrices(a, b, n)
    weights = ("q_pos", "q_vel", "f_pos", "f_vel", "r")
    scale = {} if gains is None else {"q_pos": gains.mpc_pos, "q_vel": gains.mpc_vel, "f_pos": gains.mpc_terminal,
                                      "f_vel": gains.mpc_terminal, "r": gains.mpc_input,
                                      "v_penalty": gains.mpc_speed}
    def w(name: str) -> Array:  # (3,) per axis; static weights stay constants
        weight = jnp.asarray(getattr(mpc, name), dtype)
        return weight * scale[name] if name in scale else weight

    q_aug = jax.vmap(augmented_weights, in_axes=(0, 0, None))(
        jnp.stack([w("q_pos"), w("q_vel")], -1), jnp.stack([w("f_pos"), w("f_vel")], -1), n
    )
    r_aug = jnp.repeat(w("r")[:, None], n, axis=1)
    h = jax.vmap(condensed_hessian, in_axes=(None, 0, 0))(c, q_aug, r_aug)
    c_vel = c[3::2]  # predicted velocities v(k+1..k+N)
    rho = w("v_penalty")
    shared = all(len(set(getattr(mpc, name))) == 1 for name in weights)  # static: from the config
    distinct = h[:1] if shared else h
    kernel = jnp.concatenate(
        [distinct + rho * (c_vel.T @ c_vel), jnp.broadcast_to(c_vel, distinct.shape)], axis=1)
    pen = rho * jnp.linalg.eigvalsh(c_vel.T @ c_vel)[-1]
    lipschitz = jnp.linalg.eigvalsh(h)[:, -1] + pen
    return AxisProblem(m=big_m, c=c, q_aug=q_aug, h=h, kernel=kernel, lipschitz=lipschitz, v_penalty=rho)


def solve_axes(
    prob: AxisProblem,
    x0: Array,
    x_ref: Array,
    warm: Array,
    *,
    a_max: float,
    v_max: float,
    iters: int,
    shift: Array | None = None,
) -> Array:
    """Solve the three per-axis MPC QPs together by :func:`fista`; returns the inputs (3, N).

    Args:
      x0: (6,) current state ``[p, v]``.
      x_ref: (N+1, 6) reference for ``x(k..k+N)``.
      warm: (3, N) warm start (previous solution shifted, see :func:`shift_warm_start`).
      shift: (3,) estimated disturbance ``d̂``: the inputs are then total accelerations, in the box
        ``[-a_max + d̂, a_max + d̂]`` per axis (offset-free MPC, :mod:`jaxapf.control.estimators`).
    """
    n = warm.shape[-1]
    x0_axes = jnp.stack([x0[:3], x0[3:]], axis=-1)  # (3, 2): (p_j, v_j)
    ref_axes = jnp.stack([x_ref[:, :3], x_ref[:, 3:]], axis=-1).transpose(1, 0, 2)  # (3, N+1, 2)
    c_vel, m_vel = prob.c[3::2], prob.m[3::2]
    e = jax.vmap(condensed_linear, in_axes=(None, None, 0, 0, 0))(prob.m, prob.c, prob.q_aug, x0_axes, ref_axes)
    v_free = x0_axes @ m_vel.T  # (3, N)
    e_hat = e + prob.v_penalty * (v_free @ c_vel)
    if prob.kernel.shape[0] == 1:
        stacked = lambda y: y @ prob.kernel[0].T  # noqa: E731  one product for the three axes
    else:
        stacked = lambda y: jnp.einsum("amn,an->am", prob.kernel, y)  # noqa: E731

    def grad(y):
        hy, cy = jnp.split(stacked(y), [n], axis=-1)
        return hy + e_hat - prob.v_penalty * (jnp.clip(v_free + cy, -v_max, v_max) @ c_vel)

    lower, upper = (-a_max, a_max) if shift is None else (shift[:, None] - a_max, shift[:, None] + a_max)
    return fista(grad, warm, lower, upper, step=1.0 / prob.lipschitz[:, None], iters=iters)


def shift_warm_start(u: Array) -> Array:
    """Shift (3, N) input sequences one step forward, repeating the last input."""
    return jnp.concatenate([u[:, 1:], u[:, -1:]], axis=1)
