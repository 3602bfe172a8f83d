"""Every Python example in docs/*.md runs as written.

A page's ```python blocks are one script, run in a fresh process in an empty directory (so relative
paths land in a temporary one). A block right after an HTML comment ``<!-- not run: REASON -->`` is a
fragment and is skipped. docs/extending.md's blocks are a plugin module; tests/test_docs.py runs them
as the page says (a spec naming the module, the CLI with --plugin). A page whose example reads a
sweep's output gets one first (:data:`SETUP`).
"""

from __future__ import annotations

import os
import pathlib
import re
import subprocess
import sys
import textwrap

import pytest

#: Code run before a page's blocks: what the page assumes exists.
SETUP = {
    # "Reading the output" reads the README's sweep; a small one at the same path, with failures to pick
    "sweep.md": textwrap.dedent("""
        from jaxapf.sweep import parse_spec as _parse, run_sweep as _run
        _run(_parse({"name": "compare-small", "scenario": {"families": ["trap"], "fields": 2, "oracle": False},
                     "sim": {"t_max": 4.0, "horizon": 4, "iters": 4}, "grid": {"method": ["basic", "direction"]}}),
             "runs/compare-small.parquet", quiet=True)
    """),
}
#: Pages whose blocks other tests run.
ELSEWHERE = {"extending.md": "tests/test_docs.py::test_extending_examples_run_as_documented"}

_BLOCK = re.compile(r"(<!--\s*not run:[^>]*-->\s*\n)?```python\n(.*?)```", re.S)


def python_blocks(text: str) -> list[tuple[bool, str]]:
    """``(runs, code)`` of every ```python block of a page, in order."""
    return [(not m[1], m[2]) for m in _BLOCK.finditer(text)]


DOCS = pathlib.Path(__file__).resolve().parents[1] / "docs"
#: Every page with a ```python block, but those run elsewhere.
PAGES = sorted(p.name for p in DOCS.glob("*.md")
               if "```python" in p.read_text(encoding="utf-8") and p.name not in ELSEWHERE)


def test_the_pages_are_found():
    assert {"api.md", "sweep.md"} <= set(PAGES)
    for name in PAGES:
        text = (DOCS / name).read_text(encoding="utf-8")
        assert len(python_blocks(text)) == text.count("```python"), name  # no block missed by the pattern


@pytest.mark.slow
@pytest.mark.parametrize("page", PAGES)
def test_doc_examples_run(page, tmp_path):
    blocks = python_blocks((DOCS / page).read_text(encoding="utf-8"))
    script = SETUP.get(page, "") + "\n\n".join(code for runs, code in blocks if runs)
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"} | {"JAX_PLATFORMS": "cpu"}
    proc = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, f"docs/{page}:\n{proc.stderr[-3000:]}"
