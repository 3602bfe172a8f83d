"""The division of a sweep into shards, agreed before any shard writes a part.

Shards of one output must cut the sweep into the same chunks and deal them among the same number of
shards, or two of them compute overlapping fields and leave others to nobody. The first shard to
reach an output records its division there (``OUT/.division.json``: the sweep's identity, the
number of shards and a digest of the plan's chunks, with who fixed it); every later shard, started
at the same moment or hours later, compares its own and refuses a different one in one line before
any work. Reading and writing the record happen under an exclusive ``flock`` on
``OUT/.lock-division`` (:mod:`jaxapf.io.lock`), so of two shards that start together exactly one
fixes the division and the other checks against it. A record that no part follows yet and no live
shard holds (every shard that fixed it died before writing) is replaced by the next shard's.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import hashlib
import json
import os
import pathlib
from typing import Any, Iterator, Mapping

from ..io.lock import LOCK_NAME, LockInfo, OutputLock, live_shard_locks, write_atomic
from ..io.names import open_own, read_own
from ..text import format_bytes
from ..validation import ConfigError, first_line
from .meta import identity
from .output import part_files
from .plan import Plan

__all__ = ["DIVISION_NAME", "Division", "agree_division", "forget_division", "is_division_file"]

#: The record of an output's division into shards.
DIVISION_NAME = ".division.json"
#: The file whose ``flock`` makes reading and fixing the record one step.
_GUARD = f"{LOCK_NAME}-division"


@dataclasses.dataclass(frozen=True)
class Division:
    """How a sweep is divided: ``shards`` processes dealing the chunks of a plan (``plan``: the SHA-256
    of its chunk names, ``chunks`` of them) of the sweep ``identity`` (:func:`~jaxapf.sweep.meta.identity`);
    ``chunking`` says in words what cut it (the options a user gives)."""

    shards: int
    plan: str
    chunks: int
    identity: Mapping[str, Any]
    chunking: str

    @classmethod
    def of(cls, plan: Plan, shards: int) -> "Division":
        """``plan`` (before any chunk of it ran) dealt to ``shards`` processes."""
        names = "\n".join(c.name for c in plan.chunks).encode()
        chunking = (f"--chunk-fields {plan.chunk_fields}" if plan.chunk_fields is not None
                    else f"--memory-budget {format_bytes(plan.memory_budget)}")
        return cls(shards, hashlib.sha256(names).hexdigest(), len(plan.chunks), identity(plan.meta), chunking)

    def agrees(self, other: "Division") -> bool:
        return (self.shards, self.plan, dict(self.identity)) == (other.shards, other.plan, dict(other.identity))

    def describe(self) -> str:
        return f"{self.shards} shard(s) of {self.chunks} chunks ({self.chunking})"

    def to_json(self, shard: tuple[int, int]) -> dict[str, Any]:
        return {**dataclasses.asdict(self), "identity": dict(self.identity),
                "fixed_by": {"shard": f"{shard[0]}/{shard[1]}", **dataclasses.asdict(LockInfo.mine())}}

    @classmethod
    def from_json(cls, data: Any) -> tuple["Division", str]:
        """The division of a record and who fixed it; ValueError if it is not one."""
        if not isinstance(data, dict):
            raise ValueError("not a JSON object")
        try:
            division = cls(int(data["shards"]), str(data["plan"]), int(data["chunks"]), dict(data["identity"]),
                           str(data["chunking"]))
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"lacks {first_line(err)}") from None
        by = data.get("fixed_by") if isinstance(data.get("fixed_by"), dict) else {}
        note = LockInfo(int(by.get("pid", 0)), str(by.get("host", "?")), float(by.get("since", 0.0)),
                        str(by.get("command", ""))) if by else None
        who = f"shard {by.get('shard', '?')}, {note.describe()}" if note else "an unknown shard"
        return division, who


@contextlib.contextmanager
def _guarded(out: pathlib.Path) -> Iterator[None]:
    """Hold the exclusive ``flock`` of ``OUT/.lock-division`` (blocking: another shard holds it for a
    read and at most one small write)."""
    fd = open_own(out / _GUARD, os.O_CREAT | os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _own(out: pathlib.Path, shard: tuple[int, int]) -> pathlib.Path:
    return OutputLock(out, shard).own


def agree_division(out: pathlib.Path, division: Division, shard: tuple[int, int], *, dry: bool = False) -> None:
    """Check ``division`` (of shard ``shard``) against the one recorded in ``out``, fixing it there if
    none is (module docstring); :class:`ConfigError` in one line if they differ. ``dry``: check only,
    write nothing (``--dry-run``)."""
    path = out / DIVISION_NAME
    if dry and not path.exists():
        return
    with contextlib.nullcontext() if dry else _guarded(out):
        try:
            found, who = Division.from_json(json.loads(read_own(path)))
        except FileNotFoundError:
            found = who = None
        except (OSError, ValueError, RecursionError) as err:  # not a record jaxapf wrote: judged like another
            found, who = None, f"unreadable ({first_line(err)})"
        if found is not None and found.agrees(division):
            return
        if who is not None and (part_files(out) or any(p != _own(out, shard) for p in live_shard_locks(out))):
            if found is None:
                raise ConfigError(f"--out {out}: its division into shards ({path}) is {who}; once no shard of this "
                                  "output runs, remove that file (each part keeps its own record of its shard) and "
                                  "rerun")
            if dict(found.identity) != dict(division.identity):
                differ = [k for k in division.identity if found.identity.get(k) != division.identity[k]]
                asks = f"runs another sweep ({', '.join(differ)} {'differs' if len(differ) == 1 else 'differ'})"
            else:
                asks = f"asks for {division.describe()}"
            raise ConfigError(f"--out {out} is divided into {found.describe()}, fixed by {who}; this shard "
                              f"({shard[0]}/{shard[1]}) {asks}: every shard of one output must run the same spec "
                              "(and --x64 or not) with the same --shard N, --chunk-fields and --memory-budget")
        if not dry:
            write_atomic(path, lambda fh: fh.write(json.dumps(division.to_json(shard), indent=1).encode()))


def forget_division(out: pathlib.Path) -> None:
    """Remove ``out``'s division (``--overwrite``: the parts it divided are gone)."""
    (out / DIVISION_NAME).unlink(missing_ok=True)


def is_division_file(name: str) -> bool:
    """Whether ``name`` is the record of a division or the temporary file it is written through."""
    return name == DIVISION_NAME or name.startswith(f".{DIVISION_NAME}.tmp-")
