"""The Parquet layout of a sweep: the schema of its rows and a chunk's table (docs/sweep-format.md);
the metadata every part carries is :mod:`jaxapf.sweep.meta`'s."""

from __future__ import annotations

import json
from typing import Any, Mapping

import numpy as np

from ..config import STATIC_KEYS
from ..metrics import find_metric
from ..scenarios import FAMILIES
from ..scenarios.swarms import SWARM_FAMILIES
from ..spec.settings import AXIS_WEIGHT_KEYS
from .meta import META_KEY
from .plan import Chunk, Plan
from .spec import SweepSpec

__all__ = ["schema", "row_schema", "part_table", "static_columns"]

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


def schema(plan: Plan):
    """The Arrow schema of the plan's rows (docs/sweep-format.md), with the plan's ``meta`` as its metadata."""
    return row_schema(plan.spec, plan.meta, plan.gain_columns, plan.metrics)


def row_schema(spec: SweepSpec, meta: Mapping[str, Any], gain_columns: Any = None, metrics: Any = None):
    """The Arrow schema of the rows of the sweep ``spec`` whose parts carry ``meta`` (its float type and,
    unless given, its metrics; the gain columns default to the spec's): what every sound part holds."""
    import pyarrow as pa

    gain_columns = spec.gain_columns() if gain_columns is None else gain_columns
    metrics = meta["metrics"] if metrics is None else metrics
    float_type = pa.from_numpy_dtype(np.dtype(meta["dtype"]))
    fields = [pa.field("setting", pa.int32()), pa.field("method", pa.string()), pa.field("convention", pa.string())]
    fields += [pa.field(k, pa.float64()) for k in gain_columns]
    fields += [pa.field(k, _column_type(spec, k)) for k in static_columns(spec)]
    fields += [pa.field(k, pa.string() if isinstance(v, str) else pa.int64()) for k, v in
               (spec.tags[0] if spec.tags else ())]
    fields += [pa.field("family", pa.string()), pa.field("kind", pa.string())]
    fields += [pa.field("agents", pa.int32())] if spec.swarm else []
    fields += [pa.field("field", pa.int64()), pa.field("seed", pa.int64())]
    if spec.oracle:
        fields.append(pa.field("solvable", pa.bool_()))
    fields += [pa.field(m, getattr(pa, _ARROW_TYPES[find_metric(m).dtype])() if find_metric(m).dtype in _ARROW_TYPES
                        else float_type) for m in metrics]
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
    for k in plan.gain_columns:
        cols[k] = np.repeat(np.array([s.gains[k] for s in variant.settings], np.float64), n)
    for k in spec.tag_names:
        cols[k] = np.repeat(np.array([dict(s.tags)[k] for s in variant.settings], dtype=object), n)
    for m in plan.metrics:
        cols[m] = np.ascontiguousarray(metrics[m][:, :n]).reshape(-1)
    zeros = pa.array(np.zeros(rows, np.int32))
    arrays = [pa.array([constant[f.name]], f.type).take(zeros) if f.name in constant else pa.array(cols[f.name], f.type)
              for f in layout]
    return pa.Table.from_arrays(arrays, schema=layout)


