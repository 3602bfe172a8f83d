"""The code passes the repository's ruff configuration (pyproject.toml)."""

import subprocess
import sys

import pytest
from conftest import ROOT


def test_ruff_passes():
    pytest.importorskip("ruff")
    proc = subprocess.run([sys.executable, "-m", "ruff", "check", str(ROOT)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:]
