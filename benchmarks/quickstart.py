"""The README's quick start, timed as a new user meets it: its sweep and report with an empty
compilation cache, then the report again with the cache warm (``--repeats`` times, the figure the
docs quote being each run's wall time). The commands are read from README.md's quick-start block,
so what is timed is what a user types (outputs go to a temporary folder instead). The sweep runs
once more with the cache warm: the difference to the cold run is what compiling cost it. Then
``jaxapf tune sweeps/tune-tiny.toml`` with an empty cache (the smoke test its comment times).

    python benchmarks/quickstart.py --json benchmarks/results/quickstart.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import re
import shlex
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]


def quickstart_commands(readme: str) -> tuple[list[str], list[str]]:
    """The sweep and report commands of README.md's quick-start block (the install step left out)."""
    block = re.search(r"## Quick start\n.*?```bash\n(.*?)\n```", readme, re.S).group(1)
    steps = [shlex.split(step) for step in block.split("&&")]
    sweep = next(s for s in steps if s[:2] == ["jaxapf", "sweep"])
    report = next(s for s in steps if s[:2] == ["jaxapf", "report"])
    return sweep, report


def _with_out(command: list[str], out: pathlib.Path, dataset: pathlib.Path | None = None) -> list[str]:
    """``command`` writing to ``out`` (and reading ``dataset`` instead of its own input)."""
    command = list(command)
    command[command.index("--out") + 1] = str(out)
    if dataset is not None:
        command[2] = str(dataset)
    return command


def _timed(command: list[str], env: dict[str, str]) -> float:
    start = time.perf_counter()
    proc = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if proc.returncode != 0:
        sys.exit(f"quickstart.py: {' '.join(command)} failed: {proc.stderr.strip().splitlines()[-1:]}")
    return seconds


def measure(repeats: int) -> dict:
    from jaxapf.bench.engine import environment

    sweep, report = quickstart_commands((ROOT / "README.md").read_text())
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        env = os.environ | {"XDG_CACHE_HOME": str(tmp / "cache")}  # an empty compilation cache
        dataset = tmp / "compare-small.parquet"
        sweep_cold = _timed(_with_out(sweep, dataset), env)
        report_cold = _timed(_with_out(report, tmp / "report-cold", dataset), env)
        report_warm = [_timed(_with_out(report, tmp / f"report-{i}", dataset), env) for i in range(repeats)]
        figures = sorted(p.name for p in (tmp / "report-cold" / "figures").iterdir())
        sweep_warm = _timed(_with_out(sweep, tmp / "compare-small-warm.parquet"), env)
        fresh = os.environ | {"XDG_CACHE_HOME": str(tmp / "cache-tune")}
        tune_cold = _timed(["jaxapf", "tune", "sweeps/tune-tiny.toml", "--out", str(tmp / "tune-tiny")], fresh)
    return {"command": "python benchmarks/quickstart.py", "date": datetime.date.today().isoformat(),
            "sweep": sweep, "report": report, "environment": environment("float32"),
            "sweep_cold_s": round(sweep_cold, 1), "sweep_warm_s": round(sweep_warm, 1),
            "sweep_compile_s": round(sweep_cold - sweep_warm, 1), "tune_tiny_cold_s": round(tune_cold, 1),
            "report_cold_s": round(report_cold, 1),
            "report_warm_s": [round(s, 1) for s in report_warm], "figures": figures}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3, help="warm report runs (default 3)")
    p.add_argument("--json", type=pathlib.Path, help="also write the result to this file")
    args = p.parse_args(argv)
    result = measure(args.repeats)
    print(f"sweep (empty compilation cache) {result['sweep_cold_s']} s, warm {result['sweep_warm_s']} s; report "
          f"{result['report_cold_s']} s; report warm {', '.join(f'{s} s' for s in result['report_warm_s'])}; "
          f"tune-tiny (empty cache) {result['tune_tiny_cold_s']} s")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
