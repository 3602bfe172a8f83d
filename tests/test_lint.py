"""The code passes the repository's ruff configuration (pyproject.toml), and its docstrings say what
and why in a few lines: measurements and history go to docs/."""

import ast
import re
import subprocess
import sys

import pytest
from conftest import ROOT


def test_ruff_passes():
    pytest.importorskip("ruff")
    proc = subprocess.run([sys.executable, "-m", "ruff", "check", str(ROOT)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:]


def test_no_module_is_an_essay():
    """No module's docstring is longer than its code (a package's ``__init__``, its overview and
    curated names, excepted), and none quotes a timing (ms, µs or seconds measured on some machine go
    stale; docs/performance.md holds them, from committed runs)."""
    long, timed = [], []
    for path in sorted((ROOT / "jaxapf").rglob("*.py")):
        text = path.read_text()
        doc = ast.get_docstring(ast.parse(text), clean=False) or ""
        lines = doc.count("\n") + 1 if doc else 0
        if lines > text.count("\n") - lines and path.name != "__init__.py":
            long.append(f"{path.relative_to(ROOT)} ({lines} lines of docstring)")
        if re.search(r"\d\s?(ms|µs|us)\b|\d+(\.\d+)? s (per|on|for) ", doc):
            timed.append(str(path.relative_to(ROOT)))
    assert not long, long
    assert not timed, timed
