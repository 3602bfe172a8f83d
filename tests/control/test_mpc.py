"""Condensed MPC (SPEC 4): prediction matrices, cost identity, FISTA vs independent solvers."""

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import minimize

from jaxapf.config import MPCConfig
from jaxapf.control.mpc import (
    axis_problem,
    condensed_qp,
    prediction_matrices,
    shift_warm_start,
    solve_axes,
    solve_box_qp,
)
from jaxapf.world import discrete_matrices, step

DT, N = 0.1, 8
WEIGHTS = dict(q_pos=(1.0, 2.0, 0.5), q_vel=(0.1, 0.2, 0.3), f_pos=(5.0, 4.0, 3.0), f_vel=(0.5, 0.6, 0.7),
               r=(0.05, 0.1, 0.2))


def _explicit_cost(x0, x_ref, u_seq):
    """J of paper eq. 9 by stepping the plant: Q on x(k+1..k+N-1), F on x(k+N), R on inputs."""
    q = np.concatenate([WEIGHTS["q_pos"], WEIGHTS["q_vel"]])
    f = np.concatenate([WEIGHTS["f_pos"], WEIGHTS["f_vel"]])
    x, cost = x0, 0.0
    for i, a in enumerate(u_seq):
        x = np.asarray(step(jnp.asarray(x), jnp.asarray(a), DT))
        w = f if i == N - 1 else q
        err = x - x_ref[i + 1]
        cost += err @ (w * err) + a @ (np.asarray(WEIGHTS["r"]) * a)
    return cost


def test_prediction_matrices_match_explicit_simulation():
    with jax.enable_x64(True):
        rng = np.random.default_rng(0)
        a, b = discrete_matrices(DT, 3)
        big_m, c = prediction_matrices(a, b, N)
        x0, u = rng.normal(size=6), rng.normal(size=(N, 3))
        states = [x0]
        for i in range(N):
            states.append(np.asarray(step(jnp.asarray(states[-1]), jnp.asarray(u[i]), DT)))
        np.testing.assert_allclose(big_m @ x0 + c @ u.reshape(-1), np.concatenate(states), rtol=1e-12, atol=1e-12)


def test_condensed_qp_reproduces_the_cost_up_to_a_constant():
    """J(U) = 2 (½UᵀHU + EᵀU) + const, checked on differences of random U."""
    with jax.enable_x64(True):
        rng = np.random.default_rng(1)
        x0, x_ref = rng.normal(size=6), rng.normal(size=(N + 1, 6))
        h, e = condensed_qp(jnp.asarray(x0), jnp.asarray(x_ref), dt=DT, horizon=N, **WEIGHTS)
        assert h.shape == (3 * N, 3 * N) and e.shape == (3 * N,)
        qp = lambda u: 0.5 * u @ np.asarray(h) @ u + np.asarray(e) @ u  # noqa: E731
        u1, u2 = rng.normal(size=(2, N, 3))
        lhs = _explicit_cost(x0, x_ref, u1) - _explicit_cost(x0, x_ref, u2)
        np.testing.assert_allclose(lhs, 2 * (qp(u1.reshape(-1)) - qp(u2.reshape(-1))), rtol=1e-10)


def _random_box_qp(rng, n):
    a = rng.normal(size=(n, n))
    h = a @ a.T + 0.1 * np.eye(n)
    return h, rng.normal(size=n) * 3.0, -np.abs(rng.normal(size=n)) - 0.1, np.abs(rng.normal(size=n)) + 0.1


def _scipy_box_qp(h, e, lo, hi, x0=None):
    res = minimize(lambda u: 0.5 * u @ h @ u + e @ u, np.zeros_like(e) if x0 is None else x0,
                   jac=lambda u: h @ u + e, bounds=list(zip(lo, hi)), method="L-BFGS-B",
                   options=dict(ftol=1e-15, gtol=1e-12, maxiter=10_000))
    return res.x


_solve64 = jax.jit(partial(solve_box_qp, iters=4000))


@pytest.mark.parametrize("seed", range(4))
def test_solve_box_qp_matches_scipy_float64(seed):
    rng = np.random.default_rng(seed)
    h, e, lo, hi = _random_box_qp(rng, 12)
    with jax.enable_x64(True):
        got = np.asarray(_solve64(jnp.asarray(h), jnp.asarray(e), jnp.asarray(lo), jnp.asarray(hi)))
    want = _scipy_box_qp(h, e, lo, hi)
    assert np.any(np.isclose(got, lo) | np.isclose(got, hi)), "the box must be active for this test to bite"
    np.testing.assert_allclose(got, want, atol=1e-6)


@pytest.mark.slow
def test_float32_default_iterations_cost_within_tolerance():
    """At the default 30 iterations in float32, the MPC QP is solved to within 1 % of the optimal
    decrease (relative to U = 0), on MPC problems from the default weights."""
    mpc = MPCConfig()
    rng = np.random.default_rng(5)
    gaps = []
    for _ in range(20):
        x0 = np.concatenate([rng.normal(size=3) * 2, rng.uniform(-2, 2, 3)])
        ref = x0[:3] + np.cumsum(np.tile(rng.uniform(-0.2, 0.2, 3), (mpc.horizon + 1, 1)), axis=0)
        x_ref = np.concatenate([ref, np.zeros_like(ref)], axis=1)
        kw = dict(dt=DT, horizon=mpc.horizon, q_pos=mpc.q_pos, q_vel=mpc.q_vel, f_pos=mpc.f_pos,
                  f_vel=mpc.f_vel, r=mpc.r)
        h, e = condensed_qp(jnp.asarray(x0, jnp.float32), jnp.asarray(x_ref, jnp.float32), **kw)
        u = np.asarray(solve_box_qp(h, e, -3.0, 3.0, iters=mpc.iters), np.float64)
        h64, e64 = (np.asarray(a, np.float64) for a in (h, e))
        best = _scipy_box_qp(h64, e64, np.full(e.shape, -3.0), np.full(e.shape, 3.0))
        cost = lambda x, h64=h64, e64=e64: 0.5 * x @ h64 @ x + e64 @ x
        gaps.append((cost(u) - cost(best)) / abs(cost(best)))
    assert max(gaps) < 0.01, gaps


def test_per_axis_solver_matches_general_solver():
    """The loop's per-axis QPs (no velocity penalty) equal the 3N problem of condensed_qp."""
    mpc = MPCConfig(horizon=N, iters=3000, v_penalty=0.0, **WEIGHTS)
    rng = np.random.default_rng(2)
    with jax.enable_x64(True):
        x0, x_ref = jnp.asarray(rng.normal(size=6) * 3), jnp.asarray(rng.normal(size=(N + 1, 6)) * 3)
        h, e = condensed_qp(x0, x_ref, dt=DT, horizon=N, **WEIGHTS)
        general = solve_box_qp(h, e, -1.0, 1.0, iters=3000).reshape(N, 3).T
        prob = axis_problem(mpc, *discrete_matrices(DT, 1, jnp.float64))
        # the per-axis Hessians are the diagonal blocks of the interleaved 3N Hessian
        for ax in range(3):
            np.testing.assert_allclose(prob.h[ax], h[ax::3, ax::3], rtol=1e-12)
        per_axis = solve_axes(prob, x0, x_ref, jnp.zeros((3, N)), a_max=1.0, v_max=1.0,
                              iters=3000)
        np.testing.assert_allclose(per_axis, general, atol=1e-8)


def test_shared_axis_kernel_equals_per_axis_kernels():
    """Equal weights on the three axes give one stacked kernel (A = 1) whose solution is the one
    of three copies of it (A = 3), with the velocity penalty active."""
    mpc = MPCConfig(horizon=N, iters=200, v_penalty=5.0)
    rng = np.random.default_rng(5)
    with jax.enable_x64(True):
        prob = axis_problem(mpc, *discrete_matrices(DT, 1, jnp.float64))
        assert prob.kernel.shape == (1, 2 * N, N)
        copies = dataclasses.replace(prob, kernel=jnp.broadcast_to(prob.kernel, (3, 2 * N, N)))
        x0, x_ref = jnp.asarray(rng.normal(size=6) * 3), jnp.asarray(rng.normal(size=(N + 1, 6)) * 5)
        warm = jnp.asarray(rng.normal(size=(3, N)))
        kw = dict(a_max=2.0, v_max=0.5, iters=200)
        shared = solve_axes(prob, x0, x_ref, warm, **kw)
        np.testing.assert_allclose(shared, solve_axes(copies, x0, x_ref, warm, **kw), rtol=1e-12, atol=1e-12)
        assert np.abs(np.asarray(shared)).max() == pytest.approx(2.0)  # the box is active too
    prob = axis_problem(MPCConfig(horizon=N, **WEIGHTS), *discrete_matrices(DT, 1, jnp.float32))
    assert prob.kernel.shape == (3, 2 * N, N)


def test_velocity_penalty_solution_matches_scipy():
    """With the smooth velocity penalty the per-axis FISTA reaches scipy's optimum."""
    v_max, rho = 0.5, 10.0
    mpc = MPCConfig(horizon=N, iters=4000, v_penalty=rho, **WEIGHTS)
    rng = np.random.default_rng(4)
    with jax.enable_x64(True):
        x0 = jnp.asarray(np.concatenate([np.zeros(3), [0.4, -0.3, 0.0]]))
        x_ref = jnp.asarray(np.concatenate([np.linspace(0, 1, N + 1)[:, None] * rng.normal(size=3) * 5,
                                            np.zeros((N + 1, 3))], axis=1))
        prob = axis_problem(mpc, *discrete_matrices(DT, 1, jnp.float64))
        got = solve_axes(prob, x0, x_ref, jnp.zeros((3, N)), a_max=2.0, v_max=v_max, iters=4000)
        h, e = condensed_qp(x0, x_ref, dt=DT, horizon=N, **WEIGHTS)
        big_m, c = prediction_matrices(*discrete_matrices(DT, 3, jnp.float64), N)
        h, e, big_m, c = (np.asarray(a) for a in (h, e, big_m, c))
        vel_rows = np.concatenate([np.arange(6 * i + 3, 6 * i + 6) for i in range(1, N + 1)])

        def cost(u):
            v = big_m[vel_rows] @ np.asarray(x0) + c[vel_rows] @ u
            return 0.5 * u @ h @ u + e @ u + 0.5 * rho * np.sum(np.maximum(np.abs(v) - v_max, 0) ** 2)

        res = minimize(cost, np.zeros(3 * N), bounds=[(-2.0, 2.0)] * (3 * N), method="L-BFGS-B",
                       options=dict(ftol=1e-15, gtol=1e-10, maxiter=20_000))
        ours = np.asarray(got).T.reshape(-1)
        assert cost(ours) <= res.fun + 1e-9
        np.testing.assert_allclose(ours, res.x, atol=1e-4)


def test_warm_start_shift():
    u = jnp.arange(12.0).reshape(3, 4)
    np.testing.assert_array_equal(shift_warm_start(u), [[1, 2, 3, 3], [5, 6, 7, 7], [9, 10, 11, 11]])


def test_solver_is_vmappable_and_differentiable():
    rng = np.random.default_rng(7)
    h, e, lo, hi = _random_box_qp(rng, 6)
    h, lo, hi = jnp.asarray(h, jnp.float32), jnp.asarray(lo, jnp.float32), jnp.asarray(hi, jnp.float32)
    es = jnp.asarray(rng.normal(size=(5, 6)), jnp.float32)
    batched = jax.vmap(lambda e: solve_box_qp(h, e, lo, hi, iters=50))(es)
    assert batched.shape == (5, 6) and batched.dtype == jnp.float32
    grad = jax.grad(lambda e: jnp.sum(solve_box_qp(h, e, lo, hi, iters=50) ** 2))(es[0])
    assert np.all(np.isfinite(np.asarray(grad))) and float(jnp.abs(grad).sum()) > 0
