"""Every study's facts.json, which the docs bind their numbers to (tests/bindings.py), is what its script
computes from the committed results (``--facts-only``, simulating nothing), never typed by hand: rerun
into a copy of the results folder, each comes out equal to the committed one."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest
from conftest import ROOT
from test_readme_numbers import studies

FOLDERS = {folder: stem for stem, (_, folder) in studies().items()
           if (ROOT / "analysis" / "results" / folder / "facts.json").exists()}


@pytest.mark.slow
@pytest.mark.parametrize("folder", sorted(FOLDERS))
def test_a_studys_facts_are_what_its_script_computes_from_its_results(folder, tmp_path):
    committed = ROOT / "analysis" / "results" / folder
    copy = tmp_path / folder
    shutil.copytree(committed, copy)
    done = subprocess.run([sys.executable, f"analysis/{FOLDERS[folder]}.py", "--facts-only", "--out", str(copy)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads((copy / "facts.json").read_text()) == json.loads((committed / "facts.json").read_text())


def test_every_study_has_facts():
    assert set(FOLDERS) == {folder for _, folder in studies().values()}


def test_the_results_hold_no_file_a_clean_clone_would_lack():
    """A result a script reads but git ignores passes here and fails in a fresh clone (study 18's parquet did)."""
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    ignored = subprocess.run(["git", "ls-files", "--others", "--ignored", "--exclude-standard", "analysis/results"],
                             cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    assert [p for p in ignored if "__pycache__" not in p] == []
