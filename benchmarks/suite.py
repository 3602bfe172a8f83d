"""The test suite's cost, as docs/testing.md states it: wall time, outcome line and the peak memory
of the whole process tree (pytest, its workers and the programs they start, sampled every 0.2 s),
for a tier of the suite.

    python benchmarks/suite.py --tier fast --json benchmarks/results/suite-fast.json
    python benchmarks/suite.py --tier all --json benchmarks/results/suite-all.json
    python benchmarks/suite.py --tier all --xla-flags=--xla_cpu_max_isa=AVX2 \
        --json benchmarks/results/suite-all-avx2.json
    python benchmarks/suite.py --tier fast --cores 1 --json benchmarks/results/suite-fast-1-core.json

``--xla-flags`` runs the suite with XLA:CPU code generation for another CPU (docs/testing.md);
``--cores 1`` pins it to one core in one process (``-n 0``): other thread partitions; ``--cold`` gives the
commands the tests run an empty compilation cache (a fresh clone on a fresh machine), where by default
they find the user's cache as an earlier run left it.
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
TIERS = {"fast": ["-m", "not slow"], "all": []}


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


def measure(tier: str, xla_flags: str = "", cores: int | None = None, cold: bool = False) -> dict:
    command = [sys.executable, "-m", "pytest", "-q", "-rfE", "-p", "no:cacheprovider", *TIERS[tier]]
    if cores is not None:
        command += ["-n", "0"] if cores == 1 else ["-n", str(cores)]
    env = os.environ | ({"XLA_FLAGS": xla_flags} if xla_flags else {})
    start = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryDirectory() as fresh:
        if cold:  # the commands the tests run compile into an empty cache, as on a fresh machine
            env |= {"XDG_CACHE_HOME": fresh}
        proc = subprocess.Popen(command, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, text=True, env=env,
                                preexec_fn=None if cores is None else lambda: os.sched_setaffinity(
                                    0, sorted(os.sched_getaffinity(0))[:cores]))
        peak_kib = 0
        while proc.poll() is None:
            peak_kib = max(peak_kib, _tree_rss_kib(proc.pid))
            time.sleep(0.2)
        seconds = time.perf_counter() - start
        out.seek(0)
        stdout = out.read()
    outcome = next((line.strip("= ") for line in reversed(stdout.splitlines()) if " in " in line), "")
    failed = [line.split()[1] for line in stdout.splitlines() if line.startswith(("FAILED ", "ERROR "))]
    options = ((f" --xla-flags={xla_flags}" if xla_flags else "") + (f" --cores {cores}" if cores else "")
               + (" --cold" if cold else ""))
    return {"command": f"python benchmarks/suite.py --tier {tier}{options}", "date": datetime.date.today().isoformat(),
            "pytest": command[1:], "xla_flags": xla_flags,
            "cpu_count": cores or len(os.sched_getaffinity(0)), "returncode": proc.returncode,
            "outcome": outcome, "failed": failed, "wall_min": round(seconds / 60, 1),
            "peak_memory_gb": round(peak_kib / 2**20, 1),
            "compilation_cache": "empty" if cold else "as found (warm after an earlier run)"}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tier", choices=sorted(TIERS), default="fast")
    p.add_argument("--xla-flags", default="", help="XLA_FLAGS for the suite (e.g. --xla_cpu_max_isa=AVX2)")
    p.add_argument("--cores", type=int, help="pin the suite to this many cores (1: one process, -n 0)")
    p.add_argument("--cold", action="store_true",
                   help="an empty compilation cache for the commands the tests run (a fresh machine's)")
    p.add_argument("--json", type=pathlib.Path, help="also write the result to this file")
    args = p.parse_args(argv)
    result = measure(args.tier, args.xla_flags, args.cores, args.cold)
    print(f"{args.tier}: {result['outcome']}; {result['wall_min']} min, peak {result['peak_memory_gb']} GB"
          + "".join(f"\nfailed: {name}" for name in result["failed"]))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return result["returncode"]


if __name__ == "__main__":
    sys.exit(main())
