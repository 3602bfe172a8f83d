"""``jaxapf --help``, ``jaxapf CMD --help``, ``jaxapf list ...`` and argument errors import no JAX:
they read the registries' catalogue (jaxapf/cli/catalog.py), which says what the registries say."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

from cli_capture import capture
from conftest import ROOT

from jaxapf.cli import main
from jaxapf.cli.catalog import live

LISTS = tuple(live()["lists"])
COMMANDS = ("simulate", "sweep", "report", "tune", "compare", "bench", "list")
CALLS = ([["--help"]] + [[c, "--help"] for c in COMMANDS] + [["bench", "engine", "--help"]]
         + [["list", w] for w in LISTS]
         + [["simulate", "--no-such-flag"], ["simulate", "--methods", "nope"], ["list", "nothing"], ["sweep"]])

# ``jaxapf`` stands in for the package's __init__ (which imports the whole engine for the Python API),
# so that what is measured is the command line's own imports
SCRIPT = textwrap.dedent("""
    import json, sys, types
    sys.path.insert(0, sys.argv[4])
    from cli_capture import capture
    stub = bool(int(sys.argv[2]))
    if sys.argv[5] == "live":  # the registries themselves, as a clean process imports them
        import jaxapf.engine.components
    elif stub:
        package = types.ModuleType("jaxapf")
        package.__path__ = [sys.argv[1]]
        sys.modules["jaxapf"] = package
    from jaxapf.cli import main

    results = []
    for argv in json.loads(sys.argv[3]):
        rc, out, err = capture(main, argv)
        results.append({"argv": argv, "rc": rc, "out": out, "err": err, "jax": "jax" in sys.modules})
    print("RESULT " + json.dumps(results))
""")


def _calls(tmp_path, calls, stub=True, live=False):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"} | {"XDG_CACHE_HOME": str(tmp_path),
                                                                         "JAX_PLATFORMS": "cpu"}
    work = tmp_path / "work"  # not the cache's folder: its jaxapf/ would shadow the installed package
    work.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(ROOT / "jaxapf"), str(int(stub)), json.dumps(calls),
                           str(ROOT / "tests"), "live" if live else "catalogue"],
                          env=env, capture_output=True, text=True, timeout=300, cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(next(line for line in proc.stdout.splitlines() if line.startswith("RESULT "))[7:])


def _live(argv):
    return capture(main, argv)


def test_help_list_and_argument_errors_import_no_jax_and_say_what_the_registries_say(tmp_path):
    first = _calls(tmp_path, [["--help"]])  # no catalogue yet: read live (JAX) and written
    assert first[0]["rc"] == 0 and first[0]["jax"]
    assert list((tmp_path / "jaxapf" / "cli").glob("catalog-*.json"))
    # the same text as from the registries themselves, read live in a clean process (this one may hold a
    # plugin another test registered)
    live = _calls(tmp_path / "live", CALLS, live=True)
    for result, want in zip(_calls(tmp_path, CALLS), live):
        assert not result["jax"], f"jaxapf {' '.join(result['argv'])} imported jax"
        assert want["jax"] and want["argv"] == result["argv"]
        assert (result["rc"], result["out"], result["err"]) == (want["rc"], want["out"], want["err"]), result["argv"]
    assert _calls(tmp_path, [["list", "nothing"]])[0]["rc"] == 2


def test_list_is_plain_text_and_worded_like_list_gains():
    outputs = {w: _live(["list", w])[1] for w in LISTS}
    for what, text in outputs.items():
        assert "``" not in text and ":class:" not in text and ":func:" not in text, what
    gains = dict(line.split(None, 1) for line in outputs["gains"].splitlines())
    for line in outputs["planners"].splitlines() + outputs["plants"].splitlines():
        if line.startswith(" "):  # a component's gain: the same words, unit and default as `list gains`
            name, text = line.strip().split(": ", 1)
            assert text == gains[name].strip(), line


def test_the_installed_command_imports_no_jax(tmp_path):
    _calls(tmp_path, [["--help"]], stub=False)
    assert not any(r["jax"] for r in _calls(tmp_path, [["--help"], ["list", "planners"]], stub=False))


def test_the_lazy_package_gives_every_public_name_and_no_name_shadows_a_module():
    code = textwrap.dedent("""
        import importlib.util, pkgutil, sys
        import jaxapf
        assert "jax" not in sys.modules
        # the first public name loads the engine: every component's gains are declared (docs/api.md's start)
        assert jaxapf.Gains.grid(gamma=[0.5, 1.0], k=[1.0]).gamma.shape == (2,)
        # no public name is also a submodule: `import jaxapf.<module>` always gives the module
        modules = {m.name for m in pkgutil.iter_modules(jaxapf.__path__)}
        assert not modules & set(jaxapf.__all__), modules & set(jaxapf.__all__)
        import jaxapf.engine
        assert callable(jaxapf.rollout) and jaxapf.rollout is jaxapf.engine.rollout
        namespace = {}
        exec("from jaxapf import *", namespace)
        missing = set(jaxapf.__all__) - set(namespace)
        assert not missing, missing
        assert set(jaxapf.__all__) <= set(dir(jaxapf))
        assert jaxapf.PLANNERS["basic"] is not None
        try:
            jaxapf.no_such_name
        except AttributeError as err:
            assert "no_such_name" in str(err)
        else:
            raise AssertionError("no AttributeError")
        print("OK")
    """)
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"} | {"JAX_PLATFORMS": "cpu"}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert proc.stdout.strip() == "OK", proc.stderr[-3000:]


def test_the_program_says_its_version():
    from importlib.metadata import version

    from cli_capture import capture

    from jaxapf.cli import main

    rc, out, err = capture(main, ["--version"])
    assert rc == 0 and out.strip() == f"jaxapf {version('jaxapf')}"
