"""A 10⁷-episode study on 100 machines, on paper: its parts, their metadata, and the time of verify, merge and report.

    python benchmarks/scale.py [--machines 100] [--fields 75758] [--chunk-fields 1024] [--report-fields 7576] [--json]

The study: every registered planner × 3 gain settings (a grid over ``k_att``) × 4 families ×
``--fields`` fields (10,000,056 episodes at the defaults), cut into chunks of ``--chunk-fields``
fields and dealt to ``--machines`` shards (``--shard I/N``) as ``jaxapf sweep`` would. Simulating it
is out of reach here, so every part is written by the sweep's own writer (``part_table``,
``write_part``: the real layout, content hash and metadata) with random metric values, each shard
into its own folder, as machines without a shared file system would leave them. Timed, in
subprocesses as a user runs them: ``jaxapf sweep verify`` of one shard's folder, ``jaxapf sweep merge``
of all of them and ``jaxapf sweep verify`` of the merged output. ``jaxapf report`` (no gallery: the
rows are not simulated) costs in proportion to the rows, not the parts (its bootstrap resamples every
setting × family), so it is timed on the same study with ``--report-fields`` fields (about 10⁶
episodes), and its time per million rows is printed. Printed besides: the parts, the bytes on disk,
a part's footer (its Parquet metadata: schema and the sweep's metadata) and the time to list the
merged folder. Needs about 2.5 GB of disk per copy (two copies); ``SCALE_TMP`` names the folder.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time


def spec_table(fields: int) -> dict:
    from jaxapf.planners import PLANNERS

    return {"name": "scale", "scenario": {"families": ["trap", "crossing", "overtake", "clutter"], "fields": fields,
                                          "seed": 0},
            "grid": {"method": list(PLANNERS.names()), "k_att": [0.5, 1.0, 2.0]}}


def write_synthetic(plan, machines: int, root: pathlib.Path, seed: int = 0) -> list[pathlib.Path]:
    """Every chunk of ``plan`` as a part of random metrics, shard ``i``'s parts in ``root/shard-i``."""
    import numpy as np
    import pyarrow as pa

    from jaxapf.sweep.output import write_part
    from jaxapf.sweep.plan import shard_chunks
    from jaxapf.sweep.schema import part_table, schema

    rng = np.random.default_rng(seed)
    folders = []
    for i in range(machines):
        folder = root / f"shard-{i:03d}"
        folder.mkdir(parents=True)
        layout = schema(plan)  # the plan's metadata: the same in every folder (the spec has no .py plugin)
        for chunk in shard_chunks(plan, i, machines):
            block = plan.blocks[(chunk.variant, chunk.family)]
            shape = (len(plan.variants[chunk.variant].settings), block.padded)
            metrics = {}
            for m in plan.metrics:
                kind = layout.field(m).type
                metrics[m] = (rng.random(shape) < 0.5 if pa.types.is_boolean(kind) else
                              rng.integers(0, 600, shape) if pa.types.is_integer(kind) else
                              rng.random(shape, np.float32) * 60)
            kinds = np.zeros(block.padded, np.int32)  # every field of the first kind
            solvable = rng.random(chunk.stop - chunk.start) < 0.9 if "solvable" in layout.names else None
            write_part(folder, chunk.name, part_table(plan, layout, chunk, metrics, kinds, solvable), (i, machines))
        folders.append(folder)
    return folders


def timed(argv: list[str]) -> tuple[float, subprocess.CompletedProcess]:
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "jaxapf", *argv], capture_output=True, text=True,
                          env={**os.environ, "JAX_PLATFORMS": "cpu"})
    return time.perf_counter() - start, proc


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--machines", type=int, default=100)
    p.add_argument("--fields", type=int, default=75758)
    p.add_argument("--chunk-fields", type=int, default=1024)
    p.add_argument("--report-fields", type=int, default=7576)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    import pyarrow.parquet as pq

    from jaxapf.sweep import parse_spec, plan_sweep
    from jaxapf.sweep.plan import MAX_CHUNKS, chunk_cost

    spec = parse_spec(spec_table(args.fields))
    plan = plan_sweep(spec, devices=1, chunk_fields=args.chunk_fields)
    default = plan_sweep(spec, devices=1)
    result = {"episodes": plan.episodes, "settings": plan.settings,
              "gain_settings": len(spec_table(1)["grid"]["k_att"]), "families": len(spec.families),
              "fields": args.fields, "machines": args.machines,
              "chunk_fields": args.chunk_fields, "parts": len(plan.chunks),
              "parts_at_default_chunking": len(default.chunks),
              "estimated_simulation_cpu_core_hours": round(sum(chunk_cost(plan, c) for c in plan.chunks) / 3600, 1)}
    with tempfile.TemporaryDirectory(dir=os.environ.get("SCALE_TMP")) as tmp:
        tmp = pathlib.Path(tmp)
        start = time.perf_counter()
        folders = write_synthetic(plan, args.machines, tmp / "shards")
        result["write_synthetic_s"] = round(time.perf_counter() - start, 1)
        part = next(folders[0].iterdir())
        footer = pq.ParquetFile(part).metadata
        result["part_footer_bytes"] = footer.serialized_size
        result["part_rows"] = footer.num_rows
        result["bytes_on_disk"] = sum(f.stat().st_size for folder in folders for f in folder.iterdir())
        result["footer_bytes_total"] = result["part_footer_bytes"] * result["parts"]
        result["footer_gb_at_max_parts"] = round(result["part_footer_bytes"] * MAX_CHUNKS / 1e9, 1)
        seconds, proc = timed(["sweep", "verify", str(folders[0])])
        result["verify_one_shard_s"], result["verify_one_shard_exit_status"] = round(seconds, 1), proc.returncode
        merged = tmp / "merged"
        seconds, proc = timed(["sweep", "merge", *map(str, folders), "--out", str(merged)])
        assert proc.returncode == 0, proc.stderr
        result["merge_s"] = round(seconds, 1)
        start = time.perf_counter()
        listed = sum(1 for _ in os.scandir(merged))
        result["list_merged_folder_ms"] = round(1e3 * (time.perf_counter() - start), 1)
        result["merged_entries"] = listed
        seconds, proc = timed(["sweep", "verify", str(merged)])
        result["verify_merged_s"], result["verify_merged_exit_status"] = round(seconds, 1), proc.returncode
        shutil.rmtree(tmp / "shards")
        small = plan_sweep(parse_spec(spec_table(args.report_fields)), devices=1, chunk_fields=args.chunk_fields)
        (folder,) = write_synthetic(small, 1, tmp / "small")
        seconds, proc = timed(["report", str(folder), "--gallery", "0", "--out", str(tmp / "report")])
        assert proc.returncode == 0, proc.stderr
        result |= {"report_episodes": small.episodes, "report_s": round(seconds, 1),
                   "report_s_per_million_rows": round(seconds / small.episodes * 1e6, 1)}
        result["report_s_at_all_episodes_linear"] = round(result["report_s_per_million_rows"] * plan.episodes / 1e6)
    print(json.dumps(result) if args.json else "\n".join(f"{k}: {v}" for k, v in result.items()))
    return 0 if result["verify_merged_exit_status"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
