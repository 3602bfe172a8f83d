"""The test suite's cost, as docs/testing.md states it: wall time, outcome line and the peak memory
of the largest process (pytest and the programs it starts), for a tier of the suite.

    python benchmarks/suite.py --tier fast --json benchmarks/results/suite-fast.json
    python benchmarks/suite.py --tier all --json benchmarks/results/suite-all.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import resource
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
TIERS = {"fast": ["-m", "not slow"], "all": []}


def measure(tier: str) -> dict:
    command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *TIERS[tier]]
    start = time.perf_counter()
    proc = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    peak_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # Linux: KiB, the largest child
    outcome = next((line.strip("= ") for line in reversed(proc.stdout.splitlines()) if " in " in line), "")
    return {"command": f"python benchmarks/suite.py --tier {tier}", "date": datetime.date.today().isoformat(),
            "pytest": command[1:], "cpu_count": len(os.sched_getaffinity(0)), "returncode": proc.returncode,
            "outcome": outcome, "wall_min": round(seconds / 60, 1), "peak_memory_gb": round(peak_kib / 2**20, 1)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tier", choices=sorted(TIERS), default="fast")
    p.add_argument("--json", type=pathlib.Path, help="also write the result to this file")
    args = p.parse_args(argv)
    result = measure(args.tier)
    print(f"{args.tier}: {result['outcome']}; {result['wall_min']} min, peak {result['peak_memory_gb']} GB")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return result["returncode"]


if __name__ == "__main__":
    sys.exit(main())
