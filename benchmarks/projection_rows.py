"""What solving with a few rows at a time (``sim.projection_rows``) saves the exact projections.

    python benchmarks/projection_rows.py [--json]

1. The projection alone (:func:`jaxapf.projection.nearest_feasible`): 2,048 problems of 32 unit rows
   (random directions, ``b`` uniform in [-4, 0.5]) in one vmapped call, the CBF filter's box and the
   velocity obstacles' ball of radius 3, every row (0) or 8, 12 or 16 at a time (those that bind
   soonest, then those the answer needs): microseconds per problem, the fastest of 3 calls after the
   compile, and how many answers were certified exact.
2. The closed loop: 16 ``swarm_clutter`` fields of 8 UAVs (24 obstacle slots and 8 neighbours, 32 rows),
   50 steps in the fixed-length engine, ``basic`` with the CBF filter and ``velocity_obstacle``, default
   gains, every row against 8 (CBF) and 16 (velocity obstacles) at a time: microseconds per UAV-step
   (the fastest of 2 calls after the compile) and the UAV-steps whose answer a row left out still
   violated (``cbf_truncated_steps`` plus ``vo_truncated_steps``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

PROBLEMS, SLOTS, LIMIT = 2048, 32, 3.0
KEPT = (0, 8, 12, 16)
LOOP = {"basic+cbf": 8, "velocity_obstacle": 16}
FIELDS, AGENTS, STEPS = 16, 8, 50


def fastest(call, repeats: int) -> float:
    jax.block_until_ready(call())
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(call())
        best = min(best, time.perf_counter() - start)
    return best


def projection_alone() -> list[dict]:
    from jaxapf.projection import nearest_feasible

    rng = np.random.default_rng(0)
    g = rng.normal(size=(PROBLEMS, SLOTS, 3))
    g /= np.linalg.norm(g, axis=2, keepdims=True)
    args = [jnp.asarray(a, jnp.float32) for a in (rng.uniform(-3, 3, (PROBLEMS, 3)), g,
                                                   rng.uniform(-4, 0.5, (PROBLEMS, SLOTS)))]
    out = []
    for region in ("box", "ball"):
        for rows in KEPT:
            solve = jax.jit(jax.vmap(partial(nearest_feasible, limit=LIMIT, region=region, rows=rows)))
            seconds = fastest(partial(solve, *args), 3)
            exact = int(np.sum(jax.device_get(solve(*args)[2])))
            out.append({"region": region, "rows": rows, "us_per_problem": round(1e6 * seconds / PROBLEMS, 1),
                        "exact": exact})
            print(out[-1], file=sys.stderr)
    return out


def closed_loop() -> list[dict]:
    from jaxapf import Gains
    from jaxapf.config import MPCConfig, SimConfig
    from jaxapf.engine.swarm import evaluate_swarms
    from jaxapf.scenarios.swarms import make_swarms, swarm_params

    swarms = make_swarms(300, swarm_params("swarm_clutter", agents=AGENTS), FIELDS)
    out = []
    for method, kept in LOOP.items():
        planner, _, safety = method.partition("+")
        for rows in (0, kept):
            sim = SimConfig.from_flat(method=planner, filter=safety or "none", t_max=STEPS * 0.1,
                                      max_neighbours=8, projection_rows=rows)
            run = partial(evaluate_swarms, swarms, Gains(), sim, MPCConfig(), FIELDS, streaming=False)
            seconds = fastest(run, 2)
            counts = jax.device_get(run())
            truncated = int(np.sum(counts["cbf_truncated_steps"]) + np.sum(counts["vo_truncated_steps"]))
            out.append({"method": method, "rows": rows, "us_per_uav_step":
                        round(1e6 * seconds / (FIELDS * AGENTS * sim.episode.steps), 1), "truncated_steps": truncated})
            print(out[-1], file=sys.stderr)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", action="store_true", help="print one JSON object")
    args = p.parse_args(argv)
    result = {"projection": projection_alone(), "closed_loop": closed_loop(), "device": jax.devices()[0].device_kind,
              "cores": os.cpu_count(), "problems": PROBLEMS, "rows": SLOTS, "fields": FIELDS, "agents": AGENTS,
              "steps": STEPS}
    if args.json:
        print(json.dumps(result))
    else:
        for row in result["projection"] + result["closed_loop"]:
            print(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
