"""What the streaming engine's narrower tail widths cost to compile and save at run time.

    python benchmarks/stream_levels.py [--families trap clutter] [--queues 512 1024 2048 4096] [--json]

For each family and queue length (episodes of one program, ``direction_velocity`` at its defaults, the
standard MPC, 60 s episodes), the program is compiled twice in this process: flying its queue at one
width (``slots``) and with the tail on narrower vmaps (``slots/2``, ``slots/4``, never below 64). The steady runs
are interleaved; the two must give the same numbers bit for bit (the widths change no number). The
streaming engine narrows from :data:`~jaxapf.engine.stream.NARROWING_FROM` slots on.
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np


def measure(family: str, episodes: int, repeats: int) -> dict:
    from jaxapf.bench.engine import bench_case, interleaved
    from jaxapf.engine import program
    from jaxapf.engine.batch import settings_read
    from jaxapf.engine.stream import stream_levels, stream_metrics, stream_slots
    from jaxapf.metrics import METRICS

    case = bench_case(episodes, 16, 20, 30, 600, family, width=1024)
    sim, mpc, fields = case["sim"], case["mpc"], case["scenarios"]
    _, gains = settings_read(case["gains"], sim)
    slots = stream_slots(episodes, 1024)
    variants = {"one_width": stream_levels(slots, narrowing_from=slots + 1),
                "narrowing": stream_levels(slots, narrowing_from=0)}

    @program(static_argnames=("levels",))
    def run(fields, gains, levels):
        return stream_metrics(fields, gains, sim, mpc, slots, METRICS.names(), levels=levels)

    compiled, compile_s, out = {}, {}, {}
    for name, levels in variants.items():
        t0 = time.perf_counter()
        compiled[name] = run.lower(fields, gains, levels=levels).compile()
        compile_s[name] = time.perf_counter() - t0
        out[name] = jax.device_get(jax.block_until_ready(compiled[name](fields, gains)))
    timed = interleaved({name: (lambda f=f: jax.block_until_ready(f(fields, gains))) for name, f in compiled.items()},
                        repeats)
    same = all(np.array_equal(out["one_width"][m], out["narrowing"][m], equal_nan=True) for m in out["one_width"])
    result = {"family": family, "episodes": episodes, "slots": slots, "identical": bool(same)}
    for name in variants:
        result[name] = {"levels": list(variants[name]), "compile_s": compile_s[name], "run_s": timed[name]["run_s"],
                        "cpu_s": timed[name]["cpu_s"]}
    result["run_saved_s"] = result["one_width"]["run_s"] - result["narrowing"]["run_s"]
    result["compile_added_s"] = result["narrowing"]["compile_s"] - result["one_width"]["compile_s"]
    return result


def main() -> None:
    import jax.numpy as jnp

    from jaxapf.bench.engine import environment

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--families", nargs="+", default=["trap", "clutter"])
    parser.add_argument("--queues", nargs="+", type=int, default=[512, 1024, 2048, 4096])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    cases = [measure(f, q, args.repeats) for f in args.families for q in args.queues]
    result = {"environment": environment(jnp.float32), "config": {"families": args.families, "queues": args.queues,
                                                       "repeats": args.repeats}, "cases": cases}
    if args.json:
        print(json.dumps(result, indent=1))
        return
    for c in cases:
        print(f"{c['family']:>8} {c['episodes']:>5} episodes, {c['slots']:>4} slots: narrowing saves "
              f"{c['run_saved_s']:+.2f} s of {c['one_width']['run_s']:.2f} s run, adds {c['compile_added_s']:+.2f} s "
              f"compile; identical {c['identical']}")


if __name__ == "__main__":
    main()
