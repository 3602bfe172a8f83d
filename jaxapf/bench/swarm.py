r"""What a swarm costs as it grows: ``jaxapf bench swarm``.

Each UAV of an ``A``-UAV swarm sees ``M + A`` obstacle slots (the field's and its neighbours'), and
its planner, filter and sensor work on all of them, so one swarm step costs ``O(A (M + A))``:
linear in ``A`` while the field's obstacles dominate, quadratic beyond. :func:`run_swarm_benchmark`
flies ``circle_swap`` swarms of ``A = 1, 2, 4, … , 64`` UAVs (the fixed-length engine,
:func:`~jaxapf.engine.swarm.evaluate_swarms`, with the swarm metrics; circle diameter
``max(12, A/2)`` m) on about the same number of UAVs per call (``fields = ⌈uavs / A⌉``) and
reports per ``A``: compile seconds, run seconds (fastest of ``repeats``, interleaved),
microseconds per swarm-step and per UAV-step, and the compiled program's working memory (XLA's
temporary buffers, ``memory_analysis``).
"""

from __future__ import annotations

import time
from typing import Any, Sequence

import jax
import jax.numpy as jnp

from ..config import MPCConfig, SimConfig
from ..gains import Gains
from ..validation import check_int
from .engine import environment, interleaved

__all__ = ["AGENTS", "run_swarm_benchmark", "format_swarm_benchmark"]

#: The swarm sizes of the scaling table.
AGENTS = (1, 2, 4, 8, 16, 32, 64)


def run_swarm_benchmark(agents: Sequence[int] = AGENTS, uavs: int = 256, steps: int = 200, method: str = "basic",
                        horizon: int = 20, iters: int = 30, repeats: int = 3, seed: int = 0) -> dict[str, Any]:
    """Time ``circle_swap`` swarms of each size in ``agents`` (module docstring); a JSON-serialisable
    dict with ``config``, ``environment`` and one entry per swarm size."""
    from ..engine.swarm import evaluate_swarms
    from ..scenarios.swarms import make_swarms, swarm_params

    uavs, steps, repeats = (check_int(f"bench.{k}", v, 1) for k, v in (("uavs", uavs), ("steps", steps),
                                                                       ("repeats", repeats)))
    sizes = [check_int("bench.agents", a, 1, 256) for a in agents]
    mpc = MPCConfig(horizon=horizon, iters=iters)
    sim = SimConfig.from_flat(method=method, t_max=steps * 0.1)
    gains = jax.tree_util.tree_map(lambda g: jnp.asarray(g, jnp.float32)[None], Gains())
    runs, out = {}, {}
    for a in sizes:
        fields = -(-uavs // a)
        diameter = max(12.0, 0.5 * a)  # UAVs at least 1.5 m apart on the circle
        swarms = jax.block_until_ready(make_swarms(seed, swarm_params("circle_swap", agents=a,
                                                                      distance=(diameter, diameter)), fields))
        t0 = time.perf_counter()
        compiled = evaluate_swarms.lower(swarms, gains, sim=sim, mpc=mpc).compile()
        memory = compiled.memory_analysis()
        temp = None if memory is None else int(memory.temp_size_in_bytes)
        out[a] = {"fields": fields, "compile_s": time.perf_counter() - t0, "temp_bytes": temp,
                  "temp_mib": None if temp is None else round(temp / 2**20, 1)}
        jax.block_until_ready(compiled(swarms, gains))
        runs[a] = (lambda c, s: lambda: jax.block_until_ready(c(s, gains)))(compiled, swarms)
    timed = interleaved(runs, repeats)
    for a, t in timed.items():
        swarm_steps = out[a]["fields"] * steps
        out[a] |= t | {"us_per_swarm_step": 1e6 * t["run_s"] / swarm_steps,
                       "us_per_uav_step": 1e6 * t["run_s"] / (swarm_steps * a)}
    return {"config": {"agents": sizes, "uavs": uavs, "steps": steps, "method": method, "horizon": horizon,
                       "iters": iters, "repeats": repeats, "seed": seed, "family": "circle_swap"},
            "environment": environment(jnp.float32), "sizes": {str(a): v for a, v in out.items()}}


def format_swarm_benchmark(result: dict[str, Any]) -> str:
    """A small table of :func:`run_swarm_benchmark`'s result."""
    c = result["config"]
    lines = [f"circle_swap, about {c['uavs']} UAVs per call x {c['steps']} steps, {c['method']}, N = {c['horizon']}, "
             f"{c['iters']} FISTA iterations (fastest of {c['repeats']})",
             f"{'UAVs':>5} {'fields':>7} {'compile':>9} {'run':>9} {'us/swarm-step':>14} {'us/UAV-step':>12} "
             f"{'memory':>10}"]
    for a, v in result["sizes"].items():
        memory = "–" if v["temp_mib"] is None else f"{v['temp_mib']:.1f} MiB"
        lines.append(f"{a:>5} {v['fields']:>7} {v['compile_s']:>8.1f}s {v['run_s']:>8.2f}s "
                     f"{v['us_per_swarm_step']:>14.1f} {v['us_per_uav_step']:>12.2f} {memory:>10}")
    return "\n".join(lines)
