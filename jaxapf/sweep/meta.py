"""The metadata every part of a sweep carries: the sweep's identity (format, spec, PRNG, float type,
vmap width, metrics), the versions that computed it and where its plugins came from
(docs/sweep-format.md); the plan carries it, the audit judges parts by it."""

from __future__ import annotations

import json
import pathlib
from typing import Any, Mapping, Sequence

import jax

from ..io.names import open_read
from ..validation import ConfigError, first_line
from .spec import SweepSpec

__all__ = ["FORMAT", "LEGACY_FORMAT", "READABLE_FORMATS", "META_KEY", "PRNG", "sweep_meta", "read_meta", "parse_meta",
           "identity", "own_meta", "plugin_files", "sweep_spec", "stored_spec_bound", "open_part", "PART_BYTES"]

FORMAT = "jaxapf.sweep/2"
#: The format before kinds, solvability and content hashes; still read (its parts are not verified).
LEGACY_FORMAT = "jaxapf.sweep/1"
#: Formats this version reads: /1 lacks the ``kind`` and ``solvable`` columns and the parts' content
#: hashes, nothing else changed.
READABLE_FORMATS = (LEGACY_FORMAT, FORMAT)
META_KEY = b"jaxapf"
#: The PRNG of the fields and of the random gain samples.
PRNG = {
    "impl": str(jax.config.jax_default_prng_impl),
    "field_key": "fold_in(key(seed), field)",
    "gain_samples": "bits(key(random.seed), (n, gains), uint32); u = (bits + 0.5) / 2**32",
}


#: The most a part file holds [bytes]: a chunk's rows, of at most a device's memory, compressed; a file past it
#: is refused unread (a link to ``/dev/zero`` is refused before, as a link).
PART_BYTES = 64 * 2**30


def open_part(path: pathlib.Path):
    """A part file open for reading, checked (:func:`jaxapf.io.names.open_read`): a regular file, no link
    followed, no FIFO waited on, at most :data:`PART_BYTES`; every read of a part goes through it."""
    return open_read(path, PART_BYTES)


def read_meta(path: pathlib.Path) -> dict[str, Any]:
    """The ``jaxapf`` metadata of a part file; :class:`ConfigError` if it has none."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        with open_part(path) as fh:
            raw = (pq.read_schema(fh).metadata or {}).get(META_KEY)
    except (OSError, pa.ArrowException, ValueError) as err:
        raise ConfigError(f"{path} is not a readable sweep output (Parquet): {first_line(err)}") from None
    return parse_meta(raw, path)


def parse_meta(raw: bytes | None, path: pathlib.Path) -> dict[str, Any]:
    """The ``jaxapf`` metadata ``raw`` (the bytes of a part's schema key) of the part ``path``, checked as
    :func:`read_meta` checks it: the audit parses it from the very table it read and verified."""
    try:
        meta = json.loads(raw) if raw else None
    except (ValueError, RecursionError):  # bad JSON, bytes that are not UTF-8, nesting no reader follows
        meta = None
    if not isinstance(meta, dict) or meta.get("format") not in READABLE_FORMATS:
        raise ConfigError(f"{path} is not the output of jaxapf sweep (no '{META_KEY.decode()}' metadata of format "
                          f"{' or '.join(READABLE_FORMATS)} in its Parquet schema)")
    wrong = [key for key, ok in _SHAPE.items() if key in meta and not ok(meta[key])]
    if wrong:
        raise ConfigError(f"{path}: its '{META_KEY.decode()}' metadata holds {', '.join(wrong)} as another type "
                          "than a sweep writes (edited after it was written)")
    return meta


def _texts(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, str) for v in value)


#: The type of each key a part's metadata holds (docs/sweep-format.md); a part holding one as another type
#: is no sweep's part, and one lacking a key the audit needs is refused there (:func:`needed`).
_SHAPE = {
    "spec": lambda v: isinstance(v, dict),
    "spec_hash": lambda v: isinstance(v, str),
    "dtype": lambda v: v in ("float32", "float64"),
    "vmap_width": lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1,
    "metrics": _texts,
    "versions": lambda v: isinstance(v, dict),
    "prng": lambda v: v is None or isinstance(v, dict),
    "plugin_files": lambda v: v is None or isinstance(v, list),
    "obstacle_slots": lambda v: v is None or (isinstance(v, int) and not isinstance(v, bool) and v >= 1),
    "fused": _texts,
}


def needed(meta: Mapping[str, Any], keys: Sequence[str] = ("spec", "dtype", "metrics")) -> None:
    """:class:`ConfigError` unless ``meta`` holds ``keys`` (what judging parts against their sweep reads)."""
    lacks = [k for k in keys if k not in meta]
    if lacks:
        raise ConfigError(f"the parts' '{META_KEY.decode()}' metadata lacks {', '.join(lacks)}: they cannot be "
                          "judged against their sweep (edited after they were written)")


def identity(meta: Mapping[str, Any]) -> dict[str, Any]:
    """What must match for parts to belong to one sweep (numbers bit for bit), the jaxapf version that wrote
    them included: one output holds one version's parts (docs/sweep-format.md)."""
    versions = meta.get("versions")
    return {**{k: meta.get(k) for k in ("format", "spec_hash", "dtype", "vmap_width", "metrics", "obstacle_slots",
                                        "fused")},
            "jaxapf": versions.get("jaxapf") if isinstance(versions, Mapping) else None}


def own_meta(meta: Mapping[str, Any]) -> dict[str, Any]:
    """The keys a part carries (its format and :data:`_SHAPE`'s), in ``meta``'s order, of a sweep's metadata as
    :func:`jaxapf.sweep.read_sweep` returns it (which adds what it found: parts, completeness, location)."""
    return {k: v for k, v in meta.items() if k == "format" or k in _SHAPE}


def stored_spec_bound(meta: Mapping[str, Any]) -> bool:
    """Whether the spec a part stores is the one its ``spec_hash`` names: the SHA-256 of its canonical JSON
    (:attr:`~jaxapf.sweep.spec.SweepSpec.hash`), so a stored spec edited with its hash kept is caught."""
    import hashlib

    try:
        text = json.dumps(meta.get("spec"), sort_keys=True, separators=(",", ":"))
    except (TypeError, ValueError, RecursionError):
        return False
    return hashlib.sha256(text.encode()).hexdigest() == meta.get("spec_hash")


def sweep_meta(spec: SweepSpec, dtype: str, width: int, metrics: Sequence[str], out: str | pathlib.Path | None = None,
               versions: Mapping[str, str] | None = None, obstacle_slots: int | None = None,
               fused: Sequence[str] = ()) -> dict[str, Any]:
    """The ``jaxapf`` metadata of every part of ``spec`` run in ``dtype`` at vmap ``width``, yielding
    ``metrics`` (:attr:`~jaxapf.sweep.plan.Plan.meta`); with ``.py`` plugins and the output folder ``out``,
    ``plugin_files`` records where each was imported from. ``versions``: of the process that computes the
    chunks (default this one's; a Ray run's are a worker's); ``obstacle_slots``: the slot count every
    family was padded to (the accelerator policy), which rounds some numbers apart, so it is part of the
    sweep's identity (absent: each family at its own); ``fused``: the methods flown in one program (the
    accelerator policy, :func:`~jaxapf.sweep.plan.fuse`), which rounds apart too (absent: each its own)."""
    from ..io.versions import versions as here

    files = plugin_files(spec, out)
    meta = {"format": FORMAT, "spec": spec.to_json(), "spec_hash": spec.hash,
            "versions": dict(versions) if versions is not None else here(),
            "prng": PRNG, "dtype": dtype, "vmap_width": width, "metrics": list(metrics)}
    return (meta | ({"plugin_files": files} if files else {})
            | ({"obstacle_slots": obstacle_slots} if obstacle_slots is not None else {})
            | ({"fused": list(fused)} if fused else {}))


def plugin_files(spec: SweepSpec, out: str | pathlib.Path | None) -> list[dict[str, str] | None]:
    """Per plugin of ``spec``: a ``.py`` file's absolute path and its path relative to the output
    folder ``out`` (so a dataset moved together with its plugin still finds it), None for a module;
    empty without ``.py`` plugins."""
    if not any(name.endswith(".py") for name in spec.plugins):
        return []
    import os

    out = pathlib.Path(out).resolve() if out is not None else None
    paths = spec.plugin_paths or spec.plugins
    return [None if not name.endswith(".py") else
            {"path": str(path), **({"from_output": os.path.relpath(path, out)} if out is not None else {})}
            for name, path in zip(spec.plugins, paths)]


def sweep_spec(meta: Mapping[str, Any]) -> SweepSpec:
    """:func:`_sweep_spec`; metadata whose spec cannot be read back, or is not the one its ``spec_hash`` names
    (:func:`stored_spec_bound`), is a :class:`ConfigError` in one line."""
    if "spec_hash" in meta and not stored_spec_bound(meta):
        raise ConfigError("the sweep's stored spec is not the one its spec_hash names: edited after it was written")
    try:
        return _sweep_spec(meta)
    except ConfigError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError, IndexError, RecursionError) as err:
        raise ConfigError(f"the sweep's spec in its metadata cannot be read back ({type(err).__name__}: "
                          f"{first_line(err)}): edited after it was written, or of another version") from None


def _sweep_spec(meta: Mapping[str, Any]) -> SweepSpec:
    """The spec of a sweep's metadata (``meta`` from :func:`read_sweep`). A dataset is data: its plugins
    are never imported here, only named (the components they register must be registered already:
    ``--plugin``); a ``.py`` plugin is named by its path relative to the output folder (``location``) if
    it is there (a dataset moved together with its plugin), else by the absolute path the sweep recorded."""
    files = meta.get("plugin_files") or []
    names = list(meta["spec"].get("plugins", []))
    if not files or len(files) != len(names):
        return SweepSpec.from_json(meta["spec"], import_plugins=False)
    location = meta.get("location")
    paths = []
    for name, rec in zip(names, files):
        if not isinstance(rec, Mapping) or not isinstance(rec.get("path"), str):
            paths.append(str(name))
            continue
        near = ([str((pathlib.Path(location) / str(rec["from_output"])).resolve())]
                if location and isinstance(rec.get("from_output"), str) else [])
        paths.append(next((c for c in near if pathlib.Path(c).is_file()), rec["path"]))
    return SweepSpec.from_json(meta["spec"], plugin_paths=paths, import_plugins=False)
