"""MPPI (jaxapf.planners.mppi): one update against an independent numpy implementation on the same
noise draws, its gradient in every cost weight against central differences, hand-made encounters
(a wall of an obstacle on the straight line, a trap the potential fields stall in), and its noise
coming from the field's key (same episode in any batch, a stream of its own)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import one_obstacle_scenario, outcomes

from jaxapf.config import SimConfig
from jaxapf.datatypes import Obstacles
from jaxapf.gains import Gains
from jaxapf.planners.mppi import MPPI_GAINS, mppi_update

SIM = SimConfig.from_flat(method="mppi")
WEIGHTS = {"mppi_lambda": 0.7, "mppi_sigma": 0.9, "mppi_goal": 1.3, "mppi_obstacle": 15.0, "mppi_d": 1.2,
           "mppi_collision": 500.0, "mppi_speed": 8.0, "mppi_effort": 0.02}


def _numpy_update(u, noise, x, t, goal, p_o, v_o, radius, cylinder, w, sim):
    """MPPI's step written out sample by sample and step by step (Williams et al. 2017), in numpy."""
    a_max, v_max, dt, r_uav = sim.vehicle.a_max, sim.vehicle.v_max, sim.episode.dt, sim.vehicle.r_uav
    costs, effective = [], []
    for k in range(noise.shape[0]):
        v_k = np.clip(u + noise[k], -a_max, a_max)
        eps = v_k - u
        p, v, s = x[:3].copy(), x[3:].copy(), 0.0
        for i in range(u.shape[0]):
            a = v_k[i]
            p = p + dt * v + 0.5 * dt * dt * a
            v = v + dt * a
            s += w["mppi_goal"] * np.linalg.norm(p - goal)
            for o in range(len(radius)):
                rel = p - (p_o[o] + v_o[o] * (t + (i + 1) * dt))
                if cylinder[o]:
                    rel[2] = 0.0
                c = np.linalg.norm(rel) - radius[o] - r_uav
                s += w["mppi_obstacle"] * max(0.0, 1.0 - c / w["mppi_d"]) ** 2
                s += w["mppi_collision"] * (c < 0.0)
            s += w["mppi_speed"] * np.sum(np.maximum(0.0, np.abs(v) - v_max) ** 2)
            s += w["mppi_effort"] * a @ a
            s += w["mppi_lambda"] / w["mppi_sigma"] ** 2 * u[i] @ eps[i]
        costs.append(s)
        effective.append(eps)
    costs = np.array(costs)
    weights = np.exp(-(costs - costs.min()) / w["mppi_lambda"])
    weights /= weights.sum()
    return u + np.einsum("k,kij->ij", weights, np.array(effective)), costs.min()


def _case(seed, samples=64, horizon=8, m=3):
    rng = np.random.default_rng(seed)
    x = np.concatenate([rng.uniform(-1, 1, 3), rng.uniform(-1.5, 1.5, 3)])
    goal = rng.uniform(5, 9, 3)
    p_o, v_o = x[:3] + rng.uniform(0.5, 4.0, (m, 3)), rng.uniform(-1, 1, (m, 3))
    radius, cylinder = rng.uniform(0.3, 1.0, m), rng.random(m) < 0.5
    u = rng.uniform(-2, 2, (horizon, 3))
    noise = rng.normal(0.0, 1.5, (samples, horizon, 3))  # wide enough that the box clips some
    return x, goal, p_o, v_o, radius, cylinder, u, noise


def _update(case, weights, t=0.7):
    x, goal, p_o, v_o, radius, cylinder, u, noise = case
    obstacles = Obstacles(position=jnp.asarray(p_o), velocity=jnp.asarray(v_o), radius=jnp.asarray(radius),
                          cylinder=jnp.asarray(cylinder), valid=jnp.ones(len(radius), bool)).columns()
    gains = Gains(**weights).as_arrays(jnp.float64)
    return mppi_update(jnp.asarray(u), jnp.asarray(noise), jnp.asarray(x), jnp.asarray(t), jnp.asarray(goal),
                       obstacles, gains, SIM)


@pytest.mark.parametrize("seed", range(6))
def test_one_update_matches_an_independent_numpy_mppi(seed):
    case = _case(seed)
    with jax.enable_x64(True):
        plan, best = _update(case, WEIGHTS)
    x, goal, p_o, v_o, radius, cylinder, u, noise = case
    want, want_best = _numpy_update(u, noise, x, 0.7, goal, p_o, v_o, radius, cylinder, WEIGHTS, SIM)
    np.testing.assert_allclose(np.asarray(plan), want, rtol=1e-9, atol=1e-9)
    assert float(best) == pytest.approx(want_best, rel=1e-12)
    assert np.all(np.abs(np.asarray(plan)) <= SIM.vehicle.a_max + 1e-12)  # a mean of boxed sequences


@pytest.mark.parametrize("name", [g.name for g in MPPI_GAINS])
def test_the_plan_is_differentiable_in_every_cost_weight(name):
    case = _case(11, samples=32, horizon=6)
    probe = np.random.default_rng(3).normal(size=case[6].shape)
    with jax.enable_x64(True):
        def f(value):
            return jnp.sum(_update(case, WEIGHTS | {name: value})[0] * probe)
        value = WEIGHTS[name]
        grad = float(jax.grad(f)(jnp.asarray(value)))
        h = 1e-5 * max(abs(value), 1.0)
        fd = (float(f(value + h)) - float(f(value - h))) / (2 * h)
    assert grad == pytest.approx(fd, rel=1e-5, abs=1e-8)


def _outcome(scenario, method, horizon):
    from jaxapf.config import MPCConfig
    from jaxapf.engine import rollout
    from jaxapf.metrics import episode_metrics

    sim = SimConfig.from_flat(method=method, t_max=40.0)
    traj = jax.jit(rollout, static_argnums=(2, 3))(scenario, Gains(), sim, MPCConfig(horizon=horizon, iters=20))
    return {k: bool(v) for k, v in episode_metrics(traj, scenario, sim, ("success", "collision", "stalled")).items()}


@pytest.mark.slow
def test_it_flies_round_an_obstacle_on_the_straight_line_and_out_of_a_cup_it_can_see_past():
    """An obstacle on the line to the goal: MPPI reaches the goal without touching it. A cup closed
    towards the goal, in which `basic` stalls: MPPI's sampled futures find the way round with a horizon
    of N = 30 (3 s), and stall like `basic` with N = 10 (1 s), too short to see past it."""
    wall = one_obstacle_scenario(goal_x=12.0, obstacle_x=6.0, radius=1.5)
    assert outcomes(wall, ["mppi"])["mppi"] == {"success": True, "collision": False, "stalled": False}
    cup_x, cup_y = np.array([5.0, 5.6, 5.6, 5.0]), np.array([-1.2, -0.6, 0.6, 1.2])
    m = len(cup_x)
    cup = dataclasses.replace(wall, obstacles=Obstacles(
        position=jnp.asarray(np.stack([cup_x, cup_y, np.full(m, 2.0)], axis=1)), velocity=jnp.zeros((m, 3)),
        radius=jnp.full(m, 0.6), cylinder=jnp.ones(m, bool), valid=jnp.ones(m, bool)))
    stuck = {"success": False, "collision": False, "stalled": True}
    assert _outcome(cup, "basic", 20) == stuck
    assert _outcome(cup, "mppi", 30) == {"success": True, "collision": False, "stalled": False}
    assert _outcome(cup, "mppi", 10) == stuck


def test_its_noise_is_the_fields_own_stream():
    from jaxapf.datatypes import episode_key
    from jaxapf.planners.mppi import MPPI

    scenario = one_obstacle_scenario(goal_x=12.0, obstacle_x=6.0, radius=1.5)
    keyed = [dataclasses.replace(scenario, key=jax.random.key_data(jax.random.key(s))) for s in (0, 1)]
    states = [MPPI().init(s, Gains(), SIM, 10) for s in keyed]
    assert not np.array_equal(states[0][1], states[1][1])  # another field, other draws
    assert np.array_equal(states[0][1], jax.random.key_data(episode_key(keyed[0], "mppi")))
    assert not np.array_equal(states[0][1], jax.random.key_data(episode_key(keyed[0], "sensing")))
