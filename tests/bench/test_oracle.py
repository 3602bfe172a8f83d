"""The numpy + OSQP oracle (jaxapf.bench.oracle) against the JAX engine.

The baseline shares no code with the engine, so agreement checks the engine's potentials and
their gradients (both conventions, cylinders, masks, the clearance floor), the reference flow, the
condensed MPC with its velocity penalty, and the plant, end to end.
"""

import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

osqp = pytest.importorskip("osqp")

from conftest import three_obstacle_field  # noqa: E402

from jaxapf.bench import oracle as bl  # noqa: E402
from jaxapf.config import MPCConfig, SimConfig  # noqa: E402
from jaxapf.control.mpc import axis_problem, solve_axes  # noqa: E402
from jaxapf.engine import rollout  # noqa: E402
from jaxapf.gains import Gains  # noqa: E402
from jaxapf.planners.potentials import total_force as jax_total_force  # noqa: E402
from jaxapf.world import discrete_matrices  # noqa: E402

COMBOS = [(m, c) for m in ("basic", "direction", "direction_velocity") for c in ("intent", "literal")]


def _scenario(xp=jnp):
    return three_obstacle_field(xp)


def _gains():
    return dict(gamma=1.3, k=0.7, k_rep=8.0, d_s=3.5, k_att=1.2, eta=0.6)


def _sample_points(rng, n=24):
    """Points around the field, including some inside obstacles (below the clearance floor)."""
    pts = rng.normal(size=(n, 3)) * 2.5 + np.array([6.0, 0.5, 0.5])
    pts[:4] = [[4.0, 0.3, 0.9], [4.4, 0.3, 0.0], [7.2, -1.5, -3.0], [6.0, -1.5, 9.0]]  # deep/shallow inside
    pts[4] = [4.0, 0.3, 1.0 + 0.3 + 0.03]  # clearance 0.03 < d_min
    return pts, rng.normal(size=(n, 3)), rng.uniform(0.0, 4.0, size=n)


# --------------------------------------------------------------------------------------------
# potentials
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method,convention", COMBOS)
def test_numpy_force_matches_jax_grad(method, convention):
    sim = SimConfig.from_flat(method=method, convention=convention, att_cap=6.0)
    with jax.enable_x64(True):
        scen, gains = _scenario(), Gains(**_gains()).as_arrays(jnp.float64)
        force = jax.jit(jax.vmap(lambda p, v, t: jax_total_force(
            p, v, t, scen.goal, scen.obstacles, gains, method=method, convention=convention,
            r_uav=sim.vehicle.r_uav, d_min=sim.planner.d_min, eps_v=sim.planner.eps_v, att_cap=sim.planner.att_cap)))
        pts, vels, ts = _sample_points(np.random.default_rng(0))
        expected = np.asarray(force(jnp.asarray(pts), jnp.asarray(vels), jnp.asarray(ts)))
    arrays = bl._scenario_arrays(_scenario(np))  # padded slot kept: exercised by the mask
    got = np.stack([bl.total_force(p, v, t, arrays, _gains(), sim) for p, v, t in zip(pts, vels, ts)])
    assert np.all(np.isfinite(got))
    scale = np.maximum(1.0, np.abs(expected).max(axis=1, keepdims=True))
    np.testing.assert_allclose(got / scale, expected / scale, rtol=0, atol=1e-11)


@pytest.mark.parametrize("method,convention", COMBOS)
def test_analytic_force_is_minus_gradient_of_numpy_potential(method, convention):
    sim = SimConfig.from_flat(method=method, convention=convention, att_cap=6.0)
    arrays = bl._scenario_arrays(_scenario(np))
    pts, vels, ts = _sample_points(np.random.default_rng(1))
    h = 1e-6
    for p, v, t in zip(pts, vels, ts):
        fd = np.array([
            -(bl.total_potential(p + h * e, v, t, arrays, _gains(), sim)
              - bl.total_potential(p - h * e, v, t, arrays, _gains(), sim)) / (2 * h)
            for e in np.eye(3)
        ])
        f = bl.total_force(p, v, t, arrays, _gains(), sim)
        np.testing.assert_allclose(f, fd, rtol=1e-5, atol=1e-5 * max(1.0, np.abs(f).max()))


# --------------------------------------------------------------------------------------------
# MPC QP
# --------------------------------------------------------------------------------------------


def test_osqp_slack_qp_matches_fista_with_active_box_and_velocity_penalty():
    mpc = MPCConfig(horizon=8, q_pos=(1.0, 2.0, 0.5), q_vel=(0.1, 0.0, 0.2), f_pos=(5.0, 4.0, 3.0),
                    f_vel=0.5, r=(0.05, 0.1, 0.2), v_penalty=10.0)
    sim = SimConfig.from_flat(v_max=1.0, a_max=2.0)
    x0 = np.array([0.0, 0.0, 0.0, 1.8, -1.6, 0.3])
    x_ref = np.zeros((mpc.horizon + 1, 6))
    x_ref[:, :3] = np.linspace([0.0, 0.0, 0.0], [6.0, -5.0, 1.0], mpc.horizon + 1)
    qp = bl.CondensedMPC(mpc, sim, eps=1e-9)
    u_osqp = qp.solve(x0, x_ref)
    v_pred = qp.m_v @ x0 + qp.c_v @ u_osqp.reshape(-1)
    assert np.abs(v_pred).max() > sim.vehicle.v_max + 0.05  # the penalty is active
    assert np.any(np.abs(u_osqp) >= sim.vehicle.a_max - 1e-9)  # so is the box
    with jax.enable_x64(True):
        prob = axis_problem(mpc, *discrete_matrices(sim.episode.dt, 1, jnp.float64))
        solve = jax.jit(lambda x, r, w: solve_axes(prob, x, r, w, a_max=sim.vehicle.a_max, v_max=sim.vehicle.v_max,
                                                   iters=5_000))
        u_fista = solve(jnp.asarray(x0), jnp.asarray(x_ref), jnp.zeros((3, mpc.horizon), jnp.float64))
        u_fista = np.asarray(u_fista).T
    np.testing.assert_allclose(u_osqp, u_fista, atol=1e-6)


# --------------------------------------------------------------------------------------------
# closed loop
# --------------------------------------------------------------------------------------------

CLOSED_LOOP = [
    pytest.param("basic", "intent", {}, {}, id="basic-intent"),
    pytest.param("direction_velocity", "literal", {}, {}, id="dv-literal"),
    pytest.param("direction_velocity", "intent", dict(v_max=1.0, a_max=1.5),
                 dict(q_pos=5.0, q_vel=0.0, f_pos=20.0, f_vel=0.0, v_penalty=2.0), id="dv-intent-limits"),
    pytest.param("direction", "intent", dict(reference_velocity=True, att_cap=4.0), {}, id="dir-refvel-cap"),
]


@pytest.mark.parametrize("method,convention,sim_kw,mpc_kw", CLOSED_LOOP)
def test_engine_trajectory_matches_baseline(method, convention, sim_kw, mpc_kw):
    sim = SimConfig.from_flat(method=method, convention=convention, t_max=5.0, **sim_kw)  # 50 steps
    mpc = MPCConfig(horizon=8, iters=2000, **mpc_kw)
    with jax.enable_x64(True):
        scen, gains = _scenario(), Gains(**_gains()).as_arrays(jnp.float64)
        traj = jax.device_get(jax.jit(rollout, static_argnums=(2, 3))(scen, gains, sim, mpc))
    base = bl.oracle_rollout(_scenario(np), Gains(**_gains()), sim, mpc)
    assert set(base) == {"time", "position", "velocity", "control"}
    assert base["position"].shape == (sim.episode.steps + 1, 3) and base["control"].shape == (sim.episode.steps, 3)
    np.testing.assert_allclose(base["time"], traj.time, atol=1e-12)
    # observed agreement is ~1e-12 m; the bound leaves room for FISTA's residual
    np.testing.assert_allclose(traj.position, base["position"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(traj.velocity, base["velocity"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(traj.control, base["control"], rtol=0, atol=1e-5)
    assert np.linalg.norm(base["position"][-1] - base["position"][0]) > 2.0  # it went somewhere
    if "a_max" in sim_kw:
        assert np.any(np.abs(base["control"]) >= sim.vehicle.a_max - 1e-9)  # the box was active


def test_missing_osqp_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "osqp", None)  # makes `import osqp` raise ImportError
    with pytest.raises(ImportError, match=r'pip install "jaxapf\[bench\]"'):
        bl.oracle_rollout(_scenario(np), Gains(), SimConfig.from_flat(t_max=0.2), MPCConfig(horizon=4))
