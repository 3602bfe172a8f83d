r"""Engine speed: the batched JAX evaluator against the numpy + OSQP oracle on the same fields.

:func:`run_benchmark` measures, in one process and on the same fields,

* the **engine** (:func:`jaxapf.engine.evaluate`, one compiled call over all fields): trace +
  lowering time, XLA compile time (``jit(...).lower(...).compile()``, so no run is mixed in), the
  first run of the compiled executable (includes any one-off transfer/allocation) and steady runs
  (``block_until_ready``), one before each oracle field, their median reported; throughput =
  fields × steps / steady run time;
* the **oracle** (:func:`jaxapf.bench.oracle.oracle_rollout`: a Python loop over steps, numpy
  potentials, OSQP to tolerance 1e-7 with polishing) on the first ``oracle_fields`` of those
  fields, each right after a steady engine run (engine, field 0, engine, field 1, ...), so a drift
  of a shared machine's speed hits both sides alike: seconds per field and scenario-steps per
  second;
* the **vectorised numpy peer** (:func:`jaxapf.bench.vectorised.vectorised_rollout`: the same
  closed loop in numpy over all fields at once) for ``vectorised_steps`` steps after each of the
  first three steady engine runs, after one untimed warm-up, with BLAS pinned to one thread
  (:func:`blas_one_thread`; the result records how);
* the **speed-up** = engine scenario-steps/s ÷ each peer's scenario-steps/s, both from this run.

Wall-clock times are what is reported; the process CPU time of the timed sections is recorded too
(``run_cpu_s``, ``cpu_s``), so a run on a shared machine can be recognised (CPU time well below
wall time × cores the run could use means other processes took the cores).

The two sides do the same closed loop (``tests/bench/test_oracle.py`` checks that they agree in
float64); the engine runs a fixed number of FISTA iterations (``iters``) in the default dtype, the
oracle solves every QP to tolerance, which is what a researcher without the engine would do.

Everything is returned in a JSON-serialisable dict (``jaxapf bench engine --json``);
:func:`format_benchmark` renders it as a small table. The helpers :func:`bench_case`,
:func:`lower_case` and :func:`interleaved` serve the maintainers' scripts in ``benchmarks/`` too.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import time
from importlib import metadata
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from ..config import MPCConfig, SimConfig
from ..gains import Gains
from ..metrics import metric_names
from ..text import format_bytes, format_seconds
from ..validation import ConfigError, check_int

__all__ = ["run_benchmark", "format_benchmark", "bench_case", "lower_case", "interleaved", "environment",
           "rates_summary", "blas_one_thread"]


def environment(dtype: Any) -> dict[str, Any]:
    """Versions of everything that can change a timing, with OSQP's and the dtype."""
    from ..io.versions import versions

    try:
        osqp = metadata.version("osqp")
    except metadata.PackageNotFoundError:
        osqp = "not installed"
    return {**versions(), "osqp": osqp, "dtype": str(jnp.dtype(dtype))}


def blas_one_thread() -> tuple[Any, str]:
    """A context that pins BLAS to one thread, and how: the vectorised numpy peer's matrix
    products are small (N x 2N by N x 3F), where BLAS threads cost more than they give on a CPU the
    engine already keeps busy. Uses threadpoolctl when it is installed; without it the threads can
    only be set before numpy loads BLAS (``OPENBLAS_NUM_THREADS=1``, ``OMP_NUM_THREADS=1`` or
    ``MKL_NUM_THREADS=1`` in the environment of ``jaxapf bench engine``), which is checked."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        for name in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
            if os.environ.get(name, "").strip() == "1":
                return contextlib.nullcontext(), f"1 ({name}=1)"
        return contextlib.nullcontext(), ("not pinned (pip install threadpoolctl, or run with "
                                          "OPENBLAS_NUM_THREADS=1)")
    return threadpool_limits(limits=1, user_api="blas"), "1 (threadpoolctl)"


def _block(tree: Any) -> Any:
    return jax.block_until_ready(tree)


def rates_summary(metrics: dict[str, Any]) -> dict[str, float]:
    """The mean of every rate metric and of ``final_distance``: a sanity check that the episodes did something."""
    out = {f"{name}_rate": float(np.mean(np.asarray(metrics[name], np.float64)))
           for name in metric_names(kind="rate") if name in metrics}
    if "final_distance" in metrics:
        out["final_distance_mean"] = float(np.mean(np.asarray(metrics["final_distance"], np.float64)))
    return out


def check_fits(fields: int, obstacles: int, steps: int, width: int, agents: int = 1, what: str | None = None,
               unit: str | None = None) -> None:
    """Refuse, in one line and before anything is made, a benchmark whose fields and episodes would take more
    memory than the device has free (:func:`~jaxapf.engine.policy.available_memory`), by the sweep's memory model
    (:func:`~jaxapf.sweep.plan.working_set_bytes`, :func:`~jaxapf.sweep.plan.episode_bytes`); the most fields that
    fit are named. ``what``: the option the size came from, as the refusal names it (default ``bench.fields``);
    ``unit``: what ``fields`` counts (default fields, or swarms of ``agents``)."""
    from ..engine.policy import available_memory
    from ..sweep.plan import episode_bytes, working_set_bytes

    free = available_memory()
    itemsize = jnp.dtype(jnp.result_type(float)).itemsize
    batch = working_set_bytes(min(width, fields), steps, obstacles, itemsize, agents)
    each = episode_bytes(obstacles, itemsize, agents)
    if free is not None and batch + fields * each > free:
        most = max((free - batch) // each, 0)
        need, unit = format_bytes(batch + fields * each), unit or ("fields" if agents == 1 else "swarms")
        raise ConfigError(f"{what or f'bench.fields = {fields:,}'} needs about {need} of memory ({obstacles} obstacle "
                          f"slots, {steps:,} steps), more than the {format_bytes(free)} this device has free: at most "
                          f"{most:,} {unit} here")


def bench_case(fields: int, obstacles: int, horizon: int, iters: int, steps: int, family: str, *, seed: int = 0,
               method: str = "direction_velocity", width: int | None = None, gains: Gains | None = None,
               scenarios: Any = None) -> dict[str, Any]:
    """Configs, fields (on device) and a batch of one gain setting of a benchmark case."""
    from ..engine import default_width

    steps = check_int("bench.steps", steps, 1)
    if width is not None:
        width = check_int("bench.width", width, 1)
    sim = SimConfig.from_flat(method=method, t_max=steps * 0.1)
    mpc = MPCConfig(horizon=horizon, iters=iters)
    gains = Gains() if gains is None else gains
    if scenarios is None:
        from ..scenarios import family_params, make_scenarios

        check_fits(fields, obstacles, steps, default_width() if width is None else width)
        scenarios = make_scenarios(seed, family_params(family, max_obstacles=obstacles), fields)
        source = family
    else:
        source = "custom"
    scenarios = _block(jax.tree_util.tree_map(jnp.asarray, scenarios))
    gains_batch = jax.tree_util.tree_map(lambda g: jnp.asarray(g, scenarios.start.dtype)[None], gains)
    return {"sim": sim, "mpc": mpc, "gains": gains, "gains_batch": gains_batch, "scenarios": scenarios,
            "width": default_width() if width is None else width, "source": source}


def lower_case(case: dict[str, Any]) -> tuple[Any, tuple]:
    """The engine (:func:`~jaxapf.engine.evaluate_program`) lowered for a :func:`bench_case`, and its arguments."""
    from ..engine import evaluate_program
    from ..metrics import METRICS

    args = (case["scenarios"], case["gains_batch"])
    return evaluate_program.lower(*args, sim=case["sim"], mpc=case["mpc"], width=case["width"],
                                  metrics=METRICS.names()), args


def interleaved(runs: dict[str, Callable[[], Any]], repeats: int) -> dict[str, dict[str, float]]:
    """Fastest of ``repeats`` timed calls of each of ``runs`` (wall and process CPU seconds), the
    calls interleaved (a, b, a, b, ...) so that drifts of a shared machine hit every entry alike."""
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in runs}
    for _ in range(repeats):
        for name, run in runs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            run()
            times[name].append((time.perf_counter() - t0, time.process_time() - c0))
    return {name: {"run_s": min(t)[0], "cpu_s": min(t)[1], "repeats": repeats} for name, t in times.items()}


# long: one timed session (compile, first run, the engine's rounds interleaved with both peers') and its record
def run_benchmark(
    fields: int = 1024,
    obstacles: int = 16,
    horizon: int = 20,
    iters: int = 30,
    steps: int = 300,
    oracle_fields: int = 3,
    family: str = "clutter",
    vectorised_steps: int = 30,
    seed: int = 0,
    method: str = "direction_velocity",
    width: int | None = None,
    *,
    devices: int = 1,
    gains: Gains | None = None,
    scenarios: Any = None,
) -> dict[str, Any]:
    """Time the batched engine and the numpy + OSQP oracle on the same fields.

    Args:
      fields: number of obstacle fields F in the engine's batch.
      obstacles: obstacle slots per field (``family_params(family, max_obstacles=obstacles)``).
      horizon, iters: MPC horizon N and FISTA iterations (``MPCConfig``).
      steps: control steps per episode (``SimConfig(t_max=steps * 0.1)``, dt = 0.1 s).
      oracle_fields: how many of the fields the oracle runs (0 skips it).
      vectorised_steps: control steps of the vectorised numpy peer
        (:func:`~jaxapf.bench.vectorised.vectorised_rollout`) on all ``fields`` in each timed
        round (0 skips it): a step costs the same all episode long, so its scenario-steps/s from
        fewer steps is the whole episode's.
      family, seed: scenario family and seed (``make_scenarios(seed, params, fields)``).
      method: planner (``PlannerConfig.method``).
      width: the vmap width of :func:`~jaxapf.engine.evaluate` (default:
        :func:`~jaxapf.engine.default_width` for the backend).
      devices: local devices the fields are split over (:class:`~jaxapf.engine.devices.DeviceBatch`, as
        ``jaxapf sweep`` does); ``fields`` must be a multiple. With more than one, compilation is
        not timed apart: ``first_run_s`` includes it.
      gains: one gain setting (default ``Gains()``); the engine runs it as a batch of G = 1.
      scenarios: a prebuilt batch of fields (leading axis F) to use instead of ``family``/``seed``;
        ``fields`` and ``obstacles`` are then read from it.

    Returns:
      A JSON-serialisable dict: ``config``, ``environment``, ``engine``, ``oracle`` and
      ``vectorised`` (None when skipped), ``speedup`` and ``speedup_vectorised`` (engine over each
      peer in scenario-steps/s; None when skipped).
    """
    fields = check_int("bench.fields", fields, 1)
    oracle_fields = check_int("bench.oracle_fields", oracle_fields, 0)
    vectorised_steps = check_int("bench.vectorised_steps", vectorised_steps, 0)
    devices = check_int("bench.devices", devices, 1, jax.local_device_count())
    t0 = time.perf_counter()
    case = bench_case(fields, obstacles, horizon, iters, steps, family, seed=seed, method=method, width=width,
                      gains=gains, scenarios=scenarios)
    t_scenarios = time.perf_counter() - t0
    sim, mpc, gains, width, source = case["sim"], case["mpc"], case["gains"], case["width"], case["source"]
    scenarios, gains_batch = case["scenarios"], case["gains_batch"]
    fields = int(scenarios.start.shape[0])
    obstacles = int(scenarios.obstacles.radius.shape[-1])
    if fields % devices:
        raise ConfigError(f"bench.fields = {fields} is not a multiple of bench.devices = {devices}")
    dtype = scenarios.start.dtype

    # engine: trace + lower, compile, first run, steady run
    if devices == 1:
        t0 = time.perf_counter()
        lowered, _ = lower_case(case)
        t_lower = time.perf_counter() - t0
        t0 = time.perf_counter()
        run = lowered.compile()
        t_compile = time.perf_counter() - t0
    else:
        from ..engine.devices import DeviceBatch
        from ..metrics import METRICS

        batch = DeviceBatch(jax.local_devices()[:devices])
        per_device = batch.put_gains(gains_batch)
        t_lower = t_compile = None

        def run(s, _):
            return batch.evaluate(s, per_device, sim, mpc, width, METRICS.names())
    n_base = min(oracle_fields, fields)
    n_vec = 3 if vectorised_steps > 0 else 0
    if n_base > 0 or n_vec:
        host = jax.device_get(scenarios)  # the numpy peers read the fields from the host
    if n_base > 0:
        from .oracle import oracle_rollout, require_osqp

        require_osqp()
    if n_vec:
        from .vectorised import vectorised_rollout

        vec_sim = dataclasses.replace(sim, episode=dataclasses.replace(
            sim.episode, t_max=min(vectorised_steps, sim.episode.steps) * sim.episode.dt))
        vec_steps = vec_sim.episode.steps
        blas, blas_threads = blas_one_thread()
        with blas:  # untimed warm-up: the peer's one-off set-up (its MPC matrices) and first touches
            vectorised_rollout(host, gains, dataclasses.replace(sim, episode=dataclasses.replace(
                sim.episode, t_max=sim.episode.dt)), mpc, dtype=np.dtype(dtype))
    runs, cpus, per_field, base_cpu, vec_runs, vec_cpu = [], [], [], 0.0, [], 0.0
    try:
        t0 = time.perf_counter()
        _block(run(scenarios, gains_batch))
        t_first = time.perf_counter() - t0
        # Steady engine runs alternate with the oracle's fields (engine, field 0, engine, field 1,
        # ...), so a drift of a shared machine's speed hits both sides of the ratio alike.
        for i in range(max(n_base, n_vec, 1)):
            t0, c0 = time.perf_counter(), time.process_time()
            metrics = _block(run(scenarios, gains_batch))
            runs.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
            if i < n_base:
                one = jax.tree_util.tree_map(lambda x, i=i: np.asarray(x[i]), host)
                t0, c0 = time.perf_counter(), time.process_time()
                oracle_rollout(one, gains, sim, mpc)
                per_field.append(time.perf_counter() - t0)
                base_cpu += time.process_time() - c0
            if i < n_vec:
                with blas:
                    t0, c0 = time.perf_counter(), time.process_time()
                    vectorised_rollout(host, gains, vec_sim, mpc, dtype=np.dtype(dtype))
                    vec_runs.append(time.perf_counter() - t0)
                    vec_cpu += time.process_time() - c0
    finally:
        if devices > 1:
            batch.close()
    t_run = float(np.median(runs))
    scenario_steps = fields * sim.episode.steps
    engine = {
        "scenario_build_s": t_scenarios,
        "lower_s": t_lower,
        "compile_s": t_compile,
        "first_run_s": t_first,
        "run_s": t_run,
        "run_all_s": runs,
        "run_cpu_s": float(np.median(cpus)),
        "steps_per_s": scenario_steps / t_run,
        "per_field_ms": 1e3 * t_run / fields,
        **rates_summary(jax.device_get(metrics)),
    }

    oracle = None
    speedup = None
    if n_base > 0:
        total = float(np.sum(per_field))
        oracle = {
            "fields": n_base,
            "total_s": total,
            "cpu_s": base_cpu,
            "per_field_s": total / n_base,
            "per_field_all_s": [float(x) for x in per_field],
            "steps_per_s": n_base * sim.episode.steps / total,
            "all_fields_estimate_s": total / n_base * fields,
        }
        speedup = engine["steps_per_s"] / oracle["steps_per_s"]
    vectorised = speedup_vectorised = None
    if n_vec:
        t_vec = float(np.median(vec_runs))
        vectorised = {"steps": vec_steps, "run_s": t_vec, "run_all_s": vec_runs,
                      "steps_per_s": fields * vec_steps / t_vec, "cpu_s": vec_cpu / n_vec,
                      "blas_threads": blas_threads}
        speedup_vectorised = engine["steps_per_s"] / vectorised["steps_per_s"]

    return {
        "config": {
            "fields": fields,
            "obstacles": obstacles,
            "horizon": horizon,
            "iters": iters,
            "steps": sim.episode.steps,
            "dt": sim.episode.dt,
            "oracle_fields": n_base,
            "vectorised_steps": vectorised["steps"] if vectorised else 0,
            "family": source,
            "seed": seed,
            "method": method,
            "gain_settings": 1,
            "width": width,
            "devices": devices,
        },
        "environment": environment(dtype),
        "engine": engine,
        "oracle": oracle,
        "speedup": speedup,
        "vectorised": vectorised,
        "speedup_vectorised": speedup_vectorised,
    }


def format_benchmark(result: dict[str, Any]) -> str:
    """A compact human-readable table of :func:`run_benchmark`'s result."""
    cfg, env, eng, base = result["config"], result["environment"], result["engine"], result["oracle"]
    lines = [
        f"jaxapf bench engine: {cfg['family']} fields, method {cfg['method']}",
        f"  {cfg['fields']} fields x {cfg['steps']} steps (dt {cfg['dt']:g} s), {cfg['obstacles']} obstacle slots, "
        f"MPC horizon {cfg['horizon']}, {cfg['iters']} FISTA iterations, vmap width {cfg['width']}, "
        f"{cfg['devices']} device(s)",
        f"  device {env['device']} x{env['device_count']}, {env['cpu_count']} CPUs, "
        f"jax {env['jax']} / jaxlib {env['jaxlib']}, {env['dtype']}",
        "",
        f"  {'':34s}{'time':>12s}{'scenario-steps/s':>20s}",
        *([f"  {'engine trace + lower':34s}{format_seconds(eng['lower_s']):>12s}",
           f"  {'engine compile':34s}{format_seconds(eng['compile_s']):>12s}",
           f"  {'engine first run':34s}{format_seconds(eng['first_run_s']):>12s}"] if eng["compile_s"] is not None else
          [f"  {'engine first run (with compile)':34s}{format_seconds(eng['first_run_s']):>12s}"]),
        f"  {'engine steady run, median of ' + str(len(eng['run_all_s'])):34s}{format_seconds(eng['run_s']):>12s}"
        f"{eng['steps_per_s']:>20,.0f}",
        f"  {'engine per field':34s}{format_seconds(eng['per_field_ms'] / 1e3):>12s}",
    ]
    if base is not None:
        lines += [
            f"  {'oracle (numpy + OSQP) per field':34s}{format_seconds(base['per_field_s']):>12s}"
            f"{base['steps_per_s']:>20,.0f}",
            f"  {'  (measured on ' + str(base['fields']) + ' fields)':34s}",
            f"  {'oracle, all fields (estimate)':34s}{format_seconds(base['all_fields_estimate_s']):>12s}",
            "",
            f"  speed-up (engine / oracle steps/s): {result['speedup']:,.1f}x",
        ]
    else:
        lines += ["", "  oracle skipped (oracle_fields = 0)"]
    vec = result.get("vectorised")
    if vec is not None:
        lines += [
            f"  {'vectorised numpy, all fields':34s}{format_seconds(vec['run_s']):>12s}{vec['steps_per_s']:>20,.0f}",
            f"  {'  (' + str(vec['steps']) + ' steps, median of ' + str(len(vec['run_all_s'])) + ')':34s}"
            f"  BLAS threads: {vec.get('blas_threads', '?')}",
            f"  speed-up (engine / vectorised numpy steps/s): {result['speedup_vectorised']:,.1f}x",
        ]
    rates = [f"{k[:-5]} {v:.1%}" for k, v in eng.items() if k.endswith("_rate")]
    if rates:
        lines.append("  engine episodes: " + ", ".join(rates))
    return "\n".join(lines)
