"""Coordinator-free shards: `jaxapf sweep SPEC --shard I/N` runs a fixed, cost-balanced share of the
chunks; shards run at any time, in any order, are killed and rerun, write into one output or each into
its own folder, and their rows are a one-process run's, bit for bit."""

from __future__ import annotations

import copy

import pandas as pd
import pytest
from cli_capture import capture

from jaxapf.cli import main
from jaxapf.io.lock import OutputLock
from jaxapf.sweep import parse_spec, plan_sweep, read_sweep, run_sweep
from jaxapf.sweep.merge import merge_outputs
from jaxapf.sweep.output import part_files
from jaxapf.sweep.plan import chunk_cost, shard_chunks
from jaxapf.validation import ConfigError, Interrupted

SPEC = {
    "name": "shards",
    "scenario": {"families": ["trap", "crossing"], "fields": 12, "seed": 5},
    "sim": {"t_max": 2.0, "horizon": 3, "iters": 3},
    "grid": {"method": ["basic", "direction_velocity"]},
}


def _spec(**changes):
    data = copy.deepcopy(SPEC)
    data.update(changes)
    return parse_spec(data)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "ref.parquet"
    run_sweep(_spec(), out, chunk_fields=3, quiet=True)
    return read_sweep(out)[0]


def test_the_shards_deal_every_chunk_once_balanced_by_cost():
    plan = plan_sweep(_spec(), chunk_fields=3, devices=1)
    dealt = [shard_chunks(plan, i, 3) for i in range(3)]
    assert sorted(c.name for d in dealt for c in d) == sorted(c.name for c in plan.chunks)
    loads = [sum(chunk_cost(plan, c) for c in d) for d in dealt]
    assert max(loads) - min(loads) <= max(chunk_cost(plan, c) for c in plan.chunks)  # LPT: within one chunk
    assert dealt == [shard_chunks(plan_sweep(_spec(), chunk_fields=3, devices=1), i, 3) for i in range(3)]


@pytest.mark.slow
def test_shards_run_apart_killed_and_rerun_give_the_one_process_rows(reference, tmp_path):
    out = tmp_path / "out"

    def killed(chunk):
        raise KeyboardInterrupt

    for i in (2, 0):  # out of order
        run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(i, 4))
    with pytest.raises(Interrupted):  # shard 3 dies after its first part
        run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(3, 4), after_part=killed)
    rc, stdout, _ = capture(main, ["sweep", "verify", str(out)])
    assert rc == 1 and "missing" in stdout
    again = run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(3, 4))
    assert again.skipped > 0 and again.shard == (3, 4)
    run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(1, 4))
    assert run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(1, 4)).episodes == 0  # rerun: nothing
    rc, stdout, _ = capture(main, ["sweep", "verify", str(out)])
    assert rc == 0 and "complete and sound" in stdout
    df, meta = read_sweep(out)
    assert meta["complete"]
    pd.testing.assert_frame_equal(df, reference)


@pytest.mark.slow
def test_shards_in_their_own_folders_merge_to_the_one_process_rows(reference, tmp_path):
    folders = [tmp_path / f"shard{i}" for i in range(3)]
    for i, folder in enumerate(folders):
        run_sweep(_spec(), folder, chunk_fields=3, quiet=True, shard=(i, 3))
    merge_outputs(folders, tmp_path / "all")
    df, meta = read_sweep(tmp_path / "all")
    assert meta["complete"]
    pd.testing.assert_frame_equal(df, reference)


def test_one_shard_at_a_time_and_never_beside_a_whole_output_writer(tmp_path):
    out = tmp_path / "out"
    with OutputLock(out, (1, 4)):
        with pytest.raises(ConfigError, match=r"\(shard 1/4\) is already being written by this process"):
            run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(1, 4))
        run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(0, 4))  # another shard writes beside it
        with pytest.raises(ConfigError, match=r"is being written by 1 shard\(s\): shard 1/4 \(pid"):
            run_sweep(_spec(), out, chunk_fields=3, quiet=True)
    with OutputLock(out):
        with pytest.raises(ConfigError, match="being written by"):
            run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(2, 4))


def test_shards_that_disagree_on_the_chunking_are_refused(tmp_path):
    """Two processes given different --chunk-fields lost 68 rows and doubled 64 without a word."""
    out = tmp_path / "out"
    run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(0, 2))
    with pytest.raises(ConfigError, match="chunked otherwise than this plan.*same --chunk-fields"):
        run_sweep(_spec(), out, chunk_fields=4, quiet=True, shard=(1, 2))
    assert len(part_files(out)) == len(shard_chunks(plan_sweep(_spec(), chunk_fields=3, devices=1), 0, 2))


@pytest.mark.slow
def test_the_slurm_array_of_the_docs_runs(reference, tmp_path):
    """docs/sweep.md's job script, its spec and output swapped for this test's, run by bash as the tasks
    of a 4-task array would run it (SLURM_ARRAY_TASK_ID / SLURM_ARRAY_TASK_COUNT set), the last task
    first; then `jaxapf sweep verify` passes and the rows are the one-process run's."""
    import json
    import os
    import pathlib
    import re
    import subprocess
    import sys

    doc = (pathlib.Path(__file__).resolve().parents[2] / "docs" / "sweep.md").read_text()
    import textwrap

    script = textwrap.dedent(re.search(r"```bash\n( *#!/bin/bash\n *#SBATCH --array.*?)\n *```", doc, re.S)[1])
    spec = tmp_path / "shards.toml"
    lines = [f"name = {json.dumps(SPEC['name'])}"]
    for table in ("scenario", "sim", "grid"):
        lines += [f"[{table}]"] + [f"{k} = {json.dumps(v)}" for k, v in SPEC[table].items()]
    spec.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.parquet"
    script = script.replace("sweeps/quick.toml", str(spec)).replace("runs/quick.parquet", str(out))
    script = script.replace("jaxapf sweep", f"{sys.executable} -m jaxapf sweep --no-cache --chunk-fields 3")
    for task in (3, 0, 2, 1):
        env = {**os.environ, "JAX_PLATFORMS": "cpu", "SLURM_ARRAY_TASK_ID": str(task), "SLURM_ARRAY_TASK_COUNT": "4"}
        run = subprocess.run(["bash", "-c", script], env=env, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr
        assert f"shard {task}/4" in run.stdout
    rc, stdout, _ = capture(main, ["sweep", "verify", str(out)])
    assert rc == 0, stdout
    pd.testing.assert_frame_equal(read_sweep(out)[0], reference)


def test_a_shard_refuses_another_sweeps_output_and_another_division(tmp_path):
    out = tmp_path / "out"
    run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(0, 4))
    other = copy.deepcopy(SPEC)
    other["scenario"]["seed"] = 6
    with pytest.raises(ConfigError, match="parts of another sweep .*same spec"):
        run_sweep(parse_spec(other), out, chunk_fields=3, quiet=True, shard=(1, 4))
    with pytest.raises(ConfigError, match="being written as 4 shard.s., not 3"):
        run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(1, 3))


def test_a_refusal_names_the_live_shards_not_a_dead_writers_note(tmp_path):
    import json
    import time

    out = tmp_path / "out"
    out.mkdir()
    (out / ".lock").write_text(json.dumps({"pid": 1, "host": "gone", "since": time.time(), "command": "dead run"}))
    (out / ".lock-shard-0002-of-0004").write_text(json.dumps({"pid": 2, "host": "gone", "since": 0.0,
                                                              "command": "a dead shard"}))
    with OutputLock(out, (1, 4)):
        with pytest.raises(ConfigError) as err:
            OutputLock(out).acquire()
    line = str(err.value)
    assert "1 shard(s): shard 1/4 (pid" in line and "dead run" not in line and "a dead shard" not in line


def test_a_shards_dry_run_makes_the_runs_checks_and_changes_nothing(tmp_path):
    from jaxapf.sweep import dry_run

    out = tmp_path / "out"
    run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(0, 2))
    with pytest.raises(ConfigError, match="is being written as 2 shard"):
        dry_run(_spec(), out, shard=(0, 3), chunk_fields=3)
    with pytest.raises(ConfigError, match="chunked otherwise than this plan"):
        dry_run(_spec(), out, shard=(1, 2), chunk_fields=4)
    part = part_files(out)[0]
    part.write_bytes(part.read_bytes()[:-100])  # truncated
    with pytest.raises(ConfigError, match="cannot be trusted"):
        dry_run(_spec(), out, shard=(0, 2), chunk_fields=3)
    assert "1 still to run in" in dry_run(_spec(), out, shard=(0, 2), chunk_fields=3, repair=True)
    assert part.exists() and len(part_files(out)) == 8  # nothing removed
