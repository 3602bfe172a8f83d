"""The velocity-obstacle planner (jaxapf.planners.velocity_obstacle): its ORCA half-spaces against
an independent numpy transcription of RVO2's planar construction and against the definition of a
velocity obstacle, collision-free velocities on random encounters, the closed loop on hand-made
encounters, an infeasible pincer (least violation, counted in ``vo_infeasible_steps``), and
gradients."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import one_obstacle_scenario, three_obstacle_field
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.config import MPCConfig, SimConfig
from jaxapf.datatypes import Obstacles, Scenario
from jaxapf.engine import rollout, rollout_metrics
from jaxapf.gains import Gains
from jaxapf.planners import PLANNERS, VelocityObstacle
from jaxapf.planners.velocity_obstacle import orca_half_spaces
from jaxapf.projection import INFEASIBLE_TOL

SIM = SimConfig.from_flat(method="velocity_obstacle")
PLANNER = VelocityObstacle()
_half_spaces = jax.jit(lambda x, t, obstacles, gains: orca_half_spaces(x, t, obstacles, gains, SIM))
_velocity = jax.jit(lambda x, goal, obstacles, gains: PLANNER.velocity(x, 0.0, goal, obstacles, gains, SIM))


def _obstacles(position, velocity, radius, cylinder) -> Obstacles:
    m = len(radius)
    return Obstacles(position=jnp.asarray(position, jnp.float32).reshape(m, 3),
                     velocity=jnp.asarray(velocity, jnp.float32).reshape(m, 3),
                     radius=jnp.asarray(radius, jnp.float32), cylinder=jnp.asarray(cylinder),
                     valid=jnp.ones(m, bool))


def _rvo2_line(p, v, p_o, v_o, radius, tau, dt):
    """RVO2's Agent::computeNewVelocity for one other agent, planar, written out from the library's
    algorithm, with the whole responsibility on the agent (point = v + u, not v + u/2). Returns the
    inward normal of the ORCA line (the left normal of its direction) and the line's point."""
    rel_p, rel_v = p_o - p, v - v_o
    dist_sq, r_sq = rel_p @ rel_p, radius * radius
    det = lambda a, b: a[0] * b[1] - a[1] * b[0]  # noqa: E731
    if dist_sq > r_sq:
        w = rel_v - rel_p / tau
        w_sq, dot1 = w @ w, w @ rel_p
        if dot1 < 0.0 and dot1 * dot1 > r_sq * w_sq:
            unit_w = w / np.sqrt(w_sq)
            direction = np.array([unit_w[1], -unit_w[0]])
            u = (radius / tau - np.sqrt(w_sq)) * unit_w
        else:
            leg = np.sqrt(dist_sq - r_sq)
            x, y = rel_p
            if det(rel_p, w) > 0.0:  # left leg
                direction = np.array([x * leg - y * radius, x * radius + y * leg]) / dist_sq
            else:  # right leg
                direction = -np.array([x * leg + y * radius, -x * radius + y * leg]) / dist_sq
            u = (rel_v @ direction) * direction - rel_v
    else:
        w = rel_v - rel_p / dt
        unit_w = w / np.linalg.norm(w)
        direction = np.array([unit_w[1], -unit_w[0]])
        u = (radius / dt - np.linalg.norm(w)) * unit_w
    return np.array([-direction[1], direction[0]]), v + u


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.5, 6.0), st.floats(0.0, 0.5))
def test_cylinders_match_rvo2_in_the_plane(seed, tau, margin):
    """Vertical cylinders: the half-space is horizontal and is RVO2's ORCA line (float64)."""
    rng = np.random.default_rng(seed)
    m = 4
    p_o, v_o = rng.uniform(-6, 6, (m, 3)), rng.uniform(-2, 2, (m, 3))
    radius = rng.uniform(0.3, 1.2, m)
    x = np.concatenate([rng.uniform(-2, 2, 3), rng.uniform(-2, 2, 3)])
    gains = Gains(vo_tau=tau, vo_margin=margin)
    with jax.enable_x64(True):
        obstacles = Obstacles(position=jnp.asarray(p_o), velocity=jnp.asarray(v_o), radius=jnp.asarray(radius),
                              cylinder=jnp.ones(m, bool), valid=jnp.ones(m, bool)).columns()
        n, bound = orca_half_spaces(jnp.asarray(x), 0.0, obstacles, gains.as_arrays(jnp.float64), SIM)
    n, bound = np.asarray(n), np.asarray(bound)
    for o in range(m):
        big_r = radius[o] + SIM.vehicle.r_uav + margin
        normal, point = _rvo2_line(x[:2], x[3:5], p_o[o, :2], v_o[o, :2], big_r, tau, SIM.episode.dt)
        np.testing.assert_allclose(n[o], [*normal, 0.0], atol=1e-9)
        assert bound[o] == pytest.approx(normal @ point, abs=1e-9)


def _collides_within(w, s, big_r, tau):
    """Whether the relative velocity ``w`` brings the relative position ``s`` within ``big_r``
    inside ``(0, tau]``, and the smallest distance reached."""
    t = np.clip((w @ s) / max(w @ w, 1e-300), 0.0, tau)
    closest = np.linalg.norm(t * w - s)
    return closest < big_r, closest


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_spheres_half_space_touches_the_velocity_obstacle(seed):
    """Spheres in 3-D, from the definition of the velocity obstacle: ``w + u`` lies on its boundary
    (smallest distance within τ equals R), a step along ``n`` leaves it and a step against ``n``
    enters it."""
    rng = np.random.default_rng(seed)
    s = rng.normal(size=3) * 3.0
    big_r = 0.4 + 0.3 + 0.25 + rng.uniform(0.0, 0.5)
    radius = big_r - SIM.vehicle.r_uav - 0.25
    if np.linalg.norm(s) <= big_r + 0.05:
        s *= (big_r + 0.5) / np.linalg.norm(s)
    v, v_o = rng.normal(size=3), rng.normal(size=3)
    tau = 3.0
    with jax.enable_x64(True):
        obstacles = Obstacles(position=jnp.asarray([s]), velocity=jnp.asarray([v_o]), radius=jnp.asarray([radius]),
                              cylinder=jnp.asarray([False]), valid=jnp.asarray([True])).columns()
        n, bound = orca_half_spaces(jnp.asarray(np.concatenate([np.zeros(3), v])), 0.0, obstacles,
                                    Gains(vo_tau=tau).as_arrays(jnp.float64), SIM)
    n, bound = np.asarray(n)[0], float(bound[0])
    assert np.linalg.norm(n) == pytest.approx(1.0)
    w_touch = v - v_o + (bound - n @ v) * n  # v + u projected onto the plane: v + u itself (u ∥ n)
    _, closest = _collides_within(w_touch, s, big_r, tau)
    assert closest == pytest.approx(big_r, abs=1e-6)
    assert not _collides_within(w_touch + 1e-3 * n, s, big_r, tau)[0]
    assert _collides_within(w_touch - 1e-3 * n, s, big_r, tau)[0]


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1))
@pytest.mark.slow
def test_a_feasible_velocity_collides_with_no_obstacle_within_tau(seed):
    """Random encounters with up to five spheres and cylinders around the UAV: when the half-spaces
    and the speed ball admit a velocity, ``v*`` meets no obstacle within τ, and |v*| <= v_max."""
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, 6))
    radius = rng.uniform(0.3, 1.0, m)
    direction = rng.normal(size=(m, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    p_o = direction * (radius + SIM.vehicle.r_uav + 0.25 + rng.uniform(0.2, 6.0, m))[:, None]
    cylinder = rng.random(m) < 0.5
    p_o[cylinder, 2] = rng.uniform(-3, 3, cylinder.sum())
    v_o = rng.uniform(-1.5, 1.5, (m, 3))
    x = np.concatenate([np.zeros(3), rng.uniform(-1.5, 1.5, 3)])
    obstacles = _obstacles(p_o, v_o, radius, cylinder).columns()
    goal = rng.normal(size=3) * 20.0
    v_star, worst, _ = _velocity(jnp.asarray(x, jnp.float32), jnp.asarray(goal, jnp.float32), obstacles, Gains())
    v_star = np.asarray(v_star, np.float64)
    assert np.linalg.norm(v_star) <= SIM.vehicle.v_max * (1 + 1e-5)
    if float(worst) > INFEASIBLE_TOL:
        return
    for o in range(m):
        keep = np.array([1.0, 1.0, 0.0 if cylinder[o] else 1.0])
        big_r = radius[o] + SIM.vehicle.r_uav + 0.25
        if np.linalg.norm(keep * p_o[o]) <= big_r:
            continue  # a cylinder reached through z: already overlapping, not this test's case
        _, closest = _collides_within(keep * (v_star - v_o[o]), keep * p_o[o], big_r, Gains().vo_tau)
        assert closest >= big_r - 2e-3


@pytest.mark.slow
def test_without_obstacles_it_flies_the_basic_planners_reference():
    """No valid obstacle, far from the goal (the attraction saturated): ``v_pref`` held over the
    horizon is the basic flow's reference."""
    field = three_obstacle_field(jnp, jnp.float32)
    empty = dataclasses.replace(field.obstacles, valid=jnp.zeros(4, bool)).columns()
    x, goal = jnp.asarray([0.0, 0.0, 0.0, 0.5, 0.0, 0.0]), jnp.asarray([30.0, 10.0, 0.0])
    for reference_velocity in (False, True):
        sim = SIM.replace(reference_velocity=reference_velocity)
        basic = SimConfig.from_flat(method="basic", reference_velocity=reference_velocity)
        mine, _ = jax.jit(PLANNER.reference, static_argnums=(6, 7))((), x, 0.0, goal, empty, Gains(), sim, 8)
        theirs, _ = jax.jit(PLANNERS.get("basic").reference, static_argnums=(6, 7))((), x, 0.0, goal, empty, Gains(),
                                                                                   basic, 8)
        np.testing.assert_allclose(np.asarray(mine), np.asarray(theirs), atol=1e-5)


def _crossing() -> Scenario:
    """A sphere crossing the start–goal line so that it reaches the UAV's path just as the UAV does."""
    return Scenario(start=jnp.asarray([0.0, 0.0, 2.0]), goal=jnp.asarray([20.0, 0.0, 2.0]),
                    obstacles=_obstacles([[10.0, -8.0, 2.0]], [[0.0, 1.6, 0.0]], [1.0], [False]))


def _cylinder_near_the_line(offset: float) -> Scenario:
    scenario = one_obstacle_scenario(16.0, 8.0, 1.0)
    return dataclasses.replace(scenario, obstacles=dataclasses.replace(
        scenario.obstacles, position=jnp.asarray([[8.0, offset, 2.0]])))


_SIM_LOOP, _MPC_LOOP = SimConfig.from_flat(method="velocity_obstacle", t_max=30.0), MPCConfig(horizon=10, iters=20)


@pytest.mark.slow
@pytest.mark.parametrize("scenario, name", [(_crossing(), "crossing sphere"),
                                            (_cylinder_near_the_line(0.1), "cylinder 0.1 m off the line")])
def test_the_closed_loop_avoids_what_a_short_horizon_hits(scenario, name):
    """Hand-made encounters: with τ = 0.05 s the planner sees the obstacle too late and collides;
    with the default τ it passes, clear by at least most of its margin, and reaches the goal."""
    blind = rollout_metrics(scenario, Gains(vo_tau=0.05, vo_margin=0.0), _SIM_LOOP, _MPC_LOOP)
    seeing = rollout_metrics(scenario, Gains(), _SIM_LOOP, _MPC_LOOP)
    assert bool(blind["collision"]), name
    assert bool(seeing["success"]) and not bool(seeing["collision"]), name
    assert float(seeing["min_clearance"]) > 0.2, name
    assert int(seeing["vo_infeasible_steps"]) == 0, name


@pytest.mark.slow
def test_a_cylinder_exactly_on_the_line_stops_it_short():
    """ORCA's symmetric deadlock: with the obstacle exactly on the start–goal line and nothing
    else, every half-space only limits the speed along the line, so the UAV stops ``vo_margin``
    short of the cylinder (stalled, no collision) instead of choosing a side."""
    out = rollout_metrics(_cylinder_near_the_line(0.0), Gains(), _SIM_LOOP, _MPC_LOOP)
    assert bool(out["stalled"]) and not bool(out["collision"])
    assert float(out["min_clearance"]) == pytest.approx(0.25, abs=0.02)


def _pincer() -> Scenario:
    """Two spheres rushing at the UAV from either side along x at 6 m/s each: avoiding either one
    within τ needs a sideways speed above v_max, and they ask for opposite sides."""
    obstacles = _obstacles([[-3.0, 0.0, 2.0], [3.0, 0.0, 2.0]], [[6.0, 0.0, 0.0], [-6.0, 0.0, 0.0]], [0.75, 0.75],
                           [False, False])
    return Scenario(start=jnp.asarray([0.0, 0.0, 2.0]), goal=jnp.asarray([0.0, 20.0, 2.0]), obstacles=obstacles)


@pytest.mark.slow
def test_a_pincer_is_infeasible_flown_at_least_violation_and_counted():
    """Hand-made infeasible step: the half-spaces and the speed ball have no common point; the
    velocity flown violates them least (SLSQP's minimax over the ball, float64), and every step of
    the episode until the collision counts in ``vo_infeasible_steps``."""
    from scipy.optimize import minimize

    scenario = _pincer()
    x = jnp.asarray([0.0, 0.0, 2.0, 0.0, 0.0, 0.0])
    obstacles = scenario.obstacles.columns()
    v_star, worst, _ = _velocity(x, scenario.goal, obstacles, Gains())
    n, bound = (np.asarray(a, np.float64) for a in _half_spaces(x, 0.0, obstacles, Gains()))
    assert float(worst) > INFEASIBLE_TOL
    assert float(worst) == pytest.approx(np.max(bound - n @ np.asarray(v_star, np.float64)), abs=1e-5)
    v_max = SIM.vehicle.v_max
    best = min(minimize(lambda z: z[3], np.r_[start, 10.0], method="SLSQP", options={"ftol": 1e-12},
                        constraints=[{"type": "ineq", "fun": lambda z: n @ z[:3] + z[3] - bound},
                                     {"type": "ineq", "fun": lambda z: v_max**2 - z[:3] @ z[:3]}]).fun
               for start in ([0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [-1.0, -1.0, 0.5]))
    assert float(worst) == pytest.approx(best, abs=1e-4)
    out = rollout_metrics(scenario, Gains(), SimConfig.from_flat(method="velocity_obstacle", t_max=3.0), _MPC_LOOP)
    assert bool(out["collision"]) and int(out["steps"]) >= 1
    assert int(out["vo_infeasible_steps"]) == int(out["steps"])
    assert int(out["cbf_infeasible_steps"]) == 0
    basic = rollout_metrics(scenario, Gains(), SimConfig.from_flat(method="basic", t_max=3.0), _MPC_LOOP)
    assert int(basic["vo_infeasible_steps"]) == 0  # no velocity obstacles, nothing recorded


@pytest.mark.slow
def test_gradient_matches_finite_differences():
    """d(final position)/d(vo_margin, vo_tau) through a short closed loop, float64, against central
    differences."""
    with jax.enable_x64(True):
        field = three_obstacle_field()
        sim, mpc = SimConfig.from_flat(method="velocity_obstacle", t_max=2.0), MPCConfig(horizon=5, iters=10)

        def final(theta):
            gains = Gains(vo_margin=theta[0], vo_tau=theta[1]).as_arrays(jnp.float64)
            traj = rollout(field, gains, sim, mpc)
            return jnp.sum(traj.position[-1] * jnp.asarray([1.0, 2.0, 3.0]))

        theta = jnp.asarray([0.3, 2.0], jnp.float64)
        grad = np.asarray(jax.jit(jax.grad(final))(theta))
        f = jax.jit(final)
        eps = 1e-6
        fd = [(f(theta.at[i].add(eps)) - f(theta.at[i].add(-eps))) / (2 * eps) for i in range(2)]
        np.testing.assert_allclose(grad, np.asarray(fd), rtol=1e-4, atol=1e-7)
        assert np.any(grad != 0.0)


def test_registered_with_its_gains():
    planner = PLANNERS.get("velocity_obstacle")
    assert [g.name for g in planner.gains] == ["vo_tau", "vo_margin", "k_att", "eta"]
    assert (Gains().vo_tau, Gains().vo_margin) == (3.0, 0.25)
