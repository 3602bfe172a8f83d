"""The swarm engine: every UAV flies the stack and sees the others as obstacles (jaxapf.engine.swarm)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxapf.config import MPCConfig, SimConfig
from jaxapf.datatypes import Obstacles, obstacles_at
from jaxapf.datatypes.swarm import Swarm, agent_view, neighbours, with_neighbours
from jaxapf.engine import rollout
from jaxapf.engine.swarm import swarm_rollout
from jaxapf.gains import Gains
from jaxapf.scenarios import family_params, make_scenarios

MPC = MPCConfig()


def _swap(dtype=jnp.float32, lateral: float = 0.0, valid=(True, True)) -> Swarm:
    """Two UAVs 10 m apart flying to each other's start (RVO2's two-agent circle)."""
    n = len(valid)
    start = np.array([[0.0, 0.0, 2.0], [10.0, lateral, 2.0], [5.0, 0.0, 2.0]])[:n]
    goal = np.array([[10.0, 0.0, 2.0], [0.0, lateral, 2.0], [5.0, 0.0, 2.0]])[:n]
    return Swarm(start=jnp.asarray(start, dtype), goal=jnp.asarray(goal, dtype), valid=jnp.asarray(valid),
                 obstacles=Obstacles.empty(2, dtype))


def _fly(swarm: Swarm, gains: Gains | None = None, **sim):
    config = SimConfig.from_flat({"t_max": 20.0} | sim)
    traj = jax.jit(lambda s: swarm_rollout(s, gains or Gains(), config, MPC))(swarm)
    return np.asarray(traj.position), config


def _separation(p: np.ndarray, config: SimConfig) -> np.ndarray:
    return np.linalg.norm(p[0] - p[1], axis=-1) - 2 * config.vehicle.r_uav


@pytest.mark.parametrize("sim", [{"method": "direction_velocity"},
                                 pytest.param({"method": "velocity_obstacle", "filter": "cbf"}, marks=pytest.mark.slow),
                                 pytest.param({"method": "basic_escape", "sensor": "noisy"}, marks=pytest.mark.slow)])
def test_a_one_uav_swarm_is_the_single_uav_program_bit_for_bit(sim):
    field = make_scenarios(3, family_params("clutter"), 1).take(0)
    config = SimConfig.from_flat({"t_max": 8.0} | sim)
    gains = Gains(sigma_obs_p=0.05)
    one = jax.jit(lambda s: swarm_rollout(s, gains, config, MPC))(Swarm.of(field))
    alone = jax.jit(lambda s: rollout(s, gains, config, MPC))(field)
    for a, b in zip(jax.tree_util.tree_leaves(one), jax.tree_util.tree_leaves(alone)):
        np.testing.assert_array_equal(np.asarray(a)[0], np.asarray(b))


def test_neighbours_stand_where_the_uavs_are_and_leave_out_itself_and_padding():
    swarm = _swap(valid=(True, True, False))
    view = agent_view(swarm, 0, 0.25)
    assert view.obstacles.radius.shape == (2 + 3,)  # the others at rest at their starts, padding out
    assert np.array_equal(np.asarray(view.obstacles.valid), [False, False, False, True, False])
    assert np.array_equal(np.asarray(view.obstacles.agent), [False, False, True, True, True])
    x = jnp.array([[1.0, 2.0, 2.0, 0.5, -1.0, 0.0], [7.0, 0.5, 2.0, -1.5, 0.25, 0.0], [5.0, 0.0, 2.0, 0, 0, 0]])
    t = jnp.float32(3.7)
    seen = neighbours(view.obstacles.columns(), swarm, x, t, 0, 0.25)
    assert np.array_equal(np.asarray(seen.valid), [False, False, False, True, False])  # itself and padding out
    at = obstacles_at(Obstacles(jnp.moveaxis(seen.position, 0, 1), jnp.moveaxis(seen.velocity, 0, 1), seen.radius,
                                seen.cylinder, seen.valid), t)
    np.testing.assert_allclose(np.asarray(at[3]), [7.0, 0.5, 2.0], atol=1e-6)  # where UAV 1 is at t
    np.testing.assert_allclose(np.asarray(seen.velocity[:, 3]), [-1.5, 0.25, 0.0])
    assert float(seen.radius[3]) == 0.25 and not bool(seen.cylinder[3])
    assert with_neighbours(swarm.obstacles, 0) is swarm.obstacles


def test_each_uav_has_its_own_key_and_uav_0_the_fields():
    field = make_scenarios(3, family_params("clutter"), 1).take(0)
    swarm = Swarm(start=jnp.stack([field.start] * 3), goal=jnp.stack([field.goal] * 3), valid=jnp.ones(3, bool),
                  obstacles=field.obstacles, key=field.key)
    keys = [np.asarray(agent_view(swarm, a, 0.25).key) for a in range(3)]
    assert np.array_equal(keys[0], np.asarray(field.key))
    assert len({k.tobytes() for k in keys}) == 3


def test_reciprocal_velocity_obstacles_swap_two_uavs_head_on_sharing_the_avoidance():
    """Two UAVs flying at each other: each takes half of the avoidance (ORCA's ½), so they pass
    symmetrically, no closer than the margin, and both arrive."""
    p, config = _fly(_swap(), method="velocity_obstacle")
    margin = Gains().vo_margin
    assert _separation(p, config).min() >= margin - 0.01
    np.testing.assert_allclose(p[:, -1], [[10.0, 0.0, 2.0], [0.0, 0.0, 2.0]], atol=0.05)
    np.testing.assert_allclose(p[0, :, 0] + p[1, :, 0], 10.0, atol=1e-3)  # point symmetry about the midpoint
    np.testing.assert_allclose(p[0, :, 1] + p[1, :, 1], 0.0, atol=1e-3)
    assert np.abs(p[0, :, 1]).max() > 0.1  # each swerved


@pytest.mark.slow
def test_without_reciprocity_each_uav_takes_the_whole_avoidance():
    """ORCA's half-space against another UAV asks for half the velocity change ``u`` that a passive
    obstacle at the same place asks for; ``velocity_obstacle_unilateral`` asks for all of it. One UAV
    alone flies the same numbers with either planner."""
    from jaxapf.planners import PLANNERS
    from jaxapf.planners.velocity_obstacle import orca_half_spaces

    x = jnp.array([0.0, 0.0, 2.0, 1.0, 0.0, 0.0])
    here = Obstacles(position=jnp.array([[4.0, 0.1, 2.0]] * 2), velocity=jnp.array([[-1.0, 0.0, 0.0]] * 2),
                     radius=jnp.array([0.3, 0.3]), cylinder=jnp.array([False, False]), valid=jnp.array([True, True]),
                     agent=jnp.array([False, True]))
    config = SimConfig.from_flat(method="velocity_obstacle")
    for reciprocal, share in ((True, 0.5), (False, 1.0)):
        n, bound = orca_half_spaces(x, jnp.float32(0.0), here.columns(), Gains().as_arrays(jnp.float32), config,
                                    reciprocal)
        push = np.asarray(bound) - np.asarray(n) @ np.asarray(x[3:])  # n·u of each slot
        assert push[0] > 0.1  # on a collision course: a real change is asked for
        np.testing.assert_allclose(push[1], share * push[0], rtol=1e-6)
    assert not PLANNERS.get("velocity_obstacle_unilateral").reciprocal
    field = make_scenarios(3, family_params("clutter"), 1).take(0)
    runs = [jax.jit(lambda s, m=m: rollout(s, Gains(), SimConfig.from_flat(t_max=4.0, method=m), MPC))(field)
            for m in ("velocity_obstacle", "velocity_obstacle_unilateral")]
    for a, b in zip(*(jax.tree_util.tree_leaves(r) for r in runs)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.slow
def test_potential_fields_deadlock_in_the_symmetric_swap():
    """The classical failure the swarm families are built to measure: the repulsion of two UAVs flying
    at each other balances their attraction on the line between them, and both stop short."""
    p, config = _fly(_swap(), method="basic")
    assert _separation(p, config).min() > 0.5
    assert np.all(np.linalg.norm(p[:, -1] - np.array([[10.0, 0, 2], [0, 0, 2]]), axis=-1) > 3.0)
    assert np.abs(p[:, :, 1]).max() < 1e-4  # never leave the line


@pytest.mark.slow
def test_neighbours_are_sensed_like_obstacles():
    """With a sensing range below the passing distance nobody sees anybody: the two UAVs fly straight
    through each other; in full view they do not."""
    blind, config = _fly(_swap(), Gains(sense_range=0.01), method="velocity_obstacle", sensor="noisy")
    seeing, _ = _fly(_swap(), method="velocity_obstacle", sensor="noisy")
    assert _separation(blind, config).min() < -0.4
    assert _separation(seeing, config).min() > 0.2


@pytest.mark.slow
def test_a_padded_uav_is_invisible():
    """A third slot parked on the line between the two, marked invalid: the two fly as if it were
    not there (float64, up to rounding between the two programs)."""
    with jax.enable_x64(True):
        two, _ = _fly(_swap(jnp.float64), method="velocity_obstacle")
        three, _ = _fly(_swap(jnp.float64, valid=(True, True, False)), method="velocity_obstacle")
        shown, _ = _fly(_swap(jnp.float64, valid=(True, True, True)), method="velocity_obstacle")
    np.testing.assert_allclose(three[:2], two, atol=1e-9)
    assert np.abs(shown[:2] - two).max() > 0.1  # the same UAV, valid, is avoided


def test_with_max_neighbours_a_uav_sees_the_nearest_others_nearest_first():
    swarm = _swap(valid=(True, True, True))
    x = jnp.array([[0.0, 0.0, 2.0, 0, 0, 0], [10.0, 0.0, 2.0, -1.0, 0, 0], [3.0, 0.0, 2.0, 0, 0.5, 0]])
    view = agent_view(swarm, 0, 0.25, max_neighbours=1)
    assert view.obstacles.radius.shape == (2 + 1,)  # one neighbour slot
    seen = neighbours(view.obstacles.columns(), swarm, x, jnp.float32(0.0), 0, 0.25, max_neighbours=1)
    np.testing.assert_allclose(np.asarray(seen.position[:, 2]), [3.0, 0.0, 2.0])  # UAV 2 at 3 m, not UAV 1 at 10 m
    np.testing.assert_allclose(np.asarray(seen.velocity[:, 2]), [0.0, 0.5, 0.0])
    assert np.asarray(seen.valid).tolist() == [False, False, True]
    # K >= A - 1: every other UAV, the layout of max_neighbours = 0
    full = agent_view(swarm, 0, 0.25, max_neighbours=2)
    assert full.obstacles.radius.shape == (2 + 3,)


@pytest.mark.slow
def test_max_neighbours_culls_far_uavs_from_the_stack():
    """Four UAVs in a line swapping pairwise: with every neighbour seen, UAV 0 reacts to the far pair
    too; with max_neighbours = 1 only to its partner, so its flight differs, and the swap stays safe."""
    start = np.array([[0.0, 0.0, 2.0], [8.0, 0.0, 2.0], [0.0, 3.0, 2.0], [8.0, 3.0, 2.0]])
    swarm = Swarm(start=jnp.asarray(start, jnp.float32), goal=jnp.asarray(start[[1, 0, 3, 2]], jnp.float32),
                  valid=jnp.ones(4, bool), obstacles=Obstacles.empty(2, jnp.float32))
    every, config = _fly(swarm, method="velocity_obstacle", t_max=12.0)
    near, _ = _fly(swarm, method="velocity_obstacle", t_max=12.0, max_neighbours=1)
    assert not np.array_equal(every, near)
    pairs = np.linalg.norm(near[:, None] - near[None, :], axis=-1) - 2 * config.vehicle.r_uav
    assert pairs[~np.eye(4, dtype=bool)].min() > 0.0


@pytest.mark.slow
@pytest.mark.parametrize("family, method", [("circle_swap", "velocity_obstacle"), ("swarm_clutter", "basic")])
def test_streamed_swarms_are_the_fixed_engines_swarms(family, method):
    """The streaming engine stops a swarm once every UAV has certainly ended; its metrics are those of the
    fixed-length engine up to rounding (two gain settings, the second's repulsion too weak to keep off
    the obstacles; 24 fields of 4 UAVs)."""
    from conftest import assert_same_episodes

    from jaxapf.engine.swarm import evaluate_swarms
    from jaxapf.scenarios.swarms import make_swarms, swarm_params

    swarms = make_swarms(1, swarm_params(family, agents=4), 24)
    gains = Gains(eta=np.array([0.5, 0.8], np.float32), k_rep=np.array([10.0, 0.2], np.float32))  # weak: collides
    sim = SimConfig.from_flat(method=method, t_max=25.0)
    mpc = MPCConfig(horizon=10, iters=15)
    fixed = jax.device_get(evaluate_swarms(swarms, gains, sim, mpc, 64, streaming=False))
    streamed = jax.device_get(evaluate_swarms(swarms, gains, sim, mpc, 64))
    assert_same_episodes(fixed, streamed, sim.episode.dt)
    assert np.nanmin(streamed["makespan"]) < 0.8 * 25.0, "swarms must end early for the test to bite"
    assert streamed["obstacle_collision"].any() or family != "swarm_clutter", "and some UAVs hit obstacles"


@pytest.mark.slow
def test_a_streamed_swarms_numbers_do_not_depend_on_its_queue():
    """The first 8 fields alone and inside a queue of 40 (the same slots): bit for bit the same numbers,
    also for the potential fields, whose swarms carry a rounding difference far (another program gives
    other numbers, not this one)."""
    from jaxapf.engine.swarm import evaluate_swarms
    from jaxapf.scenarios.swarms import make_swarms, swarm_params

    swarms = make_swarms(2, swarm_params("circle_swap", agents=6), 40)
    sim = SimConfig.from_flat(method="direction_velocity", t_max=20.0)
    mpc = MPCConfig(horizon=10, iters=15)
    whole = evaluate_swarms(swarms, Gains(), sim, mpc, 64)
    part = evaluate_swarms(jax.tree_util.tree_map(lambda x: x[:8], swarms), Gains(), sim, mpc, 64)
    for name in whole:
        np.testing.assert_array_equal(np.asarray(whole[name])[:, :8], np.asarray(part[name]), err_msg=name)


@pytest.mark.slow
def test_with_latency_a_uav_sees_where_the_others_truly_were():
    """Latency of 3 steps: at step 6 UAV 0's sensor shows UAV 1 where it truly was at step 3 (its true
    past state, not its present one extrapolated back), also when UAV 1 turns; before the episode the
    others stand at rest at their starts."""
    from jaxapf.engine.swarm import at_rest, remember
    from jaxapf.world.sensing import SENSORS

    swarm, dt = _swap(), 0.1
    config = SimConfig.from_flat({"t_max": 20.0, "sensor": "noisy", "dt": dt})
    gains, sensor = Gains(latency=0.3), SENSORS.get("noisy")
    assert int(sensor.delay(gains, config)) == 3 and int(SENSORS.get("ideal").delay(gains, config)) == 0

    def truth(k):  # UAV 0 still at its start; UAV 1 on a curve, its velocity the derivative
        s = k * dt
        return jnp.array([[0.0, 0.0, 2.0, 0.0, 0.0, 0.0],
                          [10.0 - 2.0 * s * s, 1.5 * s, 2.0, -4.0 * s, 1.5, 0.0]], jnp.float32)

    view = agent_view(swarm, 0, config.vehicle.r_uav)
    state = sensor.init(view, gains, config)
    history = at_rest(swarm, config)
    for k in range(7):
        x = truth(k)
        history, then, t_j = remember(history, x, jnp.int32(k), sensor.delay(gains, config), dt)
        seen = neighbours(view.obstacles.columns(), swarm, then, t_j, 0, config.vehicle.r_uav)
        _, observed, state, _ = sensor(state, x[0], jnp.int32(k), view, seen, gains, config)
        shown = np.asarray(observed.position[:, 3] + observed.velocity[:, 3] * (k * dt))  # as the stack sees it at t_k
        past = np.asarray(truth(k - 3)[1, :3]) if k >= 3 else np.asarray(swarm.start[1])
        np.testing.assert_allclose(shown, past, atol=1e-5)
    back = np.asarray(truth(6)[1, :3] - truth(6)[1, 3:] * 0.3)  # the present extrapolated back is elsewhere
    assert np.abs(back - np.asarray(truth(3)[1, :3])).max() > 0.1


@pytest.mark.slow
def test_streamed_swarms_carry_the_others_past_states_like_the_fixed_engine():
    """With latency the streaming engine keeps the UAVs' past states per swarm as the fixed engine does:
    the same metrics up to rounding, and other ones than without latency."""
    from conftest import assert_same_episodes

    from jaxapf.engine.swarm import evaluate_swarms
    from jaxapf.scenarios.swarms import make_swarms, swarm_params

    swarms = make_swarms(2, swarm_params("circle_swap", agents=4), 16)
    sim = SimConfig.from_flat(method="velocity_obstacle", sensor="noisy", t_max=25.0)
    mpc = MPCConfig(horizon=10, iters=15)
    late, now = Gains(latency=np.float32(0.5)), Gains()
    fixed = jax.device_get(evaluate_swarms(swarms, late, sim, mpc, 16, streaming=False))
    streamed = jax.device_get(evaluate_swarms(swarms, late, sim, mpc, 16))
    assert_same_episodes(fixed, streamed, sim.episode.dt)
    prompt = jax.device_get(evaluate_swarms(swarms, now, sim, mpc, 16))
    assert not np.allclose(prompt["min_agent_clearance"], streamed["min_agent_clearance"])


@pytest.mark.slow
def test_the_cbf_filter_among_many_obstacles_keeps_only_the_rows_that_bind_soonest():
    """swarm_clutter (24 obstacle slots and the neighbours) with the CBF filter: 2 UAVs, with 8 rows kept no
    step is truncated, and the swarm metrics are the full projection's up to rounding (docs/testing.md);
    4 UAVs, with 1 row kept (and so 2 in the wider solve) some answers have more rows active than that,
    and those steps are counted."""
    from conftest import assert_same_episodes

    from jaxapf.engine.swarm import evaluate_swarms
    from jaxapf.scenarios.swarms import make_swarms, swarm_params

    mpc = MPCConfig(horizon=10, iters=15)

    def fly(agents: int, rows: int) -> dict:
        swarms = make_swarms(3, swarm_params("swarm_clutter", agents=agents), 8)
        return jax.device_get(evaluate_swarms(swarms, Gains(), SimConfig.from_flat(
            method="basic", filter="cbf", t_max=20.0, projection_rows=rows), mpc, 16))

    full, kept = fly(2, 0), fly(2, 8)
    assert int(full["cbf_truncated_steps"].sum()) == 0 and int(kept["cbf_truncated_steps"].sum()) == 0
    assert_same_episodes(full, kept, 0.1)
    assert int(fly(4, 1)["cbf_truncated_steps"].sum()) > 0
