"""``jaxapf bench``: the engine's benchmark plumbing (timings are measured by the command, never asserted here)."""

import json

import jax
import numpy as np
import pytest

from jaxapf.validation import ConfigError


@pytest.mark.slow
def test_run_benchmark_small_custom_batch(field_factory):
    from jaxapf.bench import format_benchmark, run_benchmark

    one = field_factory(np)
    batch = jax.tree_util.tree_map(lambda x: np.stack([x, x]).astype(np.float32) if x.dtype == np.float64
                                   else np.stack([x, x]), one)
    result = run_benchmark(steps=5, horizon=4, iters=5, oracle_fields=2, vectorised_steps=0, scenarios=batch)
    assert result["config"]["fields"] == 2 and result["config"]["obstacles"] == 4
    assert result["engine"]["run_s"] > 0 and result["oracle"]["fields"] == 2
    # one steady engine run before each oracle field; the reported one is their median
    assert len(result["engine"]["run_all_s"]) == 2 == len(result["oracle"]["per_field_all_s"])
    assert result["engine"]["run_s"] == pytest.approx(np.median(result["engine"]["run_all_s"]))
    assert result["speedup"] == pytest.approx(result["engine"]["steps_per_s"] / result["oracle"]["steps_per_s"])
    text = format_benchmark(result)
    assert "speed-up" in text and "compile" in text
    assert "skipped" in format_benchmark(dict(result, oracle=None, speedup=None))
    json.dumps(result)


def test_bench_devices_are_checked_before_running():
    from jaxapf.bench import run_benchmark

    with pytest.raises(ConfigError, match=r"bench\.devices = 0 is out of range"):
        run_benchmark(fields=2, steps=2, oracle_fields=0, devices=0)
    with pytest.raises(ConfigError, match=r"bench\.devices = 9 is out of range"):
        run_benchmark(fields=18, steps=2, oracle_fields=0, devices=9)  # more than this process has


@pytest.mark.slow
def test_bench_on_two_devices_gives_the_metrics_of_one(tmp_path):
    # `jaxapf bench engine --devices 2` (host split into 2 CPU devices) and --devices 1 on the same fields
    import os
    import subprocess
    import sys

    script = ("import json, sys\nfrom jaxapf.engine import configure_jax\nconfigure_jax(cpu_devices=2)\n"
              "from jaxapf.bench import run_benchmark\nimport jax\n"
              "r = {d: run_benchmark(fields=4, steps=20, horizon=4, iters=4, obstacles=4, oracle_fields=0, "
              "devices=d, family='crossing') for d in (1, 2)}\n"
              "print(json.dumps({d: x['engine'] for d, x in r.items()}))\n")
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"} | {"JAX_PLATFORMS": "cpu"}
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr
    engines = json.loads(out.stdout.strip().splitlines()[-1])
    assert engines["1"]["compile_s"] is not None and engines["2"]["compile_s"] is None
    assert engines["1"]["final_distance_mean"] > 0
    for key in ("success_rate", "collision_rate", "stalled_rate", "final_distance_mean"):
        assert engines["1"][key] == engines["2"][key]  # bit-identical episodes


def test_bench_cli_has_subcommands_not_instead_flags(capsys):
    from jaxapf.cli import main

    assert main(["bench", "engine", "--fields", "0"]) == 2
    assert "bench.fields = 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["bench", "--split"])


@pytest.mark.slow
def test_sweep_benchmark_times_the_sweep_against_bare_calls_on_the_same_work():
    from jaxapf.bench.sweep import format_sweep_benchmark, run_sweep_benchmark

    table = {"name": "bench-tiny", "scenario": {"families": ["crossing"], "fields": 4},
             "sim": {"t_max": 0.5, "horizon": 3, "iters": 2}, "grid": {"method": ["basic", "direction"]}}
    result = run_sweep_benchmark(table, sharded_devices=0, repeats=1)
    assert result["config"]["episodes"] == 8 and result["config"]["scenario_steps"] == 8 * 5
    assert result["bare"]["run_s"] > 0 and result["sweep"]["run_s"] > 0 and result["sharded"] is None
    assert result["overhead"] == pytest.approx(result["sweep"]["run_s"] / result["bare"]["run_s"] - 1.0)
    assert result["streaming_speedup"] == pytest.approx(result["fixed"]["run_s"] / result["bare"]["run_s"])
    assert result["engine_agreement"]["episodes"] == result["config"]["episodes"]
    assert 0.9 <= result["engine_agreement"]["outcomes_equal"] <= 1.0
    text = format_sweep_benchmark(result)
    assert "sweep overhead" in text and "streaming engine:" in text and "engines agree" in text
    json.dumps(result)


@pytest.mark.slow
def test_world_benchmark_times_every_component_against_the_ideal_world(capsys):
    """``jaxapf bench world`` at a tiny size: every variant compiled and timed, ratios against ``ideal``."""
    from jaxapf.bench.world import VARIANTS, format_world_benchmark, run_world_benchmark

    result = run_world_benchmark(fields=4, steps=3, horizon=3, iters=2, substeps=2, repeats=1)
    assert set(result["variants"]) == set(VARIANTS)
    assert result["variants"]["ideal"]["ratio"] == 1.0
    for name, v in result["variants"].items():
        assert v["run_s"] > 0 and v["us_per_scenario_step"] == pytest.approx(1e6 * v["run_s"] / 12), name
    assert "quadrotor" in format_world_benchmark(result)
    some = run_world_benchmark(fields=2, steps=2, horizon=3, iters=2, substeps=2, repeats=1,
                               variants=("learned_weight", "cbf"))
    assert list(some["variants"]) == ["ideal", "learned_weight", "cbf"]  # the ideal world first, the baseline
