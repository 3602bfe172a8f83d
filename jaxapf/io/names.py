"""Names inside a folder jaxapf writes are the folder's own: nothing planted there sends a write outside it.

A folder can come from someone else (a shared cluster folder, a tarball) holding symbolic links, hard
links, FIFOs or folders under the names jaxapf uses. As git promises for its work tree, no write follows
them: a new file is created with ``O_CREAT | O_EXCL | O_NOFOLLOW`` (:func:`create`) and renamed over
its final name, which replaces whatever that name was without writing through it; a file opened again
(a lock) is opened with ``O_NOFOLLOW`` and must be a regular file with one link (:func:`open_own`); a
subfolder must be a folder, not a link to one (:func:`subfolder`); a leftover is removed only if it is
a regular file (:func:`remove_leftover`). A name of the wrong type is refused in one line naming it
(:class:`Planted`), and nothing is written. A file jaxapf *reads* from a folder it was handed is opened
the same way, once, and refused past the size the file can hold (:func:`open_read`, :func:`read_own`).
"""

from __future__ import annotations

import errno
import os
import pathlib
import stat
from typing import BinaryIO

from ..validation import ConfigError

__all__ = ["Planted", "TooLarge", "kind", "create", "open_own", "open_read", "read_own", "subfolder", "remove_leftover",
           "check_kind", "FLAGS"]

#: Flags of every open in a folder jaxapf writes: no link followed, no FIFO waited on, not inherited.
FLAGS = os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)


class Planted(ConfigError):
    """A name jaxapf uses holds something it never makes there (a link, a FIFO, a folder ...)."""


def kind(st: os.stat_result) -> str:
    """What an ``lstat`` result is, in words."""
    mode = st.st_mode
    if stat.S_ISLNK(mode):
        return "symbolic link"
    if stat.S_ISDIR(mode):
        return "folder"
    if stat.S_ISFIFO(mode):
        return "FIFO"
    if stat.S_ISSOCK(mode):
        return "socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "device"
    return "file"


def _planted(path: pathlib.Path, what: str, want: str = "file") -> Planted:
    return Planted(f"{path} is a {what} where jaxapf keeps a {want}; it was not made by jaxapf: remove it "
                   "(nothing was written)")


def check_kind(path: str | os.PathLike, want: str = "file") -> bool:
    """Whether ``path`` exists; :class:`Planted` if it is not a ``want`` ("file": a regular file;
    "folder": a folder, not a link to one)."""
    path = pathlib.Path(path)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return False
    what = kind(st)
    if what != want:
        raise _planted(path, what, want)
    return True


def create(path: str | os.PathLike, mode: int = 0o644) -> int:
    """A descriptor of the new regular file ``path``, open for writing; never opens what is there already.
    A leftover regular file of that name (a dead writer's whose pid this process now has) is removed
    first (removing a name never changes another); anything else there is :class:`Planted`."""
    path = pathlib.Path(path)
    for _ in range(2):
        try:
            return os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | FLAGS, mode)
        except FileExistsError:
            check_kind(path)
            path.unlink(missing_ok=True)
    raise _planted(path, "name another process keeps creating")


def open_own(path: str | os.PathLike, flags: int, mode: int = 0o644, *, one_name: bool = True) -> int:
    """A descriptor of the regular file ``path`` (created if missing when ``flags`` has ``O_CREAT``),
    opened without following a link or waiting on a FIFO; :class:`Planted` if ``path`` is anything but a
    regular file, or (``one_name``, for a file written in place) a file with another name too (the file
    is closed again, nothing written)."""
    path = pathlib.Path(path)
    try:
        fd = os.open(path, flags | FLAGS, mode)
    except OSError as err:
        if err.errno in (errno.ELOOP, errno.EISDIR, errno.ENXIO, errno.EMLINK):
            check_kind(path)
        raise
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode) or (one_name and st.st_nlink != 1):  # writing a hard link changes its other name
        os.close(fd)
        raise _planted(path, kind(st) if not stat.S_ISREG(st.st_mode) else "hard link (a file with another name)")
    return fd


class TooLarge(ConfigError):
    """A file jaxapf reads is larger than any it writes under that name."""


def open_read(path: str | os.PathLike, limit: int) -> BinaryIO:
    """The regular file ``path`` open for reading through :func:`open_own` (no link followed, no FIFO or device
    waited on); :class:`TooLarge` if it holds more than ``limit`` bytes, the most a file jaxapf writes under
    that name can hold; ``FileNotFoundError`` if it is missing. Every file jaxapf reads from a folder it was
    handed is opened here, once, and read from this descriptor alone."""
    fh = open(open_own(path, os.O_RDONLY, one_name=False), "rb")
    size = os.fstat(fh.fileno()).st_size
    if size > limit:
        fh.close()
        raise TooLarge(f"{path} holds {size:,} bytes, more than the {limit:,} a file jaxapf writes there can hold; "
                       "it was not written by jaxapf (nothing was read)")
    return fh


def read_own(path: str | os.PathLike, limit: int = 1 << 20) -> bytes:
    """The bytes of the regular file ``path``, read through :func:`open_read`; :class:`TooLarge` also if it grows
    past ``limit`` while it is read."""
    with open_read(path, limit) as fh:
        data = fh.read(limit + 1)
    if len(data) > limit:
        raise TooLarge(f"{path} grew past the {limit:,} bytes a file jaxapf writes there can hold while it was "
                       "read; it was not written by jaxapf")
    return data


def subfolder(path: str | os.PathLike) -> pathlib.Path:
    """The folder ``path`` inside a folder jaxapf writes, made if missing; :class:`Planted` if the name
    holds anything else (a link to a folder elsewhere included)."""
    path = pathlib.Path(path)
    try:
        path.mkdir()
    except FileExistsError:
        pass
    check_kind(path, "folder")
    return path


def remove_leftover(path: str | os.PathLike) -> bool:
    """Remove ``path`` if it is a regular file (a dead writer's temporary file); anything else is left
    where it is and named (:class:`Planted`). Whether a file was removed."""
    if not check_kind(path):
        return False
    pathlib.Path(path).unlink(missing_ok=True)
    return True
