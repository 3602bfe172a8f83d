"""A sweep's output directory: finding what is done, writing parts atomically."""

from __future__ import annotations

import os
import pathlib
import re
from typing import Any, Mapping

from ..validation import ConfigError
from .plan import Chunk
from .schema import identity, read_meta

__all__ = ["prepare_output", "write_part", "part_files"]

_TMP = re.compile(r"^\.part-.*\.tmp-\d+$")


def write_part(out: pathlib.Path, name: str, table) -> None:
    """Write ``table`` to ``out/name`` atomically: hidden temporary file, fsync, rename."""
    import pyarrow.parquet as pq

    tmp = out / f".{name}.tmp-{os.getpid()}"
    with open(tmp, "wb") as fh:
        pq.write_table(table, fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, out / name)


def part_files(out: pathlib.Path) -> list[pathlib.Path]:
    return sorted(p for p in out.iterdir() if Chunk.from_name(p.name) is not None)


def prepare_output(out: pathlib.Path, meta: Mapping[str, Any], *, overwrite: bool, clean: bool) -> list[Chunk]:
    """Check ``out`` against this sweep and return the chunks already finished there.

    Refuses (:class:`ConfigError`) a path that is a file, a directory holding other files, or parts
    of a different sweep (spec hash, dtype, vmap width or metrics) unless ``overwrite``, which deletes the
    parts (and nothing else). With ``clean`` (one process only), stale temporary files of a killed
    run are removed.
    """
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} is a file; a sweep writes a directory of Parquet parts")
    if not out.exists():
        return []
    foreign = [p.name for p in out.iterdir()
               if Chunk.from_name(p.name) is None and not _TMP.match(p.name)]
    if foreign:
        raise ConfigError(f"--out {out} holds files that are not sweep parts ({', '.join(sorted(foreign)[:3])}); "
                          "choose another --out")
    parts = part_files(out)
    if parts and not overwrite:
        old = identity(read_meta(parts[0]))
        new = identity(meta)
        if old != new:
            what = "; ".join(f"{k} {old[k]!s:.12} here, {new[k]!s:.12} now" for k in new if old[k] != new[k])
            raise ConfigError(f"--out {out} holds a different sweep ({what}); rerun with --overwrite to replace it, "
                              "or choose another --out")
    if clean:
        for p in out.iterdir():
            if _TMP.match(p.name) or (overwrite and p in parts):
                p.unlink()
    return [] if overwrite else [Chunk.from_name(p.name) for p in parts]


