"""The keep-out MPC (jaxapf.planners.keepout_mpc): its QPs, harvested from real episodes, against Clarabel
(objective and constraint violation), its rows against a hand-computed tangent plane, hand-made
encounters (an obstacle on the line, a faster obstacle from behind, a start inside an obstacle), and
the loop applying its plan's first acceleration with no MPC to tune or take out."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import one_obstacle_scenario

from jaxapf import Gains
from jaxapf.config import MPCConfig, SimConfig
from jaxapf.datatypes import Obstacles
from jaxapf.engine import rollout
from jaxapf.engine.loop import closed_loop, loop_init, loop_step
from jaxapf.metrics import episode_metrics
from jaxapf.planners import PLANNERS
from jaxapf.planners.keepout_mpc import keepout_qp, solve
from jaxapf.scenarios import family_params, make_scenarios
from jaxapf.validation import ConfigError

SIM = SimConfig.from_flat(method="keepout_mpc", t_max=30.0)
MPC = MPCConfig()
PLANNER = PLANNERS.get("keepout_mpc")


def _harvest(scenario, every: int):
    """The QPs ``(H, e, G, h)`` the planner solved at every ``every``-th step of one episode (float32, as flown)."""
    gains = Gains().as_arrays(jnp.float32)
    loop = closed_loop(SIM, MPC, jnp.float32)
    columns = scenario.obstacles.columns()

    def step(carry, k):
        x = loop.plant.kinematics(carry[0])
        qp = PLANNER.step_qp(carry[2], x, k * SIM.episode.dt, scenario.goal, columns, gains, SIM, MPC.horizon)
        carry, _ = loop_step(loop, carry, k, scenario, columns, gains, SIM, MPC)
        return carry, qp

    _, qps = jax.lax.scan(step, loop_init(loop, scenario, gains, SIM, MPC),
                          jnp.arange(SIM.episode.steps, dtype=jnp.float32))
    return tuple(q[::every] for q in qps)


def _real_qps(family: str, fields: int, every: int):
    """The QPs of ``fields`` episodes of ``family`` (one leading axis: episode-major, then step)."""
    qps = jax.jit(jax.vmap(lambda s: _harvest(s, every)))(make_scenarios(0, family_params(family), fields))
    return tuple(np.asarray(q).reshape((-1,) + q.shape[2:]) for q in qps)


def _clarabel(hess, lin, g, h):
    """The QP by Clarabel's interior point method in float64 to 1e-10 (OSQP's ADMM reached its iteration
    limit on 10 of 480 clutter QPs at 1e-7, whatever its scaling: Clarabel solves every one)."""
    import clarabel
    import scipy.sparse as sp

    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = 1e-10
    solver = clarabel.DefaultSolver(sp.csc_matrix(np.triu(hess)), lin, sp.csc_matrix(g), h,
                                    [clarabel.NonnegativeConeT(len(h))], settings)
    result = solver.solve()
    assert str(result.status) == "Solved"
    return np.asarray(result.x)


def _check_against_clarabel(qps):
    hess, lin, g, h = (a.astype(np.float64) for a in qps)
    reference = np.array([_clarabel(*q) for q in zip(hess, lin, g, h)])

    def objective(z):
        return 0.5 * np.einsum("bi,bij,bj->b", z, hess, z) + np.einsum("bi,bi->b", lin, z)

    def violation(z):
        return np.max(np.einsum("bij,bj->bi", g, z) - h, axis=1)

    scale = np.maximum(1.0, np.abs(objective(reference)))
    assert np.max(violation(reference)) <= 1e-6
    # float64: qpax and Clarabel agree to solver tolerance
    with jax.enable_x64(True):
        z64 = np.asarray(jax.jit(jax.vmap(solve))(*(jnp.asarray(a) for a in (hess, lin, g, h))))
    assert np.abs(objective(z64) - objective(reference)).max() / scale.min() <= 1e-5
    assert np.max(violation(z64)) <= 1e-9
    # float32 as flown: the same, up to float32 rounding of positions ~10 m (a few µm)
    z32 = np.asarray(jax.jit(jax.vmap(solve))(*(jnp.asarray(a) for a in qps))).astype(np.float64)
    assert np.max(np.abs(objective(z32) - objective(reference)) / scale) <= 1e-3
    assert np.max(violation(z32)) <= 2e-5


FAMILIES = ("trap", "clutter", "overtake", "crossing", "dynamic")


def test_its_qps_from_real_episodes_match_clarabel():
    qps = _real_qps("clutter", fields=2, every=25)  # the most rows; every family in the slow tier
    assert len(qps[0]) == 2 * SIM.episode.steps // 25
    _check_against_clarabel(qps)


@pytest.mark.slow
def test_thousands_of_its_qps_from_real_episodes_match_clarabel():
    for family in FAMILIES:  # 5 x 480 QPs
        qps = _real_qps(family, fields=8, every=5)
        assert len(qps[0]) == 8 * SIM.episode.steps // 5
        _check_against_clarabel(qps)


def test_a_keep_out_row_is_the_tangent_plane_at_the_last_plan():
    """One static cylinder, N = 2: row i reads n·p_i >= n·c + ρ + r_uav + m, n from c to the last plan's
    point with z dropped, p_i the double integrator's position."""
    scenario = one_obstacle_scenario(goal_x=12.0, obstacle_x=6.0, radius=1.5)
    x = jnp.asarray([0.0, 0.0, 2.0, 1.0, 0.5, 0.0])
    last = jnp.asarray([[3.0, 4.0, 7.0], [3.0, 4.0, 9.0]])  # last - c in the plane: (-3, 4) -> n = (-0.6, 0.8, 0)
    gains = Gains().as_arrays(jnp.float32)
    _, _, g, h = keepout_qp(x, jnp.asarray(0.0), jnp.zeros(3), last, scenario.obstacles.columns(), gains, SIM, 2)
    dt, n = SIM.episode.dt, np.array([-0.6, 0.8, 0.0])
    bound = n @ np.array([6.0, 0.0, 2.0]) + 1.5 + SIM.vehicle.r_uav + float(gains.kmpc_margin)
    for i in (1, 2):  # p_i = p + iΔt v + Σ_j (i - j - ½) Δt² a_j: the row on a_j is -(i - j - ½) Δt² n
        row = np.zeros(7)
        for j in range(i):
            row[3 * j:3 * j + 3] = -(i - j - 0.5) * dt * dt * n
        row[-1] = -1.0  # the slack
        np.testing.assert_allclose(np.asarray(g[i - 1]), row, atol=1e-7)
        assert float(h[i - 1]) == pytest.approx(-(bound - n @ (np.array([0.0, 0.0, 2.0]) + i * dt * np.asarray(x[3:]))),
                                                abs=1e-5)


def _fly(scenario, **flat):
    sim = SimConfig.from_flat(method="keepout_mpc", t_max=30.0, **flat)
    traj = jax.jit(rollout, static_argnums=(2, 3))(scenario, Gains(), sim, MPC)
    metrics = episode_metrics(traj, scenario, sim, ("success", "collision", "stalled", "min_clearance",
                                                    "kmpc_infeasible_steps"))
    return traj, {k: float(v) for k, v in metrics.items()}


def test_it_goes_round_an_obstacle_off_the_line_by_its_margin_and_halts_before_one_dead_on_it():
    """5 cm off the straight line, the tangent planes turn as it slides along them and it passes at the
    margin (0.2 m); dead on the line the plane faces it squarely and it halts at it (a symmetric deadlock)."""
    scenario = one_obstacle_scenario(goal_x=12.0, obstacle_x=6.0, radius=1.5)
    _, m = _fly(scenario)
    assert (m["success"], m["collision"], m["stalled"]) == (0.0, 0.0, 1.0)
    scenario = dataclasses.replace(scenario, obstacles=dataclasses.replace(scenario.obstacles,
                                                                           position=jnp.asarray([[6.0, 0.05, 2.0]])))
    traj, m = _fly(scenario)
    assert m["success"] == 1.0 and m["collision"] == 0.0 and m["kmpc_infeasible_steps"] == 0.0
    # the keep-out rows hold at the sample times; between samples the chord may cut in by a few mm
    assert 0.19 <= m["min_clearance"] <= 0.21
    # the loop flies the plan's first acceleration: the applied control is what the planner commanded
    plan0 = PLANNER.reference(PLANNER.init(scenario, Gains().as_arrays(jnp.float32), SIM, MPC.horizon),
                              jnp.concatenate([scenario.start, jnp.zeros(3)]), jnp.asarray(0.0), scenario.goal,
                              scenario.obstacles.columns(), Gains().as_arrays(jnp.float32), SIM, MPC.horizon)[1]
    np.testing.assert_allclose(np.asarray(traj.control[0]), np.asarray(PLANNER.command(plan0)), atol=1e-5)


def test_a_faster_obstacle_from_behind_counts_infeasible_steps_and_a_start_inside_one_too():
    """An obstacle overtaking at 3 m/s on the UAV's line: no plan keeps it out while it passes (a_max bounds
    the escape), the slack is taken and counted; starting inside an obstacle is infeasible from step 0."""
    base = one_obstacle_scenario(goal_x=30.0, obstacle_x=-4.0, radius=1.0)
    faster = dataclasses.replace(base.obstacles, velocity=jnp.asarray([[3.0, 0.0, 0.0]]))
    chase = dataclasses.replace(base, obstacles=faster)
    _, m = _fly(chase)
    assert m["kmpc_infeasible_steps"] > 0.0
    inside = one_obstacle_scenario(goal_x=12.0, obstacle_x=0.5, radius=1.0)
    traj, _ = _fly(inside)
    assert bool(traj.extras["kmpc_infeasible"][0])
    # it does what it can: it leaves the obstacle the shortest way (away from its centre, -x)
    assert float(traj.position[20, 0]) < -0.3


@pytest.mark.parametrize("field, value", [("tracking", "ideal"), ("mpc_weights", "gains")])
def test_no_mpc_tracks_it_so_there_is_none_to_weigh_or_take_out(field, value):
    with pytest.raises(ConfigError, match=f"sim.{field} = '{value}': planner 'keepout_mpc' flies its own plan"):
        closed_loop(SimConfig.from_flat(method="keepout_mpc", **{field: value}), MPC, jnp.float32)


def test_obstacles_arranged_as_a_cup_stall_it_as_they_stall_basic():
    """A local planner: a cup closed towards the goal, every keep-out row held, the goal out of reach."""
    wall = one_obstacle_scenario(goal_x=12.0, obstacle_x=6.0, radius=1.5)
    cup_x, cup_y = np.array([5.0, 5.6, 5.6, 5.0]), np.array([-1.2, -0.6, 0.6, 1.2])
    m = len(cup_x)
    cup = dataclasses.replace(wall, obstacles=Obstacles(
        position=jnp.asarray(np.stack([cup_x, cup_y, np.full(m, 2.0)], axis=1)), velocity=jnp.zeros((m, 3)),
        radius=jnp.full(m, 0.6), cylinder=jnp.ones(m, bool), valid=jnp.ones(m, bool)))
    _, metrics = _fly(cup)
    assert (metrics["success"], metrics["collision"], metrics["stalled"]) == (0.0, 0.0, 1.0)
