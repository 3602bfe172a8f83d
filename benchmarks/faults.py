"""Fault injection on ``jaxapf``: kill -9 and Ctrl-C at random moments, bit flips in parts and their
footers, racing writers and shards, a full disk, a port that is not Ray; and a folder from someone else:
names planted in it, part metadata edited, a report's process killed or hung up, two reports into one
folder, mutated specs; and names jaxapf reads: planted, swapped under a running command, forged.

    python benchmarks/faults.py [--kills 100] [--flips 60] [--races 10] [--shard-races 20] [--sigints 50]
                                [--footer-flips 300] [--disks 8] [--planted 40] [--edits 35] [--deaths 10]
                                [--reports 6] [--fuzz 300] [--reads 24] [--swaps 12] [--forged 24] [--versions 8]
                                [--notes 7] [--only CLASS ...] [--seed 0] [--json]

Every trial runs the real command (``python -m jaxapf sweep``, or the installed ``jaxapf`` script) on a
small sweep (2 families × 2 settings × 16 fields, parts of 1–4 fields) and checks the output against a
reference made once in this process:

- **kill -9**: a run is killed after a random delay (0 to 1.2 run times; some die while
  importing, some while writing a part); the output is read back after every kill, and each time
  it is complete a new output begins. Resumes use a random ``--chunk-fields``, so chunks are re-cut.
- **Ctrl-C**: SIGINT at a random moment in 0–8 s of a longer sweep (16 times the fields), alternately
  to the script and to ``python -m jaxapf``; each run must end with one line and status 130 (or
  finish before the signal, status 0 and a complete output), never a traceback, except a signal
  before jaxapf's hook is in place, while the interpreter itself starts (Python's own: :func:`interpreters_own`);
  the output is resumed until complete and then compared.
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

- **planted name**: ``jaxapf sweep`` (whole, ``--repair``, and a shard), ``sweep merge`` and ``report``
  run on a folder where one name they open (a lock, the probe, a temporary file with the run's own pid,
  the division record, a part, ``.set-aside``, ``report.md``, ``figures``) is a link to a file or folder
  outside, a hard link, a FIFO or a folder: no file outside may change, and a refusal is one line naming it.
- **metadata edit**: one part edited as a hand with pyarrow would, its content hash recomputed (a
  ``pandas`` key swapping two columns, a column retyped, added or dropped, a ``jaxapf`` key removed or
  retyped), or a stray Parquet file of changed rows beside the parts: ``jaxapf sweep verify`` and the
  reader must agree, and no changed number may be read as sound.
- **parent death**: a report with a gallery (a second process draws) killed with ``kill -9`` or hung up
  at a random moment in 0–6 s: none of its processes may live 5 s later.
- **two reports**: two reports of different datasets into one ``--out`` started 0–1 s apart: one is
  refused in one line (or runs after the other), and the folder holds one report whole.
- **spec fuzz**: the shipped specs mutated (a value replaced by one a user can mistype or a file can
  hold, or a key removed) and given to the command line's parsing: one line, status 2, or accepted.
- **planted read**: a name a command *reads* made a FIFO, a link to ``/dev/zero`` or a link to a file
  outside: a part handed to ``sweep verify``, ``report``, ``sweep merge`` or a resume, ``jaxapf tune``'s
  checkpoint, a ``jaxapf compare`` selection: one line naming it (or the record ignored and the command run),
  no hang, nothing written past twice the reference's size.
- **swapped part**: a part of the folder handed to ``sweep merge`` or ``report`` renamed over by a FIFO or a
  link to ``/dev/zero`` at a random moment in the command's first 4 s: the same, and a merge that finishes
  holds the reference's rows.
- **forged spec**: every part's stored spec edited (settings reversed, families swapped, seed, horizon,
  fields or name changed) with its ``spec_hash`` kept and the content hash resealed: verify, report, merge
  and resume refuse in one line naming a part.
- **mixed versions**: half the parts resealed as another jaxapf version: the same four refuse in one line.
- **owner note**: a lock held by another process whose note has a start no calendar shows (1e20, NaN, inf,
  -1), a pid no kernel holds, or escape sequences in its host or command: one line, nothing raw printed.

It prints, per fault kind, what was survived: rows lost, rows duplicated, numbers changed
silently, tracebacks seen. All must be zero; the exit status is 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import re
import signal
import subprocess
import sys
import tempfile
import time
from typing import Any, Sequence

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
ROOT = pathlib.Path(__file__).resolve().parents[1]


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


def _pair(procs: list[subprocess.Popen], totals: dict[str, int], says: str) -> int | None:
    """Wait for two racing processes and count how the race ended: one refused in one line saying ``says``
    (``one_refused``; a refusal otherwise worded is a bad one), or both ran, the second after the first
    had finished (``both_ran``); anything else is a bad refusal. The index of the process whose output
    stands (the one that ran; of two, the second), or None."""
    results = [(p.wait(), p.stderr.read()) for p in procs]
    totals["tracebacks"] += sum(_traceback(err) for _, err in results)
    codes = [rc for rc, _ in results]
    if sorted(codes) == [0, 2]:
        totals["one_refused"] += 1
        refusal = results[codes.index(2)][1]
        totals["bad_refusals"] += int(len(_lines(refusal)) != 1 or says not in refusal)
        return codes.index(0)
    if codes == [0, 0]:
        totals["both_ran"] += 1
        return 1
    totals["bad_refusals"] += 1
    return None


def races(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref: pd.DataFrame, rng: np.random.Generator
          ) -> dict[str, Any]:
    """``n`` pairs of writers on one fresh output each."""
    totals = _race_totals(n)
    for i in range(n):
        out = tmp / f"race-{i}.parquet"
        a = subprocess.Popen(_command(spec, out, 2), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        time.sleep(float(rng.uniform(0.0, 0.5)))
        b = subprocess.Popen(_command(spec, out, 3), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        _pair([a, b], totals, "being written by")
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


def _errors(stderr: str) -> list[str]:
    """The lines of :func:`_lines` that are not the command line's warnings (a value allowed but outside
    what the paper claims, said before the refusal of another)."""
    return [line for line in _lines(stderr) if ": warning: " not in line]


def startup_s() -> float:
    """The longest of five starts of this interpreter doing nothing (its ``site`` and ``.pth`` files)."""
    times = []
    for _ in range(5):
        begin = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], check=True)
        times.append(time.perf_counter() - begin)
    return max(times)


def _pythons_own(path: str) -> bool:
    """Whether a traceback's file is the interpreter's own: frozen, or its standard library."""
    import sysconfig

    stdlib = sysconfig.get_paths()["stdlib"]
    return path.startswith("<frozen ") or (path.startswith(stdlib) and "site-packages" not in path)


def ignored_by_python(stderr: str) -> bool:
    """Whether ``stderr`` is only CPython's report of an interrupt it ignored: a ``KeyboardInterrupt`` raised
    inside a callback of the interpreter's own while it starts (an import lock's weakref callback;
    python/cpython#95959), every frame Python's own. Python then runs the command on to its end."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    files = re.findall(r'^\s*File "([^"]+)"', stderr, flags=re.M)
    return (len(lines) >= 2 and lines[0].startswith("Exception ignored in: ") and stderr.count("Exception ignored") == 1
            and lines[-1].strip().rstrip(":") == "KeyboardInterrupt" and all(_pythons_own(f) for f in files))


def hooked(pid: int) -> bool | None:
    """Whether jaxapf's signal hook is in place in the process ``pid``: ``jaxapf.cli.program`` installs it for
    SIGINT, then SIGTERM, and CPython leaves SIGTERM alone, so a caught SIGTERM (its ``SigCgt`` mask in /proc)
    is the hook. None where /proc cannot tell (no /proc, or the process has ended)."""
    try:
        status = pathlib.Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    caught = re.search(r"^SigCgt:\s*([0-9a-fA-F]+)", status, flags=re.M)
    return None if caught is None else bool(int(caught.group(1), 16) >> (signal.SIGTERM - 1) & 1)


def interrupt(proc: subprocess.Popen) -> bool | None:
    """Send SIGINT to ``proc``; returns :func:`hooked` as read just before (the hook is never removed, so in
    place then means in place when the signal came)."""
    hook = hooked(proc.pid)
    proc.send_signal(signal.SIGINT)
    return hook


def interpreters_own(hook: bool | None, moment: float, startup: float, returncode: int, stderr: str) -> bool:
    """Whether what a SIGINT did is CPython's own, the signal having come before jaxapf's hook was in place:
    with ``hook`` read by :func:`hooked` just before sending it, whenever it was not (CPython then ended the
    process, printed a traceback, or lost the interrupt in one of its own callbacks and ran the command to its
    end, python/cpython#95959); where /proc cannot tell, a signal ``moment`` s after the start within
    ``startup`` (or Python's own fatal error in ``site``) that ended the process or that Python reported
    ignored (:func:`ignored_by_python`)."""
    if hook is not None:
        return not hook
    starting = moment < startup or "Fatal Python error: init_import_site" in stderr
    return starting and (returncode != 0 or ignored_by_python(stderr))


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
        hook = interrupt(proc)
        stdout, err = proc.communicate()
        lines = _lines(err)
        if proc.returncode == 0 and not lines:
            totals["finished"] += 1  # it ended before the signal came
            out = None
            continue
        if proc.returncode == 130 and len(lines) == 1 and "interrupted; " in lines[0]:
            totals["stopped"] += 1
        elif interpreters_own(hook, moment, startup, proc.returncode, err):
            totals["interpreter"] += 1  # the interpreter itself was starting: Python's own
            if proc.returncode == 0:  # Python lost it: the command ran to its end
                out = None
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
        both = totals["both_ran"]
        stands = _pair(procs, totals, "is divided into")
        winner = tasks[0 if stands is None or totals["both_ran"] > both else stands]
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


# --- a folder from someone else: planted names, edited metadata; processes and reports ----------------------

#: Names each command opens in its folder, and the command (``{spec}``, ``{ref}``, ``{out}`` filled in).
PLANTED = {
    "sweep": ([".lock", ".lock-division", ".write-test-{pid}", ".{part}.tmp-{pid}", "..division.json.tmp-{pid}",
               "{part}", ".set-aside"],
              ["sweep", "{spec}", "--out", "{out}", "--quiet", "--chunk-fields", "4", "--repair"]),
    "sweep shard": ([".lock", ".lock-shard-0000-of-0002", ".lock-division", "..division.json.tmp-{pid}",
                     ".division.json"],
                    ["sweep", "{spec}", "--out", "{out}", "--quiet", "--chunk-fields", "4", "--shard", "0/2"]),
    "merge": ([".lock", ".{part}.tmp-{pid}", "{part}"], ["sweep", "merge", "{ref}", "--out", "{out}"]),
    "report": ([".lock", ".write-test-{pid}", "report.md", ".report.html.tmp-{pid}", "figures", "summary.csv"],
               ["report", "{ref}", "--out", "{out}", "--baseline", "setting=0", "--gallery", "0",
                "--resamples", "200"]),
}
PLANT_KINDS = ("symlink", "dir-symlink", "hardlink", "fifo", "folder")


def _snapshot(folder: pathlib.Path) -> dict[str, str]:
    import hashlib

    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(folder.rglob("*"))}


def _plant(path: pathlib.Path, how: str, victim: pathlib.Path) -> None:
    if how == "symlink":
        os.symlink(victim, path)
    elif how == "dir-symlink":
        os.symlink(victim.parent, path)
    elif how == "hardlink":
        os.link(victim, path)
    elif how == "fifo":
        os.mkfifo(path)
    else:
        path.mkdir()


def planted(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref_out: pathlib.Path, rng: np.random.Generator
            ) -> dict[str, Any]:
    """``n`` commands run on a folder holding a planted name (a link to a file outside, a link to a
    folder outside, a hard link, a FIFO, a folder) where the command opens one: nothing outside may change,
    and a refusal is one line naming it. The real programs, with a known pid so ``-PID`` names can be planted:
    each command starts as ``python -c`` that execs jaxapf in its own process."""
    import shutil

    totals = {"trials": n, "written_outside": 0, "refused": 0, "ran": 0, "not_one_line": 0, "tracebacks": 0}
    part = sorted(p.name for p in ref_out.iterdir() if p.name.startswith("part-"))[0]
    for i in range(n):
        command = list(PLANTED)[i % len(PLANTED)]
        names, argv = PLANTED[command]
        name_t, how = names[int(rng.integers(len(names)))], PLANT_KINDS[int(rng.integers(len(PLANT_KINDS)))]
        place = tmp / f"planted-{i}"
        outside, out = place / "outside", place / "received"
        outside.mkdir(parents=True)
        victim = outside / "victim.txt"
        victim.write_text("the victim's own words\n")
        if command.startswith("sweep"):
            shutil.copytree(ref_out, out)
        else:
            out.mkdir()
        # the child's pid is known before it runs jaxapf: it waits for a line, then execs the program
        proc = subprocess.Popen([sys.executable, "-c", "import os, sys; sys.stdin.readline(); "
                                 "os.execv(sys.executable, [sys.executable, '-m', 'jaxapf', *sys.argv[1:]])",
                                 *[a.format(spec=spec, ref=ref_out, out=out) for a in argv]],
                                stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        name = name_t.format(pid=proc.pid, part=part)
        (out / name).unlink(missing_ok=True) if (out / name).is_file() and not (out / name).is_symlink() else None
        _plant(out / name, how, victim)
        before = _snapshot(outside)
        proc.stdin.write("go\n")
        proc.stdin.close()
        err = proc.stderr.read()
        rc = proc.wait()
        totals["written_outside"] += int(_snapshot(outside) != before)
        totals["tracebacks"] += _traceback(err)
        bad = False
        if rc == 2:
            totals["refused"] += 1
            bad = len(_errors(err)) != 1 or name.split("/")[-1] not in err
        elif rc == 0:
            totals["ran"] += 1  # e.g. a hard link replaced by the new file, the other name untouched
        else:
            bad = True
        totals["not_one_line"] += int(bad)
        if bad:
            totals.setdefault("examples", []).append(f"{command} {name} as {how}: status {rc}: {err.strip()[-300:]}")
        shutil.rmtree(place, ignore_errors=True)
    return totals


def metadata_edits(n: int, tmp: pathlib.Path, ref_out: pathlib.Path, ref: pd.DataFrame, rng: np.random.Generator
                   ) -> dict[str, Any]:
    """``n`` datasets with one part's metadata or columns edited the way a hand with pyarrow would (the
    content hash recomputed): a ``pandas`` key swapping two columns, a column retyped, one added or
    dropped, a ``jaxapf`` key removed or retyped, a stray Parquet file of changed rows beside the parts.
    ``jaxapf sweep verify`` and the reader must agree, and no changed number may be read as sound."""
    import json as _json
    import shutil

    import pyarrow as pa
    import pyarrow.parquet as pq

    from jaxapf.sweep import read_sweep
    from jaxapf.sweep.meta import META_KEY
    from jaxapf.validation import ConfigError

    edits = ("pandas swap", "retype", "add column", "drop column", "meta key removed", "meta key retyped", "stray")
    totals = {"trials": n, "unchecked": 0, "disagree": 0, "refused": 0, "read": 0, "tracebacks": 0,
              **{f"edit {e}": 0 for e in edits}}
    for i in range(n):
        out = tmp / f"edit-{i}"
        shutil.copytree(ref_out, out)
        parts = sorted(out.glob("part-*.parquet"))
        part = parts[int(rng.integers(len(parts)))]
        table = pq.read_table(part)
        edit = edits[i % len(edits)]
        totals[f"edit {edit}"] += 1
        names = [f.name for f in table.schema]
        metric = ["min_clearance", "path_length", "success", "time_to_goal"][int(rng.integers(4))]
        if edit == "pandas swap":
            pandas = _json.loads(pa.Table.from_pandas(table.to_pandas()).schema.metadata[b"pandas"])
            for col in pandas["columns"]:
                col["name"] = {"min_clearance": "path_length", "path_length": "min_clearance"}.get(col["name"],
                                                                                                  col["name"])
            _rewrite(part, table.replace_schema_metadata({**table.schema.metadata,
                                                         b"pandas": _json.dumps(pandas).encode()}), rehash=False)
        elif edit == "retype":
            target = pa.string() if table.schema.field(metric).type == pa.bool_() else pa.float64()
            _rewrite(part, table.set_column(names.index(metric), pa.field(metric, target),
                                           table.column(metric).cast(target)))
        elif edit == "add column":
            _rewrite(part, table.append_column("bonus", pa.array(np.ones(table.num_rows))))
        elif edit == "drop column":
            _rewrite(part, table.drop_columns([metric]))
        elif edit.startswith("meta key"):
            meta = _json.loads(table.schema.metadata[META_KEY])
            key = list(meta)[int(rng.integers(len(meta)))]
            if edit == "meta key removed":
                meta.pop(key)
            else:
                meta[key] = [[], "x", 5, None, {"a": 1}][int(rng.integers(5))]
            _rewrite(part, table.replace_schema_metadata({**table.schema.metadata,
                                                         META_KEY: _json.dumps(meta).encode()}))
        else:
            changed = table.set_column(names.index("min_clearance"), "min_clearance",
                                       pa.array(np.full(table.num_rows, 99.0, np.float32)))
            pq.write_table(changed, out / "zz-notes.parquet")
        verify = subprocess.run([sys.executable, "-m", "jaxapf", "sweep", "verify", str(out)], capture_output=True,
                                text=True)
        totals["tracebacks"] += _traceback(verify.stderr)
        try:
            df, _ = read_sweep(out)
            read = True
        except ConfigError:
            read = False
        totals["read" if read else "refused"] += 1
        sound = verify.returncode == 0
        totals["disagree"] += int(sound != read)
        if read:
            state = _check(out, ref)
            totals["unchecked"] += int(state["changed"] > 0 or state["rows"] != len(ref))
        shutil.rmtree(out, ignore_errors=True)
    return totals


# --- names jaxapf reads: planted, swapped under a running command, crafted, of mixed versions --------------

#: What a hostile folder can hold where jaxapf reads a name.
READ_KINDS = ("fifo", "dev-zero", "link")
#: The commands that read a sweep's parts, ``{src}`` a folder handed over, ``{out}`` a fresh one.
READERS = {"verify": ["sweep", "verify", "{src}"],
           "report": ["report", "{src}", "--out", "{out}", "--baseline", "setting=0", "--gallery", "0",
                      "--resamples", "200"],
           "merge": ["sweep", "merge", "{src}", "--out", "{out}"],
           "resume": ["sweep", "{spec}", "--out", "{src}", "--quiet", "--chunk-fields", "4"]}
#: How long a command handed a hostile folder may take before it counts as hung [s].
HANG_S = 120.0


def _plant_read(path: pathlib.Path, how: str, outside: pathlib.Path) -> None:
    """``path`` made a FIFO, a link to ``/dev/zero`` or a link to the regular file ``outside``."""
    path.unlink(missing_ok=True)
    if how == "fifo":
        os.mkfifo(path)
    else:
        os.symlink("/dev/zero" if how == "dev-zero" else outside, path)


def _size(folder: pathlib.Path) -> int:
    """Bytes under ``folder`` (links not followed)."""
    return sum(p.lstat().st_size for p in folder.rglob("*")) if folder.exists() else 0


def _judge(totals: dict[str, Any], proc: subprocess.Popen, timeout: float, name: str | None, what: str,
           out: pathlib.Path | None = None, bound: int = 0) -> int | None:
    """Wait for ``proc`` and count how it ended: ``refused`` (status 2 in one line, naming ``name`` where
    given), ``ran`` (status 0), ``hangs`` (killed after ``timeout``), ``not_one_line``, ``tracebacks``,
    ``raw_escapes`` (an ESC or BEL byte reached its stderr), ``past_bound`` (``out`` grew past ``bound``
    bytes). Returns the status, None for a hang."""
    try:
        listing, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        totals["hangs"] += 1
        totals.setdefault("examples", []).append(f"{what}: hung")
        return None
    totals["tracebacks"] += _traceback(err)
    totals["raw_escapes"] += int("\x1b" in err or "\x07" in err)
    if out is not None:
        totals["past_bound"] += int(_size(out) > bound)
    if proc.returncode == 1 and "NOT complete and sound" in (listing or "") and not _errors(err):
        totals["refused"] += 1  # `sweep verify`'s own refusal: status 1, the parts listed with what to do
        return 1
    bad = proc.returncode not in (0, 2) or (proc.returncode == 2 and (
        len(_errors(err)) != 1 or (name is not None and name not in err)))
    totals["refused" if proc.returncode == 2 else "ran"] += int(proc.returncode in (0, 2))
    totals["not_one_line"] += int(bad)
    if bad:
        totals.setdefault("examples", []).append(f"{what}: status {proc.returncode}: {err.strip()[-300:]}")
    return proc.returncode


def _read_totals(n: int) -> dict[str, Any]:
    return {"trials": n, "refused": 0, "ran": 0, "hangs": 0, "not_one_line": 0, "tracebacks": 0, "raw_escapes": 0,
            "past_bound": 0, "accepted": 0, "changed": 0}


def _tune_and_compare(tmp: pathlib.Path) -> dict[str, tuple[list[str], str]]:
    """Commands that read records of their own from ``{out}`` (a fresh folder): ``jaxapf tune`` its
    checkpoint, ``jaxapf compare`` a selection; each with the record's name relative to ``{out}``."""
    return {"tune": (["tune", str(ROOT / "sweeps" / "tune-tiny.toml"), "--out", "{out}", "--quiet"], "checkpoint.npz"),
            "compare": (["compare", str(ROOT / "sweeps" / "compare-quick.toml"), "--out", "{out}", "--quiet"],
                        "selection/basic-seed1.json")}


def planted_reads(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref_out: pathlib.Path, rng: np.random.Generator
                  ) -> dict[str, Any]:
    """``n`` commands handed a folder where a name they read is a FIFO, a link to ``/dev/zero`` or a link to
    a file outside: a part (verify, report, merge, resume), tune's checkpoint, a compare selection. Each must
    refuse in one line naming it (or ignore it and run), never hang, and write nothing past a bound (the
    reference's size twice over)."""
    import shutil

    totals = _read_totals(n)
    parts = sorted(p.name for p in ref_out.iterdir() if p.name.startswith("part-"))
    others = _tune_and_compare(tmp)
    bound = 2 * _size(ref_out) + (1 << 20)
    for i in range(n):
        command = [*READERS, *others][i % (len(READERS) + len(others))]
        how = READ_KINDS[int(rng.integers(len(READ_KINDS)))]
        place = tmp / f"read-{i}"
        src, out = place / "handed", place / "out"
        place.mkdir()
        outside = place / "outside.parquet"
        shutil.copyfile(ref_out / parts[0], outside)
        if command in READERS:
            shutil.copytree(ref_out, src)
            name = parts[int(rng.integers(len(parts)))]
            _plant_read(src / name, how, outside)
            argv = [a.format(spec=spec, src=src, out=out) for a in READERS[command]]
            timeout = HANG_S
        else:
            argv_t, name = others[command]
            (out / name).parent.mkdir(parents=True)
            _plant_read(out / name, how, outside)
            argv, name = [a.format(out=out) for a in argv_t], name.split("/")[-1]
            timeout = 3 * HANG_S  # a record ignored: the command runs whole
        proc = subprocess.Popen(program("module") + argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        _judge(totals, proc, timeout, name, f"{command} {name} as {how}", out, bound)
        shutil.rmtree(place, ignore_errors=True)
    return totals


def swapped_under(n: int, tmp: pathlib.Path, ref_out: pathlib.Path, ref: pd.DataFrame, rng: np.random.Generator
                  ) -> dict[str, Any]:
    """``n`` merges and reports of a folder one of whose parts is swapped, at a random moment in the command's
    first 4 s, for a FIFO or a link to ``/dev/zero`` (renamed over it, as an attacker would): never a hang or a
    disk filled (the output within twice the reference's size), a refusal in one line, or a result whose rows
    are the reference's (merge)."""
    import shutil

    totals = _read_totals(n) | {"finished_first": 0, "read_before_swap": 0}
    bound = 2 * _size(ref_out) + (1 << 20)
    for i in range(n):
        command = ("merge", "report")[i % 2]
        how = ("fifo", "dev-zero")[int(rng.integers(2))]
        place = tmp / f"swap-{i}"
        src, out = place / "handed", place / "out"
        shutil.copytree(ref_out, src)
        parts = sorted(p for p in src.iterdir() if p.name.startswith("part-"))
        victim = parts[int(rng.integers(len(parts)))]
        argv = [a.format(src=src, out=out) for a in READERS[command]]
        proc = subprocess.Popen(program("module") + argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(float(rng.uniform(0.0, 4.0)))
        swap = place / "swap"
        _plant_read(swap, how, victim)
        alive = proc.poll() is None
        os.replace(swap, victim)
        rc = _judge(totals, proc, HANG_S, None, f"{command}, {victim.name} swapped for a {how}", out, bound)
        if rc == 0:  # ended before the swap, or had read the part whole before it
            totals["read_before_swap" if alive else "finished_first"] += 1
        if command == "merge" and rc == 0:
            state = _check(out, ref)
            totals["changed"] += int(state["changed"] > 0 or state["refused"] > 0 or state["duplicated"] > 0)
        shutil.rmtree(place, ignore_errors=True)
    return totals


def _rewrite(path: pathlib.Path, table, rehash: bool = True) -> None:
    """Write ``table`` over the part ``path``, its content hash recomputed as an editor with jaxapf's own code
    would (``rehash``), or the old record kept."""
    import json as _json

    import pyarrow.parquet as pq

    from jaxapf.sweep.output import PART_KEY, content_hash

    meta = dict(table.schema.metadata or {})
    if rehash:
        plain = table.replace_schema_metadata({k: v for k, v in meta.items() if k != PART_KEY})
        meta[PART_KEY] = _json.dumps({"sha256": content_hash(plain), "rows": table.num_rows}).encode()
    pq.write_table(table.replace_schema_metadata(meta), path, write_page_checksum=True)


def _reseal(part: pathlib.Path, edit) -> None:
    """``part``'s jaxapf metadata passed through ``edit`` (a function of the dict, in place), the part's
    content hash recomputed (:func:`_rewrite`), as someone who knows the format would forge it."""
    import json as _json

    import pyarrow.parquet as pq

    from jaxapf.sweep.meta import META_KEY

    table = pq.read_table(part)
    stored = _json.loads(table.schema.metadata[META_KEY])
    edit(stored)
    _rewrite(part, table.replace_schema_metadata({**table.schema.metadata, META_KEY: _json.dumps(stored).encode()}))


def _spec_forgeries() -> dict[str, Any]:
    """Edits of a stored spec that keep its ``spec_hash``: each names what it changes."""
    def swap_settings(spec):
        spec["grid"] = [[key, values[::-1]] for key, values in spec["grid"]]

    def set_(path, value):
        def edit(spec):
            node = spec
            for key in path[:-1]:
                node = node[key]
            node[path[-1]] = value
        return edit

    return {"grid reversed": swap_settings, "families swapped": set_(("scenario", "families"), ["crossing", "trap"]),
            "seed changed": set_(("scenario", "seed"), 12), "horizon changed": set_(("sim", "horizon"), 5),
            "fields changed": set_(("scenario", "fields"), 15), "name changed": set_(("name",), "other")}


def crafted_specs(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref_out: pathlib.Path) -> dict[str, Any]:
    """``n`` folders whose every part stores an edited spec with the ``spec_hash`` kept and the content hash
    resealed (:func:`_spec_forgeries`), handed to verify, report, merge and resume: each must refuse in one
    line; one that accepts the folder counts in ``accepted``."""
    import shutil

    totals = _read_totals(n)
    forgeries = _spec_forgeries()
    for i in range(n):
        command, forgery = list(READERS)[i % len(READERS)], list(forgeries)[(i // len(READERS)) % len(forgeries)]
        place = tmp / f"forged-{i}"
        src, out = place / "handed", place / "out"
        shutil.copytree(ref_out, src)
        for part in sorted(src.glob("part-*")):
            _reseal(part, lambda meta, f=forgeries[forgery]: f(meta["spec"]))
        argv = [a.format(spec=spec, src=src, out=out) for a in READERS[command]]
        proc = subprocess.Popen(program("module") + argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        rc = _judge(totals, proc, HANG_S, "part-", f"{command}, stored spec's {forgery}")
        totals["accepted"] += int(rc == 0)
        shutil.rmtree(place, ignore_errors=True)
    return totals


def mixed_versions(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref_out: pathlib.Path,
                   rng: np.random.Generator) -> dict[str, Any]:
    """``n`` folders where a random half of the parts (at least one, never all) record another jaxapf version,
    resealed, handed to verify, report, merge and resume: each must refuse in one line."""
    import shutil

    totals = _read_totals(n)
    for i in range(n):
        command = list(READERS)[i % len(READERS)]
        place = tmp / f"versions-{i}"
        src, out = place / "handed", place / "out"
        shutil.copytree(ref_out, src)
        parts = sorted(src.glob("part-*"))
        chosen = rng.choice(len(parts), size=max(1, len(parts) // 2), replace=False)
        for k in chosen:
            _reseal(parts[int(k)], lambda meta: meta["versions"].update(jaxapf="0.0.1"))
        argv = [a.format(spec=spec, src=src, out=out) for a in READERS[command]]
        proc = subprocess.Popen(program("module") + argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        rc = _judge(totals, proc, HANG_S, None, f"{command}, {len(chosen)} of {len(parts)} parts of 0.0.1")
        totals["accepted"] += int(rc == 0)
        shutil.rmtree(place, ignore_errors=True)
    return totals


#: Owner notes a hostile lock file can hold: times no calendar shows, escapes for the refused user's terminal.
NOTES = {"since 1e20": {"since": 1e20}, "since NaN": {"since": float("nan")}, "since inf": {"since": float("inf")},
         "since -1": {"since": -1.0}, "pid 2**40": {"pid": 2 ** 40},
         "host escapes": {"host": "\x1b[2J\x1b]0;owned\x07"}, "command escapes": {"command": "\x1b[31mrm -rf ~\x07"}}


def crafted_notes(n: int, spec: pathlib.Path, tmp: pathlib.Path) -> dict[str, Any]:
    """``n`` sweeps into a folder whose lock another process holds with a crafted owner note (:data:`NOTES`):
    each must refuse in one line, no traceback, no ESC or BEL byte printed raw."""
    import json as _json

    totals = _read_totals(n)
    for i in range(n):
        what = list(NOTES)[i % len(NOTES)]
        out = tmp / f"noted-{i}"
        out.mkdir()
        note = {"pid": 4242, "host": "elsewhere", "since": 1.7e9, "command": "jaxapf sweep", **NOTES[what]}
        (out / ".lock").write_text(_json.dumps(note))
        holder = subprocess.Popen([sys.executable, "-c", "import fcntl, sys, time; f = open(sys.argv[1], 'rb'); "
                                   "fcntl.flock(f, fcntl.LOCK_EX); print('held', flush=True); time.sleep(600)",
                                   str(out / ".lock")], stdout=subprocess.PIPE, text=True)
        holder.stdout.readline()
        try:
            proc = subprocess.Popen(program("module") + ["sweep", str(spec), "--out", str(out), "--quiet"],
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            rc = _judge(totals, proc, HANG_S, None, f"a lock noted with {what}")
            totals["accepted"] += int(rc == 0)
        finally:
            holder.kill()
            holder.wait()
    return totals


def _children(pid: int) -> set[int]:
    found = set()
    for entry in pathlib.Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    found.add(int(entry.name))
            except (OSError, IndexError, ValueError):
                continue
    return found


def _alive(pid: int) -> bool:
    try:
        return pathlib.Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def parent_deaths(n: int, tmp: pathlib.Path, ref_out: pathlib.Path, rng: np.random.Generator) -> dict[str, Any]:
    """``n`` reports (with a gallery, so a second process draws) killed with ``kill -9`` or hung up (SIGHUP)
    at a random moment while their worker runs: every process they started must be gone within 5 s."""
    totals = {"trials": n, "orphans": 0, "kill -9": 0, "SIGHUP": 0, "no_worker": 0, "tracebacks": 0}
    for i in range(n):
        signum = (signal.SIGKILL, signal.SIGHUP)[i % 2]
        totals["kill -9" if signum == signal.SIGKILL else "SIGHUP"] += 1
        report = subprocess.Popen([sys.executable, "-m", "jaxapf", "report", str(ref_out), "--out",
                                   str(tmp / f"orphan-{i}"), "--baseline", "setting=0", "--gallery", "4",
                                   "--resamples", "200"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                  start_new_session=True)
        children: set[int] = set()
        give_up = time.monotonic() + 60
        while not children and report.poll() is None and time.monotonic() < give_up:
            time.sleep(0.1)
            children = _children(report.pid)
        if not children:
            totals["no_worker"] += 1
            report.wait()
            continue
        time.sleep(float(rng.uniform(0.0, 6.0)))
        os.kill(report.pid, signum)
        report.wait()
        gone = time.monotonic() + 5.0
        while any(_alive(c) for c in children) and time.monotonic() < gone:
            time.sleep(0.05)
        left = [c for c in children if _alive(c)]
        totals["orphans"] += len(left)
        for c in left:
            os.kill(c, signal.SIGKILL)
    return totals


def concurrent_reports(n: int, spec: pathlib.Path, tmp: pathlib.Path, ref_out: pathlib.Path,
                       rng: np.random.Generator) -> dict[str, Any]:
    """``n`` pairs of reports of two different datasets into one ``--out``, started apart by a random
    moment: one must be refused in one line (or run after the other finished), and the folder must hold
    one report whole, its figures those of the dataset its page names."""
    import shutil

    other = tmp / "other-dataset"
    if not other.exists():
        other_spec = tmp / "other.toml"
        other_spec.write_text(spec.read_text().replace('name = "faults"', 'name = "other"'))
        subprocess.run(_command(other_spec, other, 4), check=True, capture_output=True)
    totals = {"trials": n, "one_refused": 0, "both_ran": 0, "mixed": 0, "bad_refusals": 0, "tracebacks": 0}
    for i in range(n):
        out = tmp / f"two-reports-{i}"
        procs = []
        for k, data in enumerate((ref_out, other)):
            procs.append(subprocess.Popen([sys.executable, "-m", "jaxapf", "report", str(data), "--out", str(out),
                                           "--baseline", "setting=0", "--gallery", "0", "--resamples", "200"],
                                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True))
            if k == 0:
                time.sleep(float(rng.uniform(0.0, 1.0)))
        stands = _pair(procs, totals, "being written by")
        if stands is None:
            continue
        winner = ("faults", "other")[stands]
        page = (out / "report.md").read_text()
        summary = pd.read_csv(out / "summary.csv")
        loser = "other" if winner == "faults" else "faults"
        totals["mixed"] += int(f"jaxapf report — {winner}" not in page or f"jaxapf report — {loser}" in page
                               or len(summary) == 0)
        shutil.rmtree(out, ignore_errors=True)
    return totals


def spec_fuzz(n: int, rng: np.random.Generator) -> dict[str, Any]:
    """``n`` mutations of the shipped specs (a value replaced by one a user can mistype or a file can hold,
    a key removed, an unknown key added), each given to ``jaxapf sweep|tune|compare SPEC --dry-run`` in
    this process (the command line's own code): refused in one line with status 2, or accepted; never a
    traceback."""
    import contextlib
    import copy
    import io
    import tomllib

    from jaxapf.cli import main

    root = pathlib.Path(__file__).resolve().parents[1]
    specs = sorted((root / "sweeps").glob("*.toml"))
    values = [0, -1, 5, 2**40, 1e30, -1e30, 1e-30, float("inf"), float("nan"), "", "x", "$x^{2", True, [],
              [[1], 10.0], [1, 2, 3], {}, {"a": 1}, {"length": 1e30}, ["trap", 3]]
    totals = {"trials": n, "refused": 0, "accepted": 0, "not_one_line": 0, "tracebacks": 0}
    with tempfile.TemporaryDirectory() as name:
        tmp = pathlib.Path(name)
        for i in range(n):
            path = specs[i % len(specs)]
            data = tomllib.loads(path.read_text())
            mutated = copy.deepcopy(data)
            paths, stack = [], [((), mutated)]
            while stack:
                at, node = stack.pop()
                items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
                for k, v in items:
                    paths.append((at + (k,), node))
                    stack.append((at + (k,), v))
            (at, parent) = paths[int(rng.integers(len(paths)))]
            if isinstance(parent, dict) and rng.random() < 0.2:
                del parent[at[-1]]
            else:
                parent[at[-1]] = copy.deepcopy(values[int(rng.integers(len(values)))])
            command = "compare" if "selection" in data else "tune" if "train" in data else "sweep"
            spec = tmp / f"fuzz-{i}.toml"
            spec.write_text(_toml(mutated))
            err = io.StringIO()
            try:
                if command != "sweep":  # parsing is what is fuzzed: stop before the selections or training run
                    from jaxapf.compare.spec import parse_compare_spec
                    from jaxapf.tune.spec import parse_tune_spec
                    from jaxapf.validation import ConfigError, read_toml_file
                    try:
                        parse = parse_compare_spec if command == "compare" else parse_tune_spec
                        parse(read_toml_file(spec)[0], base=path.parent)
                        totals["accepted"] += 1
                    except ConfigError as refusal:
                        totals["refused"] += 1
                        totals["not_one_line"] += int("\n" in str(refusal).strip())
                    continue
                with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
                    rc = main([command, str(spec), "--out", str(tmp / f"o{i}"), "--dry-run"])
                bad = rc != 0 and (rc != 2 or len(_errors(err.getvalue())) != 1)
                totals["refused" if rc == 2 else "accepted"] += int(rc in (0, 2))
                totals["not_one_line"] += int(bad)
                totals["tracebacks"] += _traceback(err.getvalue())
                if bad or _traceback(err.getvalue()):
                    totals.setdefault("examples", []).append(f"{path.name} {at}: status {rc}: "
                                                             f"{err.getvalue().strip()[-300:]}")
            except Exception as error:  # noqa: BLE001 -- what is counted
                totals["tracebacks"] += 1
                totals.setdefault("examples", []).append(f"{path.name} {at}: {type(error).__name__}: {error}")
    return totals


def _toml(data: dict, prefix: str = "") -> str:
    """A TOML text of ``data`` (tables, arrays, numbers, strings, booleans; inf and nan as TOML writes them)."""
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return "inf" if v == float("inf") else "-inf" if v == -float("inf") else "nan" if v != v else repr(v)
        if isinstance(v, int):
            return str(v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return "{" + ", ".join(f"{json.dumps(k)} = {value(x)}" for k, x in v.items()) + "}"
    plain = [f"{json.dumps(k)} = {value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    tables = [f"\n[{prefix}{json.dumps(k)}]\n" + _toml(v, f"{prefix}{json.dumps(k)}.")
              for k, v in data.items() if isinstance(v, dict)]
    return "\n".join(plain) + "\n" + "".join(tables)


def run_faults(kills_n: int = 100, flips_n: int = 60, races_n: int = 10, shard_races_n: int = 20,
               sigints_n: int = 50, footer_flips_n: int = 300, disks_n: int = 8, seed: int = 0,
               planted_n: int = 40, edits_n: int = 35, deaths_n: int = 10, reports_n: int = 6, fuzz_n: int = 300,
               only: Sequence[str] | None = None, reads_n: int = 24, swaps_n: int = 12, forged_n: int = 24,
               versions_n: int = 8, notes_n: int = 7) -> dict[str, Any]:
    """Every fault class of :data:`KINDS` (``only``: those named), on one reference output."""
    from jaxapf.sweep import read_sweep

    rng = np.random.default_rng(seed)
    only = set(only or KINDS)
    with tempfile.TemporaryDirectory() as name:
        tmp = pathlib.Path(name)
        spec = tmp / "faults.toml"
        spec.write_text(SPEC_TOML)
        long_spec = tmp / "sigint.toml"
        long_spec.write_text(SPEC_TOML.replace("fields = 16", f"fields = {SIGINT_FIELDS}"))
        ref_out = tmp / "reference.parquet"
        subprocess.run(_command(spec, ref_out, 4), check=True, capture_output=True)  # warms the compile cache
        ref, _ = read_sweep(ref_out)
        long_ref = ref.iloc[:0]
        if "Ctrl-C" in only:
            long_ref_out = tmp / "long-reference.parquet"
            subprocess.run(_command(long_spec, long_ref_out, 16), check=True, capture_output=True)
            long_ref, _ = read_sweep(long_ref_out)
        start = time.perf_counter()  # one whole run, start-up included, at the finest chunking
        subprocess.run(_command(spec, tmp / "timing.parquet", 1), check=True, capture_output=True)
        run_s = time.perf_counter() - start
        classes = {"kill -9": lambda: kills(kills_n, spec, tmp, ref, rng, run_s),
                   "Ctrl-C": lambda: sigints(sigints_n, long_spec, tmp, long_ref, rng),
                   "bit flip": lambda: flips(flips_n, spec, tmp, ref_out, ref, rng),
                   "footer flip": lambda: flips(footer_flips_n, spec, tmp, ref_out, ref, rng, footer=True,
                                                resume_every=10),
                   "race": lambda: races(races_n, spec, tmp, ref, rng),
                   "shard race": lambda: shard_races(shard_races_n, spec, tmp, ref, rng),
                   "full disk": lambda: full_disks(disks_n, spec, tmp, ref, rng),
                   "not Ray": lambda: not_ray(spec, tmp),
                   "planted name": lambda: planted(planted_n, spec, tmp, ref_out, rng),
                   "metadata edit": lambda: metadata_edits(edits_n, tmp, ref_out, ref, rng),
                   "parent death": lambda: parent_deaths(deaths_n, tmp, ref_out, rng),
                   "two reports": lambda: concurrent_reports(reports_n, spec, tmp, ref_out, rng),
                   "spec fuzz": lambda: spec_fuzz(fuzz_n, rng),
                   "planted read": lambda: planted_reads(reads_n, spec, tmp, ref_out, rng),
                   "swapped part": lambda: swapped_under(swaps_n, tmp, ref_out, ref, rng),
                   "forged spec": lambda: crafted_specs(forged_n, spec, tmp, ref_out),
                   "mixed versions": lambda: mixed_versions(versions_n, spec, tmp, ref_out, rng),
                   "owner note": lambda: crafted_notes(notes_n, spec, tmp)}
        result = {"rows": len(ref), "run_s": run_s, "sigint_rows": len(long_ref)}
        for kind in KINDS:
            if kind in only:
                begin = time.perf_counter()
                result[kind] = classes[kind]() | {"wall_s": time.perf_counter() - begin}
    return result


KINDS = ("kill -9", "Ctrl-C", "bit flip", "footer flip", "race", "shard race", "full disk", "not Ray", "planted name",
         "metadata edit", "parent death", "two reports", "spec fuzz", "planted read", "swapped part", "forged spec",
         "mixed versions", "owner note")


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
        "planted name": f"{r.get('refused', 0)} refused in one line naming it, {r.get('ran', 0)} ran (a hard link "
                        "replaced, never written through)",
        "metadata edit": f"{r.get('refused', 0)} refused by verify and the reader alike, {r.get('read', 0)} read "
                         f"unchanged; {r.get('disagree', 0)} disagreements",
        "parent death": f"{r.get('kill -9', 0)} kill -9, {r.get('SIGHUP', 0)} SIGHUP; {r.get('orphans', 0)} "
                        "processes outlived the report",
        "two reports": f"{r.get('one_refused', 0)} second reports refused in one line, {r.get('both_ran', 0)} ran "
                       f"after the first finished; {r.get('mixed', 0)} folders mixing the two",
        "spec fuzz": f"{r.get('refused', 0)} refused in one line, {r.get('accepted', 0)} accepted",
        "planted read": f"{r.get('refused', 0)} refused in one line naming it, {r.get('ran', 0)} ran past it; "
                        f"{r.get('hangs', 0)} hangs, {r.get('past_bound', 0)} outputs past their bound",
        "swapped part": f"{r.get('refused', 0)} refused in one line, {r.get('finished_first', 0)} ended before the "
                        f"swap, {r.get('read_before_swap', 0)} had read the part before it; {r.get('changed', 0)} "
                        f"merges with other rows than the reference's, {r.get('hangs', 0)} hangs",
        "forged spec": f"{r.get('refused', 0)} refused in one line naming a part, {r.get('accepted', 0)} accepted",
        "mixed versions": f"{r.get('refused', 0)} refused in one line, {r.get('accepted', 0)} accepted",
        "owner note": f"{r.get('refused', 0)} refused in one line, {r.get('raw_escapes', 0)} escapes printed raw, "
                      f"{r.get('accepted', 0)} ran",
    }[kind]


def format_faults(result: dict[str, Any]) -> str:
    lines = [f"fault injection on jaxapf ({result['rows']} rows per output, {result['sigint_rows']} for Ctrl-C; "
             f"one run {result['run_s']:.1f} s)",
             f"{'fault':<13} {'trials':>6} {'lost':>5} {'dup':>5} {'silent':>6} {'outside':>7} {'orphans':>7} "
             f"{'tracebacks':>10}  details"]
    for kind in KINDS:
        if kind not in result:
            continue
        r = result[kind]
        silent = r.get("changed", 0) + r.get("unchecked", 0) + r.get("mixed", 0)
        lines.append(f"{kind:<13} {r['trials']:>6} {r.get('lost', 0):>5} {r.get('duplicated', 0):>5} {silent:>6} "
                     f"{r.get('written_outside', 0):>7} {r.get('orphans', 0):>7} {r['tracebacks']:>10}  "
                     f"{_details(kind, r)}")
    return "\n".join(lines)


def failures(result: dict[str, Any]) -> int:
    """Everything that must be zero: rows lost, doubled or changed, tracebacks, bad refusals, hangs, files
    written outside a folder, edits read as sound, disagreements, orphans, mixed reports."""
    bad = sum(result[k].get(m, 0) for k in KINDS if k in result
              for m in ("lost", "duplicated", "changed", "tracebacks", "bad_refusals", "not_one_line",
                        "exit_0_interrupted", "hangs", "written_outside", "unchecked", "disagree", "orphans", "mixed",
                        "no_worker", "raw_escapes", "past_bound"))
    # a forged spec, a mixed folder or a crafted lock note accepted is broken (a fuzzed spec may be accepted)
    bad += sum(result[k].get("accepted", 0) for k in ("forged spec", "mixed versions", "owner note") if k in result)
    ray = result.get("not Ray")
    return bad + (ray["trials"] - ray["refused"] if ray else 0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=100)
    parser.add_argument("--flips", type=int, default=60)
    parser.add_argument("--races", type=int, default=10)
    parser.add_argument("--shard-races", type=int, default=20)
    parser.add_argument("--sigints", type=int, default=50)
    parser.add_argument("--footer-flips", type=int, default=300)
    parser.add_argument("--disks", type=int, default=8)
    parser.add_argument("--planted", type=int, default=40)
    parser.add_argument("--edits", type=int, default=35)
    parser.add_argument("--deaths", type=int, default=10)
    parser.add_argument("--reports", type=int, default=6)
    parser.add_argument("--fuzz", type=int, default=300)
    parser.add_argument("--reads", type=int, default=24)
    parser.add_argument("--swaps", type=int, default=12)
    parser.add_argument("--forged", type=int, default=24)
    parser.add_argument("--versions", type=int, default=8)
    parser.add_argument("--notes", type=int, default=7)
    parser.add_argument("--only", action="append", choices=KINDS, help="run only this class (repeatable)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args(argv)
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    result = run_faults(args.kills, args.flips, args.races, args.shard_races, args.sigints, args.footer_flips,
                        args.disks, args.seed, args.planted, args.edits, args.deaths, args.reports, args.fuzz,
                        args.only, args.reads, args.swaps, args.forged, args.versions, args.notes)
    print(json.dumps(result, indent=2) if args.json else format_faults(result))
    return int(failures(result) > 0)


if __name__ == "__main__":
    sys.exit(main())
