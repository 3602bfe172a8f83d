r"""What each component costs per scenario-step, against the paper's stack in the ideal world.

:func:`run_world_benchmark` compiles the same closed loop (same fields, planner, MPC) once per
*variant* and times them interleaved (:func:`~jaxapf.bench.engine.interleaved`, fastest of
``repeats``), so a drift of a shared machine hits every variant alike:

==================  ==========================================================================
``ideal``           double integrator, ideal sensor, calm air (the paper's world, the baseline)
``sensing``         the noisy sensor with every effect on (noise, range, latency, dropout, own state)
``sensing_fd``      the same with velocities by finite differences of noisy positions
``wind``            constant wind with OU gusts
``quadrotor``       the quadrotor plant with ``substeps`` inner steps
``everything``      quadrotor, noisy sensor and wind together
``crazyflie_*``     the Crazyflie (``cf2x_L250``) at each fidelity of ``drone-models``, RK4 over ``substeps``
``cbf``             the CBF safety filter between the MPC and the plant
``direction_velocity``, ``velocity_obstacle``: another planner in the ideal world
``mppi_k64``, ``mppi``, ``mppi_k1024``: MPPI with 64, 256 (its default) and 1,024 samples
``keepout_mpc``     the MPC with every obstacle kept out over its horizon (a QP per step)
``learned_weight``  the paper's potential with the learned weight ω_θ (its default parameters)
==================  ==========================================================================

Every variant runs the fixed-length engine (``evaluate(..., streaming=False)``), so each flies
exactly ``fields × steps`` scenario-steps whatever its episodes do; the cost per scenario-step is
``run_s / (fields · steps)`` and the ratio is against ``ideal`` of the same run.
"""

from __future__ import annotations

import time
from typing import Any

import jax
import jax.numpy as jnp

from ..config import MPCConfig, SimConfig
from ..gains import Gains
from ..metrics import METRICS
from ..validation import check_int
from .engine import check_fits, environment, interleaved

__all__ = ["VARIANTS", "run_world_benchmark", "format_world_benchmark"]

_NOISE = dict(sigma_obs_p=0.1, sigma_obs_v=0.1, sigma_self_p=0.05, sigma_self_v=0.05, sense_range=8.0,
              latency=0.2, dropout=0.1)
_WIND = dict(wind_speed=3.0, gust_sigma=1.0)
#: Variant -> (static settings, gains) on top of the ideal world.
VARIANTS: dict[str, tuple[dict[str, Any], dict[str, float]]] = {
    "ideal": ({}, {}),
    "sensing": ({"sensor": "noisy"}, _NOISE),
    "sensing_fd": ({"sensor": "noisy", "velocity_estimate": "differenced"}, _NOISE),
    "wind": ({"disturbance": "wind"}, _WIND),
    "quadrotor": ({"plant": "quadrotor"}, {}),
    "everything": ({"plant": "quadrotor", "sensor": "noisy", "disturbance": "wind"}, _NOISE | _WIND),
    "crazyflie_so_rpy": ({"plant": "crazyflie_so_rpy"}, {}),
    "crazyflie_so_rpy_rotor": ({"plant": "crazyflie_so_rpy_rotor"}, {}),
    "crazyflie_so_rpy_rotor_drag": ({"plant": "crazyflie_so_rpy_rotor_drag"}, {}),
    "crazyflie_first_principles": ({"plant": "crazyflie_first_principles"}, {}),
    "cbf": ({"filter": "cbf"}, {}),
    "direction_velocity": ({"method": "direction_velocity"}, {}),
    "velocity_obstacle": ({"method": "velocity_obstacle"}, {}),
    "mppi_k64": ({"method": "mppi", "mppi_samples": 64}, {}),
    "mppi": ({"method": "mppi"}, {}),
    "mppi_k1024": ({"method": "mppi", "mppi_samples": 1024}, {}),
    "keepout_mpc": ({"method": "keepout_mpc"}, {}),
    "learned_weight": ({"method": "learned_weight"}, {}),
}


def run_world_benchmark(fields: int = 256, steps: int = 200, family: str = "dynamic", method: str = "basic",
                        horizon: int = 20, iters: int = 30, substeps: int = 10, repeats: int = 3,
                        seed: int = 0, variants: tuple[str, ...] | None = None) -> dict[str, Any]:
    """Time every :data:`VARIANTS` entry (or those named in ``variants``, ``ideal`` always first) on the same
    ``fields`` of ``family`` (module docstring).

    Returns a JSON-serialisable dict: ``config``, ``environment`` and per variant ``compile_s``,
    ``run_s``, ``cpu_s``, ``us_per_scenario_step`` and ``ratio`` (to ``ideal``).
    """
    from ..engine import evaluate_program
    from ..scenarios import family_params, make_scenarios

    fields = check_int("bench.fields", fields, 1)
    steps = check_int("bench.steps", steps, 1)
    repeats = check_int("bench.repeats", repeats, 1)
    params = family_params(family)
    check_fits(fields, params.max_obstacles, steps, fields)  # every field in one call
    scenarios = jax.block_until_ready(make_scenarios(seed, params, fields))
    mpc = MPCConfig(horizon=horizon, iters=iters)
    base = SimConfig.from_flat(method=method, t_max=steps * 0.1, substeps=substeps)
    runs, out = {}, {}
    chosen = VARIANTS if variants is None else {k: VARIANTS[k] for k in dict.fromkeys(("ideal", *variants))}
    for name, (static, gains) in chosen.items():
        sim = base.replace(**static)
        batch = jax.tree_util.tree_map(lambda g: jnp.asarray(g, scenarios.start.dtype)[None], Gains(**gains))
        t0 = time.perf_counter()
        compiled = evaluate_program.lower(scenarios, batch, sim=sim, mpc=mpc, width=fields, metrics=METRICS.names(),
                                          streaming=False).compile()
        out[name] = {"compile_s": time.perf_counter() - t0}
        jax.block_until_ready(compiled(scenarios, batch))  # the first run
        runs[name] = (lambda c, b: lambda: jax.block_until_ready(c(scenarios, b)))(compiled, batch)
    timed = interleaved(runs, repeats)
    for name, t in timed.items():
        out[name] |= t | {"us_per_scenario_step": 1e6 * t["run_s"] / (fields * steps),
                          "ratio": t["run_s"] / timed["ideal"]["run_s"]}
    return {"config": {"fields": fields, "steps": steps, "family": family, "method": method, "horizon": horizon,
                       "iters": iters, "substeps": substeps, "repeats": repeats, "seed": seed},
            "environment": environment(scenarios.start.dtype), "variants": out}


def format_world_benchmark(result: dict[str, Any]) -> str:
    """A small table of :func:`run_world_benchmark`'s result."""
    c = result["config"]
    lines = [f"{c['fields']} fields x {c['steps']} steps, {c['method']} on {c['family']}, N = {c['horizon']}, "
             f"{c['iters']} FISTA iterations, quadrotor sub-steps {c['substeps']} (fastest of {c['repeats']})",
             f"{'variant':<18} {'compile':>9} {'run':>9} {'us/scenario-step':>17} {'x ideal':>8}"]
    for name, v in result["variants"].items():
        lines.append(f"{name:<18} {v['compile_s']:>8.1f}s {v['run_s']:>8.2f}s {v['us_per_scenario_step']:>17.2f} "
                     f"{v['ratio']:>8.2f}")
    return "\n".join(lines)

