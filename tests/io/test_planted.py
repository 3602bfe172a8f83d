"""A folder received from someone else: no name planted in it sends a write outside it.

Every lock, probe, temporary, set-aside and output name a command opens is planted as a symbolic link to
a file outside (and a link to a folder outside, a hard link, a FIFO, a folder); each command that writes
must refuse in one line naming it, or replace the name without writing through it, and no file outside
the folder may change. The first class reproduces the break-in of main 59db75c (`ln -s ../victim.txt
DS/.lock; jaxapf sweep SPEC --out DS` wrote the lock's owner note into victim.txt).
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import shutil

import pytest
from cli_capture import capture
from conftest import package_calls

from jaxapf.cli import main
from jaxapf.io.lock import OutputLock, check_writable, staged, write_atomic, writing
from jaxapf.io.names import Planted, create, open_own, read_own, remove_leftover, subfolder
from jaxapf.sweep import parse_spec, run_sweep
from jaxapf.sweep.audit import SET_ASIDE, audit_output, check_folder, clear_temporaries, repair_parts
from jaxapf.sweep.division import Division, agree_division
from jaxapf.sweep.plan import plan_sweep

SPEC = {"name": "tiny", "scenario": {"families": ["trap"], "fields": 4, "seed": 2},
        "sim": {"t_max": 1.0, "horizon": 3, "iters": 3}, "grid": {"k_rep": [5.0, 10.0]}}
PART = "part-v000-trap-f00000000-00000002.parquet"


def _plant(path: pathlib.Path, how: str, outside: pathlib.Path) -> None:
    """Put at ``path`` what a hostile folder holds: a link to the file ``outside/victim.txt`` (or to the
    folder ``outside``), a hard link to it, a FIFO, a folder or a dangling link."""
    victim = outside / "victim.txt"
    if how == "symlink":
        os.symlink(os.path.relpath(victim, path.parent), path)
    elif how == "dir-symlink":
        os.symlink(outside, path)
    elif how == "hardlink":
        os.link(victim, path)
    elif how == "fifo":
        os.mkfifo(path)
    elif how == "dangling":
        os.symlink(outside / "nothing-yet", path)
    else:
        path.mkdir()


KINDS = ("symlink", "dir-symlink", "hardlink", "fifo", "folder", "dangling")


def _snapshot(folder: pathlib.Path) -> dict[str, str]:
    """Every name under ``folder`` with a hash of its content (what must not change)."""
    out = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            p = pathlib.Path(root) / name
            out[str(p.relative_to(folder))] = hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
    return out


@pytest.fixture
def place(tmp_path):
    """``(folder, outside)``: the folder a command writes, and beside it a folder of files it must never
    touch (a victim file with known content)."""
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "victim.txt").write_text("the victim's own words\n")
    folder = tmp_path / "received"
    folder.mkdir()
    return folder, outside


def _untouched(outside: pathlib.Path, before: dict[str, str]) -> None:
    assert _snapshot(outside) == before, "a file outside the folder changed, or one was made there"


@pytest.mark.parametrize("how", KINDS)
@pytest.mark.parametrize("opens", ["lock", "shard lock", "probe", "temporary", "division guard", "note"])
def test_a_planted_lock_probe_or_temporary_is_refused_and_nothing_outside_changes(place, how, opens):
    folder, outside = place
    name = {"lock": ".lock", "shard lock": ".lock-shard-0000-of-0002", "probe": f".write-test-{os.getpid()}",
            "temporary": f".report.md.tmp-{os.getpid()}", "division guard": ".lock-division",
            "note": ".lock"}[opens]
    _plant(folder / name, how, outside)
    before = _snapshot(outside)
    act = {"lock": lambda: OutputLock(folder).acquire(), "shard lock": lambda: OutputLock(folder, (0, 2)).acquire(),
           "probe": lambda: check_writable(folder), "temporary": lambda: write_atomic(folder / "report.md", "x"),
           "division guard": lambda: open_own(folder / ".lock-division", os.O_CREAT | os.O_RDWR),
           "note": lambda: read_own(folder / ".lock")}[opens]
    if how == "hardlink" and opens in ("probe", "temporary", "note"):
        act()  # a file made anew or only read: its old name is removed or read, the other name untouched
    else:
        with pytest.raises(Planted, match=rf"{name} is a .* where jaxapf keeps a file"):
            act()
    _untouched(outside, before)


@pytest.mark.parametrize("how", KINDS)
def test_a_planted_final_name_is_refused_or_replaced_never_written_through(place, how):
    folder, outside = place
    _plant(folder / "summary.json", how, outside)
    before = _snapshot(outside)
    if how == "hardlink":  # renaming over one name of a file leaves its other names as they were
        write_atomic(folder / "summary.json", "{}")
        assert (folder / "summary.json").read_text() == "{}"
    else:
        with pytest.raises(Planted, match="summary.json is a"):
            write_atomic(folder / "summary.json", "{}")
    _untouched(outside, before)
    assert [p.name for p in folder.iterdir() if ".tmp-" in p.name] == []


@pytest.mark.parametrize("how", [k for k in KINDS if k != "folder"])
def test_a_planted_subfolder_is_refused(place, how):
    folder, outside = place
    _plant(folder / "figures", how, outside)
    before = _snapshot(outside)
    with pytest.raises(Planted, match="figures is a .* where jaxapf keeps a folder"):
        subfolder(folder / "figures")
    _untouched(outside, before)


def test_a_leftover_temporary_is_removed_only_if_it_is_a_regular_file(place):
    folder, outside = place
    (folder / ".a.tmp-1").write_text("left by a dead writer")
    assert remove_leftover(folder / ".a.tmp-1") and not (folder / ".a.tmp-1").exists()
    _plant(folder / ".b.tmp-1", "symlink", outside)
    with pytest.raises(Planted):
        remove_leftover(folder / ".b.tmp-1")
    assert (outside / "victim.txt").exists()
    fd = create(folder / ".a.tmp-1")  # a name this process left earlier (its pid reused) is made anew
    os.close(fd)


def test_staged_writes_of_a_child_process_land_in_the_folder_only(place):
    folder, outside = place
    _plant(folder / "episode.gif", "symlink", outside)
    before = _snapshot(outside)
    with pytest.raises(Planted):
        with staged(folder / "episode.gif"):
            pass
    with staged(folder / "episode.mp4") as tmp:
        tmp.write_bytes(b"frames")
    assert (folder / "episode.mp4").read_bytes() == b"frames"
    _untouched(outside, before)


def test_writing_a_folder_with_a_planted_lock_writes_nothing(place):
    folder, outside = place
    _plant(folder / ".lock", "symlink", outside)
    before = _snapshot(outside)
    with pytest.raises(Planted):
        with writing(folder, "nothing"):
            pytest.fail("the block ran under a planted lock")
    _untouched(outside, before)


# --- the commands, end to end -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A finished sweep of two settings × four fields in parts of two fields."""
    out = tmp_path_factory.mktemp("planted") / "ds"
    run_sweep(parse_spec(SPEC), out, chunk_fields=2, quiet=True)
    return out


@pytest.mark.parametrize("name", [".lock", ".lock-shard-0000-of-0002", ".lock-division", ".write-test-{pid}",
                                  f".{PART}.tmp-{{pid}}", "..division.json.tmp-{pid}", ".division.json", PART,
                                  SET_ASIDE])
def test_sweep_into_a_folder_with_a_planted_name_says_so_in_one_line(dataset, tiny_spec, place, name):
    folder, outside = place
    shutil.rmtree(folder)
    shutil.copytree(dataset, folder)
    name = name.format(pid=os.getpid())
    (folder / name).unlink(missing_ok=True)
    _plant(folder / name, "symlink", outside)
    before = _snapshot(outside)
    shard = ["--shard", "0/2"] if "shard" in name or "division" in name else []
    rc, out, err = capture(main, ["sweep", str(tiny_spec), "--out", str(folder), "--quiet", "--chunk-fields", "2",
                                  "--repair", *shard])
    assert "Traceback" not in err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and name in err, err
    _untouched(outside, before)


def test_repair_never_moves_a_part_out_through_a_planted_set_aside(dataset, place):
    folder, outside = place
    shutil.rmtree(folder)
    shutil.copytree(dataset, folder)
    other = "part-v000-trap-f00000002-00000004.parquet"
    shutil.copy(folder / PART, folder / other)  # a part under another's name: foreign, set aside by --repair
    _plant(folder / SET_ASIDE, "dir-symlink", outside)
    before = _snapshot(outside)
    found = audit_output(folder, plan_sweep(parse_spec(SPEC), chunk_fields=2))
    assert other in found.foreign
    with pytest.raises(Planted, match=r"\.set-aside is a symbolic link"):
        check_folder(folder)
    with pytest.raises(Planted):
        repair_parts(folder, found, [other])
    _untouched(outside, before)
    assert (folder / other).is_file()


def test_a_planted_temporary_part_is_named_and_a_regular_one_cleared(dataset, place):
    folder, outside = place
    shutil.rmtree(folder)
    shutil.copytree(dataset, folder)
    (folder / f".{PART}.tmp-99999").write_bytes(b"half a part")
    clear_temporaries(folder)
    assert not (folder / f".{PART}.tmp-99999").exists()
    _plant(folder / f".{PART}.tmp-99998", "symlink", outside)
    with pytest.raises(Planted):
        clear_temporaries(folder)
    assert (outside / "victim.txt").read_text() == "the victim's own words\n"


def test_a_division_record_planted_as_a_link_is_never_written_through(dataset, place):
    folder, outside = place
    shutil.rmtree(folder)
    shutil.copytree(dataset, folder)
    plan = plan_sweep(parse_spec(SPEC), chunk_fields=2)
    _plant(folder / f"..division.json.tmp-{os.getpid()}", "symlink", outside)
    before = _snapshot(outside)
    with OutputLock(folder, (0, 2)), pytest.raises(Planted):
        agree_division(folder, Division.of(plan, 2), (0, 2))
    _untouched(outside, before)


@pytest.mark.parametrize("name", [".lock", f".{PART}.tmp-{{pid}}", PART])
def test_merge_into_a_folder_with_a_planted_name_writes_nothing_outside(dataset, place, name):
    folder, outside = place
    name = name.format(pid=os.getpid())
    _plant(folder / name, "symlink", outside)
    before = _snapshot(outside)
    rc, out, err = capture(main, ["sweep", "merge", str(dataset), "--out", str(folder)])
    assert "Traceback" not in err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and name in err, err
    _untouched(outside, before)


def test_merge_clears_a_dead_writers_temporary_part(dataset, place):
    folder, _ = place
    (folder / f".{PART}.tmp-99999").write_bytes(b"half a part")
    rc, out, err = capture(main, ["sweep", "merge", str(dataset), "--out", str(folder)])
    assert rc == 0, err
    assert sorted(p.name for p in folder.iterdir()) == sorted(p.name for p in dataset.iterdir()
                                                              if not p.name.startswith("."))


def test_merge_refuses_an_output_inside_a_source(dataset, tmp_path):
    src = tmp_path / "src"
    shutil.copytree(dataset, src)
    rc, out, err = capture(main, ["sweep", "merge", str(src), "--out", str(src / "sub")])
    assert rc == 2 and "inside" in err and len(err.strip().splitlines()) == 1, err
    assert not (src / "sub").exists()


@pytest.mark.parametrize("command", ["report", "tune", "compare"])
def test_report_tune_and_compare_refuse_a_planted_lock(dataset, place, command, repo_root):
    folder, outside = place
    _plant(folder / ".lock", "symlink", outside)
    before = _snapshot(outside)
    argv = {"report": ["report", str(dataset), "--out", str(folder), "--gallery", "0", "--baseline", "setting=0"],
            "tune": ["tune", str(repo_root / "sweeps" / "tune-tiny.toml"), "--out", str(folder)],
            "compare": ["compare", str(repo_root / "sweeps" / "tuned-comparison.toml"), "--out", str(folder)]}[command]
    rc, out, err = capture(main, argv)
    assert "Traceback" not in err
    assert rc == 2 and ".lock is a symbolic link" in err and len(err.strip().splitlines()) == 1, err
    _untouched(outside, before)


@pytest.mark.parametrize("name", ["report.md", "figures", "summary.csv"])
def test_report_never_writes_through_a_planted_output_name(dataset, place, name):
    folder, outside = place
    _plant(folder / name, "dir-symlink" if name == "figures" else "symlink", outside)
    before = _snapshot(outside)
    rc, out, err = capture(main, ["report", str(dataset), "--out", str(folder), "--gallery", "0",
                                  "--baseline", "setting=0", "--resamples", "200"])
    assert "Traceback" not in err
    assert rc == 2 and name in err and len(err.strip().splitlines()) == 1, err
    _untouched(outside, before)


def test_every_file_the_package_writes_goes_through_jaxapf_io(repo_root):
    """The promise holds for code not yet written: outside jaxapf/io, no module opens a file for writing
    or hands a path to a writer (matplotlib, pandas); each writes through write_atomic or staged."""
    import ast

    allowed = {"jaxapf/cli/catalog.py"}  # the catalogue cache, in the user's own cache folder (tempfile)
    found = []
    for rel, node, name in package_calls(repo_root, allowed):
        first = node.args[0] if node.args else None
        to_path = first is not None and not (isinstance(first, ast.Name) and first.id in ("fh", "buf"))
        mode = next((a.value for a in node.args[1:2] if isinstance(a, ast.Constant)), "r")
        if (name in ("write_text", "write_bytes")
                or (name == "open" and isinstance(node.func, ast.Name) and any(c in str(mode) for c in "wax+"))
                or (name in ("savefig", "to_csv", "to_parquet", "to_html", "savez") and to_path)):
            found.append(f"{rel}:{node.lineno} {name}")
    assert found == [], "write through jaxapf.io.lock.write_atomic or staged: " + ", ".join(found)
