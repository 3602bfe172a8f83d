"""Run the benchmarks whose figures docs/performance.md and docs/sweep.md quote; keep their JSON in benchmarks/results/.

    python benchmarks/record.py                 # every record below, one after the other
    python benchmarks/record.py world split     # only these

Each record is one or more runs of a command that prints one JSON object (``--json``); they are
written to ``benchmarks/results/<name>.json`` as ``{"command", "date", "runs"}``. The docs quote
these files, and tests/test_readme_numbers.py fails when a quoted number is in none of them.
Run on a quiet machine: the figures are wall times.
"""

from __future__ import annotations

import argparse
import datetime
import json
import pathlib
import re
import shlex
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

#: name -> (command, runs). ``jaxapf`` is the installed command; ``python`` this interpreter.
RECORDS: dict[str, tuple[str, int]] = {
    "engine": ("jaxapf bench engine --json", 2),
    "engine-2-devices": ("jaxapf bench engine --devices 2 --vectorised-steps 0 --json", 1),
    "sweep": ("jaxapf bench sweep --json", 1),
    "sweep-compare-small": ("jaxapf bench sweep sweeps/compare-small.toml --repeats 1 --sharded-devices 0 --json", 1),
    "sweep-paper-comparison": (
        "jaxapf bench sweep sweeps/paper-comparison.toml --repeats 1 --sharded-devices 0 --json", 1),
    "world": ("jaxapf bench world --json", 1),
    "split": ("python benchmarks/split.py --json", 1),
    "stages": ("python benchmarks/stages.py --json", 1),
    "host-time": ("python benchmarks/host_time.py --json", 1),
    "stream-levels": ("python benchmarks/stream_levels.py --json", 1),
    "kernels": ("python benchmarks/kernels.py --json", 1),
    "fit-cost": ("python benchmarks/fit_cost.py --json", 1),
    "xla-fusion-emitters": ("python benchmarks/xla_options.py --xla-option xla_cpu_use_fusion_emitters=true --json", 1),
    "xla-region-analysis": (
        "python benchmarks/xla_options.py --xla-option xla_cpu_copy_insertion_use_region_analysis=false --json", 1),
    "faults": ("python benchmarks/faults.py --json", 1),
    "shards": ("python benchmarks/shards.py --json", 1),
    "ray": ("python benchmarks/ray_cluster.py --json", 1),
    "scale": ("python benchmarks/scale.py --json", 1),
    "projection-rows": ("python benchmarks/projection_rows.py --json", 1),
    "policy": ("python benchmarks/policy.py --phases", 1),
    "compare-quick": ("python benchmarks/timed.py -- compare sweeps/compare-quick.toml --quiet", 1),
    "scorecard-basic": ("python benchmarks/scorecard.py", 1),
}


def record(name: str) -> dict:
    """Run ``RECORDS[name]`` and return what benchmarks/results/<name>.json holds."""
    command, runs = RECORDS[name]
    argv = shlex.split(command)
    if argv[0] == "python":
        argv[0] = sys.executable
    out = []
    for i in range(runs):
        proc = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"record.py: {command} failed: {(proc.stderr.strip().splitlines() or [''])[-1]}")
        start = re.search(r"^\{", proc.stdout, re.M)  # the object, after any lines of the tools it runs
        out.append(json.JSONDecoder().raw_decode(proc.stdout[start.start():])[0])
        print(f"{name}: run {i + 1} of {runs} done", file=sys.stderr)
    return {"command": command, "date": datetime.date.today().isoformat(), "runs": out}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("names", nargs="*", metavar="NAME", help=f"records to run (default all: {', '.join(RECORDS)})")
    args = p.parse_args(argv)
    unknown = [n for n in args.names if n not in RECORDS]
    if unknown:
        p.error(f"no record {unknown[0]!r}; the records are {', '.join(RECORDS)}")
    for name in args.names or list(RECORDS):
        (RESULTS / f"{name}.json").write_text(json.dumps(record(name), indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
