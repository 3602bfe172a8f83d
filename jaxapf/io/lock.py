"""Output folders: checked writable before any work, one writer each (a lock file naming its owner),
and files written atomically (:func:`write_atomic`).

A command that writes into a folder (``jaxapf sweep``, ``tune``, ``compare``) holds ``FOLDER/.lock``
while it runs: a file created atomically (``O_CREAT | O_EXCL``) holding the owner's pid, host,
process start time and command line. A second writer finds it and refuses with one line naming the
owner. A lock whose owner is provably gone -- same host, and no process with that pid and start
time -- is *stale*: it is removed with a note (a ``kill -9`` leaves one behind). A lock from another
host cannot be checked from here; the refusal then gives the command that clears it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import pathlib
import socket
import sys
import time
from typing import IO, Any, Callable, Iterator

from ..validation import ConfigError, Interrupted, first_line

__all__ = ["LOCK_NAME", "OutputLock", "LockInfo", "check_writable", "write_atomic", "writing"]

#: Name of the lock file inside the output folder.
LOCK_NAME = ".lock"


def check_writable(folder: str | os.PathLike, option: str = "--out") -> None:
    """Refuse, before any work, an output folder that cannot be created or written."""
    folder = pathlib.Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"{option} {folder} is a file; give a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        raise ConfigError(f"{option} {folder} cannot be written: {err.strerror or first_line(err)}") from None


def write_atomic(path: str | os.PathLike, write: Callable[[IO[bytes]], Any]) -> None:
    """Write ``path`` completely or not at all: ``write(fh)`` fills the hidden temporary file
    ``.NAME.tmp-PID`` beside it, which is fsynced and renamed over ``path``. An exception or Ctrl-C
    on the way removes the temporary file; a killed writer leaves at most it, never a partial
    ``path``."""
    path = pathlib.Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _start_time(pid: int) -> str | None:
    """The start time of process ``pid`` in clock ticks since boot (Linux), None where unknown."""
    try:
        stat = pathlib.Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rsplit(")", 1)[1].split()[19]  # field 22; the command name may hold spaces


def _alive(pid: int, start: str | None) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        pass
    return start is None or _start_time(pid) in (None, start)


@dataclasses.dataclass(frozen=True)
class LockInfo:
    """Who holds a lock."""

    pid: int
    host: str
    start: str | None
    since: float
    command: str

    @classmethod
    def mine(cls) -> "LockInfo":
        pid = os.getpid()
        return cls(pid, socket.gethostname(), _start_time(pid), time.time(), " ".join(sys.argv) or "python")

    def describe(self) -> str:
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.since))
        return f"pid {self.pid} on {self.host} since {when} ({self.command})"

    def stale(self) -> bool:
        """Provably gone: same host and no live process with this pid and start time."""
        return self.host == socket.gethostname() and not _alive(self.pid, self.start)


class OutputLock:
    """``with OutputLock(folder, "jaxapf sweep"):`` -- hold ``folder/.lock`` for the block.

    Raises :class:`ConfigError` when another live writer holds it, or when its owner cannot be
    checked (another host); ``note`` receives one line when a stale lock is removed.
    """

    def __init__(self, folder: str | os.PathLike, what: str, note: Callable[[str], None] | None = None) -> None:
        self.path = pathlib.Path(folder) / LOCK_NAME
        self.what = what
        self.note = note
        self.held = False

    def _read(self) -> LockInfo | None:
        try:
            data: dict[str, Any] = json.loads(self.path.read_text())
            return LockInfo(int(data["pid"]), str(data["host"]), data.get("start"), float(data["since"]),
                            str(data.get("command", "")))
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError):
            try:
                since = self.path.stat().st_mtime
            except OSError:
                return None
            return LockInfo(-1, "?", None, since, "unreadable lock file")

    def acquire(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                self._refuse_or_clear()
                continue
            with os.fdopen(fd, "w") as fh:
                json.dump(dataclasses.asdict(LockInfo.mine()), fh)
                fh.flush()
                os.fsync(fh.fileno())
            self.held = True
            return
        raise ConfigError(f"{self.path.parent}: could not take the lock {self.path} (contended); try again")

    def _refuse_or_clear(self) -> None:
        """Another lock is there: remove it if stale, else refuse naming its owner."""
        owner = self._read()
        if owner is None:
            return  # released between our two calls: try again
        if owner.pid == os.getpid() and owner.host == socket.gethostname():
            raise ConfigError(f"{self.path.parent} is already being written by this process")
        if owner.stale():
            self.path.unlink(missing_ok=True)
            if self.note is not None:
                self.note(f"removed the stale lock of {owner.describe()}: that process is gone")
            return
        if owner.host != socket.gethostname() or owner.pid < 0:
            raise ConfigError(f"{self.path.parent} is locked by {owner.describe()}, which cannot be checked "
                              f"from here; if no such run is going on, clear it with: rm '{self.path}'")
        raise ConfigError(f"{self.path.parent} is being written by {owner.describe()}; wait for it to "
                          f"finish or write elsewhere (one writer per output)")

    def release(self) -> None:
        if self.held:
            self.path.unlink(missing_ok=True)
            self.held = False

    def __enter__(self) -> "OutputLock":
        self.acquire()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()


@contextlib.contextmanager
def writing(folder: str | os.PathLike, what: str, kept: str, note: Callable[[str], None] | None = None
            ) -> Iterator[None]:
    """The block as the one writer of ``folder``: checked writable first (:func:`check_writable`),
    the lock held (:class:`OutputLock`), and Ctrl-C turned into :class:`Interrupted` saying what
    was ``kept`` there and how to resume."""
    check_writable(folder)
    with OutputLock(folder, what, note):
        try:
            yield
        except KeyboardInterrupt:
            raise Interrupted(f"interrupted; {kept} in {folder}; rerun the same command to resume") from None
