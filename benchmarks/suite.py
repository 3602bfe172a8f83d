"""The test suite's cost, as the README and docs/testing.md state it: a tier of the suite run from a fresh clone
of a commit as `.ci/run` runs it (the README's test command: an empty compilation cache, the suite's own per
run), its wall time, outcome, number of tests, the peak memory of the whole process tree (pytest, its workers
and the programs they start, sampled every 0.2 s) and its profile: the 20 slowest tests and the share of the
tests' time spent tracing, lowering and compiling JAX programs in the pytest processes and running the
programs they start.

    python benchmarks/suite.py --tier fast --against 360a044 --json benchmarks/results/suite-fast.json
    python benchmarks/suite.py --tier all --against 360a044 --json benchmarks/results/suite-all.json
    python benchmarks/suite.py --tier fast --xla-flags=--xla_cpu_max_isa=SSE4_2 --json ...suite-fast-sse42.json
    python benchmarks/suite.py --tier fast --cores 1 --json benchmarks/results/suite-fast-1-core.json

``--rev`` is the commit measured (default HEAD: commit a change before measuring it); ``--against REV`` runs
REV's suite first in the same invocation, so the two wall times are one run's ratio. ``--xla-flags`` runs
the suite with XLA:CPU code generation for another CPU (docs/testing.md); ``--cores 1`` pins it to one core
in one process (``-n 0``): other thread partitions.
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

ROOT = pathlib.Path(__file__).resolve().parents[1]
TIERS = {"fast": ["-m", "not slow"], "all": []}
#: How many of the slowest tests a record names.
SLOWEST = 20


def _tree_rss_kib(pid: int) -> int:
    """Resident memory of ``pid`` and all its descendants (Linux /proc), in KiB."""
    parents, rss = {}, {}
    for status in pathlib.Path("/proc").glob("[0-9]*/status"):
        try:
            fields = dict(line.split(":", 1) for line in status.read_text().splitlines() if ":" in line)
        except OSError:  # the process ended while being read
            continue
        p = int(status.parent.name)
        parents[p] = int(fields["PPid"])
        rss[p] = int(fields.get("VmRSS", "0 kB").split()[0])
    tree, grew = {pid}, True
    while grew:
        new = {p for p, parent in parents.items() if parent in tree} - tree
        tree |= new
        grew = bool(new)
    return sum(rss.get(p, 0) for p in tree)


def clone(rev: str, into: pathlib.Path) -> str:
    """A fresh clone of this repository at ``rev`` in ``into``; the commit's full hash."""
    subprocess.run(["git", "clone", "-q", "--no-checkout", str(ROOT), str(into)], check=True)
    subprocess.run(["git", "-C", str(into), "checkout", "-q", rev], check=True)
    return subprocess.run(["git", "-C", str(into), "rev-parse", "HEAD"], check=True, capture_output=True,
                          text=True).stdout.strip()


def collected(tree: pathlib.Path, tier: str, env: dict) -> int:
    """How many tests ``pytest --collect-only`` finds in ``tree`` for ``tier``."""
    out = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", "-n", "0",
                          *TIERS[tier]], cwd=tree, env=env, capture_output=True, text=True).stdout
    return sum(1 for line in out.splitlines() if "::" in line)


def profile(folder: pathlib.Path) -> dict | None:
    """The 20 slowest tests and the time shares of the per-test lines the suite's conftest wrote (None where
    the measured commit writes none)."""
    rows = [json.loads(line) for path in sorted(folder.glob("*.jsonl")) for line in path.read_text().splitlines()]
    if not rows:
        return None
    total = sum(r["wall_s"] for r in rows)
    jax_s = sum(r["trace_s"] + r["lower_s"] + r["compile_s"] for r in rows)
    sub_s = sum(max(r["subprocess_cpu_s"], 0.0) for r in rows)
    slow = sorted(rows, key=lambda r: -r["wall_s"])[:SLOWEST]
    return {"tests_s": round(total, 1), "trace_lower_compile_s": round(jax_s, 1),
            "compile_share": round(jax_s / total, 3), "subprocess_cpu_s": round(sub_s, 1),
            "subprocess_share": round(sub_s / total, 3),
            "slowest": [{"test": r["test"], "s": round(r["wall_s"], 1),
                         "compile_s": round(r["trace_s"] + r["lower_s"] + r["compile_s"], 1),
                         "subprocess_cpu_s": round(max(r["subprocess_cpu_s"], 0.0), 1)} for r in slow]}


def measure(rev: str, tier: str, xla_flags: str = "", cores: int | None = None,
            log: pathlib.Path | None = None) -> dict:
    """Run ``tier`` of a fresh clone of ``rev``; what it took (pytest's output also to ``log``)."""
    with tempfile.TemporaryDirectory(prefix="jaxapf-suite-") as scratch:
        tree, prof = pathlib.Path(scratch) / "jaxapf", pathlib.Path(scratch) / "profile"
        prof.mkdir()
        commit = clone(rev, tree)
        # the clone's own code first on every path a test's program may import from, a fresh user cache
        env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAXAPF_TESTS_XLA")}
        env |= {"PYTHONPATH": str(tree), "XDG_CACHE_HOME": str(pathlib.Path(scratch) / "cache"),
                "JAXAPF_SUITE_PROFILE": str(prof)} | ({"XLA_FLAGS": xla_flags} if xla_flags else {})
        command = [sys.executable, "-m", "pytest", "-q", "-rfE", "-p", "no:cacheprovider", *TIERS[tier]]
        if cores is not None:
            command += ["-n", "0"] if cores == 1 else ["-n", str(cores)]
        count = collected(tree, tier, env)
        start = time.perf_counter()
        with tempfile.TemporaryFile("w+") as out:
            proc = subprocess.Popen(command, cwd=tree, stdout=out, stderr=subprocess.STDOUT, text=True, env=env,
                                    preexec_fn=None if cores is None else lambda: os.sched_setaffinity(
                                        0, sorted(os.sched_getaffinity(0))[:cores]))
            peak_kib = 0
            while proc.poll() is None:
                peak_kib = max(peak_kib, _tree_rss_kib(proc.pid))
                time.sleep(0.2)
            seconds = time.perf_counter() - start
            out.seek(0)
            stdout = out.read()
        if log is not None:
            log.write_text(stdout)
        shares = profile(prof)
    outcome = next((line.strip("= ") for line in reversed(stdout.splitlines()) if " in " in line), "")
    ran = sum(int(n) for n, what in re.findall(r"(\d+) (passed|failed|skipped|errors?|xfailed|xpassed)", outcome)
              if what != "deselected")
    failed = [line.split()[1] for line in stdout.splitlines() if line.startswith(("FAILED ", "ERROR "))]
    return {"rev": commit, "returncode": proc.returncode, "outcome": outcome, "failed": failed,
            "tests": count, "ran": ran, "wall_min": round(seconds / 60, 1), "wall_s": round(seconds, 1),
            "peak_memory_gb": round(peak_kib / 2**20, 1), **({"profile": shares} if shares else {})}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tier", choices=sorted(TIERS), default="fast")
    p.add_argument("--rev", default="HEAD", help="the commit to measure (default HEAD)")
    p.add_argument("--against", help="also measure this commit's suite first, in the same run (a ratio)")
    p.add_argument("--xla-flags", default="", help="XLA_FLAGS for the suite (e.g. --xla_cpu_max_isa=AVX2)")
    p.add_argument("--cores", type=int, help="pin the suite to this many cores (1: one process, -n 0)")
    p.add_argument("--json", type=pathlib.Path, help="also write the result to this file")
    p.add_argument("--log", type=pathlib.Path, help="write pytest's output to this file (REV's to FILE.against)")
    args = p.parse_args(argv)
    options = ((f" --against {args.against}" if args.against else "")
               + (f" --xla-flags={args.xla_flags}" if args.xla_flags else "")
               + (f" --cores {args.cores}" if args.cores else ""))
    result = {"command": f"python benchmarks/suite.py --tier {args.tier}{options}",
              "date": datetime.date.today().isoformat(), "tier": args.tier, "pytest": TIERS[args.tier],
              "xla_flags": args.xla_flags, "cpu_count": args.cores or len(os.sched_getaffinity(0)),
              "compilation_cache": "empty (a fresh clone: the suite makes its own per run)"}
    if args.against:
        result["against"] = measure(args.against, args.tier, args.xla_flags, args.cores,
                                    args.log and args.log.with_name(args.log.name + ".against"))
    result |= measure(args.rev, args.tier, args.xla_flags, args.cores, args.log)
    if args.against:
        result["speedup"] = round(result["against"]["wall_s"] / result["wall_s"], 2)
    print(f"{args.tier} at {result['rev'][:7]}: {result['outcome']}; {result['wall_min']} min, "
          f"{result['tests']} tests, peak {result['peak_memory_gb']} GB"
          + (f"; {result['against']['rev'][:7]}: {result['against']['wall_min']} min, {result['speedup']}x"
             if args.against else "") + "".join(f"\nfailed: {name}" for name in result["failed"]))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1, ensure_ascii=False) + "\n")
    return result["returncode"]


if __name__ == "__main__":
    sys.exit(main())
