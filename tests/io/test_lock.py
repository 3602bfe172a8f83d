"""One writer per output, kept by the kernel (``fcntl.flock``): each defect the hand-judged lock had,
reproduced, and what a full disk does.

The old lock judged staleness by pid and start time and then unlinked the path: two newcomers racing
over a stale lock both took it, ``release()`` deleted whatever lock was there, a live writer in
another PID namespace was judged dead, a lock read before its owner note was called unreadable (and
its removal advised), and a full disk left an empty lock that blocked every later run.
"""

from __future__ import annotations

import errno
import json
import multiprocessing as mp
import os
import pathlib
import signal
import subprocess
import sys
import time

import pytest

from jaxapf.io.lock import LOCK_NAME, OutputLock, check_writable, write_atomic
from jaxapf.validation import ConfigError

HOLD = """
import fcntl, json, os, sys, time
path = sys.argv[1]
fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o644)
fcntl.flock(fd, fcntl.LOCK_EX)
note = sys.argv[2].replace("SELF", str(os.getpid()))
if note:
    os.write(fd, note.encode())
print("held", flush=True)
time.sleep(600)
"""


def _holder(folder: pathlib.Path, note: str = "") -> subprocess.Popen:
    """A process holding ``folder/.lock`` the way a writer does, with ``note`` as its owner note."""
    folder.mkdir(parents=True, exist_ok=True)
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(folder / LOCK_NAME), note], stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def _race(folder: str, barrier, results) -> None:
    lock = OutputLock(folder)
    barrier.wait()
    try:
        lock.acquire()
    except ConfigError:
        results.put(0)
        return
    results.put(1)
    time.sleep(0.2)  # hold it while the other one tries
    lock.release()


@pytest.mark.slow
def test_two_newcomers_over_a_dead_writers_lock_never_both_take_it(tmp_path):
    """The old lock: 26 of 60 races over a stale lock let both in. Here a writer dies holding the lock
    (``kill -9``: its note stays, the kernel drops the lock), then two processes start together, 30 times:
    exactly one gets in each time."""
    note = {"pid": "SELF", "host": os.uname().nodename, "since": time.time(), "command": "jaxapf sweep x.toml"}
    holder = _holder(tmp_path, json.dumps(note).replace('"SELF"', "SELF"))
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    assert (tmp_path / LOCK_NAME).exists()  # the note outlives its writer; the lock does not
    ctx = mp.get_context("fork")
    for _ in range(30):
        barrier, results = ctx.Barrier(2), ctx.Queue()
        procs = [ctx.Process(target=_race, args=(str(tmp_path), barrier, results)) for _ in range(2)]
        for p in procs:
            p.start()
        for p in procs:
            p.join(30)
        assert sorted(results.get(timeout=5) for _ in procs) == [0, 1]


def test_a_lock_file_replaced_between_open_and_lock_is_not_taken(tmp_path, monkeypatch):
    """The interleaving behind the old race, forced: a newcomer opens the lock file; before it locks,
    the holder releases (removing the file) and another writer creates and locks a new one. The newcomer
    then locks the removed file; it must see that the path names another file now, and refuse."""
    import fcntl

    holder: list[subprocess.Popen] = []
    real = fcntl.flock

    def replaced_first(fd, op):
        if not holder:  # the first flock of the newcomer: the file changes under it
            (tmp_path / LOCK_NAME).unlink()
            holder.append(_holder(tmp_path, json.dumps({"pid": 7, "host": "h", "since": 0.0, "command": "new"})))
        return real(fd, op)

    (tmp_path / LOCK_NAME).write_text("")
    monkeypatch.setattr(fcntl, "flock", replaced_first)
    try:
        with pytest.raises(ConfigError, match=r"being written by pid 7 on h"):
            OutputLock(tmp_path).acquire()
    finally:
        holder[0].kill()
        holder[0].wait()


def test_a_failed_acquire_never_releases_the_holders_lock(tmp_path):
    """The old ``release()`` deleted whatever lock was there, letting a third writer in."""
    with OutputLock(tmp_path):
        other = OutputLock(tmp_path)
        with pytest.raises(ConfigError, match="already being written by this process"):
            other.acquire()
        other.release()
        assert (tmp_path / LOCK_NAME).exists()
        with pytest.raises(ConfigError):
            OutputLock(tmp_path).acquire()
    assert not (tmp_path / LOCK_NAME).exists()
    with OutputLock(tmp_path):  # free again
        pass


def test_a_live_writer_is_refused_whatever_its_note_says(tmp_path):
    """A writer in another PID namespace (a container) with the same host name: its note names a pid
    this host does not have; the old lock judged it dead and removed it (128 rows doubled)."""
    note = {"pid": 4_000_000, "host": os.uname().nodename, "since": time.time(), "command": "jaxapf sweep x.toml"}
    holder = _holder(tmp_path, json.dumps(note))
    try:
        with pytest.raises(ConfigError, match=r"is being written by pid 4000000 on .*jaxapf sweep x\.toml.*one writer"):
            OutputLock(tmp_path).acquire()
    finally:
        holder.kill()
        holder.wait()


def test_a_lock_taken_but_not_yet_noted_is_a_live_writer_and_no_removal_is_advised(tmp_path):
    holder = _holder(tmp_path)  # locked, the owner note not written yet
    try:
        with pytest.raises(ConfigError) as err:
            OutputLock(tmp_path).acquire()
        line = str(err.value)
        assert "has not written its owner note yet" in line and "rm" not in line and "\n" not in line
    finally:
        holder.kill()
        holder.wait()
    with OutputLock(tmp_path):  # its writer gone, the kernel let the lock go
        pass


def test_a_full_disk_when_the_note_is_written_gives_one_line_and_leaves_no_lock(tmp_path, monkeypatch):
    def full(*args):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "pwrite", full)
    with pytest.raises(ConfigError, match="No space left on device.*full.*nothing was written") as err:
        OutputLock(tmp_path).acquire()
    assert "\n" not in str(err.value)
    assert not (tmp_path / LOCK_NAME).exists()
    monkeypatch.undo()
    with OutputLock(tmp_path):  # nothing blocks the next run
        pass


def test_check_writable_refuses_a_full_disk(tmp_path, monkeypatch):
    """The old probe wrote 0 bytes, so it passed on a full disk."""
    real = os.fsync

    def full(fd):
        if "write-test" in os.readlink(f"/proc/self/fd/{fd}"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd)

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(ConfigError, match=r"cannot be written: No space left on device \(the file system is full\)"):
        check_writable(tmp_path / "out")
    assert not (tmp_path / "out").exists()  # the probe removed, and the folder it was made in
    (tmp_path / "mine").mkdir()
    with pytest.raises(ConfigError, match="the file system is full"):
        check_writable(tmp_path / "mine")
    assert list((tmp_path / "mine").iterdir()) == []  # a folder that was there stays


def test_write_atomic_syncs_the_folder_after_the_rename(tmp_path, monkeypatch):
    """A renamed file survives a crash only once its folder is synced."""
    synced = []
    real = os.fsync

    def record(fd):
        synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        return real(fd)

    monkeypatch.setattr(os, "fsync", record)
    write_atomic(tmp_path / "part.bin", lambda fh: fh.write(b"x"))
    assert synced[-1] == str(tmp_path) and (tmp_path / "part.bin").read_bytes() == b"x"


def test_a_look_at_a_lock_does_not_make_its_taker_give_up(tmp_path):
    """Another shard looking whether a lock is held (it takes the lock shared for an instant) used to make a
    writer taking it at that instant give up, refused as if a writer held it."""
    import fcntl
    import threading

    path = tmp_path / f"{LOCK_NAME}-shard-0000-of-0002"
    path.touch()
    fd = os.open(path, os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)  # the look, held a little longer than a look lasts
    threading.Timer(0.03, os.close, (fd,)).start()
    with OutputLock(tmp_path, (0, 2)) as lock:
        assert lock.held


def test_the_last_shard_to_leave_removes_the_shared_lock_files(tmp_path):
    """`.lock` (held shared by shards) and `.lock-division` were left behind after every shard finished."""
    first, second = OutputLock(tmp_path, (0, 2)), OutputLock(tmp_path, (1, 2))
    first.acquire()
    second.acquire()
    (tmp_path / f"{LOCK_NAME}-division").touch()
    first.release()
    assert (tmp_path / LOCK_NAME).exists()  # the other shard still holds it
    second.release()
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    with OutputLock(tmp_path):  # and the output is free for a whole-output writer
        pass


@pytest.mark.parametrize("note", [
    {"since": 1e20}, {"since": float("nan")}, {"since": float("inf")}, {"since": -5.0}, {"since": "today"},
    {"pid": 2**40}, {"pid": True}, {"pid": "12"}, {"host": 7}, {"command": ["rm"]}, "[1, 2]", "{"])
def test_an_owner_note_not_as_a_writer_writes_it_is_one_line(tmp_path, note):
    """Each field of an owner note is checked before use: a start no calendar shows (1e20 s, NaN, inf: a
    traceback from time.localtime before), a pid no kernel holds, a field of another type, a note that is no
    object; the refusal is one line that says the note is not a writer's."""
    good = {"pid": 4242, "host": "h", "since": time.time(), "command": "jaxapf sweep x.toml"}
    text = json.dumps(good | note) if isinstance(note, dict) else note
    holder = _holder(tmp_path, text)
    try:
        with pytest.raises(ConfigError) as err:
            OutputLock(tmp_path).acquire()
        line = str(err.value)
        assert "not one a writer writes" in line and "\n" not in line, line
    finally:
        holder.kill()
        holder.wait()


def test_what_a_note_says_reaches_the_terminal_inert(tmp_path):
    """A host or command with escape sequences (clear the screen, set the window title) or line breaks is shown
    escaped, on one line, and a command of 10,000 characters cut short."""
    note = {"pid": 4242, "host": "h\x1b[2J\x1b]0;owned\x07", "since": time.time(),
            "command": "jaxapf sweep\nrm -rf ~ \u202e" + "x" * 10_000}
    holder = _holder(tmp_path, json.dumps(note))
    try:
        with pytest.raises(ConfigError) as err:
            OutputLock(tmp_path).acquire()
        line = str(err.value)
        assert "h\\x1b[2J\\x1b]0;owned\\x07" in line and "jaxapf sweep\\nrm -rf ~ \\u202e" in line
        assert all(c.isprintable() for c in line) and len(line) < 1000 and "…" in line
    finally:
        holder.kill()
        holder.wait()


def test_the_command_lines_error_is_printed_inert(tmp_path, capsys):
    from jaxapf.cli import main

    spec = tmp_path / "s.toml"
    spec.write_text('name = "s"\n[scenario]\nfamilies = ["crossing\\u001b[2J"]\nfields = 4\n')
    assert main(["sweep", str(spec), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "\x1b" not in err and "\\x1b[2J" in err and err.count("\n") == 1, err


def test_what_a_command_prints_to_its_output_is_inert(tmp_path, capsys, monkeypatch):
    """Every command's standard output goes through jaxapf.text.InertLines: a name from a handed folder (here
    printed by a stand-in for ``sweep verify``) reaches the terminal escaped, its line breaks kept."""
    from jaxapf.cli import commands, main

    monkeypatch.setattr(commands, "_sweep_verify", lambda args: print(f"{args.out}/part\x1b[2J\x07: sound\nnext") or 0)
    assert main(["sweep", "verify", str(tmp_path / "handed\x1b]0;owned")]) == 0
    out = capsys.readouterr().out
    assert "\x1b" not in out and "\x07" not in out
    assert out == f"{tmp_path}/handed\\x1b]0;owned/part\\x1b[2J\\x07: sound\nnext\n"
