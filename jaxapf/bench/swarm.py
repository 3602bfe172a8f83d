r"""What a swarm costs as it grows: ``jaxapf bench swarm``.

Each UAV of an ``A``-UAV swarm sees ``M + A`` obstacle slots (the field's and its neighbours'), and
its planner, filter and sensor work on all of them, so one swarm step costs ``O(A (M + A))``:
linear in ``A`` while the field's obstacles dominate, quadratic beyond. :func:`run_swarm_benchmark`
flies ``circle_swap`` swarms of ``A = 1, 2, 4, … , 64`` UAVs (the fixed-length engine,
:func:`~jaxapf.engine.swarm.evaluate_swarms`, with the swarm metrics; circle diameter
``max(12, A/2)`` m) on about the same number of UAVs per call (``fields = ⌈uavs / A⌉``) and
reports per ``A``: compile seconds, run seconds (fastest of ``repeats``, interleaved),
microseconds per swarm-step and per UAV-step, and the compiled program's working memory (XLA's
temporary buffers, ``memory_analysis``). Where the time goes: the same UAVs are also flown *alone*,
each as a single-UAV episode (:func:`~jaxapf.engine.evaluate_program`, fixed-length, its metrics)
in a field with the same ``M + A`` obstacle slots, the neighbours' left empty; the swarm's time over
that is what the interaction itself costs (placing the neighbours each step, the pair metrics), and
the alone time's growth with ``A`` is what the extra obstacle slots cost every UAV's stack.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Sequence

import jax
import jax.numpy as jnp

from ..config import MPCConfig, SimConfig
from ..gains import Gains
from ..validation import check_int
from .engine import check_fits, environment, interleaved

__all__ = ["AGENTS", "run_swarm_benchmark", "format_swarm_benchmark"]

#: The swarm sizes of the scaling table.
AGENTS = (1, 2, 4, 8, 16, 32, 64)


def run_swarm_benchmark(agents: Sequence[int] = AGENTS, uavs: int = 256, steps: int = 200, method: str = "basic",
                        horizon: int = 20, iters: int = 30, repeats: int = 3, seed: int = 0) -> dict[str, Any]:
    """Time ``circle_swap`` swarms of each size in ``agents`` (module docstring); a JSON-serialisable
    dict with ``config``, ``environment`` and one entry per swarm size."""
    from ..engine import evaluate_program
    from ..engine.swarm import evaluate_swarms
    from ..metrics import METRICS
    from ..scenarios.swarms import make_swarms, swarm_params
    from ..sweep.plan import seen_slots

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
        params = swarm_params("circle_swap", agents=a, distance=(diameter, diameter))
        check_fits(fields, seen_slots(sim, params.max_obstacles, a), steps, fields, agents=a,  # one call
                   what=f"bench.uavs = {uavs:,} ({fields:,} swarms of {a})")
        swarms = jax.block_until_ready(make_swarms(seed, params, fields))
        t0 = time.perf_counter()
        compiled = evaluate_swarms.lower(swarms, gains, sim=sim, mpc=mpc).compile()
        memory = compiled.memory_analysis()
        temp = None if memory is None else int(memory.temp_size_in_bytes)
        out[a] = {"fields": fields, "compile_s": time.perf_counter() - t0, "temp_bytes": temp,
                  "temp_mib": None if temp is None else round(temp / 2**20, 1)}
        jax.block_until_ready(compiled(swarms, gains))
        runs[a] = (lambda c, s: lambda: jax.block_until_ready(c(s, gains)))(compiled, swarms)
        alone = _alone(swarms, sim.vehicle.r_uav)
        program = evaluate_program.lower(alone, gains, sim=sim, mpc=mpc, width=fields * a,
                                         metrics=METRICS.names(), streaming=False).compile()
        jax.block_until_ready(program(alone, gains))
        runs[f"{a} alone"] = (lambda c, s: lambda: jax.block_until_ready(c(s, gains)))(program, alone)
    timed = interleaved(runs, repeats)
    for a in sizes:
        t, solo = timed[a], timed[f"{a} alone"]
        swarm_steps = out[a]["fields"] * steps
        out[a] |= t | {"us_per_swarm_step": 1e6 * t["run_s"] / swarm_steps,
                       "us_per_uav_step": 1e6 * t["run_s"] / (swarm_steps * a),
                       "alone_run_s": solo["run_s"], "alone_us_per_uav_step": 1e6 * solo["run_s"] / (swarm_steps * a)}
    return {"config": {"agents": sizes, "uavs": uavs, "steps": steps, "method": method, "horizon": horizon,
                       "iters": iters, "repeats": repeats, "seed": seed, "family": "circle_swap"},
            "environment": environment(jnp.float32), "sizes": {str(a): v for a, v in out.items()}}


def _alone(swarms: Any, r_uav: float) -> Any:
    """Every UAV of the (F, A) swarms as its own single-UAV field (F·A fields) with the swarm's obstacle
    slots, the neighbours' slots empty."""
    from ..datatypes.swarm import agent_view

    agents = swarms.start.shape[1]
    views = jax.vmap(lambda s: jax.vmap(lambda a: agent_view(s, a, r_uav))(jnp.arange(agents)))(swarms)
    flat = jax.tree_util.tree_map(lambda x: x.reshape((-1,) + x.shape[2:]), views)
    o = flat.obstacles
    if o.agent is None:  # one UAV per swarm: no neighbour slots
        return flat
    return dataclasses.replace(flat, obstacles=dataclasses.replace(o, valid=o.valid & ~o.agent))


def format_swarm_benchmark(result: dict[str, Any]) -> str:
    """A small table of :func:`run_swarm_benchmark`'s result."""
    c = result["config"]
    lines = [f"circle_swap, about {c['uavs']} UAVs per call x {c['steps']} steps, {c['method']}, N = {c['horizon']}, "
             f"{c['iters']} FISTA iterations (fastest of {c['repeats']})",
             f"{'UAVs':>5} {'fields':>7} {'compile':>9} {'run':>9} {'us/swarm-step':>14} {'us/UAV-step':>12} "
             f"{'alone':>8} {'memory':>10}"]
    for a, v in result["sizes"].items():
        memory = "–" if v["temp_mib"] is None else f"{v['temp_mib']:.1f} MiB"
        lines.append(f"{a:>5} {v['fields']:>7} {v['compile_s']:>8.1f}s {v['run_s']:>8.2f}s "
                     f"{v['us_per_swarm_step']:>14.1f} {v['us_per_uav_step']:>12.2f} "
                     f"{v['alone_us_per_uav_step']:>8.2f} {memory:>10}")
    return "\n".join(lines)
