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
    # the tasks share the run's compilation cache (a cluster's shared home would): the first compiles
    script = script.replace("jaxapf sweep", f"{sys.executable} -m jaxapf sweep --chunk-fields 3")
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
    with pytest.raises(ConfigError, match="holds parts of another sweep .spec_hash differs. .e.g. .*same spec"):
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


# ---- the division, agreed before any shard writes a part -------------------------------------------

def test_the_first_shard_fixes_the_division_and_a_later_different_one_is_refused_before_any_work(tmp_path):
    """Chunking and N used to be compared only with parts already present when a shard started."""
    import json

    from jaxapf.sweep import dry_run
    from jaxapf.sweep.division import DIVISION_NAME

    out = tmp_path / "out"
    run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(0, 2))
    record = json.loads((out / DIVISION_NAME).read_text())
    assert record["shards"] == 2 and record["chunking"] == "--chunk-fields 3" and record["fixed_by"]["shard"] == "0/2"
    for part in part_files(out):  # as if no part were written yet: the division alone decides
        part.unlink()
    with OutputLock(out, (0, 2)):  # shard 0/2 still running (say, compiling)
        for chunk_fields, shard, asks in ((4, (1, 2), "asks for 2 shard.s. of 12 chunks .--chunk-fields 4."),
                                          (3, (1, 3), "asks for 3 shard.s. of 16 chunks .--chunk-fields 3.")):
            with pytest.raises(ConfigError, match=f"is divided into 2 shard.s. of 16 chunks .--chunk-fields 3., "
                                                  f"fixed by shard 0/2, pid .*; this shard .{shard[0]}/{shard[1]}. "
                                                  f"{asks}: every shard"):
                run_sweep(_spec(), out, chunk_fields=chunk_fields, quiet=True, shard=shard)
            with pytest.raises(ConfigError, match="is divided into 2 shard"):
                dry_run(_spec(), out, shard=shard, chunk_fields=chunk_fields)
        assert not part_files(out)
        other = copy.deepcopy(SPEC)
        other["scenario"]["seed"] = 6
        with pytest.raises(ConfigError, match="this shard .1/2. runs another sweep .spec_hash differs."):
            run_sweep(parse_spec(other), out, chunk_fields=3, quiet=True, shard=(1, 2))
    run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(1, 2))  # the same division: runs


def test_a_division_that_no_part_follows_and_no_live_shard_holds_is_replaced(tmp_path):
    """Shards that died before writing a part do not bind the next ones; --overwrite forgets the division."""
    import json

    from jaxapf.sweep.division import DIVISION_NAME

    out = tmp_path / "out"
    run_sweep(_spec(), out, chunk_fields=3, quiet=True, shard=(0, 2))
    for part in part_files(out):
        part.unlink()
    run_sweep(_spec(), out, chunk_fields=4, quiet=True, shard=(0, 3))  # nobody holds or follows the old one
    assert json.loads((out / DIVISION_NAME).read_text())["shards"] == 3
    run_sweep(_spec(), out, chunk_fields=4, quiet=True, overwrite=True)
    assert not (out / DIVISION_NAME).exists()


def _race_worker(barrier, tasks, results):
    """One process of a shard race: for each task, wait at the barrier with the other process, then run
    its shard; report ``(status, what)``: ``ok`` and the episodes run, or ``refused`` and the one line."""
    import os

    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    from jaxapf.sweep import parse_spec, run_sweep
    from jaxapf.validation import ConfigError

    spec = parse_spec(SPEC)
    for out, shard, chunk_fields in iter(tasks.get, None):
        barrier.wait()
        try:
            done = run_sweep(spec, out, chunk_fields=chunk_fields, quiet=True, shard=shard)
            results.put(("ok", done.episodes))
        except ConfigError as err:
            results.put(("refused", str(err)))


@pytest.mark.slow
def test_shards_started_together_never_both_run_a_different_division(reference, tmp_path):
    """Two shards behind a barrier, 50 times with different --chunk-fields and 50 times with different N
    (and 10 that agree): never two exits without a refusal when they disagree, never a row lost,
    doubled or changed; the one refused wrote nothing. (Before the division was agreed, both exited 0
    with 24 of 96 rows missing and 24 doubled.)"""
    import multiprocessing

    import numpy as np

    from jaxapf.sweep.audit import audit_folder

    ctx = multiprocessing.get_context("spawn")
    barrier, results = ctx.Barrier(2), ctx.Queue()
    queues = [ctx.Queue(), ctx.Queue()]
    workers = [ctx.Process(target=_race_worker, args=(barrier, q, results), daemon=True) for q in queues]
    for w in workers:
        w.start()
    rng = np.random.default_rng(0)
    trials = ([("chunking", None)] * 50 + [("shards", None)] * 50 + [("agree", None)] * 10)
    key = ["setting", "family", "field"]
    try:
        for i, (kind, _) in enumerate(trials):
            out = tmp_path / f"race-{i}"
            if kind == "chunking":
                a, b = (int(x) for x in rng.choice([2, 3, 4, 5, 6, 12], 2, replace=False))
                tasks = [((0, 2), a), ((1, 2), b)]
            elif kind == "shards":
                n, m = (int(x) for x in rng.choice([2, 3, 4, 5], 2, replace=False))
                tasks = [((0, n), 3), ((1, m), 3)]
            else:
                tasks = [((0, 2), 3), ((1, 2), 3)]
            for q, (shard, chunk_fields) in zip(queues, tasks):
                q.put((out, shard, chunk_fields))
            got = [results.get(timeout=300) for _ in tasks]
            statuses = sorted(s for s, _ in got)
            if kind == "agree":
                assert statuses == ["ok", "ok"], got
            else:
                assert statuses == ["ok", "refused"], (kind, tasks, got)
                refusal = next(what for s, what in got if s == "refused")
                # the division record refuses it; a shard that lags so far (a loaded machine) that the other has
                # finished finds its parts first (chunked otherwise, or written as another number of shards) and is
                # refused by them: one line either way
                assert any(why in refusal for why in ("is divided into", "chunked otherwise", "is being written as")), \
                    refusal
                assert "\n" not in refusal
            found = audit_folder(out)[0] if part_files(out) else None
            assert found is not None and not found.problems, found
            df = read_sweep(out)[0]
            assert not df.duplicated(key).any()
            merged = df.merge(reference, on=key, suffixes=("", "_ref"))
            assert len(merged) == len(df)  # every row is one of the one-process run's, with its numbers
            for column in ("min_clearance", "path_length", "success", "steps"):
                np.testing.assert_array_equal(merged[column], merged[f"{column}_ref"])
            if kind == "agree":
                assert found.complete
    finally:
        for q in queues:
            q.put(None)
        for w in workers:
            w.join(timeout=60)
