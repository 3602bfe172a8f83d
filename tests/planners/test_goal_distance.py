"""Ge–Cui's goal-distance weight and the ``ge_cui_bounded`` planner (jaxapf.planners.goal_distance)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import one_obstacle_scenario, outcomes, three_obstacle_field
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.bench import oracle
from jaxapf.config import MPCConfig, SimConfig
from jaxapf.engine import rollout
from jaxapf.gains import Gains
from jaxapf.planners import PLANNERS
from jaxapf.planners.potentials import total_force

GAINS = Gains(n_g=1.5, k_rep=8.0, d_s=3.5, k_att=1.2)
SIM = SimConfig.from_flat(method="ge_cui_bounded")


def _force(p, goal, field, gains, method="ge_cui_bounded"):
    sim = SimConfig.from_flat(method=method)
    return total_force(p, jnp.zeros(3), 0.0, goal, field.obstacles, gains, method=method, convention="intent",
                       r_uav=sim.vehicle.r_uav, d_min=sim.planner.d_min, eps_v=sim.planner.eps_v)


def _numpy_potential(p, goal, arrays, gains):
    """Independent: ½ k_att |p - g|² + Σ_o ω U_rep with the oracle's numpy U_rep and ω written out."""
    g = {k: float(gains[k]) for k in ("gamma", "k", "k_rep", "d_s", "k_att", "eta")}
    u_rep, _, _, _ = oracle._rep_terms(p, np.zeros(3), 0.0, arrays, g, SimConfig.from_flat(method="basic"))
    rho2 = float(np.sum((p - goal) ** 2))
    omega = (rho2 / (rho2 + g["d_s"] ** 2)) ** (0.5 * float(gains["n_g"]))
    return 0.5 * g["k_att"] * rho2 + omega * float(np.sum(np.where(arrays["valid"], u_rep, 0.0)))


def test_force_is_minus_the_gradient_of_an_independent_numpy_potential():
    rng = np.random.default_rng(1)
    with jax.enable_x64(True):
        field = three_obstacle_field()
        arrays = oracle._scenario_arrays(field)
        gains = GAINS.as_arrays(jnp.float64)
        for _ in range(30):
            p = rng.normal(size=3) * 2.0 + np.array([6.0, 0.5, 0.5])
            goal = rng.normal(size=3) * 3.0 + np.array([8.0, 0.0, 0.5])
            got = np.asarray(_force(jnp.asarray(p), jnp.asarray(goal), field, gains))
            h, fd = 1e-6, np.zeros(3)
            for i in range(3):
                e = np.eye(3)[i] * h
                up, down = _numpy_potential(p + e, goal, arrays, GAINS), _numpy_potential(p - e, goal, arrays, GAINS)
                fd[i] = -(up - down) / (2 * h)
            np.testing.assert_allclose(got, fd, rtol=1e-5, atol=1e-6)


def test_the_repulsion_vanishes_at_the_goal():
    """An obstacle within d_s of the goal: with Ge–Cui the force at the goal is exactly zero (the
    goal is the minimum); the basic potential still pushes there."""
    with jax.enable_x64(True):
        field = three_obstacle_field()
        gains = GAINS.as_arrays(jnp.float64)
        goal = jnp.asarray([5.6, 0.3, 0.0])  # 0.6 m from the first sphere's surface
        assert np.all(np.asarray(_force(goal, goal, field, gains)) == 0.0)
        assert np.linalg.norm(np.asarray(_force(goal, goal, field, gains, method="basic"))) > 0.1
        near = [np.linalg.norm(np.asarray(_force(goal + jnp.asarray([r, 0.0, 0.0]), goal, field, gains)))
                for r in (1e-1, 1e-2, 1e-3)]
        assert near[0] > near[1] > near[2]  # it fades toward the goal (as ρ_g^(n-1) for n > 1)


@settings(max_examples=50, deadline=None)
@given(st.floats(0.0, 1e3), st.floats(0.0, 4.0))
def test_omega_lies_in_its_bounds_and_tends_to_one_far_away(rho, n_g):
    from jaxapf.planners.sight import Sight

    weight = PLANNERS.get("ge_cui_bounded").weight
    gains = Gains(n_g=n_g)
    sight = Sight(s=(jnp.ones(()),) * 3, v=jnp.zeros(3), v_o=jnp.zeros(3), p=jnp.asarray([rho, 0.0, 0.0]),
                  goal=jnp.zeros(3))
    w = float(weight(sight, gains, convention="intent", eps_v=1e-3))
    lo, hi = weight.bounds(gains)
    assert float(lo) <= w <= float(hi) + 1e-6
    if rho > 1e3 * 0.99:
        assert w == pytest.approx(1.0, abs=1e-4)


def test_n_zero_is_the_basic_planner_to_rounding():
    sim, basic, mpc = (SimConfig.from_flat(method="ge_cui_bounded", t_max=3.0),
                       SimConfig.from_flat(method="basic", t_max=3.0), MPCConfig(horizon=6, iters=10))
    field = three_obstacle_field(jnp, jnp.float32)
    run = jax.jit(rollout, static_argnums=(2, 3))
    np.testing.assert_allclose(np.asarray(run(field, Gains(n_g=0.0), sim, mpc).position),
                               np.asarray(run(field, Gains(), basic, mpc).position), rtol=0, atol=1e-5)
    assert not np.array_equal(np.asarray(run(field, Gains(), sim, mpc).position),
                              np.asarray(run(field, Gains(), basic, mpc).position))


@pytest.mark.slow
def test_the_ge_cui_planner_reaches_a_goal_next_to_an_obstacle():
    """GNRON: a goal 1 m in front of a cylinder. The basic field settles short of it; Ge–Cui arrives."""
    outcome = outcomes(one_obstacle_scenario(10.0, 12.0, 1.0), ("basic", "ge_cui_bounded"))
    assert outcome["basic"] == {"success": False, "collision": False, "stalled": True}
    assert outcome["ge_cui_bounded"] == {"success": True, "collision": False, "stalled": False}


def test_registered_with_its_gain():
    assert [g.name for g in PLANNERS.get("ge_cui_bounded").gains] == ["n_g", "k_rep", "d_s", "k_att", "eta"]
    assert Gains().n_g == 2.0
