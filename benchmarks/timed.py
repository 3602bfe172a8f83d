"""One jaxapf command's wall time in a fresh process with an empty compilation cache, as a newcomer meets it.

    python benchmarks/timed.py -- compare sweeps/compare-quick.toml

The command runs as ``python -m jaxapf ARGS --out TMP`` (a temporary folder for what it writes) with
``XDG_CACHE_HOME`` pointing to an empty folder; prints one JSON object: the command, its exit status, its
wall time and the versions it ran with.
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
from typing import Callable

ROOT = pathlib.Path(__file__).resolve().parents[1]


def measure(args: list[str], read: Callable[[pathlib.Path], dict] | None = None) -> dict:
    """The record of ``jaxapf ARGS --out TMP`` run cold; ``read``: what else to record of what it wrote in TMP."""
    from jaxapf.bench.engine import environment

    with tempfile.TemporaryDirectory() as tmp:
        out = pathlib.Path(tmp) / "out"
        command = [sys.executable, "-m", "jaxapf", *args, "--out", str(out)]
        start = time.perf_counter()
        env = os.environ | {"XDG_CACHE_HOME": str(pathlib.Path(tmp) / "cache")}  # an empty compilation cache
        proc = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
        seconds = time.perf_counter() - start
        if proc.returncode != 0:
            sys.exit(f"timed.py: jaxapf {' '.join(args)} failed: {proc.stderr.strip().splitlines()[-1:]}")
        found = read(out) if read is not None else {}
    return {"command": "jaxapf " + " ".join(args), "date": datetime.date.today().isoformat(),
            "cold_s": round(seconds, 1), "compilation_cache": "empty", "environment": environment("float32"),
            **found}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("args", nargs=argparse.REMAINDER, help="the jaxapf command and its arguments (after --)")
    args = p.parse_args(argv)
    command = args.args[1:] if args.args[:1] == ["--"] else args.args
    if not command:
        p.error("give a jaxapf command after --, e.g. -- compare sweeps/compare-quick.toml")
    print(json.dumps(measure(command), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
