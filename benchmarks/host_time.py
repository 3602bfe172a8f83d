"""Host time per written part of a many-setting sweep, and how much of it expands the settings.

    python benchmarks/host_time.py [--settings 2000] [--fields 64] [--parts 20] [--json]

A spec with ``[random] n = --settings`` gain samples on ``clutter`` is planned as ``jaxapf sweep`` plans it;
then ``--parts`` of its chunks are written as the sweep writes them (:func:`~jaxapf.sweep.schema.part_table`
and :func:`~jaxapf.sweep.output.write_part`, into a temporary folder) from metric arrays of the right
shapes and dtypes (no episode is flown: this is the host's share only). Every call of the spec's setting
expansion (``SweepSpec.settings`` and ``SweepSpec.gain_columns``) made while writing is counted and timed
(the plan carries the settings and gain columns, so a part should make none), and so is one expansion
from scratch (a fresh spec's first call: what every part paid before).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import tempfile
import time

import numpy as np


@contextlib.contextmanager
def timed(cls, names, spent: list[float]):
    """Time every call of the methods ``names`` of ``cls`` into ``spent`` while inside."""
    originals = {n: getattr(cls, n) for n in names}

    def wrap(fn):
        def inner(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent.append(time.perf_counter() - t0)
        return inner

    for n, fn in originals.items():
        setattr(cls, n, wrap(fn))
    try:
        yield
    finally:
        for n, fn in originals.items():
            setattr(cls, n, fn)


def measure(settings: int, fields: int, parts: int) -> dict:
    import pathlib

    from jaxapf.metrics import METRICS
    from jaxapf.sweep import parse_spec, plan_sweep
    from jaxapf.sweep.output import write_part
    from jaxapf.sweep.schema import part_table, schema
    from jaxapf.sweep.spec import SweepSpec

    table = {"name": "host-time", "scenario": {"families": ["clutter"], "fields": fields * parts, "oracle": False},
             "random": {"n": settings, "seed": 0, "gamma": [0.0, 3.0], "k": [0.0, 1.0], "k_rep": [1.0, 20.0]}}
    t0 = time.perf_counter()
    fresh = parse_spec(table)
    parse_s = time.perf_counter() - t0
    fresh = dataclasses.replace(fresh)  # the same spec, nothing expanded yet (parsing expanded it once)
    t0 = time.perf_counter()
    fresh.settings()
    fresh.gain_columns()
    expansion_s = time.perf_counter() - t0

    spec = parse_spec(table)
    plan = plan_sweep(spec, chunk_fields=fields, devices=1, width=8, backend="cpu")
    layout = schema(plan)
    chunks = plan.chunks[:parts]
    spent: list[float] = []
    per_part = []
    with tempfile.TemporaryDirectory() as folder, timed(SweepSpec, ("settings", "gain_columns"), spent):
        out = pathlib.Path(folder)
        for chunk in chunks:
            g, n = len(plan.variants[chunk.variant].settings), chunk.stop - chunk.start
            metrics = {m: np.zeros((g, n), {"bool": bool, "int32": np.int32}.get(METRICS.get(m).dtype, np.float32))
                       for m in plan.metrics}
            t0 = time.perf_counter()
            write_part(out, chunk.name, part_table(plan, layout, chunk, metrics, np.zeros(n, np.int32)))
            per_part.append(time.perf_counter() - t0)
    return {"config": {"settings": settings, "fields_per_part": fields, "parts": len(chunks),
                       "rows_per_part": settings * fields},
            "parse_s": parse_s, "expansion_from_scratch_s": expansion_s,
            "part_s": {"median": float(np.median(per_part)), "all": per_part},
            "expansion_calls": len(spent), "expansion_s_per_part": float(np.sum(spent)) / len(chunks),
            "expansion_share": float(np.sum(spent)) / float(np.sum(per_part))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--settings", type=int, default=2000)
    parser.add_argument("--fields", type=int, default=64)
    parser.add_argument("--parts", type=int, default=20)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    result = measure(args.settings, args.fields, args.parts)
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print(f"{result['config']['parts']} parts of {result['config']['rows_per_part']:,} rows: "
              f"{result['part_s']['median'] * 1e3:.1f} ms each (median); setting expansion "
              f"{result['expansion_s_per_part'] * 1e6:.1f} us per part over {result['expansion_calls']} calls "
              f"({100 * result['expansion_share']:.3f} %); from scratch it costs "
              f"{result['expansion_from_scratch_s'] * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
