"""The CBF safety filter: its constraints against an independent numpy computation, its QP against
OSQP, infeasibility detection, gradients, and the closed loop it protects."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import one_obstacle_scenario
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.config import MPCConfig, SimConfig
from jaxapf.control import FILTERS, cbf_constraints, cbf_qp
from jaxapf.control.cbf import INFEASIBLE_TOL
from jaxapf.datatypes import Obstacles
from jaxapf.gains import Gains
from jaxapf.rollout import rollout_metrics

A_MAX = 3.0
ROWS = 16  # problems padded to 16 rows (zero rows are ignored): one compiled solver for all
QP = jax.jit(cbf_qp, static_argnums=3)


def _padded(g: np.ndarray, b: np.ndarray) -> tuple[jax.Array, jax.Array]:
    m = g.shape[0]
    return (jnp.asarray(np.vstack([g, np.zeros((ROWS - m, 3))]), jnp.float32),
            jnp.asarray(np.concatenate([b, -np.ones(ROWS - m)]), jnp.float32))


def _obstacles(rng: np.random.Generator, m: int, valid: int) -> Obstacles:
    return Obstacles(position=jnp.asarray(rng.uniform(-6, 6, (m, 3)), jnp.float32),
                     velocity=jnp.asarray(rng.uniform(-1, 1, (m, 3)), jnp.float32),
                     radius=jnp.asarray(rng.uniform(0.3, 1.0, m), jnp.float32),
                     cylinder=jnp.asarray(rng.random(m) < 0.5),
                     valid=jnp.arange(m) < valid)


@given(seed=st.integers(0, 2**31 - 1), k0=st.floats(0.0, 4.0), k1=st.floats(0.0, 4.0))
@settings(max_examples=25, deadline=None)
def test_constraints_are_the_exponential_cbf_condition(seed, k0, k1):
    """``g·a - b`` (unscaled) equals ``ḧ + k1 ḣ + k0 h`` computed in float64 numpy, for any ``a``."""
    rng = np.random.default_rng(seed)
    obs = _obstacles(rng, 4, 3)
    x = rng.uniform(-3, 3, 6).astype(np.float32)
    t, a = np.float32(rng.uniform(0, 5)), rng.uniform(-3, 3, 3)
    sim = SimConfig()
    g, b = cbf_constraints(jnp.asarray(x), t, obs.columns(), Gains(cbf_k0=k0, cbf_k1=k1), sim)
    g, b = np.asarray(g, np.float64), np.asarray(b, np.float64)
    for o in range(3):
        keep = np.array([1.0, 1.0, 0.0 if bool(obs.cylinder[o]) else 1.0])
        r = keep * (x[:3] - (np.asarray(obs.position[o], np.float64) + np.asarray(obs.velocity[o], np.float64) * t))
        w = keep * (x[3:] - np.asarray(obs.velocity[o], np.float64))
        big_r = float(obs.radius[o]) + sim.vehicle.r_uav
        h, hd, hdd = r @ r - big_r**2, 2 * r @ w, 2 * w @ w + 2 * r @ a
        scale = 2 * np.linalg.norm(r)
        assert (g[o] @ a - b[o]) * scale == pytest.approx(hdd + k1 * hd + k0 * h, rel=1e-4, abs=1e-3)
        assert np.linalg.norm(g[o]) == pytest.approx(1.0, abs=1e-5)
    assert np.all(g[3] == 0) and b[3] == -1.0  # padded slot: 0 >= -1 always holds


def _osqp(a0, g, b, a_max):
    osqp = pytest.importorskip("osqp")
    from scipy import sparse

    n = a0.size
    A = sparse.csc_matrix(np.vstack([g, np.eye(n)]))
    lo = np.concatenate([b, -a_max * np.ones(n)])
    hi = np.concatenate([np.full(b.size, np.inf), a_max * np.ones(n)])
    solver = osqp.OSQP()
    solver.setup(P=sparse.csc_matrix(np.eye(n)), q=-a0, A=A, l=lo, u=hi, eps_abs=1e-9, eps_rel=1e-9, max_iter=200000,
                 polishing=True, verbose=False)
    res = solver.solve()
    assert res.info.status == "solved"
    return res.x


@pytest.mark.parametrize("seed", range(40))
def test_qp_matches_osqp_on_feasible_problems(seed):
    """Random problems with a known feasible point: the filter's acceleration is OSQP's, and every
    constraint holds within the tolerance that counts a step infeasible."""
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, ROWS + 1))
    g = rng.normal(size=(m, 3))
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    feasible = rng.uniform(-A_MAX, A_MAX, 3) * 0.8
    b = g @ feasible - rng.uniform(0, 0.5, m)
    a0 = rng.uniform(-2 * A_MAX, 2 * A_MAX, 3)
    a, worst = QP(jnp.asarray(a0, jnp.float32), *_padded(g, b), A_MAX)
    expected = _osqp(a0, g, b, A_MAX)
    np.testing.assert_allclose(np.asarray(a), expected, atol=1e-4)
    assert float(worst) <= INFEASIBLE_TOL
    assert np.all(np.abs(np.asarray(a)) <= A_MAX + 1e-6)


def test_an_unconstrained_acceleration_passes_unchanged():
    g = jnp.asarray([[1.0, 0.0, 0.0]])
    a, worst = QP(jnp.asarray([1.0, 2.0, -1.0]), *_padded(np.asarray(g), np.asarray([0.5])), A_MAX)
    np.testing.assert_array_equal(np.asarray(a), [1.0, 2.0, -1.0])
    assert float(worst) == 0.0


def test_incompatible_constraints_are_reported():
    """``a_x >= 1`` and ``-a_x >= 1`` cannot both hold; nor can ``a_x >= 5`` within the box."""
    for g, b in [([[1.0, 0, 0], [-1.0, 0, 0]], [1.0, 1.0]), ([[1.0, 0, 0]], [5.0])]:
        _, worst = QP(jnp.zeros(3), *_padded(np.asarray(g), np.asarray(b)), A_MAX)
        assert float(worst) > INFEASIBLE_TOL


def test_qp_gradient_matches_finite_differences():
    """d a*/d a_mpc through the selected candidate, in float64, against central differences."""
    with jax.enable_x64(True):
        g = jnp.asarray([[0.6, 0.8, 0.0], [0.0, -1.0, 0.0]], jnp.float64)
        b = jnp.asarray([0.5, -2.0], jnp.float64)
        f = jax.jit(lambda a0: jnp.sum(cbf_qp(a0, g, b, A_MAX)[0] * jnp.asarray([1.0, 2.0, 3.0])))
        a0 = jnp.asarray([-1.0, 0.3, 0.7], jnp.float64)
        grad = np.asarray(jax.jit(jax.grad(f))(a0))
        eps = 1e-6
        fd = [(f(a0.at[i].add(eps)) - f(a0.at[i].add(-eps))) / (2 * eps) for i in range(3)]
        np.testing.assert_allclose(grad, np.asarray(fd), rtol=1e-4, atol=1e-6)


def test_the_filter_keeps_a_repulsion_free_flight_off_the_obstacle():
    """Without repulsion (k_rep = 0) the MPC flies straight through the cylinder on the start–goal
    line; with ``filter = "cbf"`` the same flight stays clear of it, and no step is infeasible."""
    scenario = one_obstacle_scenario(16.0, 8.0, 1.0)
    base = SimConfig.from_flat(method="basic", t_max=20.0)
    gains = Gains(k_rep=1e-6)
    mpc = MPCConfig(horizon=10, iters=20)
    bare = rollout_metrics(scenario, gains, base, mpc)
    safe = rollout_metrics(scenario, gains, dataclasses.replace(base, planner=dataclasses.replace(
        base.planner, filter="cbf")), mpc)
    assert bool(bare["collision"])
    assert not bool(safe["collision"]) and float(safe["min_clearance"]) > 0.0
    assert int(safe["cbf_infeasible_steps"]) == 0 and int(bare["cbf_infeasible_steps"]) == 0
    assert FILTERS.get("cbf", "filter").gains[0].name == "cbf_k0"
