"""``jaxapf scorecard --method M`` timed as a researcher meets it: a method ranked on a scorecard with its zoo
stored, from an empty compilation cache and an empty output folder (everything selected, flown and compared),
and once more with the cache warm (the difference is what compiling cost). The method is ``basic`` under
another name (a planner of ``basic``'s cost, whose row must reproduce the stored ``basic``'s).

    python benchmarks/scorecard.py --json benchmarks/results/scorecard.json          # scorecard v1
    python benchmarks/scorecard.py --card tests/data/scorecard-tiny                   # a folder's card
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _timed(command: list[str], env: dict[str, str]) -> float:
    start = time.perf_counter()
    proc = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if proc.returncode != 0:
        sys.exit(f"scorecard.py: {' '.join(command)} failed: {proc.stderr.strip().splitlines()[-1:]}")
    return seconds


def measure(card: str, method: str) -> dict:
    from jaxapf.bench.engine import environment

    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        env = {**os.environ, "XDG_CACHE_HOME": str(tmp / "cache")}  # an empty compilation cache
        command = [sys.executable, "-m", "jaxapf", "scorecard", "--card", card, "--method", method, "--name",
                   f"{method}_timed", "--quiet"]
        cold = _timed(command + ["--out", str(tmp / "cold")], env)
        warm = _timed(command + ["--out", str(tmp / "warm")], env)
        board = (tmp / "cold" / "leaderboard.csv").read_text()
    return {"card": card, "method": method, "cold_s": cold, "warm_s": warm, "compile_s": cold - warm,
            "leaderboard_rows": board.count("\n") - 1, "environment": environment("float32"),
            "date": datetime.date.today().isoformat()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--card", default="v1", help="a shipped scorecard's version or a folder (default v1)")
    p.add_argument("--method", default="basic", help="the method scored under another name (default basic)")
    p.add_argument("--json", type=pathlib.Path, help="write the record here")
    args = p.parse_args(argv)
    found = measure(args.card, args.method)
    print(f"scorecard {args.card}, {args.method}: {found['cold_s']:.1f} s from an empty cache, "
          f"{found['warm_s']:.1f} s warm")
    if args.json:
        args.json.write_text(json.dumps({"runs": [found]}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
