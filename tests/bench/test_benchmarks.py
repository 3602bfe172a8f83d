"""The maintainers' scripts of ``benchmarks/``: they run and compute what they say (timings are not asserted)."""

import json
import sys

import numpy as np
import pytest
from conftest import ROOT

from jaxapf.validation import ConfigError

sys.path.insert(0, str(ROOT / "benchmarks"))


def test_fit_step_cost_recovers_a_known_model(monkeypatch):
    """benchmarks/fit_cost.py fits c0 + c_qp·N·I + c_obs·N·M + c_n·N: timings made from known
    coefficients come back exactly, and the table names the constant the sweep's dry run uses."""
    import fit_cost

    truth = (5.0, 0.01, 0.02, 0.1)

    def fake_benchmark(*, fields, obstacles, horizon, iters, steps, oracle_fields):
        us = truth[0] + truth[1] * horizon * iters + truth[2] * horizon * obstacles + truth[3] * horizon
        return {"engine": {"run_s": us * 1e-6 * fields * steps}}

    monkeypatch.setattr(fit_cost, "run_benchmark", fake_benchmark)
    result = fit_cost.fit_step_cost(fields=8, steps=5)
    assert len(result["rows"]) == 18
    np.testing.assert_allclose(result["coefficients"], truth, rtol=1e-9)
    assert result["fit_over_measured"]["min"] == pytest.approx(1.0) == result["fit_over_measured"]["max"]
    assert "STEP_COST_US = (5, 0.01, 0.02, 0.1)" in fit_cost.format_step_cost(result)


def test_xla_option_parsing_names_the_flag():
    from xla_options import parse_xla_option

    assert parse_xla_option("xla_cpu_use_fusion_emitters=true") == ("xla_cpu_use_fusion_emitters", True)
    assert parse_xla_option("xla_cpu_enable_fast_math=False") == ("xla_cpu_enable_fast_math", False)
    assert parse_xla_option("xla_cpu_prefer_vector_width=512") == ("xla_cpu_prefer_vector_width", 512)
    assert parse_xla_option("xla_cpu_experimental_ynn_fusion_type=") == ("xla_cpu_experimental_ynn_fusion_type", "")
    for bad in ("fast_math=true", "xla_cpu_use_fusion_emitters"):
        with pytest.raises(ConfigError, match=r"bench\.xla_option = .*KEY=VALUE"):
            parse_xla_option(bad)


@pytest.mark.slow
def test_compare_xla_options_times_both_compilations_of_one_lowering():
    """benchmarks/xla_options.py: the shipped options against an override, from one lowering.
    An override that restates a shipped option compiles the same program: same episodes."""
    from xla_options import compare_xla_options, format_xla_options

    from jaxapf.engine import XLA_OPTIONS

    key, value = next(iter(XLA_OPTIONS.items()))
    result = compare_xla_options({key: value}, repeats=1, fields=2, steps=4, obstacles=2, horizon=3, iters=2)
    assert set(result["variants"]) == {"shipped", "override"}
    assert result["variants"]["override"]["options"] == XLA_OPTIONS
    assert all(v["run_s"] > 0 and v["compile_s"] > 0 for v in result["variants"].values())
    assert result["outcome_changes"] == 0 and max(result["max_abs_diff"].values()) == 0.0
    assert result["speedup"] == pytest.approx(result["variants"]["shipped"]["run_s"]
                                              / result["variants"]["override"]["run_s"])
    assert "override / shipped speed" in format_xla_options(result)
    json.dumps(result)  # the --json output
    with pytest.raises(ConfigError, match=r"bench\.xla_option = .*xla_cpu_no_such_option.*XLA rejected it"):
        compare_xla_options({"xla_cpu_no_such_option": 1}, repeats=1, fields=2, steps=2, obstacles=2, horizon=3,
                            iters=2)


@pytest.mark.slow
def test_cost_split_attributes_the_step_to_obstacles_iterations_and_the_rest():
    """benchmarks/split.py: four compiled cases, and the attribution is their differences."""
    from split import cost_split, format_cost_split

    result = cost_split(fields=2, obstacles=3, horizon=3, iters=2, steps=3, repeats=1)
    us = result["step_us"]
    assert set(us) == {"full", "one_obstacle", "one_iteration", "both"} and min(us.values()) > 0
    assert result["obstacles_us"] == pytest.approx(sorted([us["full"] - us["one_obstacle"],
                                                           us["one_iteration"] - us["both"]]))
    assert result["iterations_us"] == pytest.approx(sorted([us["full"] - us["one_iteration"],
                                                            us["one_obstacle"] - us["both"]]))
    assert result["rest_us"] == us["both"]
    text = format_cost_split(result)
    assert "2 further obstacle slots" in text and "1 further FISTA iterations" in text


def test_kernel_cost_times_every_op_in_both_layouts_with_both_emitters():
    """benchmarks/kernels.py: one row per (op, layout, options), positive times, and a table."""
    from kernels import KERNEL_OPS, format_kernel_cost, kernel_cost

    result = kernel_cost(fields=4, obstacles=3, iterations=2, repeats=1)
    rows = result["rows"]
    assert {(r["op"], r["layout"], r["options"]) for r in rows} == {
        (op, layout, options) for op in KERNEL_OPS for layout in ("fields x obstacles", "obstacles x fields")
        for options in ("shipped", "fusion emitters")}
    assert all(r["ps_per_element"] > 0 for r in rows)
    text = format_kernel_cost(result)
    assert all(op in text for op in KERNEL_OPS) and "fusion emitters" in text
    with pytest.raises(ConfigError, match="bench.iterations"):
        kernel_cost(iterations=0)


def test_kernels_script_rejects_a_bad_size_by_name(capsys):
    import kernels

    assert kernels.main(["--fields", "0"]) == 2
    assert "bench.fields = 0" in capsys.readouterr().err


def test_quickstart_times_the_readmes_own_commands(tmp_path):
    """benchmarks/quickstart.py reads the sweep and report commands from README.md's quick start and
    only moves their outputs to its own folder."""
    from quickstart import _with_out, quickstart_commands

    sweep, report = quickstart_commands((ROOT / "README.md").read_text())
    assert sweep[:3] == ["jaxapf", "sweep", "sweeps/compare-small.toml"]
    assert report[:2] == ["jaxapf", "report"] and report[2] == sweep[sweep.index("--out") + 1]
    moved = _with_out(report, tmp_path / "r", tmp_path / "d.parquet")
    assert moved[2] == str(tmp_path / "d.parquet") and moved[moved.index("--out") + 1] == str(tmp_path / "r")
    assert len(moved) == len(report)


@pytest.mark.slow
def test_accelerator_script_records_every_size_and_the_quickstart_command(tmp_path, monkeypatch):
    """benchmarks/accelerator.py: one record per size with its rate, written as it goes; the sweep is
    the README's quick-start command (timed as a subprocess: skipped here with --sweep-timeout 0)."""
    import accelerator

    out = tmp_path / "acc.json"
    monkeypatch.setattr(sys, "argv", ["accelerator.py", "--fields", "2", "3", "--repeats", "1", "--steps", "2",
                                      "--sweep-timeout", "0", "--json", str(out)])
    accelerator.main()
    record = json.loads(out.read_text())
    assert list(record["sizes"]) == ["2", "3"] and record["sweep"] is None
    for fields, size in record["sizes"].items():
        assert size["width"] == int(fields)
        assert size["steps_per_s"] == pytest.approx(int(fields) * 2 / size["run_s"])
        assert size["run_s"] == min(size["run_all_s"])
    from quickstart import quickstart_commands

    assert quickstart_commands((ROOT / "README.md").read_text())[0][:2] == ["jaxapf", "sweep"]


def test_flop_count_of_a_hand_made_program():
    """benchmarks/stages.py counts a product 2n³, an elementwise op and a transcendental one per element,
    a scan's body times its length, and data movement nothing."""
    import jax
    import jax.numpy as jnp
    from stages import count_flops

    n = 4

    def body(c, _):
        return jnp.exp(c @ c) + c.T, None

    counted = count_flops(jax.make_jaxpr(lambda x: jax.lax.scan(body, x, None, length=3)[0])(jnp.ones((n, n))).jaxpr)
    assert counted == {"flops": 3 * (2 * n**3 + n * n + n * n), "transcendental": 3 * n * n, "while_loops": 0}


@pytest.mark.slow
def test_stage_profile_attributes_the_step_and_its_flops():
    """benchmarks/stages.py: every stage timed and counted; the FISTA iteration is the difference of the
    two MPC solves per iteration; shares of the measured peak are rates over it."""
    from stages import format_profile, stage_profile

    result = stage_profile(fields=4, repeats=1, warm_steps=2, peak_size=64)
    st = result["stages"]
    assert set(st) >= {"sensor", "reference", "mpc_one_iteration", "mpc_all_iterations", "fista_iteration", "plant",
                       "control_step", "engine_step"}
    flops = {name: row["flops_per_scenario_step"] for name, row in st.items()}
    per = (flops["mpc_all_iterations"] - flops["mpc_one_iteration"]) / 29
    assert st["fista_iteration"]["flops_per_scenario_step"] == pytest.approx(per) and per > 0
    assert st["control_step"]["flops_per_scenario_step"] >= st["mpc_all_iterations"]["flops_per_scenario_step"]
    row = st["reference"]
    assert row["share_of_peak"] == pytest.approx(row["gflops"] / result["peak_gflops"])
    assert "peak" in format_profile(result)


def test_host_time_counts_every_setting_expansion_of_the_parts_it_writes():
    """benchmarks/host_time.py: the plan carries the settings and gain columns, so writing the parts asks
    the spec for none of them; its counter does count every call (nested ones too), and a fresh
    expansion costs time."""
    from host_time import measure, timed

    from jaxapf.sweep import SweepSpec, parse_spec

    r = measure(settings=50, fields=4, parts=3)
    assert r["config"] == {"settings": 50, "fields_per_part": 4, "parts": 3, "rows_per_part": 200}
    assert r["expansion_calls"] == 0 and r["expansion_s_per_part"] == r["expansion_share"] == 0.0
    assert r["expansion_from_scratch_s"] > 0 and len(r["part_s"]["all"]) == 3
    spent: list[float] = []
    spec = parse_spec({"name": "x", "scenario": {"families": ["clutter"], "fields": 1}})
    with timed(SweepSpec, ("settings", "gain_columns"), spent):
        spec.settings()
        spec.gain_columns()
    assert len(spent) >= 2 and "inner" not in SweepSpec.settings.__qualname__  # counted, then put back


def test_policy_agreement_counts_outcome_flips_and_continuous_drift():
    """Two hand-made sets of rows: one outcome flipped, one metric moved by 2e-3 on one row, NaN where NaN."""
    import pandas as pd
    from policy import agreement

    base = pd.DataFrame({"setting": [0, 0, 0, 0], "family": ["a"] * 4, "field": [0, 1, 2, 3],
                         "success": [True, False, True, True], "collision": [False] * 4, "stalled": [False] * 4,
                         "steps": [10, 20, 30, 40], "min_clearance": [1.0, 2.0, float("nan"), float("inf")]})
    other = base.copy()
    other.loc[1, "success"] = True
    other.loc[0, "min_clearance"] = 1.002
    found = agreement(base, other.iloc[::-1])  # the order of the rows does not matter
    assert found["rows"] == 4 and found["outcomes_equal"] == 0.75
    assert found["continuous"]["min_clearance"] == {"within_1e-3": 0.75, "bit_equal": 0.75}


def test_policy_reads_a_specs_fields_per_family(tmp_path):
    from policy import _spec_file

    copy = _spec_file(ROOT / "sweeps" / "compare-small.toml", 8192, tmp_path)
    assert "fields = 8192" in copy.read_text() and "fields = 512" not in copy.read_text()
    assert _spec_file(ROOT / "sweeps" / "quick.toml", None, tmp_path) == ROOT / "sweeps" / "quick.toml"


@pytest.mark.slow
def test_the_gpu_script_runs_on_a_cpu_in_its_smoke_mode(tmp_path):
    """``SMOKE=1 bash benchmarks/gpu.sh``: every record it writes is there and says what it measured."""
    import os
    import subprocess

    done = subprocess.run(["bash", str(ROOT / "benchmarks" / "gpu.sh")], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "SMOKE": "1", "OUT": str(tmp_path), "PYTHON": sys.executable},
                          timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    quick = json.loads((tmp_path / "policy-gpu.json").read_text())
    assert set(quick["policies"]) == {"cpu", "accelerator"}
    # quick.toml: one slot count, two potential-field methods: one program each on the CPU policy, one fused
    assert quick["policies"]["cpu"]["plan"]["programs"] == 2
    assert quick["policies"]["accelerator"]["plan"]["programs"] == 1
    assert quick["policies"]["accelerator"]["phases"]["programs"] == 1
    large = json.loads((tmp_path / "policy-gpu-large.json").read_text())
    assert set(large["policies"]) == {"accelerator"} and large["policies"]["accelerator"]["episodes"] == 64
    for name in ("compare", "tune"):
        assert json.loads((tmp_path / f"{name}-gpu.json").read_text())["rc"] == 0
    fill = json.loads((tmp_path / "oracle-fill-gpu.json").read_text())["families"]
    assert set(fill) == {"clutter", "paper_static", "trap"}
    assert all(f["fields"] == 8 and f["differ"] == {"scan": 0, "associative": 0} for f in fill.values())


def test_a_bench_too_large_for_the_devices_memory_is_refused_up_front(monkeypatch, capsys, tmp_path):
    """``jaxapf bench engine --fields 100000000`` ran out of memory with a traceback; now the size is weighed
    against the device's free memory first: the fields it names as the most fit, one more does not."""
    import re

    from jaxapf.bench import engine
    from jaxapf.cli import main
    from jaxapf.engine import policy

    monkeypatch.setattr(policy, "available_memory", lambda device=None: 300 * 2**20)
    with pytest.raises(ConfigError) as err:
        engine.check_fits(10**6, 16, 300, 1024)
    most = int(re.search(r"at most ([\d,]+) fields", str(err.value))[1].replace(",", ""))
    assert 0 < most < 10**6 and "300.0 MiB this device has free" in str(err.value)
    engine.check_fits(most, 16, 300, 1024)
    with pytest.raises(ConfigError):
        engine.check_fits(most + 1, 16, 300, 1024)
    huge = tmp_path / "huge.toml"
    huge.write_text('name = "huge"\n[scenario]\nfamilies = ["trap"]\nfields = 100000000\n')
    for argv, said in ((["engine", "--fields", "100000000"], "bench.fields"), (["world", "--fields", "100000000"],
                       "bench.fields"), (["swarm", "--uavs", "100000000", "--agents", "4"], "bench.uavs"),
                       (["sweep", str(huge)], "scenario.fields")):
        assert main(["bench", *argv]) == 2
        out = capsys.readouterr().err
        assert out.count("\n") == 1 and f"{said} = 100,000,000" in out and "needs about" in out, out


@pytest.mark.slow
def test_the_oracles_flood_fill_in_jax_answers_as_the_search_on_a_closed_and_an_opened_ring():
    """benchmarks/oracle_fill.py, the option measured and not kept: a start ringed by 16 cylinders (closed:
    unsolvable) and the same ring with one left out (solvable), both sweeps of the fill against the search."""
    import oracle_fill
    from oracle import vehicle_of

    from jaxapf.datatypes import Obstacles, Scenario
    from jaxapf.scenarios import solvable
    from jaxapf.scenarios.solvability import RESOLUTION

    angle = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
    ring = np.stack([2.0 * np.cos(angle), 2.0 * np.sin(angle), np.ones(16)], 1)
    valid = np.ones((2, 16), bool)
    valid[1, 3] = False
    fields = Scenario(start=np.array([[0.0, 0, 1]] * 2), goal=np.array([[6.0, 0, 1]] * 2),
                      obstacles=Obstacles(position=np.stack([ring, ring]), velocity=np.zeros((2, 16, 3)),
                                          radius=np.full((2, 16), 0.4), cylinder=np.ones((2, 16), bool), valid=valid))
    vehicle = vehicle_of("clutter")
    assert solvable(fields, **vehicle, certify=False).tolist() == [False, True]
    prepared = oracle_fill.prepare(fields, vehicle, RESOLUTION)
    for sweep in oracle_fill.SWEEPS:
        assert oracle_fill.fill(*prepared, RESOLUTION, sweep).tolist() == [False, True]
