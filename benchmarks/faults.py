"""Fault injection on ``jaxapf sweep``: kill -9 at random moments, bit flips in parts, racing writers.

    python benchmarks/faults.py [--kills 100] [--flips 60] [--races 10] [--seed 0] [--json]

Every trial runs the real command (``python -m jaxapf sweep``) on a small sweep (2 families × 2
settings × 16 fields, parts of 1–4 fields) and checks the output against a reference made once
in this process:

- **kill -9**: a run is killed after a random delay (0 to 1.2 run times; some die while
  importing, some while writing a part); the output is read back after every kill, and each time
  it is complete a new output begins. Resumes use a random ``--chunk-fields``, so chunks are re-cut.
- **bit flips**: one random bit of one random part is flipped; reading must refuse (naming the
  part) or return exactly the reference rows, and a resume must refuse too (or find nothing wrong).
- **races**: two writers start on one fresh output within 0–0.5 s of each other with different
  chunk sizes; one must refuse with one line (or find the work done), and the output must be the
  reference.

It prints, per fault kind, what was survived: rows lost, rows duplicated, numbers changed
silently, tracebacks seen. All must be zero; the exit status is 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import signal
import subprocess
import sys
import tempfile
import time
from typing import Any

import numpy as np
import pandas as pd

SPEC_TOML = """name = "faults"
[scenario]
families = ["trap", "crossing"]
fields = 16
seed = 11
[sim]
t_max = 3.0
horizon = 4
iters = 4
[grid]
k_rep = [5.0, 10.0]
"""
KEY = ["setting", "family", "field"]


def _command(spec: pathlib.Path, out: pathlib.Path, chunk: int) -> list[str]:
    return [sys.executable, "-m", "jaxapf", "sweep", str(spec), "--out", str(out), "--quiet",
            "--chunk-fields", str(chunk)]


def _check(out: pathlib.Path, ref: pd.DataFrame) -> dict[str, int]:
    """Rows of ``out`` against the reference: duplicated, changed; and whether it is complete."""
    from jaxapf.sweep import read_sweep
    from jaxapf.validation import ConfigError

    if not out.exists() or not any(p.suffix == ".parquet" for p in out.iterdir()):
        return {"rows": 0, "duplicated": 0, "changed": 0, "refused": 0}
    try:
        df, _ = read_sweep(out)
    except ConfigError:
        return {"rows": 0, "duplicated": 0, "changed": 0, "refused": 1}
    duplicated = int(df.duplicated(KEY).sum())
    merged = df.drop_duplicates(KEY).merge(ref, on=KEY, suffixes=("", "_ref"))
    changed = 0
    for column in ref.columns:
        if column in KEY:
            continue
        a, b = merged[column].to_numpy(), merged[column + "_ref"].to_numpy()
        same = (a == b) | (pd.isna(a) & pd.isna(b)) if a.dtype.kind in "fc" else a == b
        changed += int((~np.asarray(same, bool)).sum())
    return {"rows": len(df), "duplicated": duplicated, "changed": changed, "refused": 0}


def _traceback(stderr: str) -> int:
    return int("Traceback" in stderr)


def kills(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref: pd.DataFrame, rng: np.random.Generator,
          run_s: float) -> dict[str, Any]:
    """``n`` kill -9 at random moments, resuming the same output until it is complete."""
    totals = {"trials": n, "outputs": 0, "lost": 0, "duplicated": 0, "changed": 0, "refused": 0, "tracebacks": 0}
    out = None
    for i in range(n):
        if out is None:
            out = tmp / f"kill-{i}.parquet"
            totals["outputs"] += 1
        proc = subprocess.Popen(_command(spec, out, int(rng.integers(1, 5))), stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
        time.sleep(float(rng.uniform(0.0, 1.2 * run_s)))
        proc.send_signal(signal.SIGKILL)
        _, err = proc.communicate()
        totals["tracebacks"] += _traceback(err) if proc.returncode not in (-signal.SIGKILL,) else 0
        state = _check(out, ref)
        for k in ("duplicated", "changed", "refused"):
            totals[k] += state[k]
        if state["rows"] == len(ref):
            out = None  # complete: the next kills start a new output
    if out is not None:  # finish the last output and check it whole
        done = subprocess.run(_command(spec, out, 3), capture_output=True, text=True)
        totals["tracebacks"] += _traceback(done.stderr)
    for o in tmp.glob("kill-*.parquet"):
        if _check(o, ref)["rows"] < len(ref):
            subprocess.run(_command(spec, o, 3), capture_output=True, text=True)
        state = _check(o, ref)
        totals["lost"] += len(ref) - (state["rows"] - state["duplicated"])
        totals["duplicated"] += state["duplicated"]
        totals["changed"] += state["changed"]
        totals["refused"] += state["refused"]
    return totals


def flips(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref_out: pathlib.Path, ref: pd.DataFrame,
          rng: np.random.Generator) -> dict[str, Any]:
    """``n`` single-bit flips, each in a fresh copy of the reference output."""
    from jaxapf.sweep.output import part_files

    totals = {"trials": n, "refused": 0, "harmless": 0, "resume_refused": 0, "lost": 0, "duplicated": 0,
              "changed": 0, "tracebacks": 0}
    for i in range(n):
        out = tmp / f"flip-{i}.parquet"
        out.mkdir()
        for p in ref_out.iterdir():
            (out / p.name).write_bytes(p.read_bytes())
        parts = part_files(out)
        victim = parts[int(rng.integers(len(parts)))]
        data = bytearray(victim.read_bytes())
        data[int(rng.integers(len(data)))] ^= 1 << int(rng.integers(8))
        victim.write_bytes(bytes(data))
        state = _check(out, ref)
        if state["refused"]:
            totals["refused"] += 1
        else:
            totals["harmless"] += 1
            totals["changed"] += state["changed"]
            totals["duplicated"] += state["duplicated"]
            totals["lost"] += len(ref) - state["rows"]
        dry = subprocess.run(_command(spec, out, 4) + ["--dry-run"], capture_output=True, text=True)
        totals["tracebacks"] += _traceback(dry.stderr)
        totals["resume_refused"] += int(dry.returncode == 2 and victim.name in dry.stderr)
        if state["refused"] and dry.returncode != 2:
            totals["changed"] += 1  # a resume that would trust a part that reading refuses
        for p in out.iterdir():
            p.unlink()
        out.rmdir()
    return totals


def races(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref: pd.DataFrame, rng: np.random.Generator
          ) -> dict[str, Any]:
    """``n`` pairs of writers on one fresh output each."""
    totals = {"trials": n, "one_refused": 0, "both_ran": 0, "lost": 0, "duplicated": 0, "changed": 0,
              "tracebacks": 0, "bad_refusals": 0}
    for i in range(n):
        out = tmp / f"race-{i}.parquet"
        a = subprocess.Popen(_command(spec, out, 2), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        time.sleep(float(rng.uniform(0.0, 0.5)))
        b = subprocess.Popen(_command(spec, out, 3), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        results = [(p.wait(), p.stderr.read()) for p in (a, b)]
        codes = sorted(rc for rc, _ in results)
        totals["tracebacks"] += sum(_traceback(err) for _, err in results)
        if codes == [0, 2]:
            refusal = next(err for rc, err in results if rc == 2)
            totals["one_refused"] += 1
            totals["bad_refusals"] += int(len(refusal.strip().splitlines()) != 1 or "being written by" not in refusal)
        elif codes == [0, 0]:
            totals["both_ran"] += 1  # the second started after the first had finished
        else:
            totals["bad_refusals"] += 1
        state = _check(out, ref)
        totals["lost"] += len(ref) - (state["rows"] - state["duplicated"])
        totals["duplicated"] += state["duplicated"]
        totals["changed"] += state["changed"] + state["refused"]
    return totals


def run_faults(kills_n: int = 100, flips_n: int = 60, races_n: int = 10, seed: int = 0) -> dict[str, Any]:
    from jaxapf.sweep import read_sweep

    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as name:
        tmp = pathlib.Path(name)
        spec = tmp / "faults.toml"
        spec.write_text(SPEC_TOML)
        ref_out = tmp / "reference.parquet"
        subprocess.run(_command(spec, ref_out, 4), check=True, capture_output=True)  # warms the compile cache
        ref, _ = read_sweep(ref_out)
        start = time.perf_counter()  # one whole run, start-up included, at the finest chunking
        subprocess.run(_command(spec, tmp / "timing.parquet", 1), check=True, capture_output=True)
        run_s = time.perf_counter() - start
        result = {"rows": len(ref), "run_s": run_s,
                  "kill -9": kills(kills_n, spec, tmp, ref, rng, run_s),
                  "bit flip": flips(flips_n, spec, tmp, ref_out, ref, rng),
                  "race": races(races_n, spec, tmp, ref, rng)}
    return result


def format_faults(result: dict[str, Any]) -> str:
    lines = [f"fault injection on jaxapf sweep ({result['rows']} rows per output; one run {result['run_s']:.1f} s)",
             f"{'fault':<9} {'trials':>6} {'lost':>5} {'dup':>5} {'silent':>6} {'tracebacks':>10}  details"]
    for kind in ("kill -9", "bit flip", "race"):
        r = result[kind]
        details = {"kill -9": f"{r.get('outputs', 0)} outputs, each resumed to completion; {r.get('refused', 0)} reads "
                              "refused a damaged part",
                   "bit flip": f"{r.get('refused', 0)} refused, {r.get('harmless', 0)} harmless; resume refused "
                               f"{r.get('resume_refused', 0)}",
                   "race": f"{r.get('one_refused', 0)} second writers refused, {r.get('both_ran', 0)} ran after the "
                           f"first finished, {r.get('bad_refusals', 0)} bad refusals"}[kind]
        lines.append(f"{kind:<9} {r['trials']:>6} {r['lost']:>5} {r['duplicated']:>5} {r['changed']:>6} "
                     f"{r['tracebacks']:>10}  {details}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=100)
    parser.add_argument("--flips", type=int, default=60)
    parser.add_argument("--races", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args(argv)
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    result = run_faults(args.kills, args.flips, args.races, args.seed)
    print(json.dumps(result, indent=2) if args.json else format_faults(result))
    bad = sum(result[k][m] for k in ("kill -9", "bit flip", "race") for m in ("lost", "duplicated", "changed",
                                                                              "tracebacks"))
    bad += result["race"]["bad_refusals"]
    return int(bad > 0)


if __name__ == "__main__":
    sys.exit(main())
