"""The package's layout: imports go one way (no two modules import each other, even inside a
function), and no public name of ``jaxapf`` hides a module of the same name."""

from __future__ import annotations

import ast
import graphlib
import importlib
import pathlib
import pkgutil

import pytest
from conftest import ROOT

PACKAGE = ROOT / "jaxapf"


def module_name(path: pathlib.Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: pathlib.Path, modules: set[str]) -> set[str]:
    """The jaxapf modules ``path`` imports anywhere in its code (a package: its ``__init__``; ``from
    P import name`` of a submodule ``name``: that submodule)."""
    here = module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            found.add(base)
            found |= {f"{base}.{a.name}" for a in node.names}
    return {m for m in found if m in modules and m != here}


def graph() -> dict[str, set[str]]:
    """module -> the modules it imports, leaving out a submodule's imports of its own package (whose
    ``__init__`` only hands the submodules' names on, ``from . import x``)."""
    paths = sorted(PACKAGE.rglob("*.py"))
    modules = {module_name(p) for p in paths}
    return {module_name(p): {m for m in imports(p, modules) if not module_name(p).startswith(m + ".")}
            for p in paths}


def test_no_two_modules_import_each_other():
    try:
        tuple(graphlib.TopologicalSorter(graph()).static_order())
    except graphlib.CycleError as err:
        pytest.fail(f"modules that import each other: {' -> '.join(err.args[1])}")


def test_the_check_finds_a_circle():
    g = graph()
    g["jaxapf.engine.loop"].add("jaxapf.engine.stream")  # the circle this layout removed
    with pytest.raises(graphlib.CycleError):
        tuple(graphlib.TopologicalSorter(g).static_order())


@pytest.mark.parametrize("old", ["jaxapf.rollout", "jaxapf.stream", "jaxapf.mpc", "jaxapf.potentials", "jaxapf.catalog",
                                 "jaxapf.sensing", "jaxapf.dynamics", "jaxapf.devices", "jaxapf.components",
                                 "jaxapf.lock", "jaxapf.plugins", "jaxapf.versions", "jaxapf.frame",
                                 "jaxapf.io.spec", "jaxapf.io.plugins"])
def test_no_shim_keeps_an_old_import_path(old):
    assert old not in {module_name(p) for p in PACKAGE.rglob("*.py")}


def test_no_package_attribute_hides_its_submodule():
    """``import jaxapf.X.Y as m`` gives the module Y: no package exports a name equal to one of its
    submodules (``jaxapf.rollout`` was once the function, hiding the module)."""
    hidden = []
    for path in sorted(PACKAGE.rglob("__init__.py")):
        package = importlib.import_module(module_name(path))
        for sub in pkgutil.iter_modules(package.__path__):
            if sub.name == "__main__":  # running it is the command line
                continue
            module = importlib.import_module(f"{package.__name__}.{sub.name}")
            if getattr(package, sub.name) is not module:
                hidden.append(f"{package.__name__}.{sub.name}")
    assert not hidden, hidden


#: The longest a function runs without a reason stated beside it.
LONGEST = 80


def test_no_function_runs_past_80_lines_without_a_reason_beside_it():
    """A function longer than :data:`LONGEST` lines says why on the line above its ``def`` (``# long: ...``);
    the others are split where their parts have names of their own."""
    unexplained = []
    for path in sorted(PACKAGE.rglob("*.py")):
        lines = path.read_text().split("\n")
        for node in ast.walk(ast.parse("\n".join(lines))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno >= LONGEST:
                top = min([node.lineno] + [d.lineno for d in node.decorator_list])
                if not lines[top - 2].strip().startswith("# long: "):
                    unexplained.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} "
                                       f"({node.end_lineno - node.lineno + 1} lines)")
    assert not unexplained, "give a reason (# long: ...) or split: " + "; ".join(unexplained)
