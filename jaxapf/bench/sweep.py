"""Sweep throughput (``jaxapf bench sweep``): the streaming engine against the fixed-length one on a
sweep's episodes, the whole ``jaxapf sweep`` path against bare engine calls on the same work, and the
same sweep on several CPU devices."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..metrics import METRICS
from ..text import format_seconds
from .engine import _block, check_fits, environment, interleaved

__all__ = ["SWEEP_BENCH_SPEC", "time_sweep", "run_sweep_benchmark", "format_sweep_benchmark"]


#: The work of ``jaxapf bench sweep``: 4 settings (2 compiled variants) × 2 families × 256
#: fields, 200 steps each, default MPC (N = 20, 30 FISTA iterations).
SWEEP_BENCH_SPEC: dict[str, Any] = {
    "name": "bench-sweep",
    "scenario": {"families": ["trap", "clutter"], "fields": 256, "seed": 0},
    "sim": {"t_max": 20.0},
    "grid": {"method": ["basic", "direction_velocity"], "gamma": [0.5, 1.0]},
}

_SWEEP_WORKER = """
import json, sys
from jaxapf.bench.sweep import time_sweep
print(json.dumps(time_sweep(json.loads(sys.argv[1]))))
"""


def _sweep_run(spec: Any, tmp: str) -> Any:
    """A timed-run callable of the whole sweep (scenario generation, dispatch, transfer, Parquet
    writing, into ``tmp``), after an untimed run that compiled everything."""
    from ..sweep import run_sweep

    run_sweep(spec, f"{tmp}/warm.parquet", quiet=True)
    return lambda: run_sweep(spec, f"{tmp}/timed.parquet", quiet=True, overwrite=True)


def _bare_run(spec: Any, streaming: bool) -> Any:
    """A timed-run callable of the same episodes as one ``evaluate`` call per (variant, family) on
    pre-generated fields (nothing written), with the streaming or the fixed-length engine, after a
    compiling call."""
    from ..engine import evaluate
    from ..scenarios import make_scenarios
    from ..sweep import plan_sweep

    plan = plan_sweep(spec, devices=1)
    work = []
    for v in plan.variants:
        for family in spec.families:
            block = plan.blocks[(v.index, family)]  # the sweep's vmap width (narrower for long episodes)
            params = spec.family_params(family)
            episodes = spec.fields * len(v.simulated)  # one call holds every field of the family, every setting
            check_fits(episodes, params.max_obstacles, block.sim.episode.steps, block.width,
                       what=f"scenario.fields = {spec.fields:,} ({episodes:,} episodes in one call)", unit="episodes")
            fields = _block(make_scenarios(spec.seed, params, spec.fields))
            work.append((fields, plan.gains(v), block.flown, block.mpc, block.width))
    calls = [lambda w=w: _block(evaluate(*w, streaming=streaming)) for w in work]
    results = [call() for call in calls]

    def run() -> None:
        results[:] = [call() for call in calls]
    run.results = results  # the metrics of the last run, one dict per (variant, family)
    return run


def engine_agreement(fixed: list[dict[str, Any]], streamed: list[dict[str, Any]]) -> dict[str, Any]:
    """How far the streaming engine's metrics are from the fixed-length engine's on the same
    episodes: the fraction of episodes with every outcome (the rate and count metrics: success,
    collision, stall, steps, ...) equal, and per continuous metric the largest absolute difference
    and the fraction of episodes that agree within 1e-3 (absolute or relative)."""
    def stack(results, name):
        return np.concatenate([np.asarray(r[name], np.float64).ravel() for r in results])

    outcomes = [m for m in fixed[0] if METRICS.get(m, "metric").kind != "continuous"]
    same = np.logical_and.reduce([stack(fixed, m) == stack(streamed, m) for m in outcomes])
    continuous = {}
    for name in fixed[0]:
        if name in outcomes:
            continue
        a, b = stack(fixed, name), stack(streamed, name)
        both = np.isfinite(a) & np.isfinite(b)
        diff = np.abs(np.where(both, a, 0.0) - np.where(both, b, 0.0))
        close = np.where(both, diff <= 1e-3 * np.maximum(1.0, np.abs(a)), (a == b) | (np.isnan(a) & np.isnan(b)))
        continuous[name] = {"max_abs_diff": float(diff[both].max(initial=0.0)), "within_1e-3": float(close.mean())}
    return {"episodes": int(same.size), "outcomes_equal": float(same.mean()), "continuous": continuous}


def time_sweep(spec_table: dict[str, Any], repeats: int = 3) -> dict[str, Any]:
    """Wall time of a whole sweep of the spec ``spec_table`` (a TOML table) on this process's
    devices: the fastest of ``repeats`` runs after one that compiled everything."""
    import tempfile

    from ..sweep import parse_spec

    with tempfile.TemporaryDirectory() as tmp:
        best = interleaved({"sweep": _sweep_run(parse_spec(spec_table), tmp)}, repeats)["sweep"]
    return {"devices": jax.local_device_count(), **best}


def run_sweep_benchmark(spec_table: dict[str, Any] | None = None, sharded_devices: int = 2,
                        repeats: int = 3) -> dict[str, Any]:
    """The streaming engine's speed-up, the sweep's overhead over bare engine calls and the sharded
    speed-up, on the same work.

    Measured in this process (one device unless the process was started with more), each the
    fastest of ``repeats`` interleaved runs after a compiling one: the bare ``evaluate`` calls with
    the fixed-length and with the streaming engine (:func:`_bare_run`; streaming speed-up = fixed
    time / streaming time) and the whole sweep (:func:`_sweep_run`, streaming); overhead = sweep
    time / bare streaming time - 1. Then the same sweep in a subprocess (:func:`time_sweep`) whose host CPU is
    split into ``sharded_devices`` devices (``XLA_FLAGS=--xla_force_host_platform_device_count``);
    speed-up = one-device sweep time / sharded sweep time (skipped for 0 devices, or when this
    process does not run on the CPU).
    """
    import json
    import os
    import subprocess
    import sys
    import tempfile

    from ..sweep import parse_spec, plan_sweep

    spec_table = spec_table or SWEEP_BENCH_SPEC
    spec = parse_spec(spec_table)
    plan = plan_sweep(spec)
    steps = sum(len(plan.variants[c.variant].simulated) * (c.stop - c.start)
                * plan.blocks[(c.variant, c.family)].sim.episode.steps
                for c in plan.chunks)
    engines = {"fixed": _bare_run(spec, False), "bare": _bare_run(spec, True)}
    with tempfile.TemporaryDirectory() as tmp:
        timed = interleaved({**engines, "sweep": _sweep_run(spec, tmp)}, repeats)
    agreement = engine_agreement(engines["fixed"].results, engines["bare"].results)
    fixed, bare, sweep = timed["fixed"], timed["bare"], {"devices": jax.local_device_count(), **timed["sweep"]}
    sharded = None
    if sharded_devices > 0 and jax.default_backend() == "cpu":
        env = {**os.environ, "XLA_FLAGS": f"--xla_force_host_platform_device_count={sharded_devices}"}
        proc = subprocess.run([sys.executable, "-c", _SWEEP_WORKER, json.dumps(spec_table)], env=env,
                              capture_output=True, text=True, check=True)
        sharded = json.loads(proc.stdout.strip().splitlines()[-1])
    rate = lambda r: {"episodes_per_s": plan.episodes / r["run_s"], "steps_per_s": steps / r["run_s"]}  # noqa: E731
    return {
        "config": {"spec": spec_table, "episodes": plan.episodes, "scenario_steps": steps,
                   "settings": plan.settings, "variants": len(plan.variants), "chunks": len(plan.chunks),
                   "vmap_width": plan.width},
        "environment": environment(jnp.result_type(float)),
        "fixed": {**fixed, **rate(fixed)},
        "bare": {**bare, **rate(bare)},
        "streaming_speedup": fixed["run_s"] / bare["run_s"],
        "engine_agreement": agreement,
        "sweep": {**sweep, **rate(sweep)},
        "overhead": sweep["run_s"] / bare["run_s"] - 1.0,
        "sharded": None if sharded is None else {**sharded, **rate(sharded),
                                                 "speedup": sweep["run_s"] / sharded["run_s"]},
    }


def format_sweep_benchmark(result: dict[str, Any]) -> str:
    """A compact table of :func:`run_sweep_benchmark`'s result."""
    cfg, env = result["config"], result["environment"]
    lines = [
        f"jaxapf bench sweep: {cfg['spec']['name']}: {cfg['episodes']:,} episodes ({cfg['settings']} settings in "
        f"{cfg['variants']} variants), {cfg['scenario_steps']:,} scenario-steps, {cfg['chunks']} chunks",
        f"  device {env['device']} x{env['device_count']}, {env['cpu_count']} CPUs, jax {env['jax']}, {env['dtype']}, "
        f"vmap width {cfg['vmap_width']}",
        "",
        f"  {'':34s}{'time':>10s}{'episodes/s':>14s}{'scenario-steps/s':>20s}",
        "  (scenario-steps: episodes x their t_max / dt, whether flown or not)",
    ]
    rows = [("fixed-length engine (1 device)", result["fixed"]), ("streaming engine (1 device)", result["bare"]),
            ("sweep end to end (1 device)", result["sweep"])]
    if result["sharded"] is not None:
        rows.append((f"sweep end to end ({result['sharded']['devices']} devices)", result["sharded"]))
    for label, r in rows:
        lines.append(f"  {label:34s}{format_seconds(r['run_s']):>10s}{r['episodes_per_s']:>14,.0f}"
                     f"{r['steps_per_s']:>20,.0f}")
    agree = result["engine_agreement"]
    worst = min(agree["continuous"].items(), key=lambda kv: kv[1]["within_1e-3"])
    lines += ["", f"  streaming engine: {result['streaming_speedup']:.2f}x less wall time than the fixed-length one "
                  "on the same episodes",
              f"  engines agree: every outcome on {100 * agree['outcomes_equal']:.2f} % of {agree['episodes']:,} "
              f"episodes; continuous metrics within 1e-3 on >= {100 * worst[1]['within_1e-3']:.1f} % ({worst[0]} "
              f"the least; largest difference {max(c['max_abs_diff'] for c in agree['continuous'].values()):.2g})",
              f"  sweep overhead over bare evaluate: {100 * result['overhead']:+.1f} % (target < 5 %; the solvability "
              "oracle runs on the host beside the engine, `oracle = false` in [scenario] skips it)"]
    if result["sharded"] is not None:
        sharded = result["sharded"]
        lines.append(f"  sharded speed-up ({sharded['devices']} devices / 1): {sharded['speedup']:.2f}x")
    return "\n".join(lines)
