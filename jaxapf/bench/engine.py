r"""Engine benchmark: the batched JAX evaluator against the numpy + OSQP researcher baseline.

:func:`run_benchmark` measures, in one process and on the same fields,

* the **engine** (:func:`jaxapf.rollout.evaluate`, one compiled call over all fields): trace +
  lowering time, XLA compile time (``jit(...).lower(...).compile()``, so no run is mixed in), the
  first run of the compiled executable (includes any one-off transfer/allocation) and steady runs
  (``block_until_ready``), one before each baseline field, their median reported; throughput =
  fields × steps / steady run time;
* the **baseline** (:func:`jaxapf.baseline.baseline_rollout`: a Python loop over steps, numpy
  potentials, OSQP to tolerance 1e-7 with polishing) on the first ``baseline_fields`` of those
  fields, each right after a steady engine run (engine, field 0, engine, field 1, ...), so a drift
  of a shared machine's speed hits both sides alike: seconds per field and scenario-steps per
  second;
* the **speed-up** = engine scenario-steps/s ÷ baseline scenario-steps/s, both from this run.

Wall-clock times are what is reported; the process CPU time of the timed sections is recorded too
(``run_cpu_s``, ``cpu_s``), so a run on a shared machine can be recognised (CPU time well below
wall time × cores the run could use means other processes took the cores).

The two sides do the same closed loop (``tests/test_baseline.py`` checks that they agree in float64);
the engine runs a fixed number of FISTA iterations (``iters``) in the default dtype, the baseline
solves every QP to tolerance, which is what a researcher without the engine would do.

Everything is returned in a JSON-serialisable dict (``jaxapf bench --json``);
:func:`format_benchmark` renders it as a small table.
"""

from __future__ import annotations

import time
from importlib import metadata
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .config import ConfigError, Gains, MPCConfig, SimConfig, check_int

__all__ = ["run_benchmark", "format_benchmark", "run_sweep_benchmark", "format_sweep_benchmark", "time_sweep",
           "fit_step_cost", "format_step_cost", "parse_xla_option", "compare_xla_options", "format_xla_options",
           "cost_split", "format_cost_split", "kernel_cost", "format_kernel_cost"]


def _environment(dtype: Any) -> dict[str, Any]:
    from .versions import versions

    try:
        osqp = metadata.version("osqp")
    except metadata.PackageNotFoundError:
        osqp = "not installed"
    return {**versions(), "osqp": osqp, "dtype": str(jnp.dtype(dtype))}


def _block(tree: Any) -> Any:
    return jax.block_until_ready(tree)


def _summary(metrics: dict[str, Any]) -> dict[str, float]:
    """A few means of the engine's metrics, as a sanity check that the episodes did something."""
    out = {}
    for name in ("success", "collision", "stalled"):
        if name in metrics:
            out[f"{name}_rate"] = float(np.mean(np.asarray(metrics[name], np.float64)))
    if "final_distance" in metrics:
        out["final_distance_mean"] = float(np.mean(np.asarray(metrics["final_distance"], np.float64)))
    return out


def _case(fields: int, obstacles: int, horizon: int, iters: int, steps: int, family: str, *, seed: int = 0,
          method: str = "direction_velocity", chunk: int | None = None, gains: Gains | None = None,
          scenarios: Any = None) -> dict[str, Any]:
    """Configs, fields (on device) and a batch of one gain setting of a benchmark case."""
    from .rollout import default_chunk

    steps = check_int("bench.steps", steps, 1)
    if chunk is not None:
        chunk = check_int("bench.chunk", chunk, 1)
    sim = SimConfig(method=method, t_max=steps * 0.1)
    mpc = MPCConfig(horizon=horizon, iters=iters)
    gains = Gains() if gains is None else gains
    if scenarios is None:
        from .scenarios import family_params, make_scenarios

        scenarios = make_scenarios(seed, family_params(family, max_obstacles=obstacles), fields)
        source = family
    else:
        source = "custom"
    scenarios = _block(jax.tree_util.tree_map(jnp.asarray, scenarios))
    gains_batch = jax.tree_util.tree_map(lambda g: jnp.asarray(g, scenarios.start.dtype)[None], gains)
    return {"sim": sim, "mpc": mpc, "gains": gains, "gains_batch": gains_batch, "scenarios": scenarios,
            "chunk": default_chunk() if chunk is None else chunk, "source": source}


def _lower(case: dict[str, Any]) -> tuple[Any, tuple]:
    """The engine (:func:`~jaxapf.rollout.evaluate`) lowered for a :func:`_case`, and its arguments."""
    from .rollout import evaluate

    args = (case["scenarios"], case["gains_batch"])
    return evaluate.lower(*args, sim=case["sim"], mpc=case["mpc"], chunk=case["chunk"]), args


def run_benchmark(
    fields: int = 1024,
    obstacles: int = 16,
    horizon: int = 20,
    iters: int = 30,
    steps: int = 300,
    baseline_fields: int = 3,
    family: str = "clutter",
    seed: int = 0,
    method: str = "direction_velocity",
    chunk: int | None = None,
    *,
    devices: int = 1,
    gains: Gains | None = None,
    scenarios: Any = None,
) -> dict[str, Any]:
    """Time the batched engine and the numpy + OSQP baseline on the same fields.

    Args:
      fields: number of obstacle fields F in the engine's batch.
      obstacles: obstacle slots per field (``family_params(family, max_obstacles=obstacles)``).
      horizon, iters: MPC horizon N and FISTA iterations (``MPCConfig``).
      steps: control steps per episode (``SimConfig(t_max=steps * 0.1)``, dt = 0.1 s).
      baseline_fields: how many of the fields the baseline runs (0 skips the baseline).
      family, seed: scenario family and seed (``make_scenarios(seed, params, fields)``).
      method: planner (``SimConfig.method``).
      chunk: episodes per vmapped chunk of :func:`~jaxapf.rollout.evaluate` (default:
        :func:`~jaxapf.rollout.default_chunk` for the backend).
      devices: local devices the fields are split over (:class:`~jaxapf.devices.DeviceBatch`, as
        ``jaxapf sweep`` does); ``fields`` must be a multiple. With more than one, compilation is
        not timed apart: ``first_run_s`` includes it.
      gains: one gain setting (default ``Gains()``); the engine runs it as a batch of G = 1.
      scenarios: a prebuilt batch of fields (leading axis F) to use instead of ``family``/``seed``;
        ``fields`` and ``obstacles`` are then read from it.

    Returns:
      A JSON-serialisable dict: ``config``, ``environment``, ``engine``, ``baseline`` (None when
      skipped), ``speedup`` (None when skipped).
    """
    fields = check_int("bench.fields", fields, 1)
    baseline_fields = check_int("bench.baseline_fields", baseline_fields, 0)
    devices = check_int("bench.devices", devices, 1, jax.local_device_count())
    t0 = time.perf_counter()
    case = _case(fields, obstacles, horizon, iters, steps, family, seed=seed, method=method, chunk=chunk, gains=gains,
                 scenarios=scenarios)
    t_scenarios = time.perf_counter() - t0
    sim, mpc, gains, chunk, source = case["sim"], case["mpc"], case["gains"], case["chunk"], case["source"]
    scenarios, gains_batch = case["scenarios"], case["gains_batch"]
    fields = int(scenarios.start.shape[0])
    obstacles = int(scenarios.obstacles.radius.shape[-1])
    if fields % devices:
        raise ConfigError(f"bench.fields = {fields} is not a multiple of bench.devices = {devices}")
    dtype = scenarios.start.dtype

    # engine: trace + lower, compile, first run, steady run
    if devices == 1:
        t0 = time.perf_counter()
        lowered, _ = _lower(case)
        t_lower = time.perf_counter() - t0
        t0 = time.perf_counter()
        run = lowered.compile()
        t_compile = time.perf_counter() - t0
    else:
        from .devices import DeviceBatch

        batch = DeviceBatch(jax.local_devices()[:devices])
        per_device = batch.put_gains(gains_batch)
        t_lower = t_compile = None

        def run(s, _):
            return batch.evaluate(s, per_device, sim, mpc, chunk)
    n_base = min(baseline_fields, fields)
    if n_base > 0:
        from .baseline import baseline_rollout, require_osqp

        require_osqp()
        host = jax.device_get(scenarios)
    runs, cpus, per_field, base_cpu = [], [], [], 0.0
    try:
        t0 = time.perf_counter()
        _block(run(scenarios, gains_batch))
        t_first = time.perf_counter() - t0
        # Steady engine runs alternate with the baseline's fields (engine, field 0, engine, field 1,
        # ...), so a drift of a shared machine's speed hits both sides of the ratio alike.
        for i in range(max(n_base, 1)):
            t0, c0 = time.perf_counter(), time.process_time()
            metrics = _block(run(scenarios, gains_batch))
            runs.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
            if i < n_base:
                one = jax.tree_util.tree_map(lambda x, i=i: np.asarray(x[i]), host)
                t0, c0 = time.perf_counter(), time.process_time()
                baseline_rollout(one, gains, sim, mpc)
                per_field.append(time.perf_counter() - t0)
                base_cpu += time.process_time() - c0
    finally:
        if devices > 1:
            batch.close()
    t_run = float(np.median(runs))
    scenario_steps = fields * sim.steps
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
        **_summary(jax.device_get(metrics)),
    }

    baseline = None
    speedup = None
    if n_base > 0:
        total = float(np.sum(per_field))
        baseline = {
            "fields": n_base,
            "total_s": total,
            "cpu_s": base_cpu,
            "per_field_s": total / n_base,
            "per_field_all_s": [float(x) for x in per_field],
            "steps_per_s": n_base * sim.steps / total,
            "all_fields_estimate_s": total / n_base * fields,
        }
        speedup = engine["steps_per_s"] / baseline["steps_per_s"]

    return {
        "config": {
            "fields": fields,
            "obstacles": obstacles,
            "horizon": horizon,
            "iters": iters,
            "steps": sim.steps,
            "dt": sim.dt,
            "baseline_fields": n_base,
            "family": source,
            "seed": seed,
            "method": method,
            "gain_settings": 1,
            "chunk": chunk,
            "devices": devices,
        },
        "environment": _environment(dtype),
        "engine": engine,
        "baseline": baseline,
        "speedup": speedup,
    }


def parse_xla_option(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` of ``jaxapf bench --xla-option``: VALUE ``true``/``false``, an int, a float or a
    string (an empty one allowed)."""
    key, sep, value = text.partition("=")
    if not sep or not key.startswith("xla_"):
        raise ConfigError(f"bench.xla_option = {text!r}: expected KEY=VALUE with an XLA option name "
                          "(xla_...), e.g. xla_cpu_use_fusion_emitters=true")
    for cast in (int, float):
        try:
            return key, cast(value)
        except ValueError:
            pass
    return key, {"true": True, "false": False}.get(value.lower(), value)


def _max_abs_diff(a: Any, b: Any) -> float:
    """Largest ``|a - b|`` over entries that differ (equal infinities and NaN pairs count as equal)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    same = (a == b) | (np.isnan(a) & np.isnan(b))
    with np.errstate(invalid="ignore"):
        return float(np.max(np.where(same, 0.0, np.abs(a - b)), initial=0.0))


def compare_xla_options(overrides: dict[str, Any], fields: int = 1024, obstacles: int = 16, horizon: int = 20,
                        iters: int = 30, steps: int = 300, family: str = "clutter", chunk: int | None = None,
                        repeats: int = 5) -> dict[str, Any]:
    """The engine compiled with :data:`~jaxapf.rollout.XLA_OPTIONS` ("shipped") and with
    ``XLA_OPTIONS | overrides`` ("override"), both from one lowering of the benchmark case
    (the work as in :func:`run_benchmark`), timed in this
    process: the fastest of ``repeats`` interleaved steady runs of each (so the ratio of the two is
    measured under the same load), and whether the two give the same episodes.

    Returns a JSON-serialisable dict: ``config``, ``environment``, ``overrides``, per variant
    ``compile_s``/``run_s``/``cpu_s``/``steps_per_s``, ``speedup`` (override over shipped run time:
    > 1 means the override is faster), ``outcome_changes`` (episodes whose success, collision or
    stalled flag differs: a closed loop amplifies float rounding, so a different compilation can
    send a few episodes down another path), each variant's ``rates`` and ``max_abs_diff`` of every
    metric.
    """
    from .rollout import XLA_OPTIONS

    repeats = check_int("bench.repeats", repeats, 1)
    c = _case(fields, obstacles, horizon, iters, steps, family, chunk=chunk)
    lowered, args = _lower(c)
    variants = {"shipped": dict(XLA_OPTIONS), "override": {**XLA_OPTIONS, **overrides}}
    compiled, compile_s, metrics = {}, {}, {}
    for name, options in variants.items():
        t0 = time.perf_counter()
        try:
            compiled[name] = lowered.compile(compiler_options=options)
        except jax.errors.JaxRuntimeError as err:  # an unknown option or a value of the wrong type
            raise ConfigError(f"bench.xla_option = {overrides}: XLA rejected it ({str(err).strip()})") from None
        compile_s[name] = time.perf_counter() - t0
        metrics[name] = jax.device_get(_block(compiled[name](*args)))
    timed = _interleaved({name: (lambda f=f: _block(f(*args))) for name, f in compiled.items()}, repeats)
    scenario_steps = c["scenarios"].start.shape[0] * c["sim"].steps
    outcomes = ("success", "collision", "stalled")
    diff = {k: _max_abs_diff(metrics["shipped"][k], metrics["override"][k]) for k in metrics["shipped"]}
    return {
        "config": {"fields": int(c["scenarios"].start.shape[0]), "steps": c["sim"].steps,
                   "obstacles": int(c["scenarios"].obstacles.radius.shape[-1]), "horizon": c["mpc"].horizon,
                   "iters": c["mpc"].iters, "family": c["source"], "chunk": c["chunk"], "repeats": repeats},
        "environment": _environment(c["scenarios"].start.dtype),
        "overrides": overrides,
        "variants": {name: {"options": variants[name], "compile_s": compile_s[name], **timed[name],
                            "steps_per_s": scenario_steps / timed[name]["run_s"]} for name in variants},
        "speedup": timed["shipped"]["run_s"] / timed["override"]["run_s"],
        "outcome_changes": int(np.sum(np.any([metrics["shipped"][k] != metrics["override"][k] for k in outcomes],
                                             axis=0))),
        "rates": {name: _summary(m) for name, m in metrics.items()},
        "max_abs_diff": diff,
    }


def format_xla_options(result: dict[str, Any]) -> str:
    """The two variants of :func:`compare_xla_options` side by side."""
    cfg, env = result["config"], result["environment"]
    lines = [f"jaxapf bench --xla-option: {cfg['fields']} {cfg['family']} fields x {cfg['steps']} steps, "
             f"{cfg['obstacles']} obstacle slots, N = {cfg['horizon']}, {cfg['iters']} FISTA iterations; "
             f"fastest of {cfg['repeats']} interleaved runs each",
             f"  device {env['device']}, {env['cpu_count']} CPUs, jax {env['jax']} / jaxlib {env['jaxlib']}", ""]
    for name, v in result["variants"].items():
        lines.append(f"  {name:<9s} {v['run_s']:8.3f} s  {v['steps_per_s']:>10,.0f} scenario-steps/s  "
                     f"(compile {v['compile_s']:.1f} s)  {v['options']}")
    worst = max(result["max_abs_diff"].items(), key=lambda kv: kv[1])
    lines += ["", f"  override / shipped speed: {result['speedup']:.2f}x",
              f"  episodes whose outcome (success, collision, stalled) differs: {result['outcome_changes']} of "
              f"{cfg['fields']}; largest metric difference {worst[1]:.3g} ({worst[0]})"]
    for name, rates in result["rates"].items():
        lines.append(f"  {name:<9s} " + ", ".join(f"{k} {v:.4g}" for k, v in rates.items()))
    return "\n".join(lines)


def cost_split(fields: int = 1024, obstacles: int = 16, horizon: int = 20, iters: int = 30, steps: int = 100,
               family: str = "clutter", chunk: int | None = None, repeats: int = 3) -> dict[str, Any]:
    """Where an engine step's time goes: the case run as is, with one obstacle slot, with one FISTA
    iteration, and with both, compiled in this process and timed interleaved (fastest of
    ``repeats`` steady runs each), in µs of wall time per scenario-step.

    The extra obstacle slots cost ``full - one_obstacle`` (with every iteration) or ``one_iteration
    - both`` (with one); the extra iterations ``full - one_iteration`` or ``one_obstacle - both``:
    the two readings differ where the parts overlap on the cores. ``both`` is what is left: one
    obstacle, one iteration, the plant and the metrics. The obstacle reading assumes a step costs
    more with more slots; XLA compiles each slot count differently and does not guarantee it (on
    the development CPU, 16 slots ran faster than 2 to 8, README "Speed"), so it can understate
    the obstacles' share or even come out negative, and ``both`` is no floor for the rest of the
    full step (there, half of its kernel time went to fusions the 16-slot program does not have);
    the iteration reading compares programs that differ only in a loop's trip count.
    """
    repeats = check_int("bench.repeats", repeats, 1)
    shapes = {"full": (obstacles, iters), "one_obstacle": (1, iters), "one_iteration": (obstacles, 1),
              "both": (1, 1)}
    runs = {}
    for name, (m, i) in shapes.items():
        c = _case(fields, m, horizon, i, steps, family, chunk=chunk)
        lowered, args = _lower(c)
        compiled = lowered.compile()
        _block(compiled(*args))
        runs[name] = lambda f=compiled, a=args: _block(f(*a))
    timed = _interleaved(runs, repeats)
    us = {name: 1e6 * t["run_s"] / (fields * steps) for name, t in timed.items()}
    return {
        "config": {"fields": fields, "obstacles": obstacles, "horizon": horizon, "iters": iters, "steps": steps,
                   "family": family, "repeats": repeats},
        "environment": _environment(jnp.result_type(float)),
        "step_us": us,
        "obstacles_us": sorted([us["full"] - us["one_obstacle"], us["one_iteration"] - us["both"]]),
        "iterations_us": sorted([us["full"] - us["one_iteration"], us["one_obstacle"] - us["both"]]),
        "rest_us": us["both"],
    }


def format_cost_split(result: dict[str, Any]) -> str:
    """The four runs of :func:`cost_split` and the attribution."""
    cfg, env, us = result["config"], result["environment"], result["step_us"]
    lines = [f"jaxapf bench --split: {cfg['fields']} {cfg['family']} fields x {cfg['steps']} steps, "
             f"N = {cfg['horizon']}; fastest of {cfg['repeats']} interleaved runs each",
             f"  device {env['device']}, {env['cpu_count']} CPUs, jax {env['jax']} / jaxlib {env['jaxlib']}", "",
             f"  {'run':<36s}{'us per scenario-step':>22s}"]
    labels = {"full": f"{cfg['obstacles']} obstacle slots, {cfg['iters']} iterations",
              "one_obstacle": f"1 obstacle slot, {cfg['iters']} iterations",
              "one_iteration": f"{cfg['obstacles']} obstacle slots, 1 iteration",
              "both": "1 obstacle slot, 1 iteration"}
    lines += [f"  {labels[name]:<36s}{us[name]:>22.2f}" for name in labels]
    span = lambda pair: f"{pair[0]:.2f}-{pair[1]:.2f} us"  # noqa: E731
    lines += ["", f"  {cfg['obstacles'] - 1} further obstacle slots (APF reference): {span(result['obstacles_us'])}",
              f"  {cfg['iters'] - 1} further FISTA iterations: {span(result['iterations_us'])}",
              f"  the rest (1 obstacle, 1 iteration, plant, metrics): {result['rest_us']:.2f} us"]
    return "\n".join(lines)


#: The elementwise operations of :func:`kernel_cost`, each applied to an array ``y`` once per loop
#: iteration: the arithmetic, square roots, divisions and tanh of a potential and its gradient.
KERNEL_OPS = {
    "multiply-add": lambda y: y - 1e-3 * (y * y),
    "sqrt": lambda y: y - 1e-3 * jnp.sqrt(y * y + 1.0),
    "divide": lambda y: y - 1e-3 / (y + 2.0),
    "tanh": lambda y: y - 1e-3 * jnp.tanh(y),
}


def kernel_cost(fields: int = 1024, obstacles: int = 16, iterations: int = 2000, repeats: int = 3) -> dict[str, Any]:
    """What XLA:CPU makes of one elementwise operation on the engine's per-obstacle arrays.

    Each of :data:`KERNEL_OPS` is applied ``iterations`` times in a ``lax.scan`` (as the APF flow and
    FISTA apply theirs) to a float32 array in the engine's vmapped layout, ``(fields, obstacles)``
    (batch-major: the obstacle axis is the contiguous one), and transposed, ``(obstacles,
    fields)``; each is compiled with :data:`~jaxapf.rollout.XLA_OPTIONS` ("shipped": XLA's classic
    loop emitter) and with ``xla_cpu_use_fusion_emitters = True`` ("fusion emitters"). Reported:
    wall picoseconds per element and iteration, the fastest of ``repeats`` interleaved runs. An
    operation that runs one element at a time costs about a nanosecond or more per element; a
    vectorised one a fraction of that.
    """
    from .rollout import XLA_OPTIONS

    fields = check_int("bench.fields", fields, 1)
    obstacles = check_int("bench.obstacles", obstacles, 1)
    iterations = check_int("bench.iterations", iterations, 1)
    repeats = check_int("bench.repeats", repeats, 1)
    layouts = {"fields x obstacles": (fields, obstacles), "obstacles x fields": (obstacles, fields)}
    options = {"shipped": dict(XLA_OPTIONS), "fusion emitters": {**XLA_OPTIONS, "xla_cpu_use_fusion_emitters": True}}
    y0 = {name: jnp.asarray(np.random.default_rng(0).random(shape), jnp.float32) for name, shape in layouts.items()}
    runs = {}
    for op, fn in KERNEL_OPS.items():
        loop = jax.jit(lambda y, fn=fn: jax.lax.scan(lambda y, _: (fn(y), None), y, None, length=iterations)[0])
        for layout, y in y0.items():
            lowered = loop.lower(y)
            for name, opts in options.items():
                compiled = lowered.compile(compiler_options=opts)
                _block(compiled(y))
                runs[(op, layout, name)] = lambda f=compiled, y=y: _block(f(y))
    timed = _interleaved(runs, repeats)
    per_element = 1e12 / (fields * obstacles * iterations)
    rows = [{"op": op, "layout": layout, "options": name, "ps_per_element": t["run_s"] * per_element}
            for (op, layout, name), t in timed.items()]
    return {"config": {"fields": fields, "obstacles": obstacles, "iterations": iterations, "repeats": repeats},
            "environment": _environment(jnp.float32), "rows": rows}


def format_kernel_cost(result: dict[str, Any]) -> str:
    """:func:`kernel_cost` as a table: one row per operation, one column per layout and options."""
    cfg, env = result["config"], result["environment"]
    columns = list(dict.fromkeys((r["layout"], r["options"]) for r in result["rows"]))
    cell = {(r["op"], r["layout"], r["options"]): r["ps_per_element"] for r in result["rows"]}
    lines = [f"jaxapf bench --kernels: one elementwise op on {cfg['fields']} fields x {cfg['obstacles']} obstacles "
             f"(float32), {cfg['iterations']} iterations of a lax.scan; fastest of {cfg['repeats']} interleaved runs",
             f"  device {env['device']}, {env['cpu_count']} CPUs, jax {env['jax']} / jaxlib {env['jaxlib']}",
             "  picoseconds per element and iteration", "",
             f"  {'':14s}" + "".join(f"{layout:>24s}" for layout, _ in columns),
             f"  {'':14s}" + "".join(f"{name:>24s}" for _, name in columns)]
    for op in dict.fromkeys(r["op"] for r in result["rows"]):
        lines.append(f"  {op:14s}" + "".join(f"{cell[(op, *c)]:>24.0f}" for c in columns))
    return "\n".join(lines)


def _seconds(s: float) -> str:
    if s < 1e-3:
        return f"{s * 1e6:.0f} µs"
    if s < 1:
        return f"{s * 1e3:.1f} ms"
    if s < 120:
        return f"{s:.2f} s"
    if s < 7200:
        return f"{s / 60:.1f} min"
    return f"{s / 3600:.1f} h"


def format_benchmark(result: dict[str, Any]) -> str:
    """A compact human-readable table of :func:`run_benchmark`'s result."""
    cfg, env, eng, base = result["config"], result["environment"], result["engine"], result["baseline"]
    lines = [
        f"jaxapf bench: {cfg['family']} fields, method {cfg['method']}",
        f"  {cfg['fields']} fields x {cfg['steps']} steps (dt {cfg['dt']:g} s), {cfg['obstacles']} obstacle slots, "
        f"MPC horizon {cfg['horizon']}, {cfg['iters']} FISTA iterations, vmap chunk {cfg['chunk']}, "
        f"{cfg['devices']} device(s)",
        f"  device {env['device']} x{env['device_count']}, {env['cpu_count']} CPUs, "
        f"jax {env['jax']} / jaxlib {env['jaxlib']}, {env['dtype']}",
        "",
        f"  {'':34s}{'time':>12s}{'scenario-steps/s':>20s}",
        *([f"  {'engine trace + lower':34s}{_seconds(eng['lower_s']):>12s}",
           f"  {'engine compile':34s}{_seconds(eng['compile_s']):>12s}",
           f"  {'engine first run':34s}{_seconds(eng['first_run_s']):>12s}"] if eng["compile_s"] is not None else
          [f"  {'engine first run (with compile)':34s}{_seconds(eng['first_run_s']):>12s}"]),
        f"  {'engine steady run, median of ' + str(len(eng['run_all_s'])):34s}{_seconds(eng['run_s']):>12s}"
        f"{eng['steps_per_s']:>20,.0f}",
        f"  {'engine per field':34s}{_seconds(eng['per_field_ms'] / 1e3):>12s}",
    ]
    if base is not None:
        lines += [
            f"  {'baseline (numpy + OSQP) per field':34s}{_seconds(base['per_field_s']):>12s}"
            f"{base['steps_per_s']:>20,.0f}",
            f"  {'  (measured on ' + str(base['fields']) + ' fields)':34s}",
            f"  {'baseline, all fields (estimate)':34s}{_seconds(base['all_fields_estimate_s']):>12s}",
            "",
            f"  speed-up (engine / baseline steps/s): {result['speedup']:,.1f}x",
        ]
    else:
        lines += ["", "  baseline skipped (baseline_fields = 0)"]
    rates = [f"{k[:-5]} {eng[k]:.1%}" for k in ("success_rate", "collision_rate", "stalled_rate") if k in eng]
    if rates:
        lines.append("  engine episodes: " + ", ".join(rates))
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# jaxapf bench --fit-cost: the sweep's per-step cost model
# --------------------------------------------------------------------------------------------

#: Configurations of :func:`fit_step_cost`: horizons N × FISTA iterations I × obstacle slots M.
COST_GRID = {"horizon": (10, 20, 40), "iters": (10, 30, 60), "obstacles": (4, 16)}


def fit_step_cost(fields: int = 1024, steps: int = 50) -> dict[str, Any]:
    """Fit ``jaxapf.sweep.STEP_COST_US``: wall µs per episode step on this process's first device,
    ``c0 + c_qp·N·I + c_obs·N·M + c_n·N``, by least squares over :data:`COST_GRID` (each point one
    steady :func:`run_benchmark` of ``fields`` clutter fields × ``steps`` steps).
    """
    import itertools

    rows = []
    for n, i, m in itertools.product(*COST_GRID.values()):
        eng = run_benchmark(fields=fields, obstacles=m, horizon=n, iters=i, steps=steps, baseline_fields=0)["engine"]
        rows.append({"horizon": n, "iters": i, "obstacles": m, "step_us": 1e6 * eng["run_s"] / (fields * steps)})
    design = np.array([[1.0, r["horizon"] * r["iters"], r["horizon"] * r["obstacles"], r["horizon"]] for r in rows])
    measured = np.array([r["step_us"] for r in rows])
    coef = np.linalg.lstsq(design, measured, rcond=None)[0]
    ratio = design @ coef / measured
    return {"environment": _environment(jnp.result_type(float)), "fields": fields, "steps": steps,
            "coefficients": [float(c) for c in coef], "rows": rows,
            "fit_over_measured": {"min": float(ratio.min()), "max": float(ratio.max())}}


def format_step_cost(result: dict[str, Any]) -> str:
    """The fitted coefficients and each point, measured vs fitted."""
    coef = result["coefficients"]
    env = result["environment"]
    lines = [f"jaxapf bench --fit-cost: {result['fields']} clutter fields x {result['steps']} steps per point, "
             f"device {env['device']}, {env['cpu_count']} CPUs, jax {env['jax']}",
             f"  {'N':>4s}{'I':>5s}{'M':>5s}{'measured us':>14s}{'fit us':>10s}"]
    for r in result["rows"]:
        fit = coef[0] + coef[1] * r["horizon"] * r["iters"] + coef[2] * r["horizon"] * r["obstacles"] + coef[3] * r["horizon"]
        lines.append(f"  {r['horizon']:>4d}{r['iters']:>5d}{r['obstacles']:>5d}{r['step_us']:>14.2f}{fit:>10.2f}")
    span = result["fit_over_measured"]
    lines += ["", f"  STEP_COST_US = ({', '.join(f'{c:.4g}' for c in coef)})   "
                  f"(fit / measured: {span['min']:.2f} .. {span['max']:.2f})"]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# jaxapf bench --sweep: end-to-end sweep throughput against the bare engine
# --------------------------------------------------------------------------------------------

#: The work of ``jaxapf bench --sweep``: 4 settings (2 compiled variants) × 2 families × 256
#: fields, 200 steps each, default MPC (N = 20, 30 FISTA iterations).
SWEEP_BENCH_SPEC: dict[str, Any] = {
    "name": "bench-sweep",
    "scenario": {"families": ["trap", "clutter"], "fields": 256, "seed": 0},
    "sim": {"t_max": 20.0},
    "grid": {"method": ["basic", "direction_velocity"], "gamma": [0.5, 1.0]},
}

_SWEEP_WORKER = """
import json, sys
from jaxapf.bench import time_sweep
print(json.dumps(time_sweep(json.loads(sys.argv[1]))))
"""


def _interleaved(runs: dict[str, Any], repeats: int) -> dict[str, dict[str, float]]:
    """Fastest of ``repeats`` timed calls of each of ``runs`` (wall and process CPU seconds), the
    calls interleaved (a, b, a, b, ...) so that drifts of a shared machine hit every entry alike."""
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in runs}
    for _ in range(repeats):
        for name, run in runs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            run()
            times[name].append((time.perf_counter() - t0, time.process_time() - c0))
    return {name: {"run_s": min(t)[0], "cpu_s": min(t)[1], "repeats": repeats} for name, t in times.items()}


def _sweep_run(spec: Any, tmp: str) -> Any:
    """A timed-run callable of the whole sweep (scenario generation, dispatch, transfer, Parquet
    writing, into ``tmp``), after an untimed run that compiled everything."""
    from .sweep import run_sweep

    run_sweep(spec, f"{tmp}/warm.parquet", quiet=True)
    return lambda: run_sweep(spec, f"{tmp}/timed.parquet", quiet=True, overwrite=True)


def _bare_run(spec: Any) -> Any:
    """A timed-run callable of the same episodes as one ``evaluate`` call per (variant, family) on
    pre-generated fields (nothing written), after a compiling call."""
    from .rollout import default_chunk, evaluate
    from .scenarios import make_scenarios
    from .sweep import variants

    dtype = jnp.result_type(float)
    work = []
    for v in variants(spec):
        for family in spec.families:
            sim, mpc = spec.configs(v.static, family)
            fields = _block(make_scenarios(spec.seed, spec.family_params(family), spec.fields))
            work.append((fields, v.gains(dtype), sim, mpc))
    calls = [lambda w=w: _block(evaluate(w[0], w[1], w[2], w[3], default_chunk())) for w in work]
    for call in calls:
        call()
    return lambda: [call() for call in calls]


def time_sweep(spec_table: dict[str, Any], repeats: int = 3) -> dict[str, Any]:
    """Wall time of a whole sweep of the spec ``spec_table`` (a TOML table) on this process's
    devices: the fastest of ``repeats`` runs after one that compiled everything."""
    import tempfile

    from .sweep_spec import parse_spec

    with tempfile.TemporaryDirectory() as tmp:
        best = _interleaved({"sweep": _sweep_run(parse_spec(spec_table), tmp)}, repeats)["sweep"]
    return {"devices": jax.local_device_count(), **best}


def run_sweep_benchmark(spec_table: dict[str, Any] | None = None, sharded_devices: int = 2,
                        repeats: int = 3) -> dict[str, Any]:
    """End-to-end sweep throughput vs the bare engine on the same work, and the sharded speed-up.

    Measured in this process (one device unless the process was started with more), each the
    fastest of ``repeats`` interleaved runs after a compiling one: the bare ``evaluate`` calls
    (:func:`_bare_run`) and the whole sweep (:func:`_sweep_run`); overhead = sweep time / bare
    time - 1. Then the same sweep in a subprocess (:func:`time_sweep`) whose host CPU is
    split into ``sharded_devices`` devices (``XLA_FLAGS=--xla_force_host_platform_device_count``);
    speed-up = one-device sweep time / sharded sweep time (skipped for 0 devices, or when this
    process does not run on the CPU).
    """
    import json
    import os
    import subprocess
    import sys
    import tempfile

    from .sweep import plan_sweep
    from .sweep_spec import parse_spec

    spec_table = spec_table or SWEEP_BENCH_SPEC
    spec = parse_spec(spec_table)
    plan = plan_sweep(spec)
    steps = sum(len(plan.variants[c.variant].settings) * (c.stop - c.start) * plan.blocks[(c.variant, c.family)].sim.steps
                for c in plan.chunks)
    with tempfile.TemporaryDirectory() as tmp:
        timed = _interleaved({"bare": _bare_run(spec), "sweep": _sweep_run(spec, tmp)}, repeats)
    bare, sweep = timed["bare"], {"devices": jax.local_device_count(), **timed["sweep"]}
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
        "environment": _environment(jnp.result_type(float)),
        "bare": {**bare, **rate(bare)},
        "sweep": {**sweep, **rate(sweep)},
        "overhead": sweep["run_s"] / bare["run_s"] - 1.0,
        "sharded": None if sharded is None else {**sharded, **rate(sharded),
                                                 "speedup": sweep["run_s"] / sharded["run_s"]},
    }


def format_sweep_benchmark(result: dict[str, Any]) -> str:
    """A compact table of :func:`run_sweep_benchmark`'s result."""
    cfg, env = result["config"], result["environment"]
    lines = [
        f"jaxapf bench --sweep: {cfg['spec']['name']}: {cfg['episodes']:,} episodes ({cfg['settings']} settings in "
        f"{cfg['variants']} variants), {cfg['scenario_steps']:,} scenario-steps, {cfg['chunks']} chunks",
        f"  device {env['device']} x{env['device_count']}, {env['cpu_count']} CPUs, jax {env['jax']}, {env['dtype']}, "
        f"vmap width {cfg['vmap_width']}",
        "",
        f"  {'':34s}{'time':>10s}{'episodes/s':>14s}{'scenario-steps/s':>20s}",
    ]
    rows = [("bare evaluate (1 device)", result["bare"]), ("sweep end to end (1 device)", result["sweep"])]
    if result["sharded"] is not None:
        rows.append((f"sweep end to end ({result['sharded']['devices']} devices)", result["sharded"]))
    for label, r in rows:
        lines.append(f"  {label:34s}{_seconds(r['run_s']):>10s}{r['episodes_per_s']:>14,.0f}{r['steps_per_s']:>20,.0f}")
    lines += ["", f"  sweep overhead over bare evaluate: {100 * result['overhead']:+.1f} % (target < 5 %)"]
    if result["sharded"] is not None:
        lines.append(f"  sharded speed-up ({result['sharded']['devices']} devices / 1): {result['sharded']['speedup']:.2f}x")
    return "\n".join(lines)
