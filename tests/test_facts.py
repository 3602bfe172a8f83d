"""Every study's facts.json, which the docs bind their numbers to (tests/bindings.py), is what its script
computes from the committed results (``--facts-only``, simulating nothing), never typed by hand: rerun
into a copy of the results folder, each comes out equal to the committed one."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys

import pytest
from conftest import ROOT
from test_readme_numbers import studies

FOLDERS = {folder: stem for stem, (_, folder) in studies().items()
           if (ROOT / "analysis" / "results" / folder / "facts.json").exists()}


def _rerun(script: str, folder: str, flag: str, tmp_path, timeout: int = 300) -> tuple:
    """``analysis/<script>.py <flag>`` run into a copy of the committed results ``folder``: ``(copy, committed)``."""
    committed = ROOT / "analysis" / "results" / folder
    copy = tmp_path / folder
    shutil.copytree(committed, copy)
    done = subprocess.run([sys.executable, f"analysis/{script}.py", flag, "--out", str(copy)],
                          cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, done.stderr[-2000:]
    return copy, committed


@pytest.mark.slow
@pytest.mark.parametrize("folder", sorted(FOLDERS))
def test_a_studys_facts_are_what_its_script_computes_from_its_results(folder, tmp_path):
    copy, committed = _rerun(FOLDERS[folder], folder, "--facts-only", tmp_path)
    found, kept = json.loads((copy / "facts.json").read_text()), json.loads((committed / "facts.json").read_text())
    assert _differences(found, kept) == []


#: How far a float64 fact may move between x86 CPUs: numpy's sums and BLAS reduce in an order that
#: depends on the SIMD width (the last one or two bits of a mean or a quantile's interpolation).
REL = 1e-12


def _differences(a, b, at: str = "") -> list[str]:
    """Where ``a`` and ``b`` differ: keys, lengths, texts, counts exactly, floats beyond :data:`REL`."""
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return [f"{at}: keys {sorted(set(a) ^ set(b))[:5]}"]
        return [d for k in a for d in _differences(a[k], b[k], f"{at}/{k}")]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{at}: {len(a)} items, {len(b)} committed"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _differences(x, y, f"{at}[{i}]")]
    if isinstance(a, float) and isinstance(b, float) and not (isinstance(a, bool) or isinstance(b, bool)):
        same = math.isclose(a, b, rel_tol=REL, abs_tol=0.0) or (math.isnan(a) and math.isnan(b))
        return [] if same else [f"{at}: {a!r}, {b!r} committed"]
    return [] if a == b and type(a) is type(b) else [f"{at}: {a!r}, {b!r} committed"]


def test_a_float_fact_may_move_by_rounding_and_no_more():
    assert _differences({"m": [0.1, 2, "x"]}, {"m": [0.1 * (1 + 3e-16), 2, "x"]}) == []
    assert _differences({"m": 0.1}, {"m": 0.1 * (1 + 1e-9)}) != []
    assert _differences({"n": 2}, {"n": 3}) != [] and _differences({"n": 2}, {"n": 2.0}) != []


def test_every_study_has_facts():
    assert set(FOLDERS) == {folder for _, folder in studies().values()}


def test_the_results_hold_no_file_a_clean_clone_would_lack():
    """A result a script reads but git ignores passes here and fails in a fresh clone (study 18's parquet did)."""
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    ignored = subprocess.run(["git", "ls-files", "--others", "--ignored", "--exclude-standard", "analysis/results"],
                             cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    assert [p for p in ignored if "__pycache__" not in p] == []


@pytest.mark.slow
def test_a_studys_report_is_what_its_committed_episodes_give(tmp_path):
    """``--from-episodes`` rebuilds a study's report from its committed ``episodes.parquet`` without simulating:
    the comparisons come out as committed (what lets the next change to the statistics re-derive every study
    that keeps its episodes without a rerun)."""
    import pandas as pd

    copy, committed = _rerun("sign_convention", "sign_convention", "--from-episodes", tmp_path, timeout=600)
    found, kept = (pd.read_csv(folder / "report" / "comparisons.csv") for folder in (copy, committed))
    pd.testing.assert_frame_equal(found, kept, check_exact=False, rtol=REL)
    assert _differences(json.loads((copy / "facts.json").read_text()),
                        json.loads((committed / "facts.json").read_text())) == []


@pytest.mark.slow
def test_study_13s_facts_only_rewrites_its_page_byte_for_byte(tmp_path):
    """Study 13's ``--facts-only`` rewrites its page from the committed tables and kept episodes: the page comes
    out as committed, naming the command that flew its episodes (``--kept-selections``), not its own."""
    copy, committed = _rerun("offset_free", "offset_free", "--facts-only", tmp_path)
    assert (copy / "README.md").read_text() == (committed / "README.md").read_text()


def test_the_flags_analysis_readme_names_are_the_scripts():
    """Every flag analysis/README.md's paragraph on the scripts' flags names is one the shared parser or the
    named study's own switches take, and every shared flag is named there."""
    import re

    sys.path.insert(0, str(ROOT / "analysis"))
    import study

    text = (ROOT / "analysis" / "README.md").read_text()
    paragraph = text[text.index("Every script takes"):].split("`study.py` holds")[0]
    named = set(re.findall(r"`(--[a-z-]+)", paragraph))
    shared = {o for a in study.parser("x\n")._actions for o in a.option_strings if o.startswith("--")} - {"--help"}
    own = set(re.findall(r'"(--[a-z-]+)":', (ROOT / "analysis" / "flown_planners.py").read_text()))
    assert named - shared == own and shared <= named


def test_a_pages_command_names_every_flag_that_changed_what_it_flew():
    """The "Produced by" command of a study's page names --fields, --from-episodes, --kept-selections and the
    study's own switches that were set, and no other (hand-made flags)."""
    sys.path.insert(0, str(ROOT / "analysis"))
    import study

    def args(*given):
        return study.parser("x\n").parse_args(list(given))

    assert study.command_line("s", args()) == "python analysis/s.py"
    assert study.command_line("s", args("--kept-selections", "--resamples", "9")) == \
        "python analysis/s.py --kept-selections"
    own = study.parser("x\n")
    own.add_argument("--kept-swarms", action="store_true")
    given = own.parse_args(["--fields", "4", "--kept-swarms", "--kept-selections"])
    assert study.command_line("s", given, {"--kept-swarms": "h"}) == \
        "python analysis/s.py --fields 4 --kept-selections --kept-swarms"
    assert study.command_line("s", own.parse_args([]), {"--kept-swarms": "h"}) == "python analysis/s.py"
