"""What XLA:CPU makes of one elementwise operation on the engine's per-obstacle arrays.

    python benchmarks/kernels.py [--fields 1024 --obstacles 16] [--json]

Picoseconds per element of multiply-add, sqrt, divide and tanh in a ``lax.scan``, on the engine's
(fields, obstacles) layout and transposed, with the shipped XLA options and with XLA's fusion
emitters. docs/performance.md explains what the table shows.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxapf.bench.engine import environment, interleaved
from jaxapf.validation import ConfigError, check_int


def block(tree):
    return jax.block_until_ready(tree)


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
    fields)``; each is compiled with :data:`~jaxapf.engine.XLA_OPTIONS` ("shipped": XLA's classic
    loop emitter) and with ``xla_cpu_use_fusion_emitters = True`` ("fusion emitters"). Reported:
    wall picoseconds per element and iteration, the fastest of ``repeats`` interleaved runs. An
    operation that runs one element at a time costs about a nanosecond or more per element; a
    vectorised one a fraction of that.
    """
    from jaxapf.engine import XLA_OPTIONS

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
                block(compiled(y))
                runs[(op, layout, name)] = lambda f=compiled, y=y: block(f(y))
    timed = interleaved(runs, repeats)
    per_element = 1e12 / (fields * obstacles * iterations)
    rows = [{"op": op, "layout": layout, "options": name, "ps_per_element": t["run_s"] * per_element}
            for (op, layout, name), t in timed.items()]
    return {"config": {"fields": fields, "obstacles": obstacles, "iterations": iterations, "repeats": repeats},
            "environment": environment(jnp.float32), "rows": rows}


def format_kernel_cost(result: dict[str, Any]) -> str:
    """:func:`kernel_cost` as a table: one row per operation, one column per layout and options."""
    cfg, env = result["config"], result["environment"]
    columns = list(dict.fromkeys((r["layout"], r["options"]) for r in result["rows"]))
    cell = {(r["op"], r["layout"], r["options"]): r["ps_per_element"] for r in result["rows"]}
    lines = [f"benchmarks/kernels.py: one elementwise op on {cfg['fields']} fields x {cfg['obstacles']} obstacles "
             f"(float32), {cfg['iterations']} iterations of a lax.scan; fastest of {cfg['repeats']} interleaved runs",
             f"  device {env['device']}, {env['cpu_count']} CPUs, jax {env['jax']} / jaxlib {env['jaxlib']}",
             "  picoseconds per element and iteration", "",
             f"  {'':14s}" + "".join(f"{layout:>24s}" for layout, _ in columns),
             f"  {'':14s}" + "".join(f"{name:>24s}" for _, name in columns)]
    for op in dict.fromkeys(r["op"] for r in result["rows"]):
        lines.append(f"  {op:14s}" + "".join(f"{cell[(op, *c)]:>24.0f}" for c in columns))
    return "\n".join(lines)





def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--fields", type=int, default=1024)
    p.add_argument("--obstacles", type=int, default=16)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    try:
        result = kernel_cost(fields=args.fields, obstacles=args.obstacles)
    except ConfigError as err:
        print(f"kernels: error: {err}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2) if args.json else format_kernel_cost(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
