"""A folder received from someone else: nothing planted where jaxapf *reads* hangs it, fills its memory or
its disk, or is read other than it was checked.

The break-in of main 360a044: a source part of ``jaxapf sweep merge`` swapped for a link to ``/dev/zero`` after
the audit grew the output's temporary part to 6.4 GB; a FIFO there, or as a tune summary, checkpoint or compare
selection, blocked the command forever in ``openat``. Every such name is now opened once through
:func:`jaxapf.io.names.open_read` (a regular file, no link followed, never blocking, a size bound).
"""

from __future__ import annotations

import ast
import io
import os
import pathlib

import numpy as np
import pytest
from conftest import package_calls

from jaxapf.io.names import Planted, TooLarge, open_read, read_own
from jaxapf.validation import ConfigError


@pytest.mark.parametrize("how", ["fifo", "dev-zero", "link", "folder"])
def test_a_planted_name_is_refused_at_once_without_reading(tmp_path, how):
    path = tmp_path / "summary.json"
    if how == "fifo":
        os.mkfifo(path)
    elif how == "dev-zero":
        os.symlink("/dev/zero", path)
    elif how == "link":
        (tmp_path / "real.json").write_text("{}")
        os.symlink(tmp_path / "real.json", path)
    else:
        path.mkdir()
    with pytest.raises(Planted, match="summary.json is a"):
        read_own(path, 1024)
    with pytest.raises(Planted):
        open_read(path, 1024)


def test_a_file_past_its_bound_is_refused_unread_and_one_within_it_read_whole(tmp_path):
    path = tmp_path / "record.json"
    path.write_bytes(b"x" * 1025)
    with pytest.raises(TooLarge, match=r"holds 1,025 bytes, more than the 1,024"):
        read_own(path, 1024)
    path.write_bytes(b"x" * 1024)
    assert read_own(path, 1024) == b"x" * 1024  # never a silent cut: whole or refused


def test_merge_copies_the_bytes_it_checked_and_refuses_a_source_that_grows(tmp_path):
    """The merge's copy reads from the descriptor it opened and checked, as many bytes as the file held then;
    a source appended to while it is copied is refused (before, the copy followed it to the disk's end)."""
    from jaxapf.sweep.merge import _copy

    src = tmp_path / "part.parquet"
    src.write_bytes(os.urandom(3 << 20))
    out = io.BytesIO()
    _copy(src, out, 0)
    assert out.getvalue() == src.read_bytes()

    class Growing(io.BytesIO):
        def write(self, data):  # the source grows as soon as the copy starts
            with open(src, "ab") as fh:
                fh.write(b"more")
            return super().write(data)

    with pytest.raises(ConfigError, match=r"part.parquet grew while it was copied.*3 part\(s\) were copied before"):
        _copy(src, Growing(), 3)
    os.unlink(src)
    os.symlink("/dev/zero", src)
    with pytest.raises(ConfigError, match=r"^sweep merge: .*part.parquet is a symbolic link.*; 0 part\(s\)"):
        _copy(src, io.BytesIO(), 0)


def test_merge_refuses_a_source_part_swapped_for_a_fifo_after_its_audit(tmp_path, monkeypatch):
    """The race of the break-in: the audit sees a sound part, the copy finds a FIFO (63 of 64 parts copied,
    then a hang). Now one line, the parts copied before it kept whole."""
    from jaxapf.sweep import merge as merging
    from jaxapf.sweep import parse_spec, run_sweep
    from jaxapf.sweep.output import part_files

    spec = parse_spec({"name": "m", "scenario": {"families": ["trap"], "fields": 4, "seed": 1},
                       "sim": {"t_max": 1.0, "horizon": 3, "iters": 3}})
    src = run_sweep(spec, tmp_path / "src", quiet=True, chunk_fields=2).out
    real = merging.audit_folder

    def audit_then_swap(folder, *args):
        found = real(folder, *args)
        if pathlib.Path(folder) == src:
            last = part_files(src)[-1]
            os.unlink(last)
            os.mkfifo(last)
        return found

    monkeypatch.setattr(merging, "audit_folder", audit_then_swap)
    with pytest.raises(ConfigError, match=r"is a FIFO.*1 part\(s\) were copied before it"):
        merging.merge_outputs([src], tmp_path / "out")
    assert len(part_files(tmp_path / "out")) == 1


def test_merge_copies_what_the_audit_read_and_refuses_a_sound_part_swapped_in_after_it(tmp_path, monkeypatch):
    """The audit reads each part once (its table, its metadata and its verified content hash from the same bytes)
    and the merge holds the copy to that hash: a source part replaced after the audit by a sound part of another
    sweep under the same name (before, its record was read again and agreed with the new bytes) is refused, the
    parts copied before it kept."""
    import shutil

    from jaxapf.sweep import merge as merging
    from jaxapf.sweep import parse_spec, run_sweep
    from jaxapf.sweep.output import audited_hash, part_files, read_part

    table = {"name": "m", "scenario": {"families": ["trap"], "fields": 4, "seed": 1},
             "sim": {"t_max": 1.0, "horizon": 3, "iters": 3}}
    src = run_sweep(parse_spec(table), tmp_path / "src", quiet=True, chunk_fields=2).out
    other = run_sweep(parse_spec({**table, "scenario": {**table["scenario"], "seed": 2}}), tmp_path / "other",
                      quiet=True, chunk_fields=2).out
    real = merging.audit_folder
    hashes = {}

    def audit_then_swap(folder, *args):
        found = real(folder, *args)
        if pathlib.Path(folder) == src:
            hashes.update(found[0].hashes)
            last = part_files(src)[-1]
            shutil.copyfile(other / last.name, last)  # sound, of another sweep
        return found

    monkeypatch.setattr(merging, "audit_folder", audit_then_swap)
    with pytest.raises(ConfigError, match=r"did not read back \(another part's content.*1 part\(s\) were copied"):
        merging.merge_outputs([src], tmp_path / "out")
    first = part_files(tmp_path / "out")
    assert len(first) == 1 and audited_hash(read_part(first[0])) == hashes[first[0].name]


def test_tune_and_compare_records_planted_as_fifos_are_refused_or_ignored_at_once(tmp_path, repo_root):
    """A FIFO as tune's ``summary.json`` (no finished run) or a search's state (none saved), as its checkpoint
    (damaged: one line) or as a compare selection (damaged: one line): none blocks, as each did before."""
    import types

    from jaxapf.compare.select import saved_selection
    from jaxapf.compare.spec import load_compare_spec
    from jaxapf.tune.run import finished_summary
    from jaxapf.tune.searches import _Checkpoint
    from jaxapf.tune.train import CheckpointError, TrainState

    for name in ("summary.json", "search-tpe.json", "checkpoint.npz", "basic-seed1.json"):
        os.mkfifo(tmp_path / name)
    assert finished_summary(tmp_path, "digest") is None
    assert _Checkpoint(tmp_path, "tpe", "digest").load() is None
    like = types.SimpleNamespace(theta={"gamma": np.zeros(())}, best_theta={"gamma": np.zeros(())}, opt_state=())
    with pytest.raises(CheckpointError, match=r"checkpoint.npz is damaged \(Planted: .*FIFO"):
        TrainState.load(tmp_path / "checkpoint.npz", "digest", like)
    spec, _ = load_compare_spec(repo_root / "sweeps" / "compare-quick.toml")
    with pytest.raises(ConfigError, match=r"basic-seed1.json is damaged \(Planted: .*FIFO"):
        saved_selection(spec, "basic", 1, tmp_path)


def test_every_file_the_package_reads_goes_through_jaxapf_io(repo_root):
    """The promise holds for code not yet written: outside jaxapf/io, no module reads a file by its name (a
    path's read_text/read_bytes, open for reading, numpy's, pandas' or pyarrow's readers handed a path); each
    opens it through jaxapf.io.names (the spec file through validation.read_toml_file, which refuses all but a
    regular file; the oracle's answers key reads jaxapf's own source)."""
    allowed = {"jaxapf/cli/catalog.py": "the catalogue cache, in the user's own cache folder",
               "jaxapf/scenarios/answers.py": "its own source file, hashed into the answers' key",
               "jaxapf/validation.py": "the spec file a user names, checked to be a regular file",
               "jaxapf/simulate/animate.py": "ffmpeg's pipe",
               "jaxapf/engine/policy.py": "the kernel's /proc/meminfo"}
    readers = {"read_text", "read_bytes", "read_table", "read_schema", "ParquetFile", "read_parquet", "read_csv",
               "load"}  # load: numpy's (a method named load of jaxapf's own is not a reader)
    found = []
    for rel, node, name in package_calls(repo_root, allowed):
        f, first = node.func, node.args[0] if node.args else None
        called = getattr(first.func, "id", getattr(first.func, "attr", "")) if isinstance(first, ast.Call) else ""
        # a handle or bytes jaxapf.io opened and read, not a name
        checked = (isinstance(first, ast.Name) and first.id in ("fh", "buf", "part")) or called in (
            "BytesIO", "open_own", "open_read", "open_part", "read_own")
        owner = f.value.id if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) else ""
        mode = next((a.value for a in node.args[1:2] if isinstance(a, ast.Constant)), "r")
        opens = name == "open" and isinstance(f, ast.Name) and not any(c in str(mode) for c in "wax+")
        reads = name in readers and (name != "load" or owner in ("np", "numpy", "pickle"))
        if (reads or opens) and not checked:
            found.append(f"{rel}:{node.lineno} {name}")
    assert found == [], "read through jaxapf.io.names.open_read or read_own: " + ", ".join(found)


def test_the_source_digest_is_every_py_file_by_name_and_nothing_else(tmp_path, monkeypatch):
    """identity()'s source digest (jaxapf.io.versions.source_digest): sha256 over each ``.py`` file's relative path
    and bytes in name order, a linked one read through; an editor's dot-file, a dangling link, a folder or a FIFO
    adds nothing, and a FIFO is never waited on, even one planted after the listing; an edit changes it."""
    import hashlib
    import threading

    from jaxapf.io.versions import source_digest

    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "b.py").write_text("y = 2\n")
    big = tmp_path / "big.bin"
    big.write_bytes(os.urandom(3 << 20))
    (pkg / "sub" / "c.py").symlink_to(big)
    expect = hashlib.sha256(b"a.py\0x = 1\n\0sub/b.py\0y = 2\n\0sub/c.py\0" + big.read_bytes() + b"\0").hexdigest()
    assert source_digest(pkg) == expect
    (pkg / ".#a.py").write_text("an editor's lock")
    (pkg / ".hidden").mkdir()
    (pkg / ".hidden" / "d.py").write_text("z = 3\n")
    os.mkfifo(pkg / "f.py")
    (pkg / "d.py").symlink_to(tmp_path / "gone.py")
    (pkg / "e.py").mkdir()
    assert source_digest(pkg) == expect
    # a FIFO planted after the listing looked (every name taken for a file) is still never waited on
    monkeypatch.setattr(pathlib.Path, "is_file", lambda self: True)
    found = []
    worker = threading.Thread(target=lambda: found.append(source_digest(pkg)), daemon=True)
    worker.start()
    worker.join(20)
    assert found == [expect]
    monkeypatch.undo()
    (pkg / "a.py").write_text("x = 2\n")
    assert source_digest(pkg) != expect
