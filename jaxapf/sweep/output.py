"""A sweep's output directory: one writer, parts written atomically, every part verifiable.

- **One writer.** :func:`jaxapf.io.lock.OutputLock` holds ``OUT/.lock`` while a run writes; a second
  run on the same output refuses with one line. Temporary files (``.part-….tmp-PID``) therefore
  belong to a dead writer whenever the lock is ours, and only then are they removed.
- **Atomic parts.** A part is written to a hidden temporary file, fsynced and renamed.
- **Verifiable parts.** Every part carries, in its Parquet metadata under ``jaxapf_part``, the
  SHA-256 of its ``jaxapf`` metadata and of every value of every column (:func:`content_hash`),
  and Parquet's own CRC of every data page. :func:`verify_part` re-reads a part and checks both;
  a resume verifies every part before trusting it, and :func:`jaxapf.sweep.read_sweep` every part
  it reads. A damaged part (truncated, bit-flipped, unreadable) is named with the remedy:
  ``--repair`` removes exactly the damaged parts, whose chunks the run then recomputes.
"""

from __future__ import annotations

import hashlib
import json
import pathlib
import re
from typing import Any

import numpy as np

from ..io.lock import write_atomic
from ..validation import ConfigError, first_line
from .meta import LEGACY_FORMAT, META_KEY, open_part, own_meta
from .plan import Chunk

__all__ = ["PART_KEY", "write_part", "write_rows", "part_files", "content_hash", "verify_part", "read_part",
           "audited_hash", "PartUnreadable", "part_record"]

_TMP = re.compile(r"^\.part-.*\.tmp-\d+$")
#: The probe :func:`jaxapf.io.lock.check_writable` writes and removes (a process starting beside us).
_PROBE = re.compile(r"^\.write-test-\d+$")


class PartUnreadable(ConfigError):
    """A part that cannot be read now (permissions, an I/O error): unlike a damaged one, it is left alone."""
#: Parquet metadata key of a part's own record: ``{"sha256": ..., "rows": ...}``.
PART_KEY = b"jaxapf_part"


def content_hash(table) -> str:
    """SHA-256 of a part: its ``jaxapf`` metadata, then every column's name, type and values.

    Values are hashed as arrays (numbers and booleans by their bytes, text by length-prefixed
    UTF-8), so the hash is the same whatever chunking or encoding Parquet used to store them.
    """
    h = hashlib.sha256()
    h.update((table.schema.metadata or {}).get(META_KEY, b""))
    for field, column in zip(table.schema, table.columns):
        h.update(f"\n{field.name}:{field.type}:{len(column)}\n".encode())
        values = column.to_numpy(zero_copy_only=False)
        if values.dtype == object:
            for v in values:
                b = str(v).encode()
                h.update(len(b).to_bytes(8, "little"))
                h.update(b)
        else:
            h.update(np.ascontiguousarray(values).tobytes())
    return h.hexdigest()


def write_part(out: pathlib.Path, name: str, table, shard: tuple[int, int] | None = None) -> None:
    """Write ``table`` to ``out/name`` atomically (:func:`jaxapf.io.lock.write_atomic`), with its
    content hash in the metadata (and ``shard``, the ``(i, n)`` of the shard that wrote it) and a CRC on
    every data page."""
    import pyarrow.parquet as pq

    record = {"sha256": content_hash(table), "rows": table.num_rows} | ({"shard": list(shard)} if shard else {})
    record = json.dumps(record).encode()
    table = table.replace_schema_metadata({**(table.schema.metadata or {}), PART_KEY: record})
    write_atomic(out / name, lambda fh: pq.write_table(table, fh, write_page_checksum=True))


def write_rows(out: pathlib.Path, name: str, rows, meta: dict, metrics: list[str]) -> pathlib.Path:
    """``out/name``: ``rows`` (a DataFrame of a sweep's rows, which :func:`jaxapf.sweep.read_sweep` returned with
    ``meta``) as one verified part carrying the sweep's own metadata, its metrics narrowed to ``metrics`` (those
    kept among the columns): ``read_sweep`` and ``jaxapf report`` read it as they read the sweep."""
    import pyarrow as pa

    table = pa.Table.from_pandas(rows, preserve_index=False)
    table = table.replace_schema_metadata({META_KEY: json.dumps(own_meta(meta) | {"metrics": metrics}).encode()})
    write_part(out, name, table)
    return out / name


def read_part(path: pathlib.Path):
    """The table of one part, checked: page CRCs and its content hash (a part of the legacy format,
    which carries none, is checked for readability only), with no metadata but its ``jaxapf`` key
    (:func:`_own_keys`). Raises :class:`ConfigError` naming the part and what is wrong with it."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        with open_part(path) as fh:
            table = pq.read_table(fh, page_checksum_verification=True)
    except ConfigError:  # planted, too large
        raise
    except OSError as err:
        if err.errno is not None:  # permissions, I/O errors, too many open files: the file is not judged
            raise PartUnreadable(f"{path}: cannot be read now ({err.strerror or first_line(err)}); nothing was "
                                 "changed") from None
        raise ConfigError(f"{path.name}: unreadable ({first_line(err)})") from None
    except (pa.ArrowException, ValueError) as err:
        raise ConfigError(f"{path.name}: unreadable ({first_line(err)})") from None
    metadata = dict(table.schema.metadata or {})
    try:
        hashed = json.loads(metadata.get(META_KEY, b"{}")).get("format") != LEGACY_FORMAT
    except (ValueError, AttributeError, RecursionError):
        hashed = True  # unreadable jaxapf metadata: the hash decides
    raw = metadata.pop(PART_KEY, None)
    try:
        record = json.loads(raw) if raw else None
        expected = record["sha256"] if isinstance(record, dict) else None
    except (ValueError, KeyError, TypeError, RecursionError):
        expected = None
    if expected is None and not hashed:
        return _own_keys(table, metadata)
    if expected is None:
        raise ConfigError(f"{path.name}: no content hash (damaged, or written before jaxapf checked its parts)")
    try:
        found = content_hash(table.replace_schema_metadata(metadata))
    except (pa.ArrowException, ValueError) as err:  # e.g. a column name that is not UTF-8 any more
        raise ConfigError(f"{path.name}: unreadable ({type(err).__name__}: {first_line(err)})") from None
    if found != expected:
        raise ConfigError(f"{path.name}: content hash mismatch (the file was changed after it was written)")
    return _own_keys(table, {**metadata, PART_KEY: raw})


def _own_keys(table, metadata: dict):
    """``table`` with no metadata but jaxapf's own (its sweep's, and the part's record of its verified content
    hash): another key (``pandas``, a field's) could rename, retype or reindex columns when the table is read,
    and the content hash covers only the sweep's key."""
    import pyarrow as pa

    own = {k: metadata[k] for k in (META_KEY, PART_KEY) if metadata.get(k) is not None}
    plain = pa.schema([f.remove_metadata() for f in table.schema], metadata=own or None)
    return pa.Table.from_arrays(table.columns, schema=plain)


def audited_hash(table) -> str:
    """The content hash of a table :func:`read_part` returned: the one its part's record holds, which the read
    verified (a legacy part, which holds none, hashed here): what was audited is what a merge copies."""
    try:
        record = json.loads((table.schema.metadata or {}).get(PART_KEY, b"{}"))
    except (ValueError, RecursionError):
        record = None
    found = record.get("sha256") if isinstance(record, dict) else None
    return found if isinstance(found, str) else content_hash(table)


def part_record(path: pathlib.Path) -> dict[str, Any]:
    """A part's own record (``jaxapf_part``: its content hash, rows, and the shard that wrote it), from its
    schema alone; empty if it has none."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        with open_part(path) as fh:
            record = json.loads((pq.read_schema(fh).metadata or {}).get(PART_KEY, b"{}"))
    except (OSError, ValueError, RecursionError, pa.ArrowException):  # damaged: no record (reading names it)
        return {}
    return record if isinstance(record, dict) else {}


def verify_part(path: pathlib.Path) -> str | None:
    """None if the part reads back intact (:func:`read_part`), else one line saying what is wrong."""
    try:
        read_part(path)
    except ConfigError as err:
        return str(err)
    return None


def part_files(out: pathlib.Path) -> list[pathlib.Path]:
    return sorted(p for p in out.iterdir() if Chunk.from_name(p.name) is not None)
