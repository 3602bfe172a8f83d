"""Episode metrics (SPEC 6) on hand-made trajectories whose answer is known.

Every trajectory has T = 50 steps of dt = 0.1 s and every field 3 obstacle slots (padded where
unused), so the jitted metric function compiles once and is reused (float32 throughout).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxapf.config import SimConfig
from jaxapf.datatypes import Obstacles, Scenario, Trajectory
from jaxapf.metrics import METRICS, clearance_history, episode_end, episode_metrics, time_to_collision

SIM = SimConfig.from_flat(dt=0.1, t_max=5.0, v_max=2.0, r_uav=0.3, r_goal=0.5, v_stall=0.1, t_stall=3.0, d_safe=1.0)
T = SIM.episode.steps
DT = SIM.episode.dt
M = 3
F32 = dict(rtol=1e-5, atol=1e-5)

_metrics = jax.jit(episode_metrics, static_argnames="sim")
_end = jax.jit(episode_end, static_argnames="sim")
_history = jax.jit(clearance_history, static_argnames="sim")
_ttc = jax.jit(time_to_collision, static_argnames="r_uav")


# --------------------------------------------------------------------------------------------
# builders
# --------------------------------------------------------------------------------------------


def obstacles(*specs: dict, size: int = M) -> Obstacles:
    """Obstacles from ``dict(position=, velocity=, radius=, cylinder=)`` specs, padded to ``size``."""
    pos = np.full((size, 3), 1e6)
    vel = np.zeros((size, 3))
    rad = np.zeros(size)
    cyl = np.zeros(size, bool)
    valid = np.zeros(size, bool)
    for j, s in enumerate(specs):
        pos[j] = s["position"]
        vel[j] = s.get("velocity", (0.0, 0.0, 0.0))
        rad[j] = s["radius"]
        cyl[j] = s.get("cylinder", False)
        valid[j] = True
    return Obstacles(position=jnp.asarray(pos, jnp.float32), velocity=jnp.asarray(vel, jnp.float32),
                     radius=jnp.asarray(rad, jnp.float32), cylinder=jnp.asarray(cyl),
                     valid=jnp.asarray(valid))


def scenario(start, goal, *specs: dict) -> Scenario:
    return Scenario(start=jnp.asarray(start, jnp.float32), goal=jnp.asarray(goal, jnp.float32),
                    obstacles=obstacles(*specs))


def trajectory(position, velocity, control=None) -> Trajectory:
    """A (T+1)-sample trajectory from float64 arrays (control defaults to zero)."""
    position = np.asarray(position, np.float64)
    velocity = np.broadcast_to(np.asarray(velocity, np.float64), position.shape)
    control = np.zeros((T, 3)) if control is None else np.asarray(control, np.float64)
    assert position.shape == (T + 1, 3) and control.shape == (T, 3)
    return Trajectory(time=jnp.asarray(np.arange(T + 1) * DT, jnp.float32),
                      position=jnp.asarray(position, jnp.float32),
                      velocity=jnp.asarray(velocity, jnp.float32),
                      control=jnp.asarray(control, jnp.float32))


def integrate(start, v0, control) -> Trajectory:
    """Exact double-integrator trajectory for piecewise-constant ``control`` (T, 3)."""
    control = np.asarray(control, np.float64)
    p = [np.asarray(start, np.float64)]
    v = [np.broadcast_to(np.asarray(v0, np.float64), (3,)).copy()]
    for a in control:
        p.append(p[-1] + v[-1] * DT + 0.5 * a * DT**2)
        v.append(v[-1] + a * DT)
    return trajectory(np.array(p), np.array(v), control)


def line(start, velocity) -> np.ndarray:
    """Positions (T+1, 3) of constant-velocity flight."""
    return np.asarray(start, np.float64) + np.arange(T + 1)[:, None] * DT * np.asarray(velocity, np.float64)


def values(m: dict) -> dict:
    return {k: np.asarray(v) for k, v in jax.device_get(m).items()}


def assert_metrics_equal(a: dict, b: dict) -> None:
    for name in METRICS:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


# --------------------------------------------------------------------------------------------
# API shape
# --------------------------------------------------------------------------------------------


def test_columns_and_dtypes():
    sc = scenario([0, 0, 1], [8, 0, 1], dict(position=[4, 3, 1], radius=1.0))
    traj = trajectory(line([0, 0, 1], [2, 0, 0]), [2, 0, 0])
    m = _metrics(traj, sc, SIM)
    assert set(m) == set(METRICS)  # jit hands dicts back key-sorted; the order is checked on tracing
    order: list[str] = []
    jax.eval_shape(lambda t, s: order.extend(episode_metrics(t, s, SIM)), traj, sc)
    assert tuple(order) == METRICS.names()
    for name, v in m.items():
        assert v.shape == (), name
        expected = {"bool": jnp.bool_, "int32": jnp.int32, "float": jnp.float32}[METRICS.get(name, "metric").dtype]
        assert v.dtype == expected, name
    counts = {n for n in METRICS.names() if METRICS.get(n, "metric").dtype == "int32"}
    assert counts >= {"steps", "cbf_infeasible_steps", "unseen_steps"}


def test_cbf_infeasible_steps_counts_flagged_steps_before_the_end():
    """Goal reached at sample 8 (end e = 8): flags on intervals 3 and 7 count, those on 9, 10 and 20
    (after the end) do not; without the filter's flags the count is 0."""
    sc = scenario([0, 0, 1], [2, 0, 1])
    traj = trajectory(line([0, 0, 1], [2, 0, 0]), [2, 0, 0])  # 0.2 m per step: within r_goal at sample 8
    flags = np.zeros(T, bool)
    flags[[3, 7, 9, 10, 20]] = True
    flagged = dataclasses.replace(traj, extras={"cbf_infeasible": jnp.asarray(flags)})
    m = values(_metrics(flagged, sc, SIM))
    assert int(m["steps"]) == 8 and int(m["cbf_infeasible_steps"]) == 2
    assert int(values(_metrics(traj, sc, SIM))["cbf_infeasible_steps"]) == 0


def test_world_diagnostics_count_only_before_the_end():
    """Goal reached at sample 8: tilt, saturation and unseen obstacles after it do not count; with no
    such diagnostics (the double integrator, the ideal sensor) the metrics are 0."""
    sc = scenario([0, 0, 1], [2, 0, 1])
    traj = trajectory(line([0, 0, 1], [2, 0, 0]), [2, 0, 0])
    tilt, saturated, unseen = np.zeros(T), np.zeros(T), np.zeros(T, np.int32)
    tilt[[2, 6, 20]] = np.deg2rad([10.0, 25.0, 60.0])
    saturated[[1, 7, 9]] = [0.03, 0.02, 0.1]
    unseen[[0, 5, 30]] = [2, 1, 3]
    world = dataclasses.replace(traj, extras={"tilt": jnp.asarray(tilt, jnp.float32),
                                              "saturated_time": jnp.asarray(saturated, jnp.float32),
                                              "unseen_near": jnp.asarray(unseen)})
    m = values(_metrics(world, sc, SIM))
    np.testing.assert_allclose(m["max_tilt"], 25.0, **F32)
    np.testing.assert_allclose(m["saturation_time"], 0.05, **F32)
    assert int(m["unseen_steps"]) == 3
    bare = values(_metrics(traj, sc, SIM))
    assert bare["max_tilt"] == 0 and bare["saturation_time"] == 0 and int(bare["unseen_steps"]) == 0


def test_tracking_errors_measure_the_realised_against_the_applied_acceleration():
    """The applied control is 1 m/s² on x but the plant realised 1.5 m/s² on x and 0.2 m/s² on y:
    the acceleration error is |(0.5, 0.2, 0)| on every step, one step misses by |(0.5, 0.2)| dt²/2; an
    exact double integrator realises its command (both ~0)."""
    sc = scenario([0, 0, 1], [100, 0, 1])
    applied = np.tile([1.0, 0.0, 0.0], (T, 1))
    exact = integrate([0, 0, 1], [0, 0, 0], applied)
    m = values(_metrics(exact, sc, SIM))
    assert m["accel_error_rms"] < 1e-3 and m["position_error_max"] < 1e-5
    pushed = integrate([0, 0, 1], [0, 0, 0], applied + np.array([0.5, 0.2, 0.0]))
    m = values(_metrics(dataclasses.replace(pushed, control=jnp.asarray(applied, jnp.float32)), sc, SIM))
    np.testing.assert_allclose(m["accel_error_rms"], math.hypot(0.5, 0.2), rtol=1e-3)
    np.testing.assert_allclose(m["position_error_max"], math.hypot(0.5, 0.2) * DT**2 / 2, rtol=2e-2)


# --------------------------------------------------------------------------------------------
# hand-made episodes
# --------------------------------------------------------------------------------------------


def test_straight_line_at_constant_speed():
    # x_i = 0.2 i; the goal at x = 8 is within 0.5 first at i = 38 (x = 7.6).
    sc = scenario([0, 0, 1], [8, 0, 1], dict(position=[4, 3, 1], radius=1.0))
    m = values(_metrics(trajectory(line([0, 0, 1], [2, 0, 0]), [2, 0, 0]), sc, SIM))
    assert m["success"] and not m["collision"] and not m["stalled"]
    assert m["steps"] == 38
    np.testing.assert_allclose(m["time_to_goal"], 3.8, **F32)
    np.testing.assert_allclose(m["path_length"], 7.6, **F32)
    np.testing.assert_allclose(m["path_ratio"], 0.95, **F32)
    np.testing.assert_allclose(m["final_distance"], 0.4, **F32)
    np.testing.assert_allclose(m["min_clearance"], 3.0 - 1.0 - 0.3, **F32)  # abeam at x = 4
    assert m["control_effort"] == 0 and m["jerk_rms"] == 0
    assert m["max_velocity_excess"] == 0  # |v| = v_max exactly is no excess
    assert m["time_near"] == 0
    assert m["min_ttc"] == np.inf  # the line of motion misses the obstacle
    assert m["spl"] == 1.0  # a straight success: 7.6 m flown < L = 8 m


def test_straight_line_without_obstacles_has_infinite_clearance():
    sc = scenario([0, 0, 1], [8, 0, 1])
    m = values(_metrics(trajectory(line([0, 0, 1], [2, 0, 0]), [2, 0, 0]), sc, SIM))
    assert m["min_clearance"] == np.inf and m["min_ttc"] == np.inf and m["time_near"] == 0


def test_spl_weighs_a_success_by_its_detour():
    # along (0,0) → (4,3) → (8,0) at 2.4 m/s: arc length s_i = 0.24 i; the goal (L = 8 m, at s = 10) is
    # first within 0.5 m at s = 9.6 (sample 40); the flown path is the sum of the chords (the corner
    # is cut a little): SPL = L / path. Slowness alone costs nothing.
    arc = 0.24 * np.arange(T + 1)[:, None]
    first, second = np.array([4.0, 3.0, 0.0]), np.array([4.0, -3.0, 0.0])
    positions = np.where(arc <= 5.0, arc / 5.0 * first, first + np.minimum(arc - 5.0, 5.0) / 5.0 * second)
    m = values(_metrics(trajectory(positions, 0.0), scenario([0, 0, 0], [8, 0, 0]), SIM))
    assert m["success"] and m["steps"] == 40
    flown = np.linalg.norm(np.diff(positions[:41], axis=0), axis=1).sum()
    assert 9.5 < flown < 9.6
    np.testing.assert_allclose(m["path_length"], flown, **F32)
    np.testing.assert_allclose(m["spl"], 8.0 / flown, **F32)
    slow = values(_metrics(trajectory(line([0, 0, 0], [0.5, 0, 0]), [0.5, 0, 0]), scenario([0, 0, 0], [2, 0, 0]), SIM))
    assert slow["success"] and slow["steps"] == 30 and slow["spl"] == 1.0


def test_stop_halfway_and_hover():
    # cruise 1 s at 2 m/s, brake at -2 m/s² for 1 s (stops at x = 3 at i = 20), then hover.
    a = np.zeros((T, 3))
    a[10:20, 0] = -2.0
    traj = integrate([0, 0, 0], [2, 0, 0], a)
    np.testing.assert_allclose(traj.position[20], [3, 0, 0], atol=1e-5)
    m = values(_metrics(traj, scenario([0, 0, 0], [10, 0, 0]), SIM))
    assert not m["success"] and not m["collision"]
    assert m["stalled"]  # samples 20..50 at rest: 31 samples = 3.1 s >= 3 s
    assert m["steps"] == T
    assert np.isnan(m["time_to_goal"]) and m["spl"] == 0
    np.testing.assert_allclose(m["final_distance"], 7.0, **F32)
    np.testing.assert_allclose(m["path_length"], 3.0, **F32)
    np.testing.assert_allclose(m["path_ratio"], 0.3, **F32)
    np.testing.assert_allclose(m["control_effort"], 10 * 4.0 * DT, **F32)
    # two jumps of 2 m/s² → |jerk| = 20 twice, over the e - 1 = 49 consecutive interval pairs
    np.testing.assert_allclose(m["jerk_rms"], math.sqrt(2 * 20.0**2 / 49), **F32)
    assert m["max_velocity_excess"] == 0


@pytest.mark.parametrize("n, stalled", [(29, False), (30, True), (31, True)])
def test_stall_threshold_is_n_dt_at_least_t_stall(n, stalled):
    v = np.zeros((T + 1, 3))
    v[n:, 0] = 1.0  # at rest for samples 0..n-1, then moving
    m = values(_metrics(trajectory(line([0, 0, 0], [0, 0, 0]), v), scenario([0, 0, 0], [50, 0, 0]), SIM))
    assert bool(m["stalled"]) is stalled


def test_hovering_at_the_goal_is_not_a_stall_and_split_runs_do_not_add_up():
    # two rest periods of 20 samples separated by motion: no run reaches 30
    v = np.zeros((T + 1, 3))
    v[20:25, 0] = 1.0
    m = values(_metrics(trajectory(line([0, 0, 0], [0, 0, 0]), v), scenario([0, 0, 0], [50, 0, 0]), SIM))
    assert not m["stalled"]
    # at rest inside r_goal: reached at sample 0, never a stall
    m = values(_metrics(trajectory(line([0, 0, 0], [0, 0, 0]), 0.0), scenario([0, 0, 0], [0.3, 0, 0]), SIM))
    assert m["success"] and not m["stalled"] and m["steps"] == 0


@pytest.mark.parametrize("speed, stalled", [(0.05, False), (0.02, True), (0.0, True)])
def test_a_slow_approach_that_closes_in_is_not_a_stall(speed, stalled):
    """Slower than v_stall = 0.1 m/s for the whole 5 s, toward a goal 50 m away: at 0.05 m/s it gets
    0.145 m closer over any 30-sample run (>= d_progress = 0.1 m: approaching), at 0.02 m/s only
    0.058 m (no progress: a stall), at rest nothing."""
    x = np.arange(T + 1) * DT * speed
    position = np.stack([x, np.zeros(T + 1), np.zeros(T + 1)], axis=1)
    m = values(_metrics(trajectory(position, [speed, 0.0, 0.0]), scenario([0, 0, 0], [50, 0, 0]), SIM))
    assert bool(m["stalled"]) is stalled


def test_slow_motion_away_or_around_is_a_stall_and_d_progress_sets_the_bar():
    """Creeping sideways at 0.05 m/s (no progress toward the goal) is a stall; with d_progress = 0
    even a 0.058 m approach is progress, with d_progress = 0.2 m a 0.145 m one is not."""
    y = np.arange(T + 1) * DT * 0.05
    side = np.stack([np.zeros(T + 1), y, np.zeros(T + 1)], axis=1)
    assert values(_metrics(trajectory(side, [0.0, 0.05, 0.0]), scenario([0, 0, 0], [50, 0, 0]), SIM))["stalled"]
    for speed, d_progress, stalled in ((0.02, 0.0, False), (0.05, 0.2, True)):
        x = np.arange(T + 1) * DT * speed
        position = np.stack([x, np.zeros(T + 1), np.zeros(T + 1)], axis=1)
        sim = dataclasses.replace(SIM, metrics=dataclasses.replace(SIM.metrics, d_progress=d_progress))
        m = values(_metrics(trajectory(position, [speed, 0.0, 0.0]), scenario([0, 0, 0], [50, 0, 0]), sim))
        assert bool(m["stalled"]) is stalled


def test_tunnelling_through_an_obstacle_between_samples_is_a_collision():
    # 20 m/s: samples at x = 0, 2, 4, 6, ...; sphere at x = 5 with R = 0.5 + 0.3 = 0.8.
    sc = scenario([0, 0, 0], [50, 0, 0], dict(position=[5, 0, 0], radius=0.5))
    traj = trajectory(line([0, 0, 0], [20, 0, 0]), [20, 0, 0])
    hist = np.asarray(_history(traj, sc, SIM))
    assert hist.shape == (T + 1, M)
    assert np.all(hist[:, 0] > 0)  # every sample is clear ...
    assert np.all(hist[:, 1:] == np.inf)  # padded slots
    m = values(_metrics(traj, sc, SIM))
    assert m["collision"] and not m["success"]  # ... but the swept check catches the crossing
    assert m["steps"] == 3
    np.testing.assert_allclose(m["min_clearance"], -0.8, **F32)
    np.testing.assert_allclose(m["final_distance"], 44.0, **F32)
    np.testing.assert_allclose(m["path_length"], 6.0, **F32)
    np.testing.assert_allclose(m["max_velocity_excess"], 18.0, **F32)
    # intervals [2, 4] (swept 0.2, closing in) and [4, 6] (-0.8, the closest approach inside it) are
    # below d_safe = 1; [0, 2] (2.2) is not
    np.testing.assert_allclose(m["time_near"], 2 * DT, **F32)
    # ttc at x = 0, 2, 4: 4.2/20, 2.2/20, 0.2/20; at x = 6 receding: inf
    np.testing.assert_allclose(m["min_ttc"], 0.2 / 20, **F32)
    assert np.isnan(m["time_to_goal"]) and m["spl"] == 0


@pytest.mark.parametrize("goal_x, success", [(6.0, False), (4.0, True)])
def test_collision_wins_a_tie_with_the_goal(goal_x, success):
    # collision ends at sample 3 (x = 6). Goal at x = 6: reached at that same sample → collision.
    # Goal at x = 4: reached at sample 2, before the colliding interval → success, episode over.
    sc = scenario([0, 0, 0], [goal_x, 0, 0], dict(position=[5, 0, 0], radius=0.5))
    traj = trajectory(line([0, 0, 0], [20, 0, 0]), [20, 0, 0])
    end = jax.device_get(_end(traj, sc, SIM))
    assert end["collision_index"] == 3
    assert end["goal_index"] == (3 if goal_x == 6.0 else 2)
    m = values(_metrics(traj, sc, SIM))
    assert bool(m["success"]) is success and bool(m["collision"]) is not success
    assert m["steps"] == end["end_index"] == (2 if success else 3)


def test_episode_end_never():
    traj = trajectory(line([0, 0, 0], [0, 0, 0]), 0.0)
    end = jax.device_get(_end(traj, scenario([0, 0, 0], [50, 0, 0]), SIM))
    assert end["goal_index"] == T + 1 and end["collision_index"] == T + 1 and end["end_index"] == T
    for v in end.values():
        assert v.dtype == np.int32


def test_time_near_passing_an_obstacle():
    # cylinder at (4, 1) with R = 0.2 + 0.3: clearance < 1 iff |x - 4| < sqrt(1.25) ≈ 1.118,
    # so intervals [0.2k, 0.2k + 0.2] for k = 14..25 are near; the clearance falls until abeam
    # (x = 4 at the end of interval 19): 6 intervals closing in = 0.6 s.
    sc = scenario([0, 0, 0], [10, 0, 0], dict(position=[4, 1, -3], radius=0.2, cylinder=True))
    m = values(_metrics(trajectory(line([0, 0, 0], [2, 0, 0]), [2, 0, 0]), sc, SIM))
    assert m["success"] and m["steps"] == 48
    np.testing.assert_allclose(m["time_near"], 6 * DT, **F32)
    np.testing.assert_allclose(m["min_clearance"], 0.5, **F32)
    assert m["min_ttc"] == np.inf


def test_time_near_does_not_grow_while_hovering_near_an_obstacle():
    # brake to rest 0.9 m clear of a cylinder (clearance < d_safe = 1) and hover there for 4 s:
    # only the approach counts, not the hovering (a stall must not dominate the metric)
    a = np.zeros((T, 3))
    a[:10, 0] = -2.0
    traj = integrate([0, 0, 0], [2, 0, 0], a)  # stops at x = 1 at sample 10
    sc = scenario([0, 0, 0], [10, 0, 0], dict(position=[2.4, 0, 0], radius=0.2, cylinder=True))
    m = values(_metrics(traj, sc, SIM))
    assert m["stalled"] and not m["collision"]
    np.testing.assert_allclose(m["min_clearance"], 2.4 - 1.0 - 0.5, **F32)
    assert 0 < m["time_near"] <= 10 * DT


def test_velocity_excess_counts_only_valid_samples_and_each_axis():
    v = np.tile([2.0, 0.0, 0.0], (T + 1, 1))
    v[10] = [1.0, -3.5, 0.5]  # excess 1.5 on y
    v[45] = [100.0, 0.0, 0.0]  # after the goal (sample 38): ignored
    sc = scenario([0, 0, 1], [8, 0, 1])
    m = values(_metrics(trajectory(line([0, 0, 1], [2, 0, 0]), v), sc, SIM))
    assert m["steps"] == 38
    np.testing.assert_allclose(m["max_velocity_excess"], 1.5, **F32)


def test_bang_bang_control():
    # a_x = +2, -2, +2, ... from rest: every jump is 4 m/s² → |jerk| = 40 m/s³ everywhere
    a = np.zeros((T, 3))
    a[:, 0] = 2.0 * (-1.0) ** np.arange(T)
    traj = integrate([0, 0, 0], [0, 0, 0], a)
    m = values(_metrics(traj, scenario([0, 0, 0], [50, 0, 0]), SIM))
    assert m["steps"] == T and not m["stalled"]  # speeds 0, 0.2, 0, ...: runs of one sample
    np.testing.assert_allclose(m["control_effort"], 4.0 * T * DT, **F32)
    np.testing.assert_allclose(m["jerk_rms"], 40.0, **F32)
    np.testing.assert_allclose(m["path_length"], 25 * 0.2 * DT, **F32)  # 0.02 m per up-step


def test_too_short_episodes():
    # start inside r_goal: e = 0 → nothing accumulates; min_clearance is the sample-0 clearance
    sc = scenario([0, 0, 0], [0.3, 0, 0], dict(position=[0, 2, 0], radius=0.5))
    traj = integrate([0, 0, 0], [0, 0, 0], np.tile([3.0, 1.0, 0.0], (T, 1)))
    m = values(_metrics(traj, sc, SIM))
    assert m["success"] and m["steps"] == 0
    assert m["path_length"] == 0 and m["control_effort"] == 0 and m["jerk_rms"] == 0
    assert m["time_to_goal"] == 0 and m["path_ratio"] == 0 and m["time_near"] == 0
    np.testing.assert_allclose(m["min_clearance"], 2 - 0.5 - 0.3, **F32)
    assert m["spl"] == 1.0  # L / max(0, L)
    # one valid interval: effort counts, jerk needs two
    sc = scenario([0, 0, 0], [0.6, 0, 0])
    traj = trajectory(line([0, 0, 0], [2, 0, 0]), [2, 0, 0], np.tile([1.0, 0.0, 0.0], (T, 1)))
    m = values(_metrics(traj, sc, SIM))
    assert m["steps"] == 1 and m["jerk_rms"] == 0
    np.testing.assert_allclose(m["control_effort"], DT, **F32)


def test_start_equal_goal_is_nan_free():
    traj = trajectory(line([1, 1, 1], [0, 0, 0]), 0.0)
    m = values(_metrics(traj, scenario([1, 1, 1], [1, 1, 1]), SIM))
    assert m["success"] and m["steps"] == 0
    assert m["path_ratio"] == 1.0 and m["spl"] == 1.0
    assert not any(np.isnan(v) for v in m.values())


def test_after_the_goal_nothing_counts():
    # reach the goal at sample 38, then either hover or fly wildly through an obstacle
    sc = scenario([0, 0, 1], [8, 0, 1], dict(position=[12, 0, 1], radius=1.0),
                  dict(position=[4, 2.5, 1], velocity=[0, -0.1, 0], radius=0.5))
    pos = line([0, 0, 1], [2, 0, 0])
    vel = np.tile([2.0, 0.0, 0.0], (T + 1, 1))
    calm_pos, calm_vel = pos.copy(), vel.copy()
    calm_pos[39:] = pos[38]
    calm_vel[39:] = 0.0
    rng = np.random.default_rng(0)
    wild_pos = pos.copy()
    wild_pos[39:] = pos[38] + np.cumsum(rng.normal(0, 5, (T - 38, 3)), axis=0)
    wild_pos[40] = [12, 0, 1]  # straight through the obstacle
    wild_vel = vel.copy()
    wild_vel[39:] = rng.normal(0, 50, (T - 38, 3))
    ctrl = np.zeros((T, 3))
    wild_ctrl = ctrl.copy()
    wild_ctrl[38:] = rng.normal(0, 30, (T - 38, 3))
    calm = values(_metrics(trajectory(calm_pos, calm_vel, ctrl), sc, SIM))
    wild = values(_metrics(trajectory(wild_pos, wild_vel, wild_ctrl), sc, SIM))
    assert calm["success"] and calm["steps"] == 38
    assert_metrics_equal(calm, wild)


def test_after_a_collision_nothing_counts():
    sc = scenario([0, 0, 0], [10, 0, 0], dict(position=[5, 0, 0], radius=0.5))
    pos = line([0, 0, 0], [20, 0, 0])
    vel = np.tile([20.0, 0.0, 0.0], (T + 1, 1))
    later = pos.copy()
    later[4:] = [10, 0, 0]  # ... even reaching the goal afterwards
    a = values(_metrics(trajectory(pos, vel), sc, SIM))
    b = values(_metrics(trajectory(later, 0.0 * vel), sc, SIM))
    assert a["collision"] and not b["success"]
    vel_b = vel.copy()
    vel_b[4:] = 0.0
    b = values(_metrics(trajectory(later, vel_b), sc, SIM))
    assert_metrics_equal(a, b)


# --------------------------------------------------------------------------------------------
# time to collision
# --------------------------------------------------------------------------------------------


def _one(position, velocity=(0, 0, 0), radius=0.7, cylinder=False) -> Obstacles:
    return obstacles(dict(position=position, velocity=velocity, radius=radius, cylinder=cylinder))


def _f32(x):
    return jnp.asarray(x, jnp.float32)


def test_ttc_head_on():
    # UAV at 1 m/s toward an obstacle closing at 1 m/s; R = 0.7 + 0.3 = 1
    obs = _one([10, 0, 0], [-1, 0, 0])
    ttc = np.asarray(_ttc(_f32([0, 0, 0]), _f32([1, 0, 0]), obs, 0.0, 0.3))
    np.testing.assert_allclose(ttc[0], (10 - 1) / 2, **F32)
    assert np.all(ttc[1:] == np.inf)  # padded slots
    # at t = 2 the obstacle is at x = 8, the UAV (given) at x = 2: gap 5, closing 2
    ttc = np.asarray(_ttc(_f32([2, 0, 0]), _f32([1, 0, 0]), obs, 2.0, 0.3))
    np.testing.assert_allclose(ttc[0], 2.5, **F32)


def test_ttc_offset_miss_overlap_and_receding():
    obs = _one([10, 0.6, 0], [-1, 0, 0])
    # (2τ - 10)² + 0.36 = 1 → τ = (10 - 0.8) / 2
    np.testing.assert_allclose(_ttc(_f32([0, 0, 0]), _f32([1, 0, 0]), obs, 0.0, 0.3)[0], 4.6, **F32)
    miss = _one([10, 1.5, 0], [-1, 0, 0])
    assert _ttc(_f32([0, 0, 0]), _f32([1, 0, 0]), miss, 0.0, 0.3)[0] == np.inf
    inside = _one([0.5, 0, 0], [5, 0, 0])
    assert _ttc(_f32([0, 0, 0]), _f32([0, 0, 0]), inside, 0.0, 0.3)[0] == 0
    receding = _one([10, 0, 0], [2, 0, 0])
    assert _ttc(_f32([0, 0, 0]), _f32([1, 0, 0]), receding, 0.0, 0.3)[0] == np.inf
    hovering_pair = _one([10, 0, 0])
    assert _ttc(_f32([0, 0, 0]), _f32([0, 0, 0]), hovering_pair, 0.0, 0.3)[0] == np.inf


def test_cylinder_ignores_z():
    cyl = _one([0, 0, 0], radius=1.0, cylinder=True)
    sph = _one([0, 0, 0], radius=1.0, cylinder=False)
    # vertical motion never closes on a cylinder; only the horizontal part counts
    ttc = _ttc(_f32([3, 0, 5]), _f32([-1, 0, 7]), cyl, 0.0, 0.3)[0]
    np.testing.assert_allclose(ttc, 3 - 1.3, **F32)
    assert _ttc(_f32([3, 0, 5]), _f32([0, 0, -7]), cyl, 0.0, 0.3)[0] == np.inf
    # a pass at 50 m altitude straight over the axis hits the cylinder, not the sphere
    traj = trajectory(line([-5, 0, 50], [2, 0, 0]), [2, 0, 0])
    goal = [20, 0, 50]
    m_cyl = values(_metrics(traj, Scenario(jnp.asarray([-5, 0, 50.0]), jnp.asarray(goal, jnp.float32), cyl), SIM))
    m_sph = values(_metrics(traj, Scenario(jnp.asarray([-5, 0, 50.0]), jnp.asarray(goal, jnp.float32), sph), SIM))
    # x_i = -5 + 0.2 i enters |x| < 1.3 on interval 18 ([-1.4, -1.2]); the episode ends at sample 19
    assert m_cyl["collision"] and m_cyl["steps"] == 19
    np.testing.assert_allclose(m_cyl["min_clearance"], 1.2 - 1.3, **F32)
    np.testing.assert_allclose(m_cyl["min_ttc"], 0.0, atol=1e-5)
    assert not m_sph["collision"]
    np.testing.assert_allclose(m_sph["min_clearance"], 50 - 1.3, **F32)


# --------------------------------------------------------------------------------------------
# padding, batching, NaN-freedom
# --------------------------------------------------------------------------------------------


def _random_case(seed: int, size: int = M) -> tuple[Trajectory, Scenario]:
    rng = np.random.default_rng(seed)
    a = rng.normal(0, 2.0, (T, 3))
    start = rng.uniform(-2, 2, 3)
    traj = integrate(start, rng.normal(0, 1, 3), a)
    specs = [dict(position=rng.uniform(-4, 4, 3), velocity=rng.normal(0, 1, 3),
                  radius=rng.uniform(0.2, 1.5), cylinder=bool(rng.integers(2))) for _ in range(size)]
    goal = start + rng.uniform(-3, 3, 3)
    return traj, Scenario(start=_f32(start), goal=_f32(goal), obstacles=obstacles(*specs, size=size))


EXTRA = 2  # padded slots added by the property test (one extra compiled shape)


def _pad(obs: Obstacles, order: np.ndarray) -> Obstacles:
    """Append EXTRA padded slots parked on top of the action (radius 3), then permute the slots."""
    def cat(x, fill):
        x = np.asarray(x)
        return jnp.asarray(np.concatenate([x, np.full((EXTRA,) + x.shape[1:], fill, x.dtype)])[order])
    return Obstacles(position=cat(obs.position, 0.0), velocity=cat(obs.velocity, 0.0),
                     radius=cat(obs.radius, 3.0), cylinder=cat(obs.cylinder, True),
                     valid=cat(obs.valid, False))


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), perm_seed=st.integers(0, 2**31 - 1))
def test_padded_slots_change_nothing(seed, perm_seed):
    traj, sc = _random_case(seed)
    order = np.random.default_rng(perm_seed).permutation(M + EXTRA)
    padded = Scenario(start=sc.start, goal=sc.goal, obstacles=_pad(sc.obstacles, order))
    assert_metrics_equal(values(_metrics(traj, sc, SIM)), values(_metrics(traj, padded, SIM)))
    hist, hist_padded = np.asarray(_history(traj, sc, SIM)), np.asarray(_history(traj, padded, SIM))
    keep = np.asarray(padded.obstacles.valid)
    np.testing.assert_array_equal(hist_padded[:, keep], hist[:, order[keep]])
    assert np.all(hist_padded[:, ~keep] == np.inf)


def test_vmap_matches_single_episodes_and_no_nan():
    cases = [_random_case(s) for s in range(4)]
    trajs = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *[c[0] for c in cases])
    scs = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *[c[1] for c in cases])
    batched = values(jax.jit(jax.vmap(lambda t, s: episode_metrics(t, s, SIM)))(trajs, scs))
    for i, (traj, sc) in enumerate(cases):
        single = values(_metrics(traj, sc, SIM))
        for name in METRICS:
            np.testing.assert_allclose(batched[name][i], single[name], rtol=1e-6, err_msg=name)
            if name != "time_to_goal":
                assert not np.isnan(single[name]), name
        assert np.isnan(single["time_to_goal"]) != bool(single["success"])
