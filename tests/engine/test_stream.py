"""The streaming engine (jaxapf.engine.stream) against the fixed-length one, and the metric contract it rests on."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import assert_same_episodes

from jaxapf.config import MPCConfig, PlannerConfig, SimConfig
from jaxapf.engine import evaluate, rollout
from jaxapf.engine.stream import NARROWEST, stream_levels, stream_slots
from jaxapf.gains import Gains
from jaxapf.metrics import METRICS, episode_end, episode_metrics
from jaxapf.planners import PLANNERS
from jaxapf.scenarios import family_params, make_scenarios

MPC = MPCConfig(horizon=10, iters=15)


def _sim(method: str, t_max: float = 25.0) -> SimConfig:
    sim = SimConfig(planner=PlannerConfig(method=method))
    return dataclasses.replace(sim, episode=dataclasses.replace(sim.episode, t_max=t_max))


@pytest.mark.slow
@pytest.mark.parametrize("method, family", [(m, "crossing") for m in sorted(PLANNERS.names())]
                         + [("direction_velocity", "trap")])
def test_every_planner_streams_the_fixed_engines_episodes(method, family):
    """Moving obstacles (crossing; a static trap too) and two gain settings: the same outcomes and
    metrics whichever engine flies them, for every registered planner (the stall escape's keyed
    state included)."""
    fields = make_scenarios(3, family_params(family), 24)
    two = [Gains(), Gains(gamma=0.5, k_rep=2.0)]
    gains = Gains.unchecked({n: np.array([np.asarray(g[n], np.float32) for g in two]) for n in Gains.names()})
    sim = _sim(method)
    fixed = evaluate(fields, gains, sim, MPC, width=64, streaming=False)
    streamed = evaluate(fields, gains, sim, MPC, width=64)
    assert_same_episodes(fixed, streamed, sim.episode.dt)
    assert np.asarray(streamed["steps"]).min() < sim.episode.steps, "some episode must end early for the test to bite"


@pytest.mark.slow
def test_an_episodes_streamed_numbers_do_not_depend_on_its_queue():
    """The first 64 fields alone (64 slots, one width) and inside a queue of 2,080 (512 slots, refills, a
    tail on the narrower vmaps of 256 and 128 slots): bit for bit the same numbers."""
    fields = make_scenarios(1, family_params("overtake"), 2080)
    sim = _sim("direction_velocity", 10.0)
    assert stream_slots(2080, 1024) == 512 and stream_slots(64, 1024) == NARROWEST
    assert stream_levels(512) == (512, 256, 128) and stream_levels(64) == (64,)
    whole = evaluate(fields, Gains(), sim, MPC, width=1024)
    part = evaluate(jax.tree_util.tree_map(lambda x: x[:64], fields), Gains(), sim, MPC, width=1024)
    for name in whole:
        np.testing.assert_array_equal(np.asarray(whole[name])[:, :64], np.asarray(part[name]), err_msg=name)


@pytest.mark.slow
def test_streaming_runs_in_float64():
    """``jaxapf sweep --x64``: the same outcomes as the fixed-length engine, float64 metrics."""
    with jax.enable_x64(True):
        fields = jax.tree_util.tree_map(lambda x: x.astype(jnp.float64) if x.dtype == jnp.float32 else x,
                                        make_scenarios(4, family_params("crossing"), 8))
        sim = _sim("basic")
        fixed = evaluate(fields, Gains(), sim, MPC, width=64, streaming=False)
        streamed = evaluate(fields, Gains(), sim, MPC, width=64)
        assert streamed["min_clearance"].dtype == jnp.float64
        assert_same_episodes(fixed, streamed, sim.episode.dt)


@pytest.mark.parametrize("episodes, width, slots", [(1, 1024, 64), (64, 1024, 64), (300, 1024, 64), (512, 1024, 128),
                                                    (4096, 1024, 1024), (10**6, 512, 512), (100, 16, 16)])
def test_stream_slots(episodes, width, slots):
    assert stream_slots(episodes, width) == slots


@pytest.mark.parametrize("slots, levels", [(64, (64,)), (128, (128,)), (255, (255,)), (256, (256, 128, 64)),
                                           (512, (512, 256, 128)), (1024, (1024, 512, 256))])
def test_stream_levels(slots, levels):
    """A queue's tail narrows from 256 slots on (where it was measured to repay its compilation); never below
    NARROWEST."""
    assert stream_levels(slots) == levels and min(levels) >= NARROWEST


def test_stream_levels_narrowed_below_the_threshold_never_go_below_the_narrowest():
    """benchmarks/stream_levels.py measures the narrowing where the engine does not use it."""
    assert stream_levels(128, narrowing_from=0) == (128, NARROWEST) and stream_levels(64, narrowing_from=0) == (64,)
    assert stream_levels(512, narrowing_from=513) == (512,)


@pytest.mark.slow
def test_metrics_never_read_samples_after_the_end():
    """The contract streaming rests on: every registered metric is a function of the samples up to
    the episode's end (``end_index``) and the controls before it; garbage after it changes nothing."""
    fields = make_scenarios(2, family_params("crossing"), 16)
    sim = _sim("direction_velocity")
    trajs = jax.vmap(lambda s: rollout(s, Gains(), sim, MPC))(fields)
    ends = np.asarray(jax.vmap(lambda t, s: episode_end(t, s, sim)["end_index"])(trajs, fields))
    assert ends.min() < sim.episode.steps
    rng = np.random.default_rng(0)
    sample = np.arange(sim.episode.steps + 1)[None, :, None] > ends[:, None, None]
    interval = np.arange(sim.episode.steps)[None, :, None] >= ends[:, None, None]
    garbage = dataclasses.replace(
        trajs,
        position=jnp.where(sample, rng.normal(0, 50, trajs.position.shape), trajs.position).astype(jnp.float32),
        velocity=jnp.where(sample, rng.normal(0, 50, trajs.velocity.shape), trajs.velocity).astype(jnp.float32),
        control=jnp.where(interval, rng.normal(0, 50, trajs.control.shape), trajs.control).astype(jnp.float32))
    measure = jax.jit(jax.vmap(lambda t, s: episode_metrics(t, s, sim)))
    clean, dirty = measure(trajs, fields), measure(garbage, fields)
    assert set(clean) == set(METRICS.names())
    for name in clean:
        np.testing.assert_array_equal(np.asarray(clean[name]), np.asarray(dirty[name]), err_msg=name)


def test_engine_agreement_by_hand():
    from jaxapf.bench.sweep import engine_agreement

    fixed = [{"success": [True, False], "collision": [False, False], "stalled": [False, True], "steps": [10, 20],
              "min_clearance": [1.0, 2.0], "time_to_goal": [1.0, np.nan]}]
    streamed = [{"success": [True, False], "collision": [False, False], "stalled": [False, True], "steps": [10, 21],
                 "min_clearance": [1.0005, 2.5], "time_to_goal": [1.0, np.nan]}]
    out = engine_agreement(fixed, streamed)
    assert out["episodes"] == 2 and out["outcomes_equal"] == 0.5
    assert out["continuous"]["min_clearance"] == {"max_abs_diff": pytest.approx(0.5), "within_1e-3": 0.5}
    assert out["continuous"]["time_to_goal"] == {"max_abs_diff": 0.0, "within_1e-3": 1.0}
