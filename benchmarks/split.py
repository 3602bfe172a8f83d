"""Where an engine step's time goes: all obstacle slots and FISTA iterations, one slot, one iteration, both.

    python benchmarks/split.py [--steps 100] [--json]

The four variants of the standard case are compiled in one process and timed interleaved.
docs/performance.md reads the figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

import jax
import jax.numpy as jnp

from jaxapf.bench.engine import bench_case, environment, interleaved, lower_case
from jaxapf.validation import ConfigError, check_int


def block(tree):
    return jax.block_until_ready(tree)


def cost_split(fields: int = 1024, obstacles: int = 16, horizon: int = 20, iters: int = 30, steps: int = 100,
               family: str = "clutter", width: int | None = None, repeats: int = 3) -> dict[str, Any]:
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
        c = bench_case(fields, m, horizon, i, steps, family, width=width)
        lowered, args = lower_case(c)
        compiled = lowered.compile()
        block(compiled(*args))
        runs[name] = lambda f=compiled, a=args: block(f(*a))
    timed = interleaved(runs, repeats)
    us = {name: 1e6 * t["run_s"] / (fields * steps) for name, t in timed.items()}
    return {
        "config": {"fields": fields, "obstacles": obstacles, "horizon": horizon, "iters": iters, "steps": steps,
                   "family": family, "repeats": repeats},
        "environment": environment(jnp.result_type(float)),
        "step_us": us,
        "obstacles_us": sorted([us["full"] - us["one_obstacle"], us["one_iteration"] - us["both"]]),
        "iterations_us": sorted([us["full"] - us["one_iteration"], us["one_obstacle"] - us["both"]]),
        "rest_us": us["both"],
    }


def format_cost_split(result: dict[str, Any]) -> str:
    """The four runs of :func:`cost_split` and the attribution."""
    cfg, env, us = result["config"], result["environment"], result["step_us"]
    lines = [f"benchmarks/split.py: {cfg['fields']} {cfg['family']} fields x {cfg['steps']} steps, "
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




def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--fields", type=int, default=1024)
    p.add_argument("--obstacles", type=int, default=16)
    p.add_argument("--horizon", type=int, default=20)
    p.add_argument("--iters", type=int, default=30)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--family", default="clutter")
    p.add_argument("--width", type=int, help="vmap width (default: the backend's)")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    try:
        result = cost_split(fields=args.fields, obstacles=args.obstacles, horizon=args.horizon, iters=args.iters,
                            steps=args.steps, family=args.family, width=args.width)
    except ConfigError as err:
        print(f"split: error: {err}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2) if args.json else format_cost_split(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
