"""The sweep's path from spec to device under each backend policy, end to end and phase by phase.

    python benchmarks/policy.py [--spec sweeps/compare-small.toml] [--fields N] [--policy cpu accelerator]
                                [--phases | --phases-only] [--json FILE]

Per policy (:mod:`jaxapf.engine.policy`, ``jaxapf sweep --policy``):

* **end to end**: ``jaxapf sweep SPEC --policy P`` in a fresh process with an empty compilation cache
  (``cold``), then ``--repeats`` times again with the cache it filled (``warm``: the fastest, all kept); the
  engine programs it built, counted from ``JAX_LOG_COMPILES`` (``jit(evaluate_program)`` lines: compiled when
  cold, loaded from the cache when warm), and the plan's sequential control steps (``--dry-run``).
* **phases** (``--phases``): the same chunks run one phase after another in this process, nothing
  overlapped, each phase blocked on before the next: fields made on the device, the engine program
  compiled (``lower``/``compile``, once per program), the control loop (the compiled call), the metrics
  copied to the host, the solvability oracle (host), the part built and written (Parquet). The sweep
  itself overlaps the oracle and the writing with the device; this is where its time goes, not its wall time.
* **rates**: scenario-steps per second of the warm run, counted as ``jaxapf bench engine`` counts them
  (episodes × the steps of ``t_max``, ``warm_steps_per_s``) and as flown (the rows' ``steps``).
* **rows**: every policy's rows against the first policy's: outcomes (success, collision, stalled, steps)
  equal, and each continuous metric within 1e-3 (absolute, or relative above one).

``--fields N`` runs the spec with N fields per family (the 98,304-episode sweep is ``--fields 8192`` on
compare-small); ``--phases-only`` times the phases alone (no end-to-end runs: at that size each takes
minutes on a CPU). The same script runs on a GPU (``benchmarks/gpu.sh``).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import re
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUTCOMES = ("success", "collision", "stalled", "steps")


def _spec_file(spec: pathlib.Path, fields: int | None, folder: pathlib.Path) -> pathlib.Path:
    """``spec``, or a copy of it with ``fields`` fields per family."""
    if fields is None:
        return spec
    text = re.sub(r"(?m)^fields\s*=\s*\d+", f"fields = {fields}", spec.read_text())
    copy = folder / spec.name
    copy.write_text(text)
    return copy


def _sweep(spec: pathlib.Path, out: pathlib.Path, policy: str, env: dict[str, str]) -> dict:
    """One ``jaxapf sweep`` in a fresh process: its wall time and the engine programs it compiled."""
    command = [sys.executable, "-m", "jaxapf", "sweep", str(spec), "--out", str(out), "--policy", policy, "--quiet"]
    start = time.perf_counter()
    proc = subprocess.run(command, cwd=ROOT, env=env | {"JAX_LOG_COMPILES": "1"}, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if proc.returncode != 0:
        sys.exit(f"policy.py: {' '.join(command)} failed: {proc.stderr.strip().splitlines()[-1:]}")
    programs = len(re.findall(r"Finished XLA compilation of jit\((?:evaluate_program|evaluate_swarms)\)",
                              proc.stderr))
    return {"seconds": round(seconds, 2), "programs_built": programs}


def _dry_run(spec: pathlib.Path, policy: str, env: dict[str, str]) -> dict:
    proc = subprocess.run([sys.executable, "-m", "jaxapf", "sweep", str(spec), "--dry-run", "--policy", policy,
                           "--out", os.devnull + ".parquet"], cwd=ROOT, env=env, capture_output=True, text=True)
    programs = int(re.search(r"(\d+) evaluate program", proc.stdout)[1])
    steps = int(re.search(r"up to ([\d,]+) one after another", proc.stdout)[1].replace(",", ""))
    # every chunk line: "... G settings × B fields per chunk (padded P), T steps": episodes × T over the sweep
    episodes = int(re.search(r"episodes:\s+([\d,]+)", proc.stdout)[1].replace(",", ""))
    lengths = {int(t) for t in re.findall(r"\), (\d+) steps, N=", proc.stdout)}
    return {"programs": programs, "control_steps": steps,
            "steps_at_t_max": episodes * lengths.pop() if len(lengths) == 1 else None}


def agreement(reference, other) -> dict:
    """Outcomes equal, and each continuous metric within 1e-3, over rows matched by (setting, family, field)."""
    key = ["setting", "family", "field"]
    a, b = (frame.sort_values(key).reset_index(drop=True) for frame in (reference, other))
    same = np.ones(len(a), bool)
    for name in OUTCOMES:
        same &= (a[name].to_numpy() == b[name].to_numpy())
    continuous = {}
    for name in a.columns:
        if name in OUTCOMES or name in key or a[name].dtype.kind != "f":
            continue
        x, y = a[name].to_numpy(float), b[name].to_numpy(float)
        with np.errstate(invalid="ignore"):  # inf - inf where both are inf: equal, caught by x == y
            close = (np.abs(x - y) <= 1e-3 * np.maximum(1.0, np.abs(x))) | (np.isnan(x) & np.isnan(y)) | (x == y)
        equal = (x == y) | (np.isnan(x) & np.isnan(y))
        continuous[name] = {"within_1e-3": round(float(close.mean()), 6), "bit_equal": round(float(equal.mean()), 6)}
    return {"rows": len(a), "outcomes_equal": round(float(same.mean()), 6), "continuous": continuous}


def phases(spec_path: pathlib.Path, policy: str) -> dict:
    """The sweep's chunks, phase after phase in this process (module docstring)."""
    import jax
    import jax.numpy as jnp

    from jaxapf.engine import evaluate_program
    from jaxapf.scenarios import make_scenarios
    from jaxapf.sweep import load_spec
    from jaxapf.sweep.execute import ChunkRunner
    from jaxapf.sweep.output import write_part
    from jaxapf.sweep.plan import plan_sweep
    from jaxapf.sweep.schema import part_table, schema

    spent = dict.fromkeys(("fields", "compile", "control_loop", "to_host", "oracle", "write"), 0.0)
    start = time.perf_counter()
    spec = load_spec(spec_path)
    plan = plan_sweep(spec, policy=policy)
    runner = ChunkRunner(plan)
    compiled: dict = {}
    layout = schema(plan)
    spent["plan"] = time.perf_counter() - start

    def write(folder, chunk, host, kinds, solvable):
        """The part: its table built from the metrics on the host, written as the sweep writes it."""
        write_part(folder, chunk.name, part_table(plan, layout, chunk, host, kinds, solvable))

    def clock(phase: str, fun, *args):
        t = time.perf_counter()
        out = jax.block_until_ready(fun(*args))
        spent[phase] += time.perf_counter() - t
        return out

    with tempfile.TemporaryDirectory() as tmp:
        for chunk in plan.chunks:
            block = plan.blocks[(chunk.variant, chunk.family)]
            indices = np.full(block.padded, chunk.start, np.int64)
            indices[: chunk.stop - chunk.start] = np.arange(chunk.start, chunk.stop)
            fields = clock("fields", make_scenarios, spec.seed, spec.family_params(chunk.family), jnp.asarray(indices))
            flown = plan.flown(fields)
            gains = runner._variant_gains(plan.variants[chunk.variant])[0]
            static = dict(sim=block.flown, mpc=block.mpc, width=block.width, metrics=plan.metrics,
                          refill=plan.policy.refill)
            shapes = jax.tree_util.tree_map(lambda x: (x.shape, x.dtype), flown)
            program = (repr(static), str(shapes))
            if program not in compiled:
                compiled[program] = clock("compile", lambda f, g, kw: evaluate_program.lower(f, g, **kw).compile(),
                                          flown, gains, static)
            metrics = clock("control_loop", compiled[program], flown, gains)
            host = clock("to_host", lambda m: {k: np.asarray(v) for k, v in m.items()}, metrics)
            solvable = clock("oracle", runner._solvable, chunk, fields, block.sim) if spec.oracle else None
            clock("write", write, pathlib.Path(tmp), chunk, host, np.asarray(fields.kind), solvable)
    runner.close()
    total = time.perf_counter() - start
    return {"seconds": {k: round(v, 3) for k, v in spent.items()}, "total_s": round(total, 2),
            "programs": len(compiled), "chunks": len(plan.chunks)}


def measure(spec: pathlib.Path, fields: int | None, policies: list[str], with_phases: bool, repeats: int,
            end_to_end: bool = True) -> dict:
    from jaxapf.bench.engine import environment
    from jaxapf.sweep import read_sweep

    runs, frames = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        path = _spec_file(ROOT / spec, fields, tmp)
        for policy in policies:
            env = os.environ | {"XDG_CACHE_HOME": str(tmp / f"cache-{policy}")}  # an empty compilation cache
            if not end_to_end:
                runs[policy] = {"plan": _dry_run(path, policy, env), "phases": phases(path, policy)}
                continue
            cold = _sweep(path, tmp / f"{policy}-cold.parquet", policy, env)
            warms = [_sweep(path, tmp / f"{policy}-warm-{i}.parquet", policy, env) for i in range(repeats)]
            warm = min(warms, key=lambda w: w["seconds"]) | {"all_s": [w["seconds"] for w in warms]}
            frames[policy] = read_sweep(tmp / f"{policy}-cold.parquet")[0]
            plan = _dry_run(path, policy, env)
            flown = int(frames[policy]["steps"].sum())
            runs[policy] = {"cold": cold, "warm": warm, "plan": plan, "episodes": len(frames[policy]),
                            "steps_flown": flown, "steps_at_t_max": plan["steps_at_t_max"],
                            "warm_steps_per_s": round((plan["steps_at_t_max"] or 0) / warm["seconds"]),
                            "warm_flown_steps_per_s": round(flown / warm["seconds"])}
            if with_phases:
                runs[policy]["phases"] = phases(path, policy)
        first = policies[0]
        for policy in policies[1:] if end_to_end else ():
            runs[policy]["rows_against_" + first] = agreement(frames[first], frames[policy])
    return {"command": "python benchmarks/policy.py " + " ".join(sys.argv[1:]),
            "date": datetime.date.today().isoformat(), "spec": str(spec), "fields": fields,
            "environment": environment("float32"), "policies": runs}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--spec", type=pathlib.Path, default=pathlib.Path("sweeps/compare-small.toml"))
    p.add_argument("--fields", type=int, help="fields per family (default the spec's)")
    p.add_argument("--policy", nargs="+", default=["cpu", "accelerator"], choices=("cpu", "accelerator"))
    p.add_argument("--phases", action="store_true", help="also time the phases one after another in this process")
    p.add_argument("--phases-only", action="store_true", help="time the phases alone, no end-to-end runs")
    p.add_argument("--repeats", type=int, default=2, help="warm runs per policy (default 2; the fastest is quoted)")
    p.add_argument("--json", type=pathlib.Path, help="also write the result to this file")
    args = p.parse_args(argv)
    result = measure(args.spec, args.fields, args.policy, args.phases or args.phases_only, args.repeats,
                     end_to_end=not args.phases_only)
    for name, run in result["policies"].items():
        if "cold" not in run:
            print(f"{name}: plan {run['plan']}; phases {run['phases']}")
            continue
        print(f"{name}: cold {run['cold']['seconds']} s ({run['cold']['programs_built']} programs), warm "
              f"{run['warm']['seconds']} s; plan {run['plan']}" + (f"; phases {run['phases']}" if "phases" in run
                                                                    else ""))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    else:
        print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
