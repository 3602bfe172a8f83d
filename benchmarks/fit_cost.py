"""Fit the per-step cost model behind ``jaxapf sweep --dry-run`` (``jaxapf.sweep.STEP_COST_US``) on this machine.

    python benchmarks/fit_cost.py [--json]
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from typing import Any

import numpy as np

from jaxapf.bench.engine import environment, run_benchmark

#: Configurations of :func:`fit_step_cost`: horizons N × FISTA iterations I × obstacle slots M.
COST_GRID = {"horizon": (10, 20, 40), "iters": (10, 30, 60), "obstacles": (4, 16)}


def fit_step_cost(fields: int = 1024, steps: int = 50) -> dict[str, Any]:
    """Fit ``jaxapf.sweep.STEP_COST_US``: wall µs per episode step on this process's first device,
    ``c0 + c_qp·N·I + c_obs·N·M + c_n·N``, by least squares over :data:`COST_GRID` (each point one
    steady :func:`run_benchmark` of ``fields`` clutter fields × ``steps`` steps).
    """
    rows = []
    for n, i, m in itertools.product(*COST_GRID.values()):
        eng = run_benchmark(fields=fields, obstacles=m, horizon=n, iters=i, steps=steps, oracle_fields=0)["engine"]
        rows.append({"horizon": n, "iters": i, "obstacles": m, "step_us": 1e6 * eng["run_s"] / (fields * steps)})
    design = np.array([[1.0, r["horizon"] * r["iters"], r["horizon"] * r["obstacles"], r["horizon"]] for r in rows])
    measured = np.array([r["step_us"] for r in rows])
    coef = np.linalg.lstsq(design, measured, rcond=None)[0]
    ratio = design @ coef / measured
    return {"environment": environment(np.float32), "fields": fields, "steps": steps,
            "coefficients": [float(c) for c in coef], "rows": rows,
            "fit_over_measured": {"min": float(ratio.min()), "max": float(ratio.max())}}


def format_step_cost(result: dict[str, Any]) -> str:
    """The fitted coefficients and each point, measured vs fitted."""
    coef = result["coefficients"]
    env = result["environment"]
    lines = [f"benchmarks/fit_cost.py: {result['fields']} clutter fields x {result['steps']} steps per point, "
             f"device {env['device']}, {env['cpu_count']} CPUs, jax {env['jax']}",
             f"  {'N':>4s}{'I':>5s}{'M':>5s}{'measured us':>14s}{'fit us':>10s}"]
    for r in result["rows"]:
        n = r["horizon"]
        fit = coef[0] + coef[1] * n * r["iters"] + coef[2] * n * r["obstacles"] + coef[3] * n
        lines.append(f"  {r['horizon']:>4d}{r['iters']:>5d}{r['obstacles']:>5d}{r['step_us']:>14.2f}{fit:>10.2f}")
    span = result["fit_over_measured"]
    lines += ["", f"  STEP_COST_US = ({', '.join(f'{c:.4g}' for c in coef)})   "
                  f"(fit / measured: {span['min']:.2f} .. {span['max']:.2f})"]
    return "\n".join(lines)




def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--fields", type=int, default=1024)
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    result = fit_step_cost(fields=args.fields, steps=args.steps)
    print(json.dumps(result, indent=2) if args.json else format_step_cost(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
