"""Bad input is one line, never a traceback: seeded fuzzing of every shipped spec (sweep, tune and compare)
and of a dataset's part metadata, and the cases the break-in of main 59db75c found, each by name.

A mutated spec must parse or be refused with :class:`~jaxapf.validation.ConfigError` (the command line's
one line and status 2); crafted ``jaxapf`` metadata (a key removed, of another type), its content hash
recomputed as anyone can, must leave ``jaxapf sweep verify`` and the report agreeing: verify finds every
part sound exactly when the report reads the rows.
"""

from __future__ import annotations

import copy
import json
import os
import pathlib
import random
import shutil
import sys
import tomllib

import pyarrow.parquet as pq
import pytest
from cli_capture import capture
from conftest import ROOT

from jaxapf.cli import main
from jaxapf.compare.spec import parse_compare_spec
from jaxapf.report.load import ReportError, load_sweep
from jaxapf.sweep import parse_spec, run_sweep
from jaxapf.sweep.meta import META_KEY
from jaxapf.sweep.output import part_files
from jaxapf.tune.spec import parse_tune_spec
from jaxapf.validation import ConfigError

sys.path.insert(0, str(ROOT / "benchmarks"))
import faults  # noqa: E402  (the benchmark's forgery of a part's metadata)

ROOT = pathlib.Path(__file__).resolve().parents[1]
SPECS = sorted((ROOT / "sweeps").glob("*.toml"))
#: What a user can mistype or a hostile file can hold, in place of any value.
VALUES = [0, -1, 5, 2**40, 1e30, -1e30, 1e-30, float("inf"), float("nan"), "", "x", "$x^{2", True, [], [[1], 10.0],
          [1, 2, 3], {}, {"a": 1}, {"length": 1e30}, ["trap", 3]]


def _parser(data: dict):
    """The spec's parser, by the tables it has (as the commands tell them apart)."""
    if "selection" in data:
        return lambda d: parse_compare_spec(d, base=ROOT / "sweeps")
    if "train" in data:
        return lambda d: parse_tune_spec(d, base=ROOT / "sweeps")
    return parse_spec


def _paths(node, at=()):
    """Every (path, value) of a nested table, tables and arrays included."""
    yield at, node
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, at + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, at + (i,))


def _mutate(data: dict, rng: random.Random) -> tuple[dict, str]:
    """One random change: a value replaced, a key removed, or an unknown key added; and what it was."""
    data = copy.deepcopy(data)
    paths = [p for p, _ in _paths(data) if p]
    path = rng.choice(paths)
    parent = data
    for k in path[:-1]:
        parent = parent[k]
    how = rng.random()
    if how < 0.7:
        parent[path[-1]] = copy.deepcopy(rng.choice(VALUES))
        return data, f"{'.'.join(map(str, path))} = {parent[path[-1]]!r}"
    if how < 0.85 and isinstance(parent, dict):
        del parent[path[-1]]
        return data, f"{'.'.join(map(str, path))} removed"
    if isinstance(parent, dict):
        parent["trap"] = rng.choice(VALUES)
        return data, f"{'.'.join(map(str, path[:-1]))}.trap = {parent['trap']!r}"
    return data, "unchanged"


@pytest.mark.parametrize("spec", SPECS, ids=[p.stem for p in SPECS])
def test_mutated_specs_are_parsed_or_refused_in_one_line(spec):
    data = tomllib.loads(spec.read_text())
    parse = _parser(data)
    rng = random.Random(spec.stem)
    for _ in range(24):  # 24 per shipped spec: about 400 mutations a run, the same ones every run
        mutated, what = _mutate(data, rng)
        try:
            parse(mutated)
        except ConfigError as err:
            assert str(err) and "\n" not in str(err).strip(), f"{spec.name}, {what}: {err!r}"
        except Exception as err:  # noqa: BLE001 -- the test's point: nothing else may escape
            pytest.fail(f"{spec.name} with {what}: {type(err).__name__}: {err}")


SPEC = {"name": "tiny", "scenario": {"families": ["trap"], "fields": 4, "seed": 2},
        "sim": {"t_max": 1.0, "horizon": 3, "iters": 3}, "grid": {"k_rep": [5.0, 10.0]}}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("fuzz") / "ds"
    run_sweep(parse_spec(SPEC), out, chunk_fields=2, quiet=True)
    return out


def _craft(out: pathlib.Path, change) -> None:
    """Every part's ``jaxapf`` metadata changed by ``change(meta)``, the content hash recomputed (as the faults
    benchmark forges it)."""
    for part in part_files(out):
        faults._reseal(part, change)


def test_crafted_part_metadata_leaves_verify_and_the_report_agreeing(dataset, tmp_path):
    meta = json.loads(pq.read_schema(part_files(dataset)[0]).metadata[META_KEY])
    rng = random.Random(7)
    keys = [(k,) for k in meta] + [("spec", k) for k in meta["spec"]] + [("spec", "scenario", k)
                                                                         for k in meta["spec"]["scenario"]]
    cases = [(path, "removed") for path in keys] + [(path, rng.choice(VALUES)) for path in keys for _ in range(2)]
    for n, (path, value) in enumerate(cases):
        out = tmp_path / f"c{n}"
        shutil.copytree(dataset, out)

        def change(m, path=path, value=value):
            for k in path[:-1]:
                m = m[k]
            if value == "removed":
                m.pop(path[-1], None)
            else:
                m[path[-1]] = value
        _craft(out, change)
        rc, text, err = capture(main, ["sweep", "verify", str(out)])
        what = f"{'.'.join(path)} {value!r}"
        assert "Traceback" not in err and rc in (0, 1, 2), f"{what}: {err}"
        assert rc == 2 or len(err.strip().splitlines()) == 0, f"{what}: {err}"
        try:
            load_sweep(out)
            read = True
        except (ReportError, ConfigError):
            read = False
        except Exception as error:  # noqa: BLE001
            pytest.fail(f"{what}: the report's reader raised {type(error).__name__}: {error}")
        sound = rc == 0 or (rc == 1 and "damaged" not in text and "foreign" not in text and "overlapping" not in text)
        assert sound == read, f"{what}: verify says {text or err!r}, the report {'reads' if read else 'refuses'}"


# --- the cases of the break-in, each by name: one line, status 2 --------------------------------------------

def _one_line(argv, match: str) -> None:
    rc, out, err = capture(main, argv)
    assert "Traceback" not in err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and match in err, (rc, err)


@pytest.mark.parametrize("argv,match", [
    (["--shard", "0/1000000000", "--dry-run"], "N <= 1,000,000"),
    (["--memory-budget", "1e400", "--dry-run"], "more than 1 TiB"),
    (["--memory-budget", "-5", "--dry-run"], "is not a size"),
])
def test_counts_and_sizes_a_user_can_mistype_name_their_limit(tiny_spec, tmp_path, argv, match):
    _one_line(["sweep", str(tiny_spec), "--out", str(tmp_path / "o"), *argv], match)


@pytest.mark.parametrize("argv,match", [
    (["--resamples", "100000000"], "from 100 to 100,000"),
    (["--seed", "-1"], "--seed = -1 must be an integer from 0"),
    (["--gallery", "100000"], "--gallery = 100000"),
])
def test_report_options_out_of_bounds_name_their_limit(dataset, tmp_path, argv, match):
    _one_line(["report", str(dataset), "--out", str(tmp_path / "r"), "--baseline", "setting=0", *argv], match)


@pytest.mark.parametrize("table,match", [
    ("[scenario.params]\ntrap = 5\n", "scenario.params.trap must be a table"),
    ("[scenario.params.trap]\ndistance = [[1], 10.0]\n", "scenario.params.trap.distance"),
    ("[scenario.params.trap]\nscale = { length = 1e30 }\n", "scale.length = 1e+30 is out of range"),
])
def test_a_spec_table_of_the_wrong_shape_or_scale_is_one_line(tmp_path, table, match):
    path = tmp_path / "bad.toml"
    path.write_text('name = "bad"\n[scenario]\nfamilies = ["trap"]\nfields = 4\n' + table)
    _one_line(["sweep", str(path), "--out", str(tmp_path / "o"), "--dry-run"], match)


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="needs /dev/zero")
def test_a_device_or_a_pipe_as_the_spec_is_refused_without_reading_it(tmp_path):
    _one_line(["sweep", "/dev/zero", "--out", str(tmp_path / "o")], "is not a regular file")
    os.mkfifo(tmp_path / "fifo.toml")
    _one_line(["sweep", str(tmp_path / "fifo.toml"), "--out", str(tmp_path / "o")], "is not a regular file")


def test_a_set_aside_that_is_a_file_is_named(dataset, tiny_spec, tmp_path):
    out = tmp_path / "o"
    shutil.copytree(dataset, out)
    (out / ".set-aside").write_text("not a folder")
    _one_line(["sweep", str(tiny_spec), "--out", str(out), "--repair", "--chunk-fields", "2"],
              ".set-aside is a file where jaxapf keeps a folder")


def test_a_full_disk_while_the_report_writes_is_one_line(dataset, tmp_path, full_disk):
    full_disk(".report.html")
    _one_line(["report", str(dataset), "--out", str(tmp_path / "r"), "--baseline", "setting=0", "--gallery", "0",
               "--resamples", "200"], "(the file system is full)")


def test_a_full_disk_while_merging_is_one_line(dataset, tmp_path, full_disk):
    full_disk(after=1)
    _one_line(["sweep", "merge", str(dataset), "--out", str(tmp_path / "m")], "(the file system is full)")


def test_a_damaged_cached_catalogue_is_read_again(monkeypatch, tmp_path):
    from jaxapf.cli import catalog

    path = tmp_path / "catalog.json"
    data = catalog.live()
    del data["lists"]["estimators"]
    path.write_text(json.dumps(data))
    monkeypatch.setattr(catalog, "catalog_path", lambda: path)
    assert "estimators" in catalog.catalog()["lists"]


def test_a_search_checkpoint_missing_a_key_is_one_line(tmp_path):
    from jaxapf.tune.searches import _Checkpoint
    from jaxapf.tune.train import CheckpointError

    saved = _Checkpoint(tmp_path, "tpe", "d")
    saved.save({"trials": []})
    with pytest.raises(CheckpointError, match="seconds missing or of another type"):
        saved.load({"trials": list, "seconds": float})
    assert isinstance(CheckpointError("x"), ConfigError)


def test_a_tag_holding_mathtext_is_drawn_as_written(tmp_path):
    spec = tmp_path / "tag.toml"
    spec.write_text('name = "tag"\n[scenario]\nfamilies = ["trap"]\nfields = 4\nseed = 2\n'
                    '[sim]\nt_max = 1.0\nhorizon = 3\niters = 3\n'
                    '[[setting]]\nk_rep = 5.0\ntags = { role = "$\\\\alpha_{x$" }\n'
                    '[[setting]]\nk_rep = 10.0\ntags = { role = "$x^{2" }\n')
    rc, out, err = capture(main, ["sweep", str(spec), "--out", str(tmp_path / "ds"), "--quiet"])
    assert rc == 0, err
    rc, out, err = capture(main, ["report", str(tmp_path / "ds"), "--out", str(tmp_path / "r"),
                                  "--baseline", "setting=0", "--gallery", "0", "--resamples", "200"])
    assert rc == 0 and "Traceback" not in err, err


@pytest.mark.skipif(shutil.which("bash") is None, reason="sets the limit with bash's ulimit")
def test_a_small_address_space_is_one_line_not_a_native_abort(dataset, tmp_path):
    import shlex
    import subprocess
    import sys

    command = shlex.join([sys.executable, "-m", "jaxapf", "report", str(dataset), "--out", str(tmp_path / "r"),
                          "--baseline", "setting=0"])
    done = subprocess.run(["bash", "-c", f"ulimit -v 2000000 && exec {command}"], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 2 and "ulimit -v" in done.stderr and len(done.stderr.strip().splitlines()) == 1, \
        done.stderr[-500:]
