"""The vortex force term and the ``vortex`` planner (jaxapf.planners.vortex)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import one_obstacle_scenario, outcomes, three_obstacle_field
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.bench import oracle
from jaxapf.config import MPCConfig, SimConfig
from jaxapf.datatypes import Obstacles
from jaxapf.engine import rollout
from jaxapf.gains import Gains
from jaxapf.planners import PLANNERS, Vortex

SIM = SimConfig.from_flat(method="vortex")
GAINS = Gains(k_v=1.5, k_rep=8.0, d_s=3.5)
_vortex = jax.jit(lambda p, t, goal, obstacles, gains: Vortex()(p, jnp.zeros(3), t, goal, obstacles, gains, SIM))


def _numpy_vortex(p, t, goal, field, gains):
    """Independent: the oracle's numpy basic repulsion per obstacle, turned by hand."""
    arrays = oracle._scenario_arrays(field)
    g = {k: float(gains[k]) for k in ("gamma", "k", "k_rep", "d_s", "k_att", "eta")}
    sim = SimConfig.from_flat(method="basic")
    _, grad_u, _, _ = oracle._rep_terms(np.asarray(p, np.float64), np.zeros(3), t, arrays, g, sim)
    force = np.where(arrays["valid"][:, None], -grad_u, 0.0)  # F_o = -∇U_rep per obstacle
    s = arrays["proj"] * (arrays["position"] + arrays["velocity"] * t - p)
    w = SIM.vehicle.v_max * (goal - p) / np.linalg.norm(goal - p) - arrays["velocity"]  # (M, 3)
    side = np.where(s[:, 0] * w[:, 1] - s[:, 1] * w[:, 0] >= 0.0, 1.0, -1.0)
    turned = np.stack([force[:, 1], -force[:, 0]], axis=1)  # R(-90°) (x, y) = (y, -x)
    return float(gains["k_v"]) * np.append((side[:, None] * turned).sum(axis=0), 0.0)


def test_matches_an_independent_numpy_computation():
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        field = three_obstacle_field()
        gains = GAINS.as_arrays(jnp.float64)
        for _ in range(40):
            p = rng.normal(size=3) * 2.5 + np.array([6.0, 0.5, 0.5])
            goal, t = rng.normal(size=3) * 6.0, rng.uniform(0.0, 4.0)
            got = np.asarray(_vortex(jnp.asarray(p), t, jnp.asarray(goal), field.obstacles.columns(), gains))
            np.testing.assert_allclose(got, _numpy_vortex(p, t, goal, field, GAINS), rtol=1e-9, atol=1e-12)


def _one_obstacle(p_o=(5.0, 0.0, 2.0), radius=1.0, cylinder=False):
    return Obstacles(position=jnp.asarray([p_o]), velocity=jnp.zeros((1, 3)), radius=jnp.asarray([radius]),
                     cylinder=jnp.asarray([cylinder]), valid=jnp.asarray([True])).columns()


@settings(max_examples=60, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-8.0, 8.0), st.floats(-8.0, 8.0))
def test_perpendicular_to_the_repulsion_with_k_v_times_its_horizontal_size(x, y, gx, gy):
    """One obstacle: the term is the horizontal repulsion turned by ±90°, scaled by k_v."""
    from jaxapf.planners.potentials import repulsive_force

    p, obstacles = jnp.asarray([x, y, 2.3]), _one_obstacle()
    term = np.asarray(_vortex(p, 0.0, jnp.asarray([gx, gy, 2.0]), obstacles, GAINS))
    rep = np.asarray(repulsive_force(p, jnp.zeros(3), obstacles.position[:, 0], jnp.zeros(3), k_rep=GAINS.k_rep,
                                     d_s=GAINS.d_s, method="basic", convention="intent", radius=1.0 + SIM.vehicle.r_uav,
                                     cylinder=False, d_min=SIM.planner.d_min))
    assert term[2] == 0.0
    assert abs(term[:2] @ rep[:2]) <= 1e-4 * (1.0 + np.linalg.norm(rep[:2]) ** 2)
    np.testing.assert_allclose(np.linalg.norm(term[:2]), 1.5 * np.linalg.norm(rep[:2]), rtol=1e-4, atol=1e-6)


def test_static_obstacle_side_changes_only_when_the_goal_crosses_the_line_of_sight():
    """UAV at the origin, static obstacle on +x: a goal left of the x axis turns the UAV to +y, a
    goal right of it to -y; a goal on the line counts as left; moving the goal along one side
    never flips it."""
    obstacles, p = _one_obstacle(p_o=(3.0, 0.0, 0.0)), jnp.zeros(3)
    side = lambda gx, gy: np.sign(np.asarray(_vortex(p, 0.0, jnp.asarray([gx, gy, 0.0]), obstacles, GAINS))[1])  # noqa: E731
    assert [side(x, 0.5) for x in (-5.0, 0.0, 2.0, 6.0, 20.0)] == [1.0] * 5
    assert [side(x, -0.5) for x in (-5.0, 0.0, 2.0, 6.0, 20.0)] == [-1.0] * 5
    assert side(10.0, 0.0) == 1.0 and side(10.0, 1e-6) == 1.0 and side(10.0, -1e-6) == -1.0


def _moving(p_o, v_o):
    return Obstacles(position=jnp.asarray([p_o]), velocity=jnp.asarray([v_o]), radius=jnp.asarray([0.6]),
                     cylinder=jnp.asarray([False]), valid=jnp.asarray([True])).columns()


@pytest.mark.parametrize("offset", [0.4, -0.4])
def test_an_obstacle_from_behind_is_dodged_away_from_its_path(offset):
    """An obstacle 2 m behind, ``offset`` to one side, overtaking at 4 m/s (> v_max): the term
    pushes the UAV to the other side (away from the obstacle's path), whereas the goal's side of
    the line of sight would push it toward the obstacle's side."""
    goal = jnp.asarray([30.0, 0.0, 0.0])
    term = np.asarray(_vortex(jnp.zeros(3), 0.0, goal, _moving((-2.0, offset, 0.0), (4.0, 0.0, 0.0)), GAINS))
    assert np.sign(term[1]) == -np.sign(offset)


@pytest.mark.parametrize("offset", [0.4, -0.4])
def test_an_oncoming_obstacle_is_dodged_away_from_its_path(offset):
    """Head-on: an obstacle 2.5 m ahead, ``offset`` to one side, coming at 2 m/s: away from it."""
    goal = jnp.asarray([30.0, 0.0, 0.0])
    term = np.asarray(_vortex(jnp.zeros(3), 0.0, goal, _moving((2.5, offset, 0.0), (-2.0, 0.0, 0.0)), GAINS))
    assert np.sign(term[1]) == -np.sign(offset)


def _overtake_field(offset: float, speed: float = 4.0, behind: float = 6.0):
    """The ``overtake`` family by hand: the UAV flies 40 m along x at 2 m up; one 0.8 m sphere starts
    ``behind`` m behind it, ``offset`` to the side, and flies along x at ``speed``."""
    from jaxapf.datatypes import Scenario

    return Scenario(start=jnp.asarray([0.0, 0.0, 2.0]), goal=jnp.asarray([40.0, 0.0, 2.0]),
                    obstacles=Obstacles(position=jnp.asarray([[-behind, offset, 2.0]]),
                                        velocity=jnp.asarray([[speed, 0.0, 0.0]]), radius=jnp.asarray([0.8]),
                                        cylinder=jnp.asarray([False]), valid=jnp.asarray([True])))


def _head_on_field(offset: float, speed: float = 2.0):
    """One 0.8 m sphere 25 m ahead, ``offset`` to the side, flying toward the UAV at ``speed``."""
    from jaxapf.datatypes import Scenario

    return Scenario(start=jnp.asarray([0.0, 0.0, 2.0]), goal=jnp.asarray([40.0, 0.0, 2.0]),
                    obstacles=Obstacles(position=jnp.asarray([[25.0, offset, 2.0]]),
                                        velocity=jnp.asarray([[-speed, 0.0, 0.0]]), radius=jnp.asarray([0.8]),
                                        cylinder=jnp.asarray([False]), valid=jnp.asarray([True])))


@pytest.mark.parametrize("offset", [0.3, -0.3])
def test_the_vortex_planner_survives_an_overtaking_obstacle(offset):
    """Closed loop on hand-made ``overtake`` and ``head_on`` fields: the vortex planner lets the
    obstacle pass without a collision (the goal's-side rule steered into an overtaking obstacle's path)."""
    for field in (_overtake_field(offset), _head_on_field(offset)):
        assert outcomes(field, ("vortex",))["vortex"]["collision"] is False


def test_vanishes_beyond_the_influence_distance_and_for_padded_slots():
    far = _one_obstacle(p_o=(50.0, 0.0, 2.0))
    assert np.all(np.asarray(_vortex(jnp.zeros(3), 0.0, jnp.asarray([99.0, 1.0, 0.0]), far, GAINS)) == 0.0)
    padded = Obstacles(position=jnp.asarray([[1.5, 0.0, 0.0]]), velocity=jnp.zeros((1, 3)),
                       radius=jnp.asarray([1.0]), cylinder=jnp.asarray([False]), valid=jnp.asarray([False]))
    assert np.all(np.asarray(_vortex(jnp.zeros(3), 0.0, jnp.asarray([9.0, 1.0, 0.0]), padded.columns(), GAINS)) == 0)


def test_the_vortex_planner_passes_an_obstacle_on_the_line_to_the_goal():
    """The GNRON trap in its purest form: a sphere exactly between start and goal. The basic
    potential field stalls in front of it; the vortex goes around and reaches the goal."""
    outcome = outcomes(one_obstacle_scenario(16.0, 8.0, 1.5), ("basic", "vortex"))
    assert outcome["basic"] == {"success": False, "collision": False, "stalled": True}
    assert outcome["vortex"] == {"success": True, "collision": False, "stalled": False}


def test_registered_with_its_gain():
    planner = PLANNERS.get("vortex")
    assert [g.name for g in planner.gains] == ["k_v", "k_rep", "d_s", "k_att", "eta"]
    assert Gains().k_v == 1.0


@pytest.mark.parametrize("k_v", [0.0, 2.0])
def test_k_v_zero_is_the_basic_planner(k_v):
    """With k_v = 0 the vortex planner flies the basic planner's episode (two compiled programs: up to
    float32 rounding over 30 steps, 1e-4 m); with k_v = 2 it flies a visibly different one."""
    sim, mpc = SimConfig.from_flat(method="vortex", t_max=3.0), MPCConfig(horizon=6, iters=10)
    basic = SimConfig.from_flat(method="basic", t_max=3.0)
    field = three_obstacle_field(jnp, jnp.float32)
    run = jax.jit(rollout, static_argnums=(2, 3))
    mine = np.asarray(run(field, Gains(k_v=k_v), sim, mpc).position)
    theirs = np.asarray(run(field, Gains(), basic, mpc).position)
    gap = float(np.max(np.abs(mine - theirs)))
    assert gap <= 1e-4 if k_v == 0.0 else gap > 1e-2
