"""The numpy + OSQP baseline (jaxapf.baseline) against the JAX engine, and the benchmark's plumbing.

The baseline shares no code with the engine, so agreement checks the engine's potentials and
their gradients (both conventions, cylinders, masks, the clearance floor), the reference flow, the
condensed MPC with its velocity penalty, and the plant, end to end.
"""

import json
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

osqp = pytest.importorskip("osqp")

from jaxapf import baseline as bl  # noqa: E402
from jaxapf.config import ConfigError, Gains, MPCConfig, SimConfig  # noqa: E402
from jaxapf.mpc import axis_problem, solve_axes  # noqa: E402
from jaxapf.obstacles import Obstacles, Scenario  # noqa: E402
from jaxapf.potentials import total_force as jax_total_force  # noqa: E402
from jaxapf.rollout import rollout  # noqa: E402

COMBOS = [(m, c) for m in ("basic", "direction", "direction_velocity") for c in ("intent", "literal")]


def _scenario(xp=jnp):
    """3 real obstacles (a static sphere near the start-goal line, a cylinder, a moving sphere
    crossing the path) and one padded slot. Create inside the x64 context for float64."""
    f = lambda a: xp.asarray(a, dtype=xp.float64)  # noqa: E731
    return Scenario(
        start=f([0.0, 0.0, 0.0]),
        goal=f([12.0, 0.5, 0.5]),
        obstacles=Obstacles(
            position=f([[4.0, 0.3, 0.0], [7.0, -1.5, 5.0], [9.0, 4.0, 0.2], [1e6, 1e6, 1e6]]),
            velocity=f([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-0.3, -0.6, 0.0], [0.0, 0.0, 0.0]]),
            radius=f([1.0, 0.8, 0.7, 0.0]),
            cylinder=xp.asarray([False, True, False, False]),
            valid=xp.asarray([True, True, True, False]),
        ),
    )


def _gains():
    return dict(gamma=1.3, k=0.7, k_rep=8.0, d_s=3.5, k_att=1.2, eta=0.6)


def _sample_points(rng, n=24):
    """Points around the field, including some inside obstacles (below the clearance floor)."""
    pts = rng.normal(size=(n, 3)) * 2.5 + np.array([6.0, 0.5, 0.5])
    pts[:4] = [[4.0, 0.3, 0.9], [4.4, 0.3, 0.0], [7.2, -1.5, -3.0], [6.0, -1.5, 9.0]]  # deep/shallow inside
    pts[4] = [4.0, 0.3, 1.0 + 0.3 + 0.03]  # clearance 0.03 < d_min
    return pts, rng.normal(size=(n, 3)), rng.uniform(0.0, 4.0, size=n)


# --------------------------------------------------------------------------------------------
# potentials
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method,convention", COMBOS)
def test_numpy_force_matches_jax_grad(method, convention):
    sim = SimConfig(method=method, convention=convention, att_cap=6.0)
    with jax.enable_x64(True):
        scen, gains = _scenario(), Gains(**_gains()).as_arrays(jnp.float64)
        force = jax.jit(jax.vmap(lambda p, v, t: jax_total_force(
            p, v, t, scen.goal, scen.obstacles, gains, method=method, convention=convention,
            r_uav=sim.r_uav, d_min=sim.d_min, eps_v=sim.eps_v, att_cap=sim.att_cap)))
        pts, vels, ts = _sample_points(np.random.default_rng(0))
        expected = np.asarray(force(jnp.asarray(pts), jnp.asarray(vels), jnp.asarray(ts)))
    arrays = bl._scenario_arrays(_scenario(np))  # padded slot kept: exercised by the mask
    got = np.stack([bl.total_force(p, v, t, arrays, _gains(), sim) for p, v, t in zip(pts, vels, ts)])
    assert np.all(np.isfinite(got))
    scale = np.maximum(1.0, np.abs(expected).max(axis=1, keepdims=True))
    np.testing.assert_allclose(got / scale, expected / scale, rtol=0, atol=1e-11)


@pytest.mark.parametrize("method,convention", COMBOS)
def test_analytic_force_is_minus_gradient_of_numpy_potential(method, convention):
    sim = SimConfig(method=method, convention=convention, att_cap=6.0)
    arrays = bl._scenario_arrays(_scenario(np))
    pts, vels, ts = _sample_points(np.random.default_rng(1))
    h = 1e-6
    for p, v, t in zip(pts, vels, ts):
        fd = np.array([
            -(bl.total_potential(p + h * e, v, t, arrays, _gains(), sim)
              - bl.total_potential(p - h * e, v, t, arrays, _gains(), sim)) / (2 * h)
            for e in np.eye(3)
        ])
        f = bl.total_force(p, v, t, arrays, _gains(), sim)
        np.testing.assert_allclose(f, fd, rtol=1e-5, atol=1e-5 * max(1.0, np.abs(f).max()))


# --------------------------------------------------------------------------------------------
# MPC QP
# --------------------------------------------------------------------------------------------


def test_osqp_slack_qp_matches_fista_with_active_box_and_velocity_penalty():
    mpc = MPCConfig(horizon=8, q_pos=(1.0, 2.0, 0.5), q_vel=(0.1, 0.0, 0.2), f_pos=(5.0, 4.0, 3.0),
                    f_vel=0.5, r=(0.05, 0.1, 0.2), v_penalty=10.0)
    sim = SimConfig(v_max=1.0, a_max=2.0)
    x0 = np.array([0.0, 0.0, 0.0, 1.8, -1.6, 0.3])
    x_ref = np.zeros((mpc.horizon + 1, 6))
    x_ref[:, :3] = np.linspace([0.0, 0.0, 0.0], [6.0, -5.0, 1.0], mpc.horizon + 1)
    qp = bl.CondensedMPC(mpc, sim, eps=1e-9)
    u_osqp = qp.solve(x0, x_ref)
    v_pred = qp.m_v @ x0 + qp.c_v @ u_osqp.reshape(-1)
    assert np.abs(v_pred).max() > sim.v_max + 0.05  # the penalty is active
    assert np.any(np.abs(u_osqp) >= sim.a_max - 1e-9)  # so is the box
    with jax.enable_x64(True):
        prob = axis_problem(mpc, sim.dt, jnp.float64)
        solve = jax.jit(lambda x, r, w: solve_axes(prob, x, r, w, a_max=sim.a_max, v_max=sim.v_max,
                                                   iters=5_000))
        u_fista = solve(jnp.asarray(x0), jnp.asarray(x_ref), jnp.zeros((3, mpc.horizon), jnp.float64))
        u_fista = np.asarray(u_fista).T
    np.testing.assert_allclose(u_osqp, u_fista, atol=1e-6)


# --------------------------------------------------------------------------------------------
# closed loop
# --------------------------------------------------------------------------------------------

CLOSED_LOOP = [
    pytest.param("basic", "intent", {}, {}, id="basic-intent"),
    pytest.param("direction_velocity", "literal", {}, {}, id="dv-literal"),
    pytest.param("direction_velocity", "intent", dict(v_max=1.0, a_max=1.5),
                 dict(q_pos=5.0, q_vel=0.0, f_pos=20.0, f_vel=0.0, v_penalty=2.0), id="dv-intent-limits"),
    pytest.param("direction", "intent", dict(reference_velocity=True, att_cap=4.0), {}, id="dir-refvel-cap"),
]


@pytest.mark.parametrize("method,convention,sim_kw,mpc_kw", CLOSED_LOOP)
def test_engine_trajectory_matches_baseline(method, convention, sim_kw, mpc_kw):
    sim = SimConfig(method=method, convention=convention, t_max=5.0, **sim_kw)  # 50 steps
    mpc = MPCConfig(horizon=8, iters=2000, **mpc_kw)
    with jax.enable_x64(True):
        scen, gains = _scenario(), Gains(**_gains()).as_arrays(jnp.float64)
        traj = jax.device_get(jax.jit(rollout, static_argnums=(2, 3))(scen, gains, sim, mpc))
    base = bl.baseline_rollout(_scenario(np), Gains(**_gains()), sim, mpc)
    assert set(base) == {"time", "position", "velocity", "control"}
    assert base["position"].shape == (sim.steps + 1, 3) and base["control"].shape == (sim.steps, 3)
    np.testing.assert_allclose(base["time"], traj.time, atol=1e-12)
    # observed agreement is ~1e-12 m; the bound leaves room for FISTA's residual
    np.testing.assert_allclose(traj.position, base["position"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(traj.velocity, base["velocity"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(traj.control, base["control"], rtol=0, atol=1e-5)
    assert np.linalg.norm(base["position"][-1] - base["position"][0]) > 2.0  # it went somewhere
    if "a_max" in sim_kw:
        assert np.any(np.abs(base["control"]) >= sim.a_max - 1e-9)  # the box was active


# --------------------------------------------------------------------------------------------
# packaging and benchmark plumbing
# --------------------------------------------------------------------------------------------


def test_missing_osqp_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "osqp", None)  # makes `import osqp` raise ImportError
    with pytest.raises(ImportError, match=r'pip install "jaxapf\[bench\]"'):
        bl.baseline_rollout(_scenario(np), Gains(), SimConfig(t_max=0.2), MPCConfig(horizon=4))


def test_run_benchmark_small_custom_batch():
    from jaxapf.bench import format_benchmark, run_benchmark

    one = _scenario(np)
    batch = jax.tree_util.tree_map(lambda x: np.stack([x, x]).astype(np.float32) if x.dtype == np.float64
                                   else np.stack([x, x]), one)
    result = run_benchmark(steps=5, horizon=4, iters=5, baseline_fields=2, scenarios=batch)
    assert result["config"]["fields"] == 2 and result["config"]["obstacles"] == 4
    assert result["engine"]["run_s"] > 0 and result["baseline"]["fields"] == 2
    # one steady engine run before each baseline field; the reported one is their median
    assert len(result["engine"]["run_all_s"]) == 2 == len(result["baseline"]["per_field_all_s"])
    assert result["engine"]["run_s"] == pytest.approx(np.median(result["engine"]["run_all_s"]))
    assert result["speedup"] == pytest.approx(result["engine"]["steps_per_s"] / result["baseline"]["steps_per_s"])
    text = format_benchmark(result)
    assert "speed-up" in text and "compile" in text
    assert "skipped" in format_benchmark(dict(result, baseline=None, speedup=None))
    json.dumps(result)


def test_bench_devices_are_checked_before_running():
    from jaxapf.bench import run_benchmark

    with pytest.raises(ConfigError, match=r"bench\.devices = 0 is out of range"):
        run_benchmark(fields=2, steps=2, baseline_fields=0, devices=0)
    with pytest.raises(ConfigError, match=r"bench\.devices = 9 is out of range"):
        run_benchmark(fields=18, steps=2, baseline_fields=0, devices=9)  # more than this process has


def test_bench_on_two_devices_gives_the_metrics_of_one(tmp_path):
    # `jaxapf bench --devices 2` (host split into 2 CPU devices) and --devices 1 on the same fields
    import os
    import subprocess
    import sys

    script = ("import json, sys\nfrom jaxapf.sweep import configure_jax\nconfigure_jax(cpu_devices=2)\n"
              "from jaxapf.bench import run_benchmark\nimport jax\n"
              "r = {d: run_benchmark(fields=4, steps=20, horizon=4, iters=4, obstacles=4, baseline_fields=0, "
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


def test_fit_step_cost_recovers_a_known_model(monkeypatch):
    """`jaxapf bench --fit-cost` fits c0 + c_qp·N·I + c_obs·N·M + c_n·N: timings made from known
    coefficients come back exactly, and the table names the constant the sweep's dry run uses."""
    from jaxapf import bench

    truth = (5.0, 0.01, 0.02, 0.1)

    def fake_benchmark(*, fields, obstacles, horizon, iters, steps, baseline_fields):
        us = truth[0] + truth[1] * horizon * iters + truth[2] * horizon * obstacles + truth[3] * horizon
        return {"engine": {"run_s": us * 1e-6 * fields * steps}}

    monkeypatch.setattr(bench, "run_benchmark", fake_benchmark)
    result = bench.fit_step_cost(fields=8, steps=5)
    assert len(result["rows"]) == 18
    np.testing.assert_allclose(result["coefficients"], truth, rtol=1e-9)
    assert result["fit_over_measured"]["min"] == pytest.approx(1.0) == result["fit_over_measured"]["max"]
    assert "STEP_COST_US = (5, 0.01, 0.02, 0.1)" in bench.format_step_cost(result)


def test_xla_option_parsing_names_the_flag():
    from jaxapf.bench import parse_xla_option

    assert parse_xla_option("xla_cpu_use_fusion_emitters=true") == ("xla_cpu_use_fusion_emitters", True)
    assert parse_xla_option("xla_cpu_enable_fast_math=False") == ("xla_cpu_enable_fast_math", False)
    assert parse_xla_option("xla_cpu_prefer_vector_width=512") == ("xla_cpu_prefer_vector_width", 512)
    assert parse_xla_option("xla_cpu_experimental_ynn_fusion_type=") == ("xla_cpu_experimental_ynn_fusion_type", "")
    for bad in ("fast_math=true", "xla_cpu_use_fusion_emitters"):
        with pytest.raises(ConfigError, match=r"bench\.xla_option = .*KEY=VALUE"):
            parse_xla_option(bad)


def test_compare_xla_options_times_both_compilations_of_one_lowering():
    """`jaxapf bench --xla-option`: the shipped options against an override, from one lowering.
    An override that restates a shipped option compiles the same program: same episodes."""
    from jaxapf.bench import compare_xla_options, format_xla_options
    from jaxapf.rollout import XLA_OPTIONS

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


def test_cost_split_attributes_the_step_to_obstacles_iterations_and_the_rest():
    """`jaxapf bench --split`: four compiled cases, and the attribution is their differences."""
    from jaxapf.bench import cost_split, format_cost_split

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
    """`jaxapf bench --kernels`: one row per (op, layout, options), positive times, and a table."""
    from jaxapf.bench import KERNEL_OPS, format_kernel_cost, kernel_cost

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


def test_bench_kernels_cli_rejects_a_bad_size_by_name(capsys):
    from jaxapf.cli import main

    assert main(["bench", "--kernels", "--fields", "0"]) == 2
    assert "bench.fields = 0" in capsys.readouterr().err
