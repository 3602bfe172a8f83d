"""Every byte that changes what a reader sees is covered: crafted part metadata (the `ref`-style attacks on
main 59db75c) is either ignored by the reader or refused, and `jaxapf sweep verify` and the report agree.

The content hash covers the ``jaxapf`` key and every column's name, type and values; a part rewritten with
its hash recomputed (anyone can) still must hold the sweep's columns, so a retyped or extra column is
foreign. A schema's ``pandas`` key, which renamed columns when the rows became a DataFrame, is never read.
"""

from __future__ import annotations

import json
import shutil
import sys

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from cli_capture import capture
from conftest import ROOT

from jaxapf.cli import main
from jaxapf.report.load import ReportError, load_sweep
from jaxapf.sweep import parse_spec, read_sweep, run_sweep
from jaxapf.sweep.output import part_files
from jaxapf.validation import ConfigError

sys.path.insert(0, str(ROOT / "benchmarks"))
from faults import _reseal, _rewrite  # noqa: E402  (a part's content forged as the faults benchmark forges it)

SPEC = {"name": "crafted", "scenario": {"families": ["trap", "crossing"], "fields": 4, "seed": 5},
        "sim": {"t_max": 1.5, "horizon": 3, "iters": 3}, "grid": {"k_rep": [5.0, 10.0]}}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("crafted") / "ds"
    run_sweep(parse_spec(SPEC), out, chunk_fields=2, quiet=True)
    return out, read_sweep(out)[0]


def _crafted(dataset, tmp_path):
    out = tmp_path / "ds"
    shutil.copytree(dataset[0], out)
    return out, part_files(out)[0]


def _verdicts(out):
    """``(verify's status, its text, the report loader's rows or its refusal)``."""
    rc, text, err = capture(main, ["sweep", "verify", str(out)])
    assert "Traceback" not in err
    try:
        rows = load_sweep(out)[0]
    except ReportError as refusal:
        rows = str(refusal)
    return rc, text + err, rows


def test_a_pandas_key_that_swaps_two_columns_is_never_read(dataset, tmp_path):
    out, part = _crafted(dataset, tmp_path)
    table = pq.read_table(part)
    pandas = json.loads(pa.Table.from_pandas(table.to_pandas()).schema.metadata[b"pandas"])
    for col in pandas["columns"]:  # the DataFrame would call min_clearance path_length and the reverse
        col["name"] = {"min_clearance": "path_length", "path_length": "min_clearance"}.get(col["name"], col["name"])
    _rewrite(part, table.replace_schema_metadata({**table.schema.metadata, b"pandas": json.dumps(pandas).encode()}),
             rehash=False)
    assert list(pq.read_table(part).to_pandas().columns) != list(table.to_pandas().columns)  # the attack bites raw
    rc, text, rows = _verdicts(out)
    assert rc == 0 and "complete and sound" in text
    assert rows[["min_clearance", "path_length"]].equals(dataset[1][["min_clearance", "path_length"]])


@pytest.mark.parametrize("column,retype", [("min_clearance", pa.float64()), ("success", pa.string())])
def test_a_retyped_column_with_its_hash_recomputed_is_foreign_to_verify_and_the_report(dataset, tmp_path, column,
                                                                                        retype):
    out, part = _crafted(dataset, tmp_path)
    table = pq.read_table(part)
    i = table.schema.get_field_index(column)
    _rewrite(part, table.set_column(i, pa.field(column, retype), table.column(column).cast(retype)))
    rc, text, rows = _verdicts(out)
    assert rc == 1 and f"foreign: {part.name}: holds column {column} as {retype}" in text, text
    assert isinstance(rows, str) and part.name in rows and column in rows
    with pytest.raises(ConfigError, match=column):
        read_sweep(out)


def test_an_extra_column_with_its_hash_recomputed_is_foreign(dataset, tmp_path):
    out, part = _crafted(dataset, tmp_path)
    table = pq.read_table(part)
    _rewrite(part, table.append_column("bonus", pa.array([1.0] * table.num_rows)))
    rc, text, rows = _verdicts(out)
    assert rc == 1 and "columns bonus not of this sweep" in text and isinstance(rows, str)


def test_a_stray_parquet_file_never_switches_the_audit_off(dataset, tmp_path):
    out, part = _crafted(dataset, tmp_path)
    table = pq.read_table(part)
    pq.write_table(table.set_column(table.schema.get_field_index("min_clearance"), "min_clearance",
                                    pa.array([99.0] * table.num_rows, pa.float32())), out / "zz-notes.parquet")
    (out / "NOTES.txt").write_text("notes")
    _rewrite(part, table.append_column("bonus", pa.array([1.0] * table.num_rows)))  # and a foreign part
    rc, text, rows = _verdicts(out)
    assert rc == 1 and "not a part (never read as rows): NOTES.txt, zz-notes.parquet" in text
    assert isinstance(rows, str) and part.name in rows  # the audit still ran: the foreign part is refused
    part.unlink()
    shutil.copy(dataset[0] / part.name, part)
    rc, text, rows = _verdicts(out)
    assert rc == 0 and "zz-notes.parquet" in text
    assert rows.equals(dataset[1]) and read_sweep(out)[1]["stray"] == ["NOTES.txt", "zz-notes.parquet"]


def test_every_parts_stored_spec_rewritten_with_its_hash_kept_is_refused_everywhere(dataset, tmp_path):
    """The break-in: every part's stored grid rewritten (a gain's values swapped), ``spec_hash`` kept, content
    hashes re-sealed: verify called it complete and sound, resume accepted it, the report re-simulated under
    the wrong labels. The stored spec is now bound to its hash: verify, the report, resume and merge refuse."""
    out = _crafted(dataset, tmp_path)[0]

    def swap(meta):
        meta["spec"]["grid"] = [["k_rep", [10.0, 5.0]]]

    for part in part_files(out):
        _reseal(part, swap)
    rc, text, rows = _verdicts(out)
    assert rc != 0 and "complete and sound" not in text and isinstance(rows, str), text
    assert "spec_hash" in text or "spec_hash" in rows
    assert "part-" in text and "part-" in rows, (text, rows)  # each refusal names a part
    with pytest.raises(ConfigError, match="part-.*(cannot be trusted|spec_hash)"):
        run_sweep(parse_spec(SPEC), out, chunk_fields=2, quiet=True)
    rc, _, err = capture(main, ["sweep", "merge", str(out), "--out", str(tmp_path / "m")])
    assert rc == 2 and "Traceback" not in err and err.count("\n") == 1 and "part-" in err, err


def test_half_a_folders_parts_of_another_jaxapf_version_are_not_one_sweep(dataset, tmp_path):
    """Half the parts recorded as written by another jaxapf version: verify, report and merge called the folder
    complete and sound, and resume added parts to it. One output holds one version's parts."""
    out = _crafted(dataset, tmp_path)[0]
    parts = part_files(out)

    def older(meta):
        meta["versions"]["jaxapf"] = "0.0.1"

    for part in parts[: len(parts) // 2]:
        _reseal(part, older)
    rc, text, rows = _verdicts(out)
    assert rc == 1 and "jaxapf differs" in text and isinstance(rows, str) and "version" in rows, (text, rows)
    with pytest.raises(ConfigError, match="cannot be trusted"):
        run_sweep(parse_spec(SPEC), out, chunk_fields=2, quiet=True)
    rc, _, err = capture(main, ["sweep", "merge", str(out), "--out", str(tmp_path / "m")])
    assert rc == 2 and "Traceback" not in err and err.count("\n") == 1, err
    for part in parts[len(parts) // 2:]:  # all of another version: resume says what to do
        _reseal(part, older)
    with pytest.raises(ConfigError, match=r"holds a different sweep \(jaxapf 0\.0\.1 here, .* now\); rerun with "
                                          r"--overwrite"):
        run_sweep(parse_spec(SPEC), out, chunk_fields=2, quiet=True)
