"""The engine on whatever backend JAX has (a GPU when one is lent): `jaxapf bench engine`'s standard
case (``clutter``, 16 obstacle slots, N = 20, 30 FISTA iterations, 300 steps, ``direction_velocity``)
at 1,024 to 262,144 fields per call, and the README's quick-start sweep end to end.

    python benchmarks/accelerator.py --json benchmarks/results/engine-h200.json

Per size: trace and compile, the first run, the fastest of ``--repeats`` steady runs, scenario-steps/s
and the working memory (``memory_analysis``). The record is written after every size, so a run
stopped early keeps what it finished. The sweep is ``python -m jaxapf sweep`` on the quick start's
spec, timed as a subprocess (an empty compilation cache: a new process), with its wall seconds and
the episodes it wrote; it runs first, before this process takes the accelerator's memory.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile
import time

import jax

from jaxapf.bench.engine import bench_case, environment, lower_case

ROOT = pathlib.Path(__file__).resolve().parents[1]
SIZES = (1024, 4096, 16384, 65536, 262144)


def _temp_bytes(compiled) -> float | None:
    """The working memory XLA reports for ``compiled`` (None where the backend reports none)."""
    try:
        return float(compiled.memory_analysis().temp_size_in_bytes)
    except Exception:  # a backend without memory analysis
        return None


def engine_size(fields: int, repeats: int, steps: int) -> dict:
    """The standard case at ``fields`` fields, all in one vmap of that width."""
    case = bench_case(fields, 16, 20, 30, steps, "clutter", width=fields)
    t0 = time.perf_counter()
    lowered, args = lower_case(case)
    compiled = lowered.compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(compiled(*args))
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        runs.append(time.perf_counter() - t0)
    run = min(runs)
    scenario_steps = fields * case["sim"].episode.steps
    return {"fields": fields, "width": fields, "compile_s": compile_s, "first_run_s": first, "run_s": run,
            "run_all_s": runs, "steps_per_s": scenario_steps / run, "us_per_scenario_step": 1e6 * run / scenario_steps,
            "temp_bytes": _temp_bytes(compiled)}


def quickstart_sweep(timeout: float) -> dict:
    """``python -m jaxapf sweep`` on the quick start's spec in a new process (empty compilation cache)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from quickstart import _with_out, quickstart_commands

    sweep, _ = quickstart_commands((ROOT / "README.md").read_text())
    with tempfile.TemporaryDirectory() as tmp:
        command = _with_out([sys.executable, "-m", "jaxapf", *sweep[1:]], pathlib.Path(tmp) / "out.parquet")
        t0 = time.perf_counter()
        done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=timeout)
        wall = time.perf_counter() - t0
        rows = None
        if done.returncode == 0:
            import pyarrow.dataset as ds

            rows = ds.dataset(pathlib.Path(tmp) / "out.parquet", format="parquet").count_rows()
    return {"command": " ".join(["jaxapf", *sweep[1:]]), "returncode": done.returncode, "wall_s": wall,
            "episodes": rows, "stderr_tail": done.stderr[-2000:]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fields", type=int, nargs="+", default=list(SIZES), help="fields per call")
    parser.add_argument("--repeats", type=int, default=3, help="steady runs per size (fastest kept)")
    parser.add_argument("--steps", type=int, default=300, help="control steps per episode")
    parser.add_argument("--sweep-timeout", type=float, default=300.0,
                        help="seconds for the quick-start sweep (0: skip)")
    parser.add_argument("--json", type=pathlib.Path, help="write the record here (after every size)")
    args = parser.parse_args()
    record = {"config": {"family": "clutter", "obstacles": 16, "horizon": 20, "iters": 30, "steps": args.steps,
                         "method": "direction_velocity", "repeats": args.repeats}, "sweep": None}

    def save() -> None:
        if args.json:
            args.json.write_text(json.dumps(record, indent=1) + "\n")

    if args.sweep_timeout > 0:  # first: a process holding the accelerator would starve the sweep's
        try:
            record["sweep"] = quickstart_sweep(args.sweep_timeout)
            sweep = record["sweep"]
            print(f"quick-start sweep: {sweep['wall_s']:.1f} s, rc {sweep['returncode']}", flush=True)
        except subprocess.TimeoutExpired:
            record["sweep"] = {"error": f"over {args.sweep_timeout} s"}
    record |= {"environment": environment(jax.numpy.float32), "devices": [str(d) for d in jax.devices()],
               "sizes": {}}
    save()
    for fields in args.fields:
        try:
            record["sizes"][str(fields)] = size = engine_size(fields, args.repeats, args.steps)
            print(f"{fields:>7} fields: {size['steps_per_s'] / 1e6:8.2f} M scenario-steps/s "
                  f"(run {size['run_s']:.3f} s, compile {size['compile_s']:.1f} s)", flush=True)
        except Exception as err:  # out of memory at the largest sizes: kept as what it is
            record["sizes"][str(fields)] = {"fields": fields, "error": f"{type(err).__name__}: {str(err)[:300]}"}
            print(f"{fields:>7} fields: {type(err).__name__}", flush=True)
        save()


if __name__ == "__main__":
    main()
