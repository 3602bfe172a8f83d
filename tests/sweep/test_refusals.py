"""Input a sweep cannot take, refused in one line with exit 2 before any work; what a user names in a
dataset shown as text. Each case was a traceback, a hang or a crash once (the comment says which)."""

from __future__ import annotations

import errno
import os

import pytest
from cli_capture import capture

from jaxapf.cli import main

SPEC = """name = "{name}"
[scenario]
families = ["clutter"]
fields = 2
{params}
[sim]
t_max = {t_max}
horizon = 3
iters = 3
"""


def _spec(tmp_path, name="refuse", params="", t_max=2.0):
    path = tmp_path / "spec.toml"
    path.write_text(SPEC.format(name=name, params=params, t_max=t_max))
    return path


def _refused(argv, *needles):
    rc, stdout, stderr = capture(main, argv)
    assert rc == 2 and stderr.count("\n") == 1 and "Traceback" not in stderr, stderr
    for needle in needles:
        assert needle in stderr, stderr
    return stderr


@pytest.mark.parametrize("params, t_max, limit", [
    # "negative shift count" in the plan's width, both
    ("[scenario.params.clutter]\nmax_obstacles = 100000", 60.0,
     "clutter: one episode of 600 steps (t_max 60 s at dt 0.1 s) among 100,000 obstacle slots needs 693.6 MiB of "
     "working memory, more than --memory-budget 256.0 MiB: at most 217 steps (t_max <= 21.7 s) with these slots, "
     "or at most 36,374 obstacle slots at this length"),
    ("", 100000.0, "clutter: one episode of 1,000,000 steps (t_max 100000 s at dt 0.1 s) among 16 obstacle slots "
                   "needs 339.5 MiB of working memory, more than --memory-budget 256.0 MiB: at most 754,026 steps"),
])
def test_an_episode_no_memory_budget_holds_is_refused_with_the_limit(params, t_max, limit, tmp_path):
    out = tmp_path / "o"
    for extra in ([], ["--dry-run"], ["--chunk-fields", "1"]):
        _refused(["sweep", str(_spec(tmp_path, params=params, t_max=t_max)), "--out", str(out), "--no-cache", *extra],
                 limit)
    assert not out.exists()


def test_a_spec_nested_five_thousand_deep_is_one_line(tmp_path):
    """RecursionError."""
    path = tmp_path / "deep.toml"
    path.write_text('name = "d"\nx = ' + "[" * 5000 + "]" * 5000 + "\n")
    _refused(["sweep", str(path), "--out", str(tmp_path / "o")], "nests arrays or tables too deeply to read")


def test_a_cache_dir_that_is_a_file_is_one_line(tmp_path):
    """FileExistsError."""
    (tmp_path / "cache").write_text("mine")
    _refused(["sweep", str(_spec(tmp_path)), "--out", str(tmp_path / "o"), "--cache-dir", str(tmp_path / "cache")],
             f"the compilation cache {tmp_path / 'cache'} is not a folder")
    assert (tmp_path / "cache").read_text() == "mine"


def test_a_name_too_long_for_a_file_name_is_refused_with_the_limit(tmp_path, monkeypatch):
    """ENAMETOOLONG with the default --out runs/NAME.parquet."""
    monkeypatch.chdir(tmp_path)
    _refused(["sweep", str(_spec(tmp_path, name="a" * 5000))], "is 5,000 characters long; at most 128")
    assert not (tmp_path / "runs").exists()
    rc, _, stderr = capture(main, ["sweep", str(_spec(tmp_path, name="a" * 128)), "--dry-run", "--no-cache"])
    assert rc == 0, stderr


def test_a_variant_name_too_long_for_its_parts_file_names_is_refused_before_any_work(tmp_path):
    """A variant names its parts' files: 300 characters passed --dry-run, then every run failed after computing
    ("File name too long"); 128 characters, the longest allowed, are written (a part and its temporary name)."""
    def spec(label):
        path = tmp_path / f"{len(label)}.toml"
        text = SPEC.format(name="v", t_max=2.0, params=f'[scenario.params.{label}]\nfamily = "clutter"')
        path.write_text(text.replace('families = ["clutter"]', f'families = ["{label}"]'))
        return path

    _refused(["sweep", str(spec("a" * 300)), "--dry-run"], "at most 128 characters (it is 300)", "255 bytes")
    assert not (tmp_path / "runs").exists()
    rc, _, stderr = capture(main, ["sweep", str(spec("b" * 128)), "--out", str(tmp_path / "o"), "--quiet",
                                   "--no-cache"])
    assert rc == 0 and len(list((tmp_path / "o").glob("part-*-" + "b" * 128 + "-*.parquet"))) == 1, stderr


def test_more_devices_than_cores_are_refused_before_jax_makes_them(tmp_path):
    """--devices 100000 was accepted and grew to 2.5 GB in 110 s."""
    cores = len(os.sched_getaffinity(0))
    for argv in (["sweep", str(_spec(tmp_path)), "--out", str(tmp_path / "o"), "--dry-run"],
                 ["bench", "engine"]):
        _refused(argv + ["--devices", "100000"],
                 f"--devices = 100000 is more than the {cores} CPU core(s) this process may use; at most {cores}")


def test_merge_into_a_folder_of_other_files_is_refused(tmp_path):
    """`sweep merge --out` copied parts among unrelated files that `jaxapf sweep` then refused."""
    from jaxapf.sweep import parse_spec, run_sweep

    src = tmp_path / "src"
    run_sweep(parse_spec({"name": "m", "scenario": {"families": ["trap"], "fields": 2},
                          "sim": {"t_max": 1.0, "horizon": 3, "iters": 3}}), src, quiet=True)
    home = tmp_path / "home"
    home.mkdir()
    (home / "thesis.tex").write_text("mine")
    _refused(["sweep", "merge", str(src), "--out", str(home)], "holds entries that are not sweep parts (thesis.tex)")
    assert sorted(p.name for p in home.iterdir()) == ["thesis.tex"]


def test_a_nearly_full_disk_that_takes_part_of_the_probe_is_refused_before_any_work(tmp_path, monkeypatch):
    """8 KiB free: the 64 KiB probe's write was short (no error), the run failed only after a chunk."""
    from jaxapf.io import lock

    real, taken = os.write, {"bytes": 0}

    def full(fd, data):  # what a file system with 8 KiB left does: takes 8 KiB, then ENOSPC
        if taken["bytes"] >= 8192:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        n = real(fd, bytes(data[: 8192 - taken["bytes"]]))
        taken["bytes"] += n
        return n

    monkeypatch.setattr(lock.os, "write", full)
    out = tmp_path / "o"
    _refused(["sweep", str(_spec(tmp_path)), "--out", str(out), "--no-cache"],
             f"--out {out} cannot be written: No space left on device (the file system is full)")
    assert not out.exists()


def test_a_name_ending_in_a_newline_is_refused(tmp_path):
    """`name = "review\\n"` was accepted (a regex `$` matches before a final newline) and named the folder."""
    _refused(["sweep", str(_spec(tmp_path, name="review\\n")), "--dry-run"], "must be a string of letters")


def test_json_nested_past_any_reader_is_damage_not_a_traceback(tmp_path):
    """RecursionError from a part's metadata, a division record or a tuner's checkpoint."""
    import json

    import pyarrow.parquet as pq

    from jaxapf.sweep import parse_spec, run_sweep
    from jaxapf.sweep.division import DIVISION_NAME
    from jaxapf.sweep.output import part_files, verify_part
    from jaxapf.tune.searches import _Checkpoint

    deep = "[" * 100_000 + "]" * 100_000
    out = tmp_path / "o"
    spec = parse_spec({"name": "deep", "scenario": {"families": ["trap"], "fields": 2},
                       "sim": {"t_max": 1.0, "horizon": 3, "iters": 3}})
    run_sweep(spec, out, quiet=True)
    part = part_files(out)[0]
    table = pq.read_table(part)
    meta = table.schema.metadata | {b"jaxapf": table.schema.metadata[b"jaxapf"][:-1] + b', "x": ' + deep.encode()
                                    + b"}", b"jaxapf_part": deep.encode()}
    pq.write_table(table.replace_schema_metadata(meta), part)
    assert verify_part(part) is not None
    stderr = _refused(["sweep", "verify", str(out)])
    assert "is not the output of jaxapf sweep" in stderr or "damaged" in stderr
    shard_out = tmp_path / "s"
    shard_out.mkdir()
    (shard_out / DIVISION_NAME).write_text(deep)
    run_sweep(spec, shard_out, quiet=True, shard=(0, 2))  # no part follows it, no shard holds it: replaced
    assert json.loads((shard_out / DIVISION_NAME).read_text())["shards"] == 2
    (tmp_path / "search-cmaes.json").write_text(deep)
    assert _Checkpoint(tmp_path, "cmaes", "digest").load() is None


def test_devices_forced_by_xla_flags_and_a_shards_own_refusal_come_first(tmp_path, monkeypatch):
    """The core count is the CPU platform's limit only where --devices makes the devices: XLA_FLAGS forcing a
    count is left alone, and a shard's one-device rule is said before it."""
    from jaxapf.engine import configure_jax

    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=4")
    configure_jax(cpu_devices=100000)  # XLA_FLAGS decides: nothing to refuse
    monkeypatch.delenv("XLA_FLAGS")
    _refused(["sweep", str(_spec(tmp_path)), "--shard", "0/2", "--devices", "100000"],
             "--devices = 100000: a shard runs on one device")
    _refused(["sweep", str(_spec(tmp_path)), "--shard", "0/2", "--overwrite", "--dry-run"],
             "--overwrite replaces a whole output; a shard writes only its own parts")


def test_a_memory_budget_is_met_or_refused_never_exceeded():
    """A budget between one field's memory and the smallest padded chunk's was accepted, and the plan's
    chunks then needed more than it."""
    from jaxapf.sweep import parse_spec, plan_sweep
    from jaxapf.validation import ConfigError

    spec = parse_spec({"name": "budget", "scenario": {"families": ["trap", "clutter"], "fields": 300},
                       "sim": {"t_max": 20.0, "horizon": 3, "iters": 3}, "grid": {"k_rep": [5.0, 10.0, 20.0]}})
    refused = met = 0
    for budget in (2 ** k for k in range(17, 30)):
        try:
            plan = plan_sweep(spec, memory_budget=budget, devices=1)
        except ConfigError as err:
            assert "is too small: a chunk here needs at least" in str(err)
            refused += 1
        else:
            assert plan.peak_bytes <= budget
            met += 1
    assert refused and met
