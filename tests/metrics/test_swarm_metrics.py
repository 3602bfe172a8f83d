"""Swarm metrics (jaxapf.metrics.swarm) on hand-made and flown swarm episodes."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf.config import MPCConfig, SimConfig
from jaxapf.datatypes import Obstacles, Trajectory
from jaxapf.datatypes.swarm import Swarm
from jaxapf.engine.swarm import swarm_rollout
from jaxapf.gains import Gains
from jaxapf.metrics.swarm import pair_clearance, swarm_metric_names, swarm_metrics

R = 0.3


def _straight(starts, ends, steps: int, dt: float = 0.1) -> Trajectory:
    """UAVs flying straight from ``starts`` to ``ends`` (A, 3) at constant velocity over ``steps`` steps."""
    s = np.linspace(0.0, 1.0, steps + 1)[None, :, None]
    p = np.asarray(starts)[:, None] + s * (np.asarray(ends) - np.asarray(starts))[:, None]
    v = np.broadcast_to((np.asarray(ends) - np.asarray(starts))[:, None] / (steps * dt), p.shape)
    a = len(starts)
    return Trajectory(time=jnp.broadcast_to(jnp.arange(steps + 1) * dt, (a, steps + 1)), position=jnp.asarray(p),
                      velocity=jnp.asarray(v), control=jnp.zeros((a, steps, 3)))


def _swarm(starts, goals, valid=None) -> Swarm:
    n = len(starts)
    return Swarm(start=jnp.asarray(starts, jnp.float32), goal=jnp.asarray(goals, jnp.float32),
                 valid=jnp.ones(n, bool) if valid is None else jnp.asarray(valid), obstacles=Obstacles.empty(2))


def _metrics(traj, swarm, **sim):
    config = SimConfig.from_flat({"t_max": 10.0, "r_goal": 0.01} | sim)  # arrival: the last sample
    return {k: np.asarray(v) for k, v in swarm_metrics(traj, swarm, config).items()}


def test_pair_clearance_is_the_closest_approach_between_samples():
    """Two UAVs crossing at right angles pass through the same point within one interval: only the swept
    clearance sees it (the samples keep 0.81 m of clearance); against a dense sampling of the interval."""
    p = jnp.asarray([[[-1.0, 0.0, 2.0], [1.0, 0.0, 2.0]], [[0.0, -1.0, 2.0], [0.0, 1.0, 2.0]]])
    c = np.asarray(pair_clearance(p, jnp.ones(2, bool), R))
    s = np.linspace(0, 1, 20001)[:, None]
    dense = np.min(np.linalg.norm((p[0, 0] + s * (p[0, 1] - p[0, 0])) - (p[1, 0] + s * (p[1, 1] - p[1, 0])), axis=1))
    np.testing.assert_allclose(c[0, 0, 1], dense - 2 * R, atol=1e-4)
    np.testing.assert_allclose(c[0, 0, 1], -2 * R, atol=1e-6)
    assert np.linalg.norm(np.asarray(p[0, 0] - p[1, 0])) - 2 * R > 0.8
    assert np.isinf(c[0, 0, 0]) and np.isinf(pair_clearance(p, jnp.array([True, False]), R)[0, 0, 1])


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-5, 5, allow_nan=False), min_size=18, max_size=18))
def test_pair_clearance_is_symmetric_and_below_both_samples(xs):
    p = jnp.asarray(np.reshape(xs, (3, 2, 3)), jnp.float32)
    c = np.asarray(pair_clearance(p, jnp.ones(3, bool), R))[0]
    np.testing.assert_array_equal(c, c.T)
    ends = np.linalg.norm(np.asarray(p)[:, None] - np.asarray(p)[None], axis=-1) - 2 * R  # (3, 3, 2)
    off = ~np.eye(3, dtype=bool)
    assert np.all(c[off] <= ends.min(axis=-1)[off] + 1e-5)


def test_a_head_on_crossing_of_straight_flights_collides():
    traj = _straight([[0, 0, 2], [10, 0, 2]], [[10, 0, 2], [0, 0, 2]], 100)
    m = _metrics(traj, _swarm([[0, 0, 2], [10, 0, 2]], [[10, 0, 2], [0, 0, 2]]))
    assert m["agent_collision"] and not m["obstacle_collision"]
    assert m["at_goal"] == 0.0 and not m["swarm_success"] and np.isnan(m["makespan"])
    assert m["min_agent_clearance"] < 0  # the interval that ends the episode


def test_parallel_flights_arrive_and_their_times_are_fair():
    """Two UAVs 2 m apart flying in parallel: no collision, the closest approach is 2 - 2 r_uav, both arrive
    at 10 s, the makespan and the mean are 10 s and Jain's index is 1; a padded third slot on their path
    changes nothing."""
    starts, goals = [[0, 0, 2], [0, 2, 2], [5, 1, 2]], [[10, 0, 2], [10, 2, 2], [5, 1, 2]]
    traj = _straight(starts, goals, 100)
    m = _metrics(traj, _swarm(starts, goals, [True, True, False]))
    assert m["swarm_success"] and m["at_goal"] == 1.0 and not m["agent_collision"] and not m["deadlock"]
    np.testing.assert_allclose(m["min_agent_clearance"], 2 - 2 * R, rtol=1e-6)
    np.testing.assert_allclose([m["makespan"], m["mean_time_to_goal"], m["arrival_fairness"]], [10.0, 10.0, 1.0],
                               rtol=1e-5)


def test_component_counts_sum_each_flag_over_the_uavs_before_each_end():
    """Hand-made extras: UAV 0 arrives at step 50 (10 m in 5 s, then hovers), UAV 1 at step 100; the CBF
    filter flags steps 10, 49 and 60 of UAV 0 and 99 of UAV 1 (three before their UAV's end: UAV 0's step 60
    is after it), the velocity obstacles step 20 of UAV 1; a padded third slot flagged on every step adds
    nothing, a flag the stack does not record counts 0, and so does a stack that records neither."""
    fast, slow = _straight([[0, 5, 2]], [[10, 5, 2]], 50), _straight([[0, 0, 2]], [[10, 0, 2]], 100)
    pad = lambda x, n: jnp.concatenate([x, jnp.repeat(x[:, -1:], n, axis=1)], axis=1)  # noqa: E731
    position = jnp.concatenate([pad(fast.position, 50), slow.position, slow.position + 20.0])
    cbf, vo = np.zeros((3, 100), bool), np.zeros((3, 100), bool)
    cbf[0, [10, 49, 60]] = True
    cbf[1, 99] = vo[1, 20] = True
    cbf[2] = vo[2] = True
    bare = Trajectory(time=slow.time.repeat(3, 0), position=position, velocity=jnp.zeros_like(position),
                      control=jnp.zeros((3, 100, 3)))
    traj = dataclasses.replace(bare, extras={"cbf_truncated": jnp.asarray(cbf), "vo_truncated": jnp.asarray(vo)})
    swarm = _swarm([[0, 5, 2], [0, 0, 2], [20, 20, 22]], [[10, 5, 2], [10, 0, 2], [30, 20, 22]], [True, True, False])
    counts = _metrics(traj, swarm)
    assert [int(counts[n]) for n in ("cbf_truncated_steps", "vo_truncated_steps", "cbf_infeasible_steps")] == [3, 1, 0]
    assert all(int(_metrics(bare, swarm)[n]) == 0 for n in ("cbf_truncated_steps", "vo_truncated_steps"))
    assert counts["cbf_truncated_steps"].dtype == jnp.int32


def test_unequal_slowdowns_lower_the_fairness_to_jains_index():
    """One UAV flies 10 m in 10 s, the other 10 m in 5 s and then hovers: slowdowns 1 and 0.5 s/m,
    Jain's index 1.5² / (2 · 1.25) = 0.9."""
    slow = _straight([[0, 0, 2]], [[10, 0, 2]], 100)
    fast = _straight([[0, 5, 2]], [[10, 5, 2]], 50)
    pad = lambda x, n: jnp.concatenate([x, jnp.repeat(x[:, -1:], n, axis=1)], axis=1)  # noqa: E731
    traj = Trajectory(time=slow.time.repeat(2, 0), position=jnp.concatenate([slow.position, pad(fast.position, 50)]),
                      velocity=jnp.concatenate([slow.velocity, pad(fast.velocity, 50) * 0]),
                      control=jnp.zeros((2, 100, 3)))
    m = _metrics(traj, _swarm([[0, 0, 2], [0, 5, 2]], [[10, 0, 2], [10, 5, 2]]))
    np.testing.assert_allclose(m["arrival_fairness"], 0.9, rtol=1e-4)
    np.testing.assert_allclose([m["makespan"], m["mean_time_to_goal"]], [10.0, 7.5], rtol=1e-5)


@pytest.mark.slow
def test_flown_swaps_reciprocal_arrival_and_potential_field_deadlock():
    sim = SimConfig.from_flat(method="velocity_obstacle", t_max=20.0)
    swarm = _swarm([[0, 0, 2], [10, 0, 2]], [[10, 0, 2], [0, 0, 2]])
    fly = lambda s: jax.jit(lambda w: swarm_rollout(w, Gains(), s, MPCConfig()))(swarm)  # noqa: E731
    m = {k: np.asarray(v) for k, v in swarm_metrics(fly(sim), swarm, sim).items()}
    assert list(m) == list(swarm_metric_names())
    assert m["swarm_success"] and not m["deadlock"] and m["min_agent_clearance"] > 0.2
    np.testing.assert_allclose(m["arrival_fairness"], 1.0, atol=1e-6)  # a symmetric swap
    basic = sim.replace(method="basic")
    m = {k: np.asarray(v) for k, v in swarm_metrics(fly(basic), swarm, basic).items()}
    assert m["deadlock"] and m["at_goal"] == 0.0 and not m["agent_collision"] and np.isnan(m["mean_time_to_goal"])


def test_an_episode_shorter_than_t_stall_cannot_deadlock():
    traj = _straight([[0, 0, 2], [10, 0, 2]], [[0, 0, 2], [10, 0, 2]], 10)  # both hover, 1 s < t_stall = 3 s
    m = _metrics(traj, _swarm([[0, 0, 2], [10, 0, 2]], [[5, 0, 2], [5, 5, 2]]))
    assert not m["deadlock"] and m["at_goal"] == 0.0
    long = _straight([[0, 0, 2], [10, 0, 2]], [[0, 0, 2], [10, 0, 2]], 40)
    assert _metrics(long, _swarm([[0, 0, 2], [10, 0, 2]], [[5, 0, 2], [5, 5, 2]]))["deadlock"]


@pytest.mark.slow
def test_evaluate_swarms_is_the_metrics_of_each_setting_and_field():
    from jaxapf.engine.swarm import evaluate_swarms
    from jaxapf.scenarios.swarms import make_swarms, swarm_params

    sim = SimConfig.from_flat(method="velocity_obstacle", t_max=4.0)
    mpc = MPCConfig(horizon=5, iters=5)
    swarms = make_swarms(0, swarm_params("circle_swap", agents=3), 2)
    gains = Gains(vo_tau=jnp.array([1.0, 3.0]))
    grid = evaluate_swarms(swarms, gains, sim, mpc)
    assert set(grid) == set(swarm_metric_names()) and grid["at_goal"].shape == (2, 2)
    for g, tau in enumerate((1.0, 3.0)):
        for f in range(2):
            one = jax.tree_util.tree_map(lambda x, f=f: x[f], swarms)
            alone = swarm_metrics(jax.jit(lambda s, t=tau: swarm_rollout(s, Gains(vo_tau=t), sim, mpc))(one), one, sim)
            np.testing.assert_allclose(float(grid["min_agent_clearance"][g, f]), float(alone["min_agent_clearance"]),
                                       rtol=1e-4)
