"""Sweeps, simulations and reports of swarm families: one row per swarm episode with the swarm metrics."""


import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from cli_capture import capture
from conftest import changed

from jaxapf.cli import main
from jaxapf.config import SimConfig
from jaxapf.engine.swarm import evaluate_swarms
from jaxapf.gains import Gains
from jaxapf.metrics import METRICS
from jaxapf.metrics.swarm import swarm_metric_names
from jaxapf.scenarios.swarms import make_swarms
from jaxapf.sweep import parse_spec, plan_sweep, read_sweep, row_config, run_sweep
from jaxapf.sweep.plan import episode_bytes, seen_slots, working_set_bytes
from jaxapf.validation import ConfigError, Interrupted

SWARM = {
    "name": "swarm-tiny",
    "scenario": {"families": ["circle_swap", "crossing_flows"], "fields": 3, "seed": 2,
                 "params": {"circle_swap": {"agents": 3, "distance": [6.0, 7.0]},
                            "crossing_flows": {"agents": 4, "distance": [6.0, 7.0]}}},
    "sim": {"t_max": 3.0, "horizon": 4, "iters": 4},
    "grid": {"method": ["basic", "velocity_obstacle"]},
}


def _spec(**changes):
    return parse_spec(changed(SWARM, **changes))


# --------------------------------------------------------------------------------------------
# specs
# --------------------------------------------------------------------------------------------


def test_a_spec_of_swarm_families_is_a_swarm_spec():
    spec = _spec()
    assert spec.swarm and spec.family_params("circle_swap").agents == 3
    assert not parse_spec({**SWARM, "scenario": {"families": ["trap"], "fields": 2}}).swarm


def test_a_swarm_variant_names_its_family():
    spec = _spec(**{"scenario.families": ["circle_swap", "big_circle"],
                    "scenario.params": {"big_circle": {"family": "circle_swap", "agents": 16}}})
    assert spec.family_params("big_circle").agents == 16 and spec.family_params("circle_swap").agents == 8


def test_mixing_swarm_and_single_uav_families_is_refused_in_one_line():
    with pytest.raises(ConfigError, match=r"mixes swarm families \(circle_swap\) with single-UAV ones \(trap\)") as err:
        _spec(**{"scenario.families": ["circle_swap", "trap"], "scenario.params": {}})
    assert "\n" not in str(err.value)


def test_a_bad_swarm_parameter_names_its_key():
    with pytest.raises(ConfigError, match=r"scenario\.params\.crossing_flows\.agents = 3 must be a multiple of groups"):
        _spec(**{"scenario.params.crossing_flows.agents": 3})


def test_tune_and_compare_specs_do_not_take_swarm_families():
    from jaxapf.compare.spec import parse_compare_spec
    from jaxapf.tune.spec import parse_tune_spec

    with pytest.raises(ConfigError, match="circle_swap"):
        parse_tune_spec({"name": "t", "train": {"families": ["circle_swap"]}})
    with pytest.raises(ConfigError, match="circle_swap"):
        parse_compare_spec({"name": "c", "methods": ["basic", "direction"],
                            "selection": {"families": ["circle_swap"], "seeds": [1, 2, 3], "budget": 64},
                            "test": {"families": ["circle_swap"], "fields": 8}})


def test_the_memory_model_of_one_uav_is_unchanged_and_grows_with_the_swarm():
    # one UAV: the single-UAV model exactly (chunking and part names of every single-UAV sweep stay)
    assert working_set_bytes(8, 100, 4, 4, 1) == working_set_bytes(8, 100, 4, 4)
    assert episode_bytes(4, 4, 1) == episode_bytes(4, 4) == 2 * ((7 * 4 + 12) * 4 + 8) + 3 * len(METRICS) * 4 + 320
    assert working_set_bytes(1, 100, seen_slots(SimConfig(), 4, 16), 4, 16) > 16 * working_set_bytes(1, 100, 4, 4)
    assert seen_slots(SimConfig(), 4, 1) == 4 and seen_slots(SimConfig(), 4, 16) == 4 + 16  # its own slot, invalid
    assert seen_slots(SimConfig.from_flat(max_neighbours=6), 4, 16) == 4 + 6


# --------------------------------------------------------------------------------------------
# sweeps
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    spec = _spec()
    out = tmp_path_factory.mktemp("swarm") / "out"
    run_sweep(spec, out, quiet=True)
    return spec, out, read_sweep(out)


def test_a_swarm_sweep_writes_one_row_per_episode_with_the_swarm_metrics(swept):
    spec, _, (df, meta) = swept
    assert meta["complete"] and len(df) == 2 * 2 * 3
    assert meta["metrics"] == list(swarm_metric_names())
    counts = {n for n, m in METRICS.items() if m.flag}  # the components' counts, summed over the UAVs
    assert set(swarm_metric_names()) <= set(df.columns) and set(METRICS.names()) & set(df.columns) == counts
    agents = df.groupby("family")["agents"].unique()
    assert agents["circle_swap"].tolist() == [3] and agents["crossing_flows"].tolist() == [4]
    assert (df["kind"] == df["family"]).all()
    from jaxapf.scenarios.swarms import agents_solvable

    for family in spec.families:  # every UAV alone: here only the time limit can stop one (no obstacles)
        fields = jax.device_get(make_swarms(spec.seed, spec.family_params(family), spec.fields))
        alone = agents_solvable(fields, r_uav=0.3, v_max=2.0, t_max=3.0, r_goal=0.5).all(axis=-1)
        rows = df[(df["family"] == family) & (df["method"] == "basic")].sort_values("field")
        assert rows["solvable"].tolist() == alone.tolist()


@pytest.mark.slow
def test_a_swarm_sweep_row_is_evaluate_swarms_of_its_field(swept):
    # the rows are the engine's numbers bit for bit: same fields, same program, same vmap width
    spec, _, (df, meta) = swept
    plan = plan_sweep(spec)
    for variant in plan.variants:
        method = dict(variant.static)["method"]
        for family in spec.families:
            block = plan.blocks[(variant.index, family)]
            indices = np.zeros(block.padded, np.int64)
            indices[: spec.fields] = np.arange(spec.fields)
            fields = make_swarms(spec.seed, spec.family_params(family), jnp.asarray(indices))
            want = evaluate_swarms(fields, variant.gains(plan.dtype), block.sim, block.mpc, block.width,
                                   plan.metrics)
            rows = df[(df["method"] == method) & (df["family"] == family)].sort_values("field")
            for m in swarm_metric_names():
                np.testing.assert_array_equal(rows[m].to_numpy(), np.asarray(want[m])[0, : spec.fields], err_msg=m)


def test_an_interrupted_swarm_sweep_resumes_to_the_same_rows(swept, tmp_path):
    spec, _, (df, _) = swept

    def stop(chunk):
        raise KeyboardInterrupt

    with pytest.raises(Interrupted, match="1 finished part"):
        run_sweep(spec, tmp_path / "out", quiet=True, after_part=stop)
    result = run_sweep(spec, tmp_path / "out", quiet=True)
    assert result.skipped == 3  # the first part: one setting × 3 fields
    again, _ = read_sweep(tmp_path / "out")
    pd.testing.assert_frame_equal(again, df)


def test_a_row_of_a_swarm_sweep_is_resimulated_by_simulate_swarm(swept):
    from jaxapf.simulate.swarm import simulate_swarm

    _, _, (df, meta) = swept
    row = df[(df["method"] == "velocity_obstacle") & (df["family"] == "crossing_flows")].iloc[1]
    cfg = row_config(meta, row.to_dict())
    _, runs, _ = simulate_swarm(cfg.family, cfg.seed, cfg.field, [cfg.sim.planner.method], cfg.gains, cfg.sim,
                                cfg.mpc, cfg.overrides)
    metrics = runs[0].metrics
    for m in ("swarm_success", "agent_collision", "deadlock"):
        assert metrics[m] == row[m], m
    assert metrics["min_agent_clearance"] == pytest.approx(row["min_agent_clearance"], abs=1e-4)


def test_a_sweep_of_16_uav_swarms(tmp_path):
    # the case: A = 16, one row per episode, every swarm metric finite where it must be
    spec = _spec(**{"scenario.families": ["circle_swap"], "scenario.fields": 2,
                    "scenario.params": {"circle_swap": {"agents": 16}}, "grid": {"method": ["velocity_obstacle"]}})
    run_sweep(spec, tmp_path / "out", quiet=True)
    df, meta = read_sweep(tmp_path / "out")
    assert meta["complete"] and len(df) == 2 and (df["agents"] == 16).all()
    assert np.isfinite(df["min_agent_clearance"]).all() and df["at_goal"].between(0, 1).all()


# --------------------------------------------------------------------------------------------
# the report of a swarm sweep
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_the_report_of_a_swarm_sweep_reads_the_swarm_metrics_and_draws_its_worst_swarms(swept, tmp_path):
    from jaxapf.report import ReportOptions, build_report

    _, out, (df, _) = swept
    result = build_report(out, tmp_path / "rep", ReportOptions(gallery=1, resamples=100, heatmap=None, animate=True))
    assert not any("could not re-simulate" in n for n in result.notes), result.notes
    summary = pd.read_csv(tmp_path / "rep" / "summary.csv")
    pooled = summary[(summary["method"] == "basic") & (summary["family"] == "circle_swap")].iloc[0]
    rows = df[(df["method"] == "basic") & (df["family"] == "circle_swap")]
    assert pooled["swarm_success_k"] == int(rows["swarm_success"].sum())
    figures = tmp_path / "rep" / "figures"
    assert (figures / "ecdf_min_agent_clearance.png").is_file() and (figures / "profile_at_goal.png").is_file()
    if (~df["swarm_success"]).any():
        assert (figures / "gallery_1.png").is_file() and (figures / "gallery_1_snapshots.png").is_file()
        assert (figures / "gallery_1_animated.gif").is_file() and (figures / "gallery_1_animated.mp4").is_file()
    tex = (tmp_path / "rep" / "table.tex").read_text()
    assert "Makespan" in tex and "closest UAV--UAV" in tex


# --------------------------------------------------------------------------------------------
# jaxapf simulate --family <swarm family>
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_simulate_draws_every_uav_of_a_swarm(tmp_path):
    out = tmp_path / "sim"
    rc, stdout, stderr = capture(main, ["simulate", "--family", "circle_swap", "--agents", "3", "--methods",
                                        "basic,velocity_obstacle", "--t-max", "3", "--horizon", "4", "--iters", "4",
                                        "--out", str(out)])
    assert rc == 0, stderr
    assert "circle_swap, 3 UAVs" in stdout and "swarm_success" in stdout
    table = pd.read_parquet(out / "trajectories.parquet")
    for _, rows in table.groupby("method"):
        assert sorted(rows["agent"].unique()) == [0, 1, 2]
        assert rows.groupby("agent").size().nunique() == 1  # every UAV drawn up to the swarm's end
    metrics = pd.read_csv(out / "metrics.csv")
    assert list(metrics["method"]) == ["basic", "velocity_obstacle"] and "at_goal" in metrics
    for name in ("swarm_trajectories.png", "swarm_snapshots.png"):
        assert (out / name).stat().st_size > 10_000


def test_simulate_refuses_agents_for_a_single_uav_family(tmp_path):
    rc, _, stderr = capture(main, ["simulate", "--family", "trap", "--agents", "4", "--out", str(tmp_path / "s")])
    assert rc == 2 and "--agents: trap is a single-UAV family" in stderr and "Traceback" not in stderr


@pytest.mark.slow
def test_the_outcome_of_each_uav_agrees_with_the_swarm_metrics():
    from jaxapf.config import MPCConfig, SimConfig
    from jaxapf.engine.swarm import swarm_rollout
    from jaxapf.metrics.swarm import agent_outcomes, swarm_metrics
    from jaxapf.scenarios.swarms import swarm_params

    swarm = jax.tree_util.tree_map(lambda x: x[0], make_swarms(0, swarm_params("circle_swap", agents=4,
                                                                                distance=(6.0, 7.0)), 1))
    sim, mpc = SimConfig.from_flat(t_max=8.0, method="basic"), MPCConfig(horizon=4, iters=4)
    traj = swarm_rollout(swarm, Gains(), sim, mpc)
    outcome, metrics = agent_outcomes(traj, swarm, sim), swarm_metrics(traj, swarm, sim)
    assert float(metrics["at_goal"]) == pytest.approx(float(jnp.mean(outcome["success"])))
    assert bool(metrics["swarm_success"]) == bool(jnp.all(outcome["success"]))
    assert (outcome["end"] <= sim.episode.steps).all()


def test_max_neighbours_with_a_sensor_that_remembers_slots_is_refused():
    """The nearest neighbours change slots every step; a noisy sensor's per-slot memory would carry one
    UAV's reading into another's slot."""
    with pytest.raises(ConfigError, match=r"sim\.max_neighbours = 4 needs sensor = \"ideal\""):
        _spec(sim={"t_max": 3.0, "max_neighbours": 4, "sensor": "noisy"})
    _spec(sim={"t_max": 3.0, "max_neighbours": 4})
