"""The Parquet layout of a sweep: the schema of its rows, a chunk's table, and the metadata every
part carries (docs/sweep-format.md)."""

from __future__ import annotations

import json
import pathlib
from typing import Any, Mapping

import jax
import numpy as np

from ..config import STATIC_KEYS
from ..metrics import find_metric
from ..scenarios import FAMILIES
from ..scenarios.swarms import SWARM_FAMILIES
from ..spec.settings import AXIS_WEIGHT_KEYS
from ..validation import ConfigError, first_line
from .plan import Chunk, Plan
from .spec import SweepSpec

__all__ = ["sweep_spec", "FORMAT", "LEGACY_FORMAT", "META_KEY", "PRNG", "sweep_meta", "schema", "part_table",
           "read_meta", "identity", "static_columns"]

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
_ARROW_TYPES = {"bool": "bool_", "int32": "int32"}


def static_columns(spec: SweepSpec) -> tuple[str, ...]:
    """The simulation/MPC settings that get a column: those the spec names (but method and
    convention, which always have one), and ``t_max`` always (its default is the family's)."""
    named = set(spec.static_keys) - {"method", "convention"} | {"t_max"}
    return tuple(k for k in STATIC_KEYS if k in named)


def _spec_values(spec: SweepSpec, key: str) -> list[Any]:
    return ([v for k, v in spec.sim.items() if k == key] + [x for k, values in spec.grid if k == key for x in values]
            + [v for entry in spec.explicit for k, v in entry if k == key])


def _column_type(spec: SweepSpec, key: str):
    import pyarrow as pa

    values = _spec_values(spec, key)
    if any(isinstance(v, str) for v in values):
        return pa.string()  # names: filter, plant
    if any(isinstance(v, tuple) for v in values):
        return pa.string()  # per-axis weights given as [x, y, z]: JSON text
    if any(isinstance(v, bool) for v in values):
        return pa.bool_()
    if any(isinstance(v, int) for v in values):
        return pa.int64()
    return pa.float64()


def schema(plan: Plan, meta: Mapping[str, Any]):
    """The Arrow schema of the plan's rows (docs/sweep-format.md), with ``meta`` as its metadata."""
    import pyarrow as pa

    spec = plan.spec
    float_type = pa.from_numpy_dtype(np.dtype(meta["dtype"]))
    fields = [pa.field("setting", pa.int32()), pa.field("method", pa.string()), pa.field("convention", pa.string())]
    fields += [pa.field(k, pa.float64()) for k in spec.gain_columns()]
    fields += [pa.field(k, _column_type(spec, k)) for k in static_columns(spec)]
    fields += [pa.field(k, pa.string() if isinstance(v, str) else pa.int64()) for k, v in
               (spec.tags[0] if spec.tags else ())]
    fields += [pa.field("family", pa.string()), pa.field("kind", pa.string())]
    fields += [pa.field("agents", pa.int32())] if spec.swarm else []
    fields += [pa.field("field", pa.int64()), pa.field("seed", pa.int64())]
    if spec.oracle:
        fields.append(pa.field("solvable", pa.bool_()))
    fields += [pa.field(m, getattr(pa, _ARROW_TYPES[find_metric(m).dtype])() if find_metric(m).dtype in _ARROW_TYPES
                        else float_type) for m in plan.metrics]
    return pa.schema(fields, metadata={META_KEY: json.dumps(meta, sort_keys=True).encode()})


def _cell(key: str, value: Any, text: bool) -> Any:
    """A static setting's value in its column: per-axis weights in a text column as JSON text."""
    if text and key in AXIS_WEIGHT_KEYS:
        return json.dumps(list(value) if isinstance(value, tuple) else value)
    return value


def part_table(plan: Plan, layout, chunk: Chunk, metrics: Mapping[str, np.ndarray], kinds: np.ndarray,
               solvable: np.ndarray | None = None):
    """The rows of one chunk: settings-major, fields-minor. Every column but the setting index,
    the gains, the field, its kind, its solvability and the metrics is constant within a chunk (one
    variant, one family). ``kinds``: the kind index of each of the chunk's (padded) fields;
    ``solvable``: the oracle's answer for each real field (with the spec's ``oracle``)."""
    import pyarrow as pa

    spec, variant = plan.spec, plan.variants[chunk.variant]
    sim = plan.blocks[(chunk.variant, chunk.family)].sim
    n = chunk.stop - chunk.start
    rows = n * len(variant.settings)
    static = dict(variant.static)
    params = spec.family_params(chunk.family)
    constant = {"method": sim.planner.method, "convention": sim.planner.convention, "family": chunk.family,
                "seed": spec.seed, **({"agents": params.agents} if spec.swarm else {})}
    for k in static_columns(spec):  # only t_max can be unnamed, and it is a SimConfig field
        constant[k] = _cell(k, static[k] if k in static else sim.flat()[k], pa.types.is_string(layout.field(k).type))
    names = np.asarray((SWARM_FAMILIES if spec.swarm else FAMILIES).get(params.family).kinds, dtype=object)
    cols: dict[str, Any] = {"setting": np.repeat(np.array([s.index for s in variant.settings], np.int32), n),
                            "field": np.tile(np.arange(chunk.start, chunk.stop, dtype=np.int64), len(variant.settings)),
                            "kind": np.tile(names[np.asarray(kinds)[:n]], len(variant.settings))}
    if solvable is not None:
        cols["solvable"] = np.tile(np.asarray(solvable, bool), len(variant.settings))
    for k in spec.gain_columns():
        cols[k] = np.repeat(np.array([s.gains[k] for s in variant.settings], np.float64), n)
    for k in spec.tag_names:
        cols[k] = np.repeat(np.array([dict(s.tags)[k] for s in variant.settings], dtype=object), n)
    for m in plan.metrics:
        cols[m] = np.ascontiguousarray(metrics[m][:, :n]).reshape(-1)
    zeros = pa.array(np.zeros(rows, np.int32))
    arrays = [pa.array([constant[f.name]], f.type).take(zeros) if f.name in constant else pa.array(cols[f.name], f.type)
              for f in layout]
    return pa.Table.from_arrays(arrays, schema=layout)


def read_meta(path: pathlib.Path) -> dict[str, Any]:
    """The ``jaxapf`` metadata of a part file; :class:`ConfigError` if it has none."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        raw = (pq.read_schema(path).metadata or {}).get(META_KEY)
    except (OSError, pa.ArrowException, ValueError) as err:
        raise ConfigError(f"{path} is not a readable sweep output (Parquet): {first_line(err)}") from None
    try:
        meta = json.loads(raw) if raw else None
    except (ValueError, RecursionError):  # bad JSON, bytes that are not UTF-8, nesting no reader follows
        meta = None
    if not isinstance(meta, dict) or meta.get("format") not in READABLE_FORMATS:
        raise ConfigError(f"{path} is not the output of jaxapf sweep (no '{META_KEY.decode()}' metadata of format "
                          f"{' or '.join(READABLE_FORMATS)} in its Parquet schema)")
    return meta


def identity(meta: Mapping[str, Any]) -> dict[str, Any]:
    """What must match for parts to belong to one sweep (numbers bit for bit)."""
    return {k: meta.get(k) for k in ("format", "spec_hash", "dtype", "vmap_width", "metrics")}


def sweep_meta(spec: SweepSpec, plan: Plan, out: str | pathlib.Path | None = None,
               versions: Mapping[str, str] | None = None) -> dict[str, Any]:
    """The ``jaxapf`` metadata of every part (docs/sweep-format.md); with ``.py`` plugins and the
    output folder ``out``, ``plugin_files`` records where each was imported from. ``versions``: of the
    process that computes the chunks (default this one's; a Ray run's are a worker's)."""
    from ..io.versions import versions as here

    meta = {"format": FORMAT, "spec": spec.to_json(), "spec_hash": spec.hash,
            "versions": dict(versions) if versions is not None else here(),
            "prng": PRNG, "dtype": plan.dtype, "vmap_width": plan.width, "metrics": list(plan.metrics)}
    files = plugin_files(spec, out)
    return meta | ({"plugin_files": files} if files else {})


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
