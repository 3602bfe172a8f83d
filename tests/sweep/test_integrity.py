"""A dataset that proves its own integrity: resume, --repair, read_sweep, `jaxapf sweep verify` and
`jaxapf sweep merge` read what the parts hold, not only their names.

Each defect of the name-only reading is reproduced first: duplicates accepted ("320 already done"
where 256 were expected) and kept by --repair; a part copied over another's name read as complete
(rows doubled and missing); a part of another spec extending the plan (fields outside the spec
simulated).
"""

from __future__ import annotations

import copy
import pathlib
import shutil

import pandas as pd
import pytest
from cli_capture import capture

from jaxapf.cli import main
from jaxapf.sweep import parse_spec, plan_sweep, read_sweep, run_sweep
from jaxapf.sweep.audit import SET_ASIDE, audit_output
from jaxapf.sweep.merge import merge_outputs
from jaxapf.sweep.output import part_files
from jaxapf.validation import ConfigError

SPEC = {
    "name": "integrity",
    "scenario": {"families": ["trap", "crossing"], "fields": 12, "seed": 3},
    "sim": {"t_max": 2.0, "horizon": 3, "iters": 3},
    "grid": {"k_rep": [5.0, 10.0]},
}
ROWS = 2 * 2 * 12


def _spec(**scenario):
    data = copy.deepcopy(SPEC)
    data["scenario"].update(scenario)
    return parse_spec(data)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "ref.parquet"
    run_sweep(_spec(), out, chunk_fields=3, quiet=True)
    df, _ = read_sweep(out)
    return out, df


def _copy(src: pathlib.Path, dst: pathlib.Path, names=None) -> pathlib.Path:
    dst.mkdir(parents=True)
    for p in part_files(src):
        if names is None or p.name in names:
            shutil.copy(p, dst / p.name)
    return dst


def _verify(out: pathlib.Path) -> tuple[int, str]:
    rc, stdout, stderr = capture(main, ["sweep", "verify", str(out)])
    assert "Traceback" not in stderr
    return rc, stdout


def test_verify_passes_a_complete_dataset_and_lists_a_missing_chunk(reference, tmp_path):
    rc, text = _verify(reference[0])
    assert rc == 0 and "complete and sound, every episode exactly once" in text and f"{ROWS} of {ROWS}" in text
    out = _copy(reference[0], tmp_path / "gap.parquet")
    (out / "part-v000-trap-f00000003-00000006.parquet").unlink()
    rc, text = _verify(out)
    assert rc == 1 and "NOT complete" in text and "missing: variant v000, trap, fields 3-5" in text


def test_a_part_copied_over_anothers_name_is_found_and_repaired(reference, tmp_path):
    """Name-only reading called this complete (rows doubled and missing in equal numbers)."""
    out = _copy(reference[0], tmp_path / "renamed.parquet")
    shutil.copy(out / "part-v000-trap-f00000000-00000003.parquet", out / "part-v000-trap-f00000003-00000006.parquet")
    with pytest.raises(ConfigError, match=r"part-v000-trap-f00000003-00000006\.parquet holds fields 0-2, its name "
                                          r"says 3-5"):
        read_sweep(out)
    rc, text = _verify(out)
    assert rc == 1 and "foreign: part-v000-trap-f00000003-00000006.parquet: holds fields 0-2" in text
    with pytest.raises(ConfigError, match="1 part.* cannot be trusted.*--repair"):
        run_sweep(_spec(), out, chunk_fields=3, quiet=True)
    result = run_sweep(_spec(), out, chunk_fields=3, quiet=True, repair=True)
    assert result.episodes == 2 * 3  # exactly the set-aside chunk's fields, for its variant's settings
    assert (out / SET_ASIDE / "part-v000-trap-f00000003-00000006.parquet").exists()
    df, meta = read_sweep(out)
    assert meta["complete"]
    pd.testing.assert_frame_equal(df, reference[1])
    assert _verify(out)[0] == 0


def test_duplicate_episodes_are_found_and_repair_removes_them(reference, tmp_path):
    """Name-only resume read '0 episodes (… already done)' over doubled rows, and --repair kept them."""
    other = tmp_path / "other.parquet"
    run_sweep(_spec(), other, chunk_fields=4, quiet=True)
    out = _copy(reference[0], tmp_path / "dup.parquet")
    shutil.copy(other / "part-v000-crossing-f00000004-00000008.parquet", out)
    rc, text = _verify(out)
    # the widest part is kept; the two it overlaps are not trusted
    assert rc == 1 and ("overlapping: part-v000-crossing-f00000003-00000006.parquet: shares fields 4-5 with "
                        "part-v000-crossing-f00000004-00000008.parquet") in text
    assert "overlapping: part-v000-crossing-f00000006-00000009.parquet: shares fields 6-7" in text
    with pytest.raises(ConfigError, match="cannot be trusted"):
        run_sweep(_spec(), out, chunk_fields=3, quiet=True)
    with pytest.raises(ConfigError, match="shares fields"):
        read_sweep(out)
    result = run_sweep(_spec(), out, chunk_fields=3, quiet=True, repair=True)
    assert result.episodes == 2 * 2  # fields 3 and 8, which only the removed parts held
    df, meta = read_sweep(out)
    assert meta["complete"] and not df.duplicated(["setting", "family", "field"]).any()
    pd.testing.assert_frame_equal(df, reference[1])


@pytest.mark.slow
def test_a_part_of_another_spec_never_extends_the_plan(reference, tmp_path):
    """A part of a 20-field sweep (fields 16-19) in this 12-field output made resume simulate fields
    outside the spec and exit 0."""
    bigger = tmp_path / "bigger.parquet"
    run_sweep(_spec(fields=20), bigger, chunk_fields=4, quiet=True)
    out = _copy(reference[0], tmp_path / "foreign.parquet")
    shutil.copy(bigger / "part-v000-trap-f00000016-00000020.parquet", out)
    found = audit_output(out, plan=plan_sweep(_spec()))
    assert "part-v000-trap-f00000016-00000020.parquet" in found.foreign and not found.missing
    with pytest.raises(ConfigError, match="cannot be trusted"):
        run_sweep(_spec(), out, chunk_fields=3, quiet=True)
    result = run_sweep(_spec(), out, chunk_fields=3, quiet=True, repair=True)
    assert result.episodes == 0  # nothing outside the spec was simulated
    df, meta = read_sweep(out)
    assert meta["complete"] and df["field"].max() == 11
    pd.testing.assert_frame_equal(df, reference[1])


def test_merge_of_two_shard_folders_gives_the_one_process_rows(reference, tmp_path):
    parts = [p.name for p in part_files(reference[0])]
    a = _copy(reference[0], tmp_path / "a", parts[::2])
    b = _copy(reference[0], tmp_path / "b", parts[1::2])
    rc, stdout, stderr = capture(main, ["sweep", "merge", str(a), str(b), "--out", str(tmp_path / "m")])
    assert rc == 0 and f"{len(parts)} part(s) copied" in stdout and "complete and sound" in stdout, stderr
    df, meta = read_sweep(tmp_path / "m")
    assert meta["complete"]
    pd.testing.assert_frame_equal(df, reference[1])
    again = merge_outputs([a, b], tmp_path / "m")  # a second merge copies nothing, doubles nothing
    assert again.copied == 0 and again.present == len(parts) and again.audit.complete


def test_merge_refuses_a_folder_of_another_spec_in_one_line(reference, tmp_path):
    other = tmp_path / "other.parquet"
    run_sweep(_spec(seed=4), other, chunk_fields=3, quiet=True)
    rc, _, stderr = capture(main, ["sweep", "merge", str(reference[0]), str(other), "--out", str(tmp_path / "m")])
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert rc == 2 and len(lines) == 1 and "is of another sweep or version" in lines[0]
    assert "spec_hash" in lines[0] and "nothing merged" in lines[0]
    assert not (tmp_path / "m").exists() or not part_files(tmp_path / "m")


def test_merge_refuses_folders_chunked_differently(reference, tmp_path):
    other = tmp_path / "other.parquet"
    run_sweep(_spec(), other, chunk_fields=4, quiet=True)
    with pytest.raises(ConfigError, match="hold the same fields, chunked differently; .*nothing merged"):
        merge_outputs([reference[0], other], tmp_path / "m")
    assert not part_files(tmp_path / "m")


def test_a_part_that_cannot_be_read_now_is_not_damage_and_repair_keeps_it(reference, tmp_path, monkeypatch):
    """A permission or I/O error is not damage: the run stops in one line and --repair deletes nothing."""
    import errno
    import os

    from jaxapf.sweep import output

    out = _copy(reference[0], tmp_path / "eio.parquet")
    real = output.open_part

    def flaky(path):
        if str(path).endswith("f00000003-00000006.parquet"):
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        return real(path)

    monkeypatch.setattr(output, "open_part", flaky)
    with pytest.raises(ConfigError, match="cannot be read now .*Input/output error.*nothing was changed"):
        run_sweep(_spec(), out, chunk_fields=3, quiet=True, repair=True)
    assert len(part_files(out)) == len(part_files(reference[0]))


def test_a_set_aside_part_never_replaces_an_earlier_one(reference, tmp_path):
    from jaxapf.sweep.audit import audit_output, repair_parts

    out = _copy(reference[0], tmp_path / "aside.parquet")
    name = "part-v000-trap-f00000003-00000006.parquet"
    for _ in range(2):
        shutil.copy(out / "part-v000-trap-f00000000-00000003.parquet", out / name)  # misnamed: foreign
        found = audit_output(out, plan=plan_sweep(_spec()))
        repair_parts(out, found, [name])
    assert sorted(p.name for p in (out / SET_ASIDE).iterdir()) == [name, f"{name}.1"]


def test_a_stray_copy_of_a_part_is_named_and_never_read(reference, tmp_path):
    out = _copy(reference[0], tmp_path / "stray.parquet")
    shutil.copy(out / "part-v000-trap-f00000000-00000003.parquet", out / "copy.parquet")
    df, meta = read_sweep(out)
    assert meta["stray"] == ["copy.parquet"] and meta["complete"]
    pd.testing.assert_frame_equal(df, reference[1])
