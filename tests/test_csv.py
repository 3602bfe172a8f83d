"""CSV that jaxapf writes is data to a spreadsheet, never a formula (OWASP, "CSV Injection")."""

import ast
import io

import pandas as pd
from conftest import package_calls

from jaxapf.text import csv_text


def test_a_cell_a_spreadsheet_would_run_is_prefixed_and_numbers_are_left_alone():
    frame = pd.DataFrame({"=cmd|' /C calc'!A0": ["=HYPERLINK(\"http://x\")", "+1", "-2+3", "@SUM(A1)", "\tx", "ok",
                                                  "a=b"],
                          "delta": [-1.5, -2.0, 3.0, 0.0, 1.0, 3.0, 4.0]})
    back = pd.read_csv(io.StringIO(csv_text(frame)), keep_default_na=False)
    assert list(back.columns) == ["'=cmd|' /C calc'!A0", "delta"]
    assert back.iloc[:, 0].tolist() == ["'=HYPERLINK(\"http://x\")", "'+1", "'-2+3", "'@SUM(A1)", "'\tx", "ok",
                                        "a=b"]
    assert back["delta"].tolist() == [-1.5, -2.0, 3.0, 0.0, 1.0, 3.0, 4.0]  # a negative number stays one
    assert "'\rx" in csv_text(pd.DataFrame({"a": ["\rx"]}))


def test_every_csv_the_package_writes_goes_through_csv_text(repo_root):
    found = [f"{rel}:{node.lineno}" for rel, node, name in package_calls(repo_root, {"jaxapf/text.py"}, False)
             if name == "to_csv" and isinstance(node.func, ast.Attribute)]
    assert found == [], "write CSV through jaxapf.text.csv_text: " + ", ".join(found)
