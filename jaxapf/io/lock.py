"""Output folders: checked writable before any work, one writer each (a lock the kernel keeps), and
files written atomically and durably (:func:`write_atomic`), never through a name planted in the
folder (:mod:`jaxapf.io.names`).

A command that writes into a folder (``jaxapf sweep``, ``tune``, ``compare``, ``report``) holds ``FOLDER/.lock``
while it runs: an exclusive ``fcntl.flock`` on that file, which the operating system releases when
the process ends however it ends (``kill -9`` included), so no lock outlives its writer and none is
ever judged stale by hand. The file carries an *owner note* (pid, host, start, command) written
after the lock is taken; a second writer is refused in one line naming that owner (or saying the
owner has not written its note yet). The holder removes the file as it releases; a process that
opened the old file meanwhile finds, after locking it, that the path no longer names what it locked,
and tries again, so two writers never both hold the lock.

What holds where: on a local file system (ext4, xfs, btrfs, tmpfs) and between containers that share
one (whatever their PID namespaces or host names), ``flock`` excludes any other writer. On NFS, Linux
maps ``flock`` onto NFS byte-range locks (NFSv4, or v3 with ``lockd``): writers on different clients
exclude each other, and a client that dies loses its lock when its lease expires (NFSv4: about 90 s).
Mounted with ``nolock`` (or ``local_lock=flock``) the lock only excludes writers on the same client;
Lustre and GPFS honour ``flock`` when mounted with ``-o flock`` (the Lustre default is ``localflock``:
per node only). Where locks cannot be trusted, give each writer its own output.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import fcntl
import json
import os
import pathlib
import socket
import sys
import time
from typing import IO, Any, Callable, Iterator

from ..text import inert
from ..validation import ConfigError, Interrupted, first_line
from .names import FLAGS, check_kind, create, open_own, read_own

__all__ = ["LOCK_NAME", "OutputLock", "LockInfo", "check_writable", "staged", "write_atomic", "writing", "fsync_folder",
           "live_shard_locks"]

#: Name of the lock file inside the output folder.
LOCK_NAME = ".lock"
#: Bytes :func:`check_writable` writes (and syncs) to see that the folder takes data, not only names.
PROBE_BYTES = 64 * 1024


def _no_space(err: OSError) -> bool:
    return err.errno in (errno.ENOSPC, errno.EDQUOT)


def check_writable(folder: str | os.PathLike, option: str = "--out") -> None:
    """Refuse, before any work, an output folder that cannot be created or written, or whose file
    system has no room left (a probe of :data:`PROBE_BYTES` bytes is written, synced and removed)."""
    folder = pathlib.Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"{option} {folder} is a file; give a folder")
    probe = folder / f".write-test-{os.getpid()}"
    made, fd = not folder.exists(), None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd = create(probe)
        try:
            left = memoryview(b"\0" * PROBE_BYTES)
            while left:  # a nearly full disk takes part of a write, then refuses the rest (ENOSPC)
                left = left[os.write(fd, left):]
            os.fsync(fd)
        finally:
            os.close(fd)
            probe.unlink(missing_ok=True)  # the file this call created
    except OSError as err:
        full = " (the file system is full)" if _no_space(err) else ""
        if made:  # refused before any work: leave no empty folder behind
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise ConfigError(f"{option} {folder} cannot be written: {err.strerror or first_line(err)}{full}") from None


def fsync_folder(folder: str | os.PathLike) -> None:
    """Make the names in ``folder`` durable (a rename or unlink survives a power cut once this returns)."""
    fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def staged(path: str | os.PathLike, durable: bool = True) -> Iterator[pathlib.Path]:
    """``with staged(path) as tmp:`` -- the block writes the hidden file ``tmp`` (``.NAME.tmp-PID`` beside
    ``path``, created anew: :func:`jaxapf.io.names.create`, never a link or a file already there), which
    is then renamed over ``path``: whatever ``path`` was is replaced, never written through, and a name
    there that is not a regular file is refused in one line (:class:`~jaxapf.io.names.Planted`).
    ``durable``: the folder is fsynced after the rename. An exception or Ctrl-C in the block removes
    ``tmp``; a killed writer leaves at most it, never a partial ``path``."""
    path = pathlib.Path(path)
    check_kind(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    os.close(create(tmp))
    try:
        yield tmp
        os.replace(tmp, path)
        if durable:
            fsync_folder(path.parent)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_atomic(path: str | os.PathLike, write: Callable[[IO[bytes]], Any] | bytes | str,
                 durable: bool = True) -> None:
    """Write ``path`` completely or not at all (:func:`staged`): ``write(fh)``, or the bytes or text
    ``write``, fills the temporary file; ``durable``: it is fsynced before the rename, so the new file
    survives a crash."""
    data = write.encode("utf-8") if isinstance(write, str) else write
    with staged(path, durable) as tmp, open(open_own(tmp, os.O_WRONLY), "wb") as fh:
        if callable(data):
            data(fh)
        else:
            fh.write(data)
        fh.flush()
        if durable:
            os.fsync(fh.fileno())


@dataclasses.dataclass(frozen=True)
class LockInfo:
    """Who holds a lock: the owner note of the lock file."""

    pid: int
    host: str
    since: float
    command: str

    @classmethod
    def mine(cls) -> "LockInfo":
        return cls(os.getpid(), socket.gethostname(), time.time(), " ".join(sys.argv) or "python")

    def describe(self) -> str:
        """The owner in a few words, its host and command escaped (:func:`~jaxapf.text.inert`) and cut short."""
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.since))
        command = inert(self.command[:_SHOWN]) + ("…" if len(self.command) > _SHOWN else "")
        return f"pid {self.pid} on {inert(self.host[:_SHOWN])} since {when} ({command})"


#: The most characters of an owner note's host or command a refusal shows.
_SHOWN = 200
#: The range of an owner note's start time that a note of a real writer holds [s since the epoch]: up to the
#: year 9999, which every platform's calendar shows.
_SINCE = (0.0, 253_402_300_799.0)


#: How long :func:`_take` keeps trying a lock that is taken [s]: another process looking whether a lock is
#: held (:func:`_held`) takes it for an instant, and must not make a writer give up.
_PATIENCE_S = 0.1


def _take(path: pathlib.Path, exclusive: bool) -> int | None:
    """An open descriptor of ``path`` holding its ``flock`` (exclusive or shared), or None if another
    process holds it in a conflicting mode (for longer than :data:`_PATIENCE_S`); the file is created if
    missing and locked only while ``path`` still names it (a holder may remove it as it releases)."""
    give_up = time.monotonic() + _PATIENCE_S
    while True:
        try:
            fd = open_own(path, os.O_CREAT | os.O_RDWR)
        except OSError as err:
            raise ConfigError(f"{path.parent}: cannot create the lock {path}: "
                              f"{err.strerror or first_line(err)}") from None
        try:
            fcntl.flock(fd, (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            if time.monotonic() < give_up:
                time.sleep(0.005)
                continue
            return None
        try:
            same = os.lstat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)  # the holder removed it as we opened it: lock the file that is there now


def _held(path: pathlib.Path) -> bool:
    """Whether some process holds ``path``'s lock now (a lock file left by a dead writer is not held)."""
    try:
        fd = os.open(path, os.O_RDONLY | FLAGS)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return False
    except BlockingIOError:
        return True
    finally:
        os.close(fd)


def live_shard_locks(folder: pathlib.Path) -> list[pathlib.Path]:
    """The shard locks (:class:`OutputLock` with ``shard``) some process holds in ``folder`` now."""
    return [p for p in sorted(folder.glob(f"{LOCK_NAME}-shard-*")) if _held(p)]


def _read_note(path: pathlib.Path) -> LockInfo | None:
    try:
        data: dict[str, Any] = json.loads(read_own(path, 64 * 1024))
        pid, host, since, command = data["pid"], data["host"], data["since"], data.get("command", "")
    except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError):
        return None
    # every field as a writer writes it (LockInfo.mine), else no note: a pid a kernel can hold, a start a
    # calendar shows (1e20, NaN and inf are not), texts
    if (not isinstance(pid, int) or isinstance(pid, bool) or not 0 < pid < 2**31
            or not isinstance(since, (int, float)) or isinstance(since, bool)
            or not _SINCE[0] <= since <= _SINCE[1] or not isinstance(host, str) or not isinstance(command, str)):
        return None
    return LockInfo(pid, host, float(since), command)


class OutputLock:
    """``with OutputLock(folder):`` -- hold ``folder/.lock`` for the block (module docstring).

    With ``shard = (i, n)`` the block is one shard of a sweep written by several processes: it holds
    ``folder/.lock`` *shared* (shards write side by side; a whole-output writer, which holds it
    exclusively, excludes them all and they it) and ``folder/.lock-shard-I-of-N`` exclusively (one
    process per shard). Raises :class:`ConfigError` in one line when another writer holds what is
    wanted, naming it from its owner note.
    """

    def __init__(self, folder: str | os.PathLike, shard: tuple[int, int] | None = None) -> None:
        self.folder = pathlib.Path(folder)
        self.path = self.folder / LOCK_NAME
        self.shard = shard
        self.own = self.folder / f"{LOCK_NAME}-shard-{shard[0]:04d}-of-{shard[1]:04d}" if shard else self.path
        self.fd: int | None = None
        self.shared: int | None = None

    @property
    def held(self) -> bool:
        return self.fd is not None

    def owner(self) -> LockInfo | None:
        """The owner note of the lock this one wants; None if there is none (yet) or it cannot be read."""
        return _read_note(self.own)

    def acquire(self) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        if self.shard is not None:
            self.shared = _take(self.path, exclusive=False)
            if self.shared is None:
                self._refuse(self.path, "the whole output")
        try:
            fd = _take(self.own, exclusive=True)
        except ConfigError:
            self._release_shared()
            raise
        if fd is None:
            self._release_shared()
            self._refuse(self.own, f"shard {self.shard[0]}/{self.shard[1]}" if self.shard else None)
        self.fd = fd
        try:
            note = json.dumps(dataclasses.asdict(LockInfo.mine())).encode()
            os.ftruncate(fd, 0)
            os.pwrite(fd, note, 0)
            os.fsync(fd)
        except OSError as err:
            self.release()
            full = " (the file system is full)" if _no_space(err) else ""
            raise ConfigError(f"{self.folder}: cannot write the lock's owner note: "
                              f"{err.strerror or first_line(err)}{full}; nothing was written") from None

    def _refuse(self, path: pathlib.Path, what: str | None) -> None:
        """Another writer holds ``path``: refuse, naming it (a whole-output lock held shared names its shards)."""
        if path == self.path:  # live shards hold it shared (its note may be a dead writer's): name them
            live = [(p, _read_note(p)) for p in live_shard_locks(self.folder)]
            names = [f"shard {int(p.name.split('shard-')[1].split('-of-')[0])}/"
                     f"{int(p.name.split('-of-')[1])} ({note.describe() if note else 'no owner note yet'})"
                     for p, note in live]
            if names:
                raise ConfigError(f"{self.folder} is being written by {len(names)} shard(s): {'; '.join(names[:3])}"
                                  f"{' …' if len(names) > 3 else ''}; wait for them or write elsewhere")
        owner = _read_note(path)
        where = f"{self.folder}" + (f" ({what})" if what else "")
        if owner is None:
            raise ConfigError(f"{where} is being written by another process (it has not written its owner note "
                              "yet, or the note is not one a writer writes); wait for it to finish or write "
                              "elsewhere (one writer per output)")
        if owner.pid == os.getpid() and owner.host == socket.gethostname():
            raise ConfigError(f"{where} is already being written by this process")
        raise ConfigError(f"{where} is being written by {owner.describe()}; wait for it to "
                          f"finish or write elsewhere (one writer per output)")

    def _release_shared(self) -> None:
        """Let the shared hold of ``.lock`` go; the last shard to leave removes ``.lock`` and
        ``.lock-division`` (it can take ``.lock`` exclusively only when no other shard holds it)."""
        if self.shared is None:
            return
        try:
            fcntl.flock(self.shared, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pass  # other shards still write
        else:
            with contextlib.suppress(OSError):
                if os.lstat(self.path).st_ino == os.fstat(self.shared).st_ino:
                    (self.folder / f"{LOCK_NAME}-division").unlink(missing_ok=True)
                    self.path.unlink()
        os.close(self.shared)
        self.shared = None

    def release(self) -> None:
        """Remove the lock file (while still holding it) and let the lock go; only the holder's call acts."""
        if self.fd is None:
            return
        with contextlib.suppress(OSError):
            if os.lstat(self.own).st_ino == os.fstat(self.fd).st_ino:
                self.own.unlink()
        os.close(self.fd)  # closing releases the flock
        self.fd = None
        self._release_shared()

    def __enter__(self) -> "OutputLock":
        self.acquire()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()


@contextlib.contextmanager
def writing(folder: str | os.PathLike, kept: str, shard: tuple[int, int] | None = None) -> Iterator[None]:
    """The block as the one writer of ``folder`` (with ``shard``, as that shard, beside the others):
    checked writable first (:func:`check_writable`), the lock held (:class:`OutputLock`), and Ctrl-C
    turned into :class:`Interrupted` saying what was ``kept`` there and how to resume."""
    check_writable(folder)
    with OutputLock(folder, shard):
        try:
            yield
        except KeyboardInterrupt:
            raise Interrupted(f"interrupted; {kept} in {folder}; rerun the same command to resume") from None
