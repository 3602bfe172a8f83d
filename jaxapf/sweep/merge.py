"""``jaxapf sweep merge A B … --out OUT``: one dataset from shard folders written apart.

Folders written on machines without a shared file system (each a shard's, or a resumed copy) are
combined part by part: every source is audited first (:mod:`jaxapf.sweep.audit`) and must be sound
and of the same sweep and jaxapf version as the others and as ``OUT``; a part whose name is already in
``OUT`` (or in another source) with the same content is taken once, one with other content, or
parts that chunk the same fields differently, refuse the merge before anything is copied. Parts are
copied atomically and read back, so a merge never doubles a row, and a merge repeated or resumed
after an interruption copies only what is not there yet.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import re
from typing import Sequence

from ..io.lock import OutputLock, check_writable, write_atomic
from ..validation import ConfigError
from .audit import Audit, audit_folder, check_folder, clear_temporaries
from .meta import identity, open_part
from .output import audited_hash, read_part
from .plan import Chunk

__all__ = ["MergeResult", "merge_outputs"]


@dataclasses.dataclass(frozen=True)
class MergeResult:
    """What a merge did: parts copied, parts already there, and the audit of ``OUT`` after it."""

    out: pathlib.Path
    copied: int
    present: int
    audit: Audit

    def summary(self) -> str:
        state = "complete and sound" if self.audit.complete else (
            f"{self.audit.rows:,} of {self.audit.expected:,} episodes; `jaxapf sweep verify {self.out}` lists the rest")
        return (f"merged into {self.out}: {self.copied} part(s) copied, {self.present} already there; "
                f"{len(self.audit.sound)} part(s), {state}")


def _copy(src: pathlib.Path, fh, copied: int) -> None:
    """The part ``src`` copied into ``fh`` from the descriptor it was opened and checked with
    (:func:`~jaxapf.sweep.meta.open_part`), the bytes it held then and no more: a source swapped for a link or
    a FIFO is refused unread, one that grows while it is copied is refused when it does."""
    try:
        part = open_part(src)
    except ConfigError as err:  # planted or grown since the audit
        said = re.sub(r" \(nothing was \w+\)$", "", str(err))
        raise ConfigError(f"sweep merge: {said}; {copied} part(s) were copied before it") from None
    with part:
        left = os.fstat(part.fileno()).st_size
        while left > 0 and (block := part.read(min(left, 1 << 20))):
            fh.write(block)
            left -= len(block)
        if part.read(1):
            raise ConfigError(f"sweep merge: {src} grew while it was copied (a part never changes once written); "
                              f"{copied} part(s) were copied before it")


def _audited_sources(sources: list[pathlib.Path], out: pathlib.Path) -> tuple[list[Audit], list[dict]]:
    """Each source's audit and metadata, all of one sweep and version: :class:`ConfigError` for a source that
    is no folder, holds ``out``, has a part that cannot be trusted, or is of another sweep or version."""
    if not sources:
        raise ConfigError("sweep merge: name at least one folder to merge")
    for s in sources:
        if not s.is_dir():
            raise ConfigError(f"sweep merge: {s} is not a folder")
        if s.resolve() == out.resolve():
            raise ConfigError(f"sweep merge: {s} is the output itself")
        if s.resolve() in out.resolve().parents:  # the output would be a folder of entries that are not parts
            raise ConfigError(f"sweep merge: --out {out} is inside {s}, a folder to merge; give an --out outside it")
    audits, metas = [], []
    for s in sources:
        found, meta = audit_folder(s)
        if found.problems:
            name = sorted(found.problems)[0]
            raise ConfigError(f"sweep merge: {s} has {len(found.problems)} part(s) that cannot be trusted (e.g. "
                              f"{name}: {found.problems[name]}; `jaxapf sweep verify {s}` lists them); "
                              "nothing merged")
        audits.append(found)
        metas.append(meta)
    first = identity(metas[0])  # the jaxapf version among it: one output holds one version's parts
    for s, meta in zip(sources[1:], metas[1:]):
        other = identity(meta)
        if other != first:
            differ = ", ".join(k for k in first if other[k] != first[k])
            raise ConfigError(f"sweep merge: {s} is of another sweep or version than {sources[0]} ({differ} differ); "
                              "nothing merged")
    return audits, metas


def merge_outputs(sources: Sequence[str | pathlib.Path], out: str | pathlib.Path) -> MergeResult:
    """Merge the sweep outputs ``sources`` into ``out`` (module docstring); :class:`ConfigError` in one
    line, before anything is copied, for a source that is not sound or of another sweep or version,
    or parts that conflict."""
    out = pathlib.Path(out)
    sources = [pathlib.Path(s) for s in sources]
    audits, metas = _audited_sources(sources, out)
    if out.is_dir():
        check_folder(out)  # a folder of other files is not a dataset to merge into
    check_writable(out)
    with OutputLock(out):
        clear_temporaries(out)  # the lock is ours: a temporary part is a dead merge's
        here = audit_folder(out, metas[0])[0] if any(Chunk.from_name(p.name) for p in out.iterdir()) else None
        if here is not None and here.problems:  # another jaxapf version's parts among them: identity holds it
            name = sorted(here.problems)[0]
            raise ConfigError(f"sweep merge: {out} has {len(here.problems)} part(s) that cannot be trusted or of "
                              f"another sweep (e.g. {name}: {here.problems[name]}; `jaxapf sweep verify {out}` lists "
                              "them); nothing merged")
        # every part by name, once; a name with two contents, or two names over the same fields, conflict. Each
        # content hash is the one its audit verified on the bytes it read, and the copy must have it too
        chosen: dict[str, pathlib.Path] = {c.name: out / c.name for c in (here.sound if here else ())}
        audited: dict[str, str] = dict(here.hashes) if here else {}
        for s, found in zip(sources, audits):
            for c in found.sound:
                if c.name in chosen:
                    if audited[c.name] != found.hashes[c.name]:
                        raise ConfigError(f"sweep merge: {c.name} differs between {chosen[c.name].parent} and {s}; "
                                          "nothing merged")
                    continue
                chosen[c.name], audited[c.name] = s / c.name, found.hashes[c.name]
        chunks = sorted((Chunk.from_name(n) for n in chosen), key=lambda c: (c.variant, c.family, c.start))
        for a, b in zip(chunks, chunks[1:]):
            if (a.variant, a.family) == (b.variant, b.family) and b.start < a.stop:
                raise ConfigError(f"sweep merge: {chosen[a.name]} and {chosen[b.name]} hold the same fields, chunked "
                                  "differently; merge folders of one chunking (or rerun one of them); nothing merged")
        copied = 0
        for name, src in chosen.items():
            if src.parent == out:
                continue
            write_atomic(out / name, lambda fh, src=src, copied=copied: _copy(src, fh, copied))
            try:  # the copy read once: intact, and the content its source's audit verified
                problem = None if audited_hash(read_part(out / name)) == audited[name] else (
                    "another part's content: the source changed after it was audited")
            except ConfigError as err:
                problem = str(err).split(": ", 1)[-1]
            if problem is not None:
                (out / name).unlink(missing_ok=True)
                raise ConfigError(f"sweep merge: the copy of {src} did not read back ({problem}); "
                                  f"{copied} part(s) were copied before it")
            copied += 1
        result = audit_folder(out, metas[0])[0]
    return MergeResult(out, copied, len(chosen) - copied, result)
