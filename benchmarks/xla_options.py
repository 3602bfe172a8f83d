"""Time the engine compiled with ``jaxapf.engine.XLA_OPTIONS`` against the same with other XLA options.

    python benchmarks/xla_options.py --xla-option xla_cpu_use_fusion_emitters=true [--json]

One lowering of the standard case is compiled both ways and the steady runs are interleaved, so the
ratio is measured under the same load; the script also reports whether the two compilations give
the same episodes (a closed loop amplifies float rounding, so a different compilation can send a
few episodes down another path). docs/performance.md lists what was measured with it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

import jax
import numpy as np

from jaxapf.bench.engine import bench_case, environment, interleaved, lower_case, rates_summary
from jaxapf.validation import ConfigError, check_int


def block(tree):
    return jax.block_until_ready(tree)


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
                        iters: int = 30, steps: int = 300, family: str = "clutter", width: int | None = None,
                        repeats: int = 5) -> dict[str, Any]:
    """The engine compiled with :data:`~jaxapf.engine.XLA_OPTIONS` ("shipped") and with
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
    from jaxapf.engine import XLA_OPTIONS

    repeats = check_int("bench.repeats", repeats, 1)
    c = bench_case(fields, obstacles, horizon, iters, steps, family, width=width)
    lowered, args = lower_case(c)
    variants = {"shipped": dict(XLA_OPTIONS), "override": {**XLA_OPTIONS, **overrides}}
    compiled, compile_s, metrics = {}, {}, {}
    for name, options in variants.items():
        t0 = time.perf_counter()
        try:
            compiled[name] = lowered.compile(compiler_options=options)
        except jax.errors.JaxRuntimeError as err:  # an unknown option or a value of the wrong type
            raise ConfigError(f"bench.xla_option = {overrides}: XLA rejected it ({str(err).strip()})") from None
        compile_s[name] = time.perf_counter() - t0
        metrics[name] = jax.device_get(block(compiled[name](*args)))
    timed = interleaved({name: (lambda f=f: block(f(*args))) for name, f in compiled.items()}, repeats)
    scenario_steps = c["scenarios"].start.shape[0] * c["sim"].episode.steps
    outcomes = ("success", "collision", "stalled")
    diff = {k: _max_abs_diff(metrics["shipped"][k], metrics["override"][k]) for k in metrics["shipped"]}
    return {
        "config": {"fields": int(c["scenarios"].start.shape[0]), "steps": c["sim"].episode.steps,
                   "obstacles": int(c["scenarios"].obstacles.radius.shape[-1]), "horizon": c["mpc"].horizon,
                   "iters": c["mpc"].iters, "family": c["source"], "width": c["width"], "repeats": repeats},
        "environment": environment(c["scenarios"].start.dtype),
        "overrides": overrides,
        "variants": {name: {"options": variants[name], "compile_s": compile_s[name], **timed[name],
                            "steps_per_s": scenario_steps / timed[name]["run_s"]} for name in variants},
        "speedup": timed["shipped"]["run_s"] / timed["override"]["run_s"],
        "outcome_changes": int(np.sum(np.any([metrics["shipped"][k] != metrics["override"][k] for k in outcomes],
                                             axis=0))),
        "rates": {name: rates_summary(m) for name, m in metrics.items()},
        "max_abs_diff": diff,
    }


def format_xla_options(result: dict[str, Any]) -> str:
    """The two variants of :func:`compare_xla_options` side by side."""
    cfg, env = result["config"], result["environment"]
    lines = [f"benchmarks/xla_options.py: {cfg['fields']} {cfg['family']} fields x {cfg['steps']} steps, "
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




def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--xla-option", action="append", required=True, metavar="KEY=VALUE", help="repeatable")
    p.add_argument("--fields", type=int, default=1024)
    p.add_argument("--obstacles", type=int, default=16)
    p.add_argument("--horizon", type=int, default=20)
    p.add_argument("--iters", type=int, default=30)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--family", default="clutter")
    p.add_argument("--width", type=int, help="vmap width (default: the backend's)")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    try:
        result = compare_xla_options(dict(parse_xla_option(o) for o in args.xla_option), fields=args.fields,
                                     obstacles=args.obstacles, horizon=args.horizon, iters=args.iters,
                                     steps=args.steps, family=args.family, width=args.width)
    except ConfigError as err:
        print(f"xla_options: error: {err}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2) if args.json else format_xla_options(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
