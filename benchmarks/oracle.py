"""The solvability oracle against the one of an earlier commit: the same answers, and the time per field.

    python benchmarks/oracle.py [--against 360a044] [--fields 8192] [--families trap crossing ...] [--jobs 2]
                                [--json FILE]

For every shipped family (single-UAV fields, and each UAV of a swarm field alone, as a swarm sweep asks), the
first ``--fields`` fields of seed 0 at the vehicle's defaults and the family's ``t_max``: the answers of
``jaxapf.scenarios.solvable`` and of the same function of commit ``--against`` (its module as that commit
holds it, loaded from git), field by field; where they differ, the fields are listed. Both run in this process,
interleaved in blocks of 64 fields, so a drift of the machine hits both; the time per field of each.
``--jobs N`` compares N families at a time, each in a process of its own (both oracles are single-threaded).

``--quick-start`` instead times the quick start's oracle phase: the 2,048 fields of sweeps/compare-small.toml
(its four families at 512 fields; ``--fields`` changes that), as the sweep asks about them, per family, and
in all.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import multiprocessing
import pathlib
import subprocess
import sys
import tempfile
import time

import jax
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
BLOCK = 64


def module_at(rev: str):
    """``jaxapf.scenarios.solvability`` as commit ``rev`` holds it, imported under another name."""
    source = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:jaxapf/scenarios/solvability.py"],
                            check=True, capture_output=True, text=True).stdout
    folder = pathlib.Path(tempfile.mkdtemp(prefix="jaxapf-oracle-"))
    path = folder / f"solvability_{rev}.py"
    path.write_text(source.replace("from ..validation import", "from jaxapf.validation import"))
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def fields_of(family: str, count: int, seed: int = 0):
    """``(fields, swarm)``: the family's first ``count`` fields (numpy leaves)."""
    from jaxapf.scenarios import FAMILIES, family_params, make_scenarios
    from jaxapf.scenarios.swarms import SWARM_FAMILIES, make_swarms, swarm_params

    if family in FAMILIES.names():
        return jax.device_get(make_scenarios(seed, family_params(family), count)), False
    assert family in SWARM_FAMILIES.names(), family
    return jax.device_get(make_swarms(seed, swarm_params(family), count)), True


def ask(oracle, fields, swarm: bool, vehicle: dict) -> np.ndarray:
    """What ``oracle`` (a solvability module's ``solvable``) answers for ``fields``: per field, or per UAV alone."""
    if not swarm:
        return oracle(fields, **vehicle)
    from jaxapf.datatypes import Obstacles, Scenario

    start = np.asarray(fields.start)
    agents = start.shape[-2]
    o = fields.obstacles
    alone = Obstacles(*(np.repeat(np.expand_dims(np.asarray(x), 1), agents, axis=1)
                        for x in (o.position, o.velocity, o.radius, o.cylinder, o.valid)))
    return oracle(Scenario(start=start, goal=np.asarray(fields.goal), obstacles=alone), **vehicle) | ~np.asarray(
        fields.valid)


def vehicle_of(family: str) -> dict:
    """The oracle's vehicle and episode: the defaults, the family's ``t_max`` (as a sweep of it asks)."""
    from jaxapf.config import SimConfig
    from jaxapf.scenarios import FAMILIES, family_params
    from jaxapf.scenarios.swarms import swarm_params

    sim = SimConfig()
    params = family_params(family) if family in FAMILIES.names() else swarm_params(family)
    return dict(r_uav=sim.vehicle.r_uav, v_max=sim.vehicle.v_max, t_max=float(params.t_max), r_goal=sim.episode.r_goal)


def compare(family: str, count: int, old, new) -> dict:
    """The two oracles on ``count`` fields of ``family``, interleaved in blocks: answers, differences, time."""
    fields, swarm = fields_of(family, count)
    vehicle = vehicle_of(family)
    answers, seconds = {"old": [], "new": []}, {"old": 0.0, "new": 0.0}
    for first in range(0, count, BLOCK):
        block = jax.tree_util.tree_map(lambda x, first=first: x[first:first + BLOCK], fields)
        for name, oracle in (("old", old), ("new", new)):
            start = time.perf_counter()
            answers[name].append(ask(oracle, block, swarm, vehicle))
            seconds[name] += time.perf_counter() - start
    a, b = (np.concatenate(answers[k]) for k in ("old", "new"))
    differ = np.argwhere(a != b)
    return {"fields": count, "swarm": swarm, "questions": int(a.size), "vehicle": vehicle,
            "solvable": round(float(a.mean()), 4), "differ": int(len(differ)),
            "differing": [[int(i) for i in d] for d in differ[:50]],
            "old_ms_per_field": round(1e3 * seconds["old"] / count, 3),
            "new_ms_per_field": round(1e3 * seconds["new"] / count, 3),
            "speedup": round(seconds["old"] / seconds["new"], 1)}


def _compare_family(job: tuple[str, int, str]) -> tuple[str, dict]:
    """:func:`compare` of one family in a worker process (``job``: family, fields, the reference commit)."""
    from jaxapf.scenarios import solvable

    family, count, against = job
    return family, compare(family, count, module_at(against).solvable, solvable)


def quick_start(count: int | None, old, new) -> dict:
    """The quick start's oracle phase, per family and in all, for both oracles (interleaved by family)."""
    import tomllib

    spec = tomllib.loads((ROOT / "sweeps" / "compare-small.toml").read_text())
    families, count = spec["scenario"]["families"], count or spec["scenario"]["fields"]
    out = {"spec": "sweeps/compare-small.toml", "fields": count, "families": {}}
    for family in families:
        fields, _ = fields_of(family, count, spec["scenario"]["seed"])
        vehicle = vehicle_of(family)
        times = {}
        for name, oracle in (("old", old), ("new", new)):
            start = time.perf_counter()
            answer = oracle(fields, **vehicle)
            times[name] = time.perf_counter() - start
            times[f"{name}_answers"] = answer
        out["families"][family] = {"old_s": round(times["old"], 3), "new_s": round(times["new"], 3),
                                   "differ": int((times["old_answers"] != times["new_answers"]).sum())}
    out["old_s"] = round(sum(f["old_s"] for f in out["families"].values()), 2)
    out["new_s"] = round(sum(f["new_s"] for f in out["families"].values()), 2)
    out["speedup"] = round(out["old_s"] / out["new_s"], 1)
    out["differ"] = sum(f["differ"] for f in out["families"].values())
    return out


def main(argv: list[str] | None = None) -> int:
    from jaxapf.bench.engine import environment
    from jaxapf.scenarios import FAMILIES, solvable
    from jaxapf.scenarios.swarms import SWARM_FAMILIES

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--against", default="360a044", help="the commit whose oracle is the reference")
    p.add_argument("--fields", type=int, default=None, help="fields per family (default 8192; quick start 512)")
    p.add_argument("--families", nargs="*", help="default: every shipped family, single-UAV and swarm")
    p.add_argument("--quick-start", action="store_true", help="time the quick start's oracle phase instead")
    p.add_argument("--jobs", type=int, default=1, help="families compared at a time, one process each")
    p.add_argument("--json", type=pathlib.Path)
    args = p.parse_args(argv)
    old = module_at(args.against).solvable
    result = {"command": "python benchmarks/oracle.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "date": datetime.date.today().isoformat(), "against": args.against,
              "environment": environment("float64")}
    if args.quick_start:
        result["quick_start"] = quick_start(args.fields, old, solvable)
        q = result["quick_start"]
        print(f"quick start, {q['fields']} fields per family: {args.against} {q['old_s']} s, now {q['new_s']} s "
              f"({q['speedup']}x), {q['differ']} answers differ")
        failed = q["differ"]
    else:
        names = args.families or [*FAMILIES.names(), *SWARM_FAMILIES.names()]
        result["families"] = {}
        jobs = [(family, args.fields or 8192, args.against) for family in names]
        with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
            done = dict(pool.imap_unordered(_compare_family, jobs))
        for family in names:
            r = result["families"][family] = done[family]
            print(f"{family}: {r['questions']} questions, {r['differ']} differ; {r['old_ms_per_field']} -> "
                  f"{r['new_ms_per_field']} ms per field ({r['speedup']}x)", flush=True)
        failed = sum(r["differ"] for r in result["families"].values())
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
