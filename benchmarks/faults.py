"""Fault injection on ``jaxapf sweep``: kill -9 and Ctrl-C at random moments, bit flips in parts and
their footers, racing writers and shards, a full disk, a port that is not Ray.

    python benchmarks/faults.py [--kills 100] [--flips 60] [--races 10] [--shard-races 20] [--sigints 50]
                                [--footer-flips 300] [--disks 6] [--seed 0] [--json]

Every trial runs the real command (``python -m jaxapf sweep``, or the installed ``jaxapf`` script) on a
small sweep (2 families × 2 settings × 16 fields, parts of 1–4 fields) and checks the output against a
reference made once in this process:

- **kill -9**: a run is killed after a random delay (0 to 1.2 run times; some die while
  importing, some while writing a part); the output is read back after every kill, and each time
  it is complete a new output begins. Resumes use a random ``--chunk-fields``, so chunks are re-cut.
- **Ctrl-C**: SIGINT at a random moment in 0–8 s of a longer sweep (16 times the fields), alternately
  to the script and to ``python -m jaxapf``; each run must end with one line and status 130 (or
  finish before the signal, status 0 and a complete output), never a traceback; the output is
  resumed until complete and then compared.
- **bit flips**: one random bit of one random part is flipped; reading must refuse (naming the
  part) or return exactly the reference rows, and a resume must refuse too (or find nothing wrong).
- **footer flips**: the same, with the bit in a part's footer (its schema, column names, statistics).
- **races**: two writers start on one fresh output within 0–0.5 s of each other with different
  chunk sizes; one must refuse with one line (or find the work done), and the output must be the
  reference.
- **shard races**: two shards started at the same moment on one fresh output with a different
  ``--chunk-fields`` or a different N; one must refuse in one line before any work; then each
  shard of the winner's division runs, and the output must be the reference.
- **full disk**: the output on a tmpfs with 8 KiB to 200 KiB left (``mount -t tmpfs``; skipped where
  this process may not mount); the run must refuse before any work or stop in one line keeping its
  finished parts; with room made, the rerun must complete it to the reference.
- **not Ray**: ``--ray HOST:PORT`` at a port that accepts and stays silent, and at one that answers
  HTTP: one line, status 2, within the probe's timeout.

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
          rng: np.random.Generator, footer: bool = False, resume_every: int = 1) -> dict[str, Any]:
    """``n`` single-bit flips, each in a random part of a copy of the reference output (restored after it):
    anywhere in the file, or with ``footer`` in its footer (schema, column names, statistics); every
    ``resume_every``-th trial a resume's dry run must refuse what reading refuses."""
    import shutil
    import struct

    from jaxapf.sweep.output import part_files

    totals = {"trials": n, "refused": 0, "harmless": 0, "resume_refused": 0, "lost": 0, "duplicated": 0,
              "changed": 0, "tracebacks": 0}
    out = tmp / ("footer-flips.parquet" if footer else "flips.parquet")
    shutil.copytree(ref_out, out)
    parts = part_files(out)
    for i in range(n):
        victim = parts[int(rng.integers(len(parts)))]
        original = victim.read_bytes()
        data = bytearray(original)
        span = struct.unpack("<I", original[-8:-4])[0] + 8 if footer else len(data)
        data[len(data) - span + int(rng.integers(span))] ^= 1 << int(rng.integers(8))
        victim.write_bytes(bytes(data))
        try:
            state = _check(out, ref)
        except Exception:  # noqa: BLE001 - what this trial counts: reading must never raise
            totals["tracebacks"] += 1
            state = {"refused": 1}
        if state["refused"]:
            totals["refused"] += 1
        else:
            totals["harmless"] += 1
            totals["changed"] += state["changed"]
            totals["duplicated"] += state["duplicated"]
            totals["lost"] += len(ref) - state["rows"]
        if i % resume_every == 0:
            dry = subprocess.run(_command(spec, out, 4) + ["--dry-run"], capture_output=True, text=True)
            totals["tracebacks"] += _traceback(dry.stderr)
            totals["resume_refused"] += int(dry.returncode == 2 and victim.name in dry.stderr)
            if state["refused"] and dry.returncode != 2:
                totals["changed"] += 1  # a resume that would trust a part that reading refuses
        victim.write_bytes(original)
    return totals


def _race_totals(n: int) -> dict[str, int]:
    """The counters of a kind of race over ``n`` trials."""
    return {"trials": n, "one_refused": 0, "both_ran": 0, "lost": 0, "duplicated": 0, "changed": 0, "tracebacks": 0,
            "bad_refusals": 0}


def races(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref: pd.DataFrame, rng: np.random.Generator
          ) -> dict[str, Any]:
    """``n`` pairs of writers on one fresh output each."""
    totals = _race_totals(n)
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


SIGINT_FIELDS = 768  # the Ctrl-C trials' sweep: fields per family (a run longer than the 8 s a signal may wait)


def program(kind: str) -> list[str]:
    """The program as a user starts it: the installed ``jaxapf`` script, or ``python -m jaxapf``."""
    script = pathlib.Path(sys.executable).parent / "jaxapf"
    return [str(script)] if kind == "script" and script.is_file() else [sys.executable, "-m", "jaxapf"]


def _lines(stderr: str) -> list[str]:
    """What a run wrote to stderr besides how far it had got (jaxapf.progress)."""
    from jaxapf.progress import without_progress

    return [line for line in without_progress(stderr).splitlines() if line.strip()]


def startup_s() -> float:
    """The longest of five starts of this interpreter doing nothing (its ``site`` and ``.pth`` files)."""
    times = []
    for _ in range(5):
        begin = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], check=True)
        times.append(time.perf_counter() - begin)
    return max(times)


def sigints(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref: pd.DataFrame, rng: np.random.Generator
            ) -> dict[str, Any]:
    """``n`` SIGINTs at random moments in 0–8 s, resuming one output until it is complete, then the next."""
    totals = {"trials": n, "outputs": 0, "stopped": 0, "finished": 0, "interpreter": 0, "not_one_line": 0,
              "exit_0_interrupted": 0, "lost": 0, "duplicated": 0, "changed": 0, "refused": 0, "tracebacks": 0}
    startup = 2 * startup_s() + 0.02
    cache = tmp / "sigint-cache"
    out = None

    def command(out):
        return ["sweep", str(spec), "--out", str(out), "--quiet", "--chunk-fields", "2", "--cache-dir", str(cache)]
    for i in range(n):
        if out is None:
            out = tmp / f"sigint-{i}.parquet"
            totals["outputs"] += 1
        moment = float(rng.uniform(0.0, 8.0))
        proc = subprocess.Popen(program("script" if i % 2 else "module") + command(out), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        time.sleep(moment)
        proc.send_signal(signal.SIGINT)
        stdout, err = proc.communicate()
        lines = _lines(err)
        if proc.returncode == 0 and not lines:
            totals["finished"] += 1  # it ended before the signal came
            out = None
            continue
        if proc.returncode == 130 and len(lines) == 1 and "interrupted; " in lines[0]:
            totals["stopped"] += 1
        elif moment < startup and proc.returncode != 0:
            totals["interpreter"] += 1  # the interpreter itself was starting: Python's own
        else:
            totals["tracebacks"] += _traceback(err)
            totals["not_one_line"] += int(len(lines) != 1)
            totals["exit_0_interrupted"] += int(proc.returncode == 0)
    for o in tmp.glob("sigint-*.parquet"):
        done = subprocess.run(program("module") + command(o), capture_output=True, text=True)
        totals["tracebacks"] += _traceback(done.stderr)
        state = _check(o, ref)
        totals["lost"] += len(ref) - (state["rows"] - state["duplicated"])
        for k in ("duplicated", "changed", "refused"):
            totals[k] += state[k]
    return totals


def shard_races(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref: pd.DataFrame, rng: np.random.Generator
                ) -> dict[str, Any]:
    """``n`` pairs of disagreeing shards started at the same moment on one fresh output each."""
    totals = _race_totals(n)
    for i in range(n):
        out = tmp / f"shards-{i}.parquet"
        if i % 2:  # another number of shards
            a, b = (int(x) for x in rng.choice([2, 3, 4], 2, replace=False))
            tasks = [(f"0/{a}", 2), (f"1/{b}", 2)]
        else:  # another chunking
            a, b = (int(x) for x in rng.choice([1, 2, 3, 4], 2, replace=False))
            tasks = [("0/2", a), ("1/2", b)]
        procs = [subprocess.Popen(_command(spec, out, chunk) + ["--shard", shard], stdout=subprocess.DEVNULL,
                                  stderr=subprocess.PIPE, text=True) for shard, chunk in tasks]
        results = [(p.wait(), p.stderr.read()) for p in procs]
        totals["tracebacks"] += sum(_traceback(err) for _, err in results)
        codes = sorted(rc for rc, _ in results)
        if codes == [0, 2]:
            totals["one_refused"] += 1
            refusal = next(err for rc, err in results if rc == 2)
            totals["bad_refusals"] += int(len(_lines(refusal)) != 1 or "is divided into" not in refusal)
            winner = tasks[[rc for rc, _ in results].index(0)]
        else:
            totals["both_ran"] += int(codes == [0, 0])
            totals["bad_refusals"] += int(codes != [0, 0])
            winner = tasks[0]
        count = int(winner[0].split("/")[1])
        for k in range(count):  # every shard of the winner's division, then the whole output is checked
            done = subprocess.run(_command(spec, out, winner[1]) + ["--shard", f"{k}/{count}"], capture_output=True,
                                  text=True)
            totals["tracebacks"] += _traceback(done.stderr)
        state = _check(out, ref)
        totals["lost"] += len(ref) - (state["rows"] - state["duplicated"])
        totals["duplicated"] += state["duplicated"]
        totals["changed"] += state["changed"] + state["refused"]
    return totals


def full_disks(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref: pd.DataFrame, rng: np.random.Generator
               ) -> dict[str, Any]:
    """``n`` runs onto a tmpfs with 8 KiB to 200 KiB left; then room is made and the run resumed."""
    totals = {"trials": n, "refused_before_work": 0, "stopped_keeping_parts": 0, "finished": 0, "lost": 0,
              "duplicated": 0, "changed": 0, "tracebacks": 0, "not_one_line": 0, "skipped": 0}
    mnt = tmp / "disk"
    mnt.mkdir()
    for i in range(n):
        size = 1024 * 1024
        if subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)],
                          capture_output=True).returncode != 0:
            totals["skipped"] = n - i  # this process may not mount
            break
        try:
            left = int([8, 40, 120, 200][i % 4] * 1024)
            stat = os.statvfs(mnt)
            (mnt / "fill").write_bytes(b"\0" * (stat.f_bavail * stat.f_frsize - left))
            out = mnt / "out.parquet"
            run = subprocess.run(_command(spec, out, 1), capture_output=True, text=True)
            lines = _lines(run.stderr)
            totals["tracebacks"] += _traceback(run.stderr)
            if run.returncode == 0:
                totals["finished"] += 1
            elif run.returncode == 2 and len(lines) == 1 and "cannot be written" in lines[0] and "--out" in lines[0]:
                totals["refused_before_work"] += int(not out.exists() or not any(out.glob("part-*")))
            elif run.returncode == 2 and len(lines) == 1 and "finished part(s) are kept" in lines[0]:
                totals["stopped_keeping_parts"] += 1
            else:
                totals["not_one_line"] += 1
            (mnt / "fill").unlink()  # room made: the rerun completes it
            done = subprocess.run(_command(spec, out, 1), capture_output=True, text=True)
            totals["tracebacks"] += _traceback(done.stderr)
            state = _check(out, ref)
            totals["lost"] += len(ref) - (state["rows"] - state["duplicated"])
            totals["duplicated"] += state["duplicated"]
            totals["changed"] += state["changed"] + state["refused"]
        finally:
            subprocess.run(["umount", str(mnt)], capture_output=True)
    return totals


def not_ray(spec: pathlib.Path, tmp: pathlib.Path) -> dict[str, Any]:
    """``--ray`` at a port that accepts and stays silent, and at one that answers HTTP."""
    import socket
    import threading

    totals = {"trials": 2, "refused": 0, "hangs": 0, "tracebacks": 0, "seconds": []}
    held = []

    def serve(listener, http):
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            if http:
                conn.recv(64)
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
                conn.close()
            else:
                held.append(conn)
    for http in (False, True):
        listener = socket.create_server(("127.0.0.1", 0))
        threading.Thread(target=serve, args=(listener, http), daemon=True).start()
        begin = time.perf_counter()
        try:
            run = subprocess.run(_command(spec, tmp / "ray.parquet", 2) + [
                "--ray", f"127.0.0.1:{listener.getsockname()[1]}"], capture_output=True, text=True, timeout=120)
            totals["tracebacks"] += _traceback(run.stderr)
            totals["refused"] += int(run.returncode == 2 and len(_lines(run.stderr)) == 1
                                     and "not as a Ray cluster does" in run.stderr)
        except subprocess.TimeoutExpired:
            totals["hangs"] += 1
        finally:
            listener.close()
        totals["seconds"].append(round(time.perf_counter() - begin, 1))
    return totals


def run_faults(kills_n: int = 100, flips_n: int = 60, races_n: int = 10, shard_races_n: int = 20,
               sigints_n: int = 50, footer_flips_n: int = 300, disks_n: int = 8, seed: int = 0) -> dict[str, Any]:
    from jaxapf.sweep import read_sweep

    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as name:
        tmp = pathlib.Path(name)
        spec = tmp / "faults.toml"
        spec.write_text(SPEC_TOML)
        long_spec = tmp / "sigint.toml"
        long_spec.write_text(SPEC_TOML.replace("fields = 16", f"fields = {SIGINT_FIELDS}"))
        ref_out = tmp / "reference.parquet"
        subprocess.run(_command(spec, ref_out, 4), check=True, capture_output=True)  # warms the compile cache
        ref, _ = read_sweep(ref_out)
        long_ref_out = tmp / "long-reference.parquet"
        subprocess.run(_command(long_spec, long_ref_out, 16), check=True, capture_output=True)
        long_ref, _ = read_sweep(long_ref_out)
        start = time.perf_counter()  # one whole run, start-up included, at the finest chunking
        subprocess.run(_command(spec, tmp / "timing.parquet", 1), check=True, capture_output=True)
        run_s = time.perf_counter() - start
        result = {"rows": len(ref), "run_s": run_s, "sigint_rows": len(long_ref),
                  "kill -9": kills(kills_n, spec, tmp, ref, rng, run_s),
                  "Ctrl-C": sigints(sigints_n, long_spec, tmp, long_ref, rng),
                  "bit flip": flips(flips_n, spec, tmp, ref_out, ref, rng),
                  "footer flip": flips(footer_flips_n, spec, tmp, ref_out, ref, rng, footer=True, resume_every=10),
                  "race": races(races_n, spec, tmp, ref, rng),
                  "shard race": shard_races(shard_races_n, spec, tmp, ref, rng),
                  "full disk": full_disks(disks_n, spec, tmp, ref, rng),
                  "not Ray": not_ray(spec, tmp)}
    return result


KINDS = ("kill -9", "Ctrl-C", "bit flip", "footer flip", "race", "shard race", "full disk", "not Ray")


def _details(kind: str, r: dict[str, Any]) -> str:
    return {
        "kill -9": f"{r.get('outputs', 0)} outputs, each resumed to completion; {r.get('refused', 0)} reads refused a "
                   "damaged part",
        "Ctrl-C": f"{r.get('stopped', 0)} stopped in one line (status 130), {r.get('finished', 0)} finished first, "
                  f"{r.get('interpreter', 0)} in the interpreter's own start; {r.get('outputs', 0)} outputs resumed "
                  "to completion",
        "bit flip": f"{r.get('refused', 0)} refused, {r.get('harmless', 0)} harmless; resume refused "
                    f"{r.get('resume_refused', 0)}",
        "footer flip": f"{r.get('refused', 0)} refused naming the part, {r.get('harmless', 0)} harmless",
        "race": f"{r.get('one_refused', 0)} second writers refused, {r.get('both_ran', 0)} ran after the first "
                f"finished, {r.get('bad_refusals', 0)} bad refusals",
        "shard race": f"{r.get('one_refused', 0)} of the pair refused in one line before any work, "
                      f"{r.get('bad_refusals', 0)} bad refusals",
        "full disk": (f"{r.get('refused_before_work', 0)} refused before any work, "
                      f"{r.get('stopped_keeping_parts', 0)} stopped keeping their parts, {r.get('finished', 0)} "
                      "finished; each rerun with room completed" if not r.get("skipped") else
                      f"{r['skipped']} skipped (this process may not mount a tmpfs)"),
        "not Ray": f"{r.get('refused', 0)} refused in one line, {r.get('hangs', 0)} hangs, in "
                   f"{', '.join(f'{x:g}' for x in r.get('seconds', []))} s",
    }[kind]


def format_faults(result: dict[str, Any]) -> str:
    lines = [f"fault injection on jaxapf sweep ({result['rows']} rows per output, {result['sigint_rows']} for Ctrl-C; "
             f"one run {result['run_s']:.1f} s)",
             f"{'fault':<11} {'trials':>6} {'lost':>5} {'dup':>5} {'silent':>6} {'tracebacks':>10}  details"]
    for kind in KINDS:
        r = result[kind]
        lines.append(f"{kind:<11} {r['trials']:>6} {r.get('lost', 0):>5} {r.get('duplicated', 0):>5} "
                     f"{r.get('changed', 0):>6} {r['tracebacks']:>10}  {_details(kind, r)}")
    return "\n".join(lines)


def failures(result: dict[str, Any]) -> int:
    """Everything that must be zero: rows lost, doubled or changed, tracebacks, bad refusals, hangs."""
    bad = sum(result[k].get(m, 0) for k in KINDS for m in ("lost", "duplicated", "changed", "tracebacks",
                                                            "bad_refusals", "not_one_line", "exit_0_interrupted",
                                                            "hangs"))
    return bad + (result["not Ray"]["trials"] - result["not Ray"]["refused"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=100)
    parser.add_argument("--flips", type=int, default=60)
    parser.add_argument("--races", type=int, default=10)
    parser.add_argument("--shard-races", type=int, default=20)
    parser.add_argument("--sigints", type=int, default=50)
    parser.add_argument("--footer-flips", type=int, default=300)
    parser.add_argument("--disks", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args(argv)
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    result = run_faults(args.kills, args.flips, args.races, args.shard_races, args.sigints, args.footer_flips,
                        args.disks, args.seed)
    print(json.dumps(result, indent=2) if args.json else format_faults(result))
    return int(failures(result) > 0)


if __name__ == "__main__":
    sys.exit(main())
