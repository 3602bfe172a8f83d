"""A spec's ``.py`` plugins are read from the spec file's folder, and a sweep's dataset names them
(never imports them) from any working directory, also after the dataset and its plugin moved together."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap

import pytest
from conftest import ROOT

from jaxapf.sweep import load_spec, parse_spec
from jaxapf.validation import ConfigError

PLUGIN = ROOT / "tests" / "plugins" / "sideways.py"

SPEC = textwrap.dedent("""
    name = "ext"
    plugins = ["plugins/sideways.py"]
    [scenario]
    families = ["pillar"]
    fields = 2
    oracle = false
    [sim]
    t_max = 2.0
    horizon = 3
    iters = 3
    [grid]
    method = ["basic", "sideways_drift"]
""")

# run in a fresh process (registries are process-wide), in the working directory it is given
SCRIPT = textwrap.dedent("""
    import contextlib, io, json, sys
    from jaxapf.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(sys.argv[1:])
    print("RESULT " + json.dumps({"rc": rc, "stdout": out.getvalue()}))
""")


def _run(cwd, *argv, rc=0):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"} | {"JAX_PLATFORMS": "cpu"}
    proc = subprocess.run([sys.executable, "-c", SCRIPT, *map(str, argv)], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=400)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(next(line for line in proc.stdout.splitlines() if line.startswith("RESULT "))[7:])
    assert result["rc"] == rc, proc.stderr[-3000:]
    return result["stdout"], proc.stderr


@pytest.mark.slow
def test_spec_plugins_sweep_and_report_from_any_directory(tmp_path):
    study = tmp_path / "study"
    (study / "plugins").mkdir(parents=True)
    shutil.copy(PLUGIN, study / "plugins" / "sideways.py")
    (study / "spec.toml").write_text(SPEC)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    # the spec from another directory: its plugin path is the spec folder's
    _run(elsewhere, "sweep", study / "spec.toml", "--out", study / "runs" / "ext.parquet", "--quiet", "--no-cache")
    meta = json.loads(__import__("pyarrow.parquet", fromlist=["x"]).read_schema(
        next((study / "runs" / "ext.parquet").glob("part-*.parquet"))).metadata[b"jaxapf"])
    assert meta["spec"]["plugins"] == ["plugins/sideways.py"]  # as written: the hash does not depend on where
    assert meta["plugin_files"] == [{"path": str((study / "plugins" / "sideways.py").resolve()),
                                     "from_output": os.path.join("..", "..", "plugins", "sideways.py")}]
    # the study folder moved (the recorded absolute path is gone): opening the dataset imports nothing, and
    # its refusal names the plugin where it now lies, next to the dataset; named with --plugin, the report
    # reads it from yet another directory and re-simulates the gallery
    moved = tmp_path / "moved"
    study.rename(moved)
    report = ["report", moved / "runs" / "ext.parquet", "--out", tmp_path / "report", "--resamples", "100",
              "--gallery", "1", "--heatmap", "none", "--no-cache"]
    _, err = _run(elsewhere, *report, rc=2)
    assert err.count("\n") == 1 and f"plugin(s) {(moved / 'plugins' / 'sideways.py').resolve()}, which" in err, err
    stdout, _ = _run(elsewhere, "--plugin", moved / "plugins" / "sideways.py", *report)
    assert "could not re-simulate" not in stdout, stdout
    assert (tmp_path / "report" / "figures" / "gallery_1.png").is_file(), stdout


def test_spec_plugin_paths_are_the_spec_folders(tmp_path, monkeypatch):
    (tmp_path / "specs").mkdir()
    (tmp_path / "specs" / "noop_plugin.py").write_text("LOADED = True\n")
    (tmp_path / "specs" / "s.toml").write_text('name = "s"\nplugins = ["noop_plugin.py"]\n'
                                               '[scenario]\nfamilies = ["clutter"]\nfields = 1\n')
    other = tmp_path / "other"
    other.mkdir()
    monkeypatch.chdir(other)
    spec = load_spec(tmp_path / "specs" / "s.toml")
    assert spec.plugins == ("noop_plugin.py",)
    assert spec.plugin_paths == (str((tmp_path / "specs" / "noop_plugin.py").resolve()),)
    # a bad path: one line naming the field and where it looked
    table = {"name": "s", "plugins": ["missing.py"], "scenario": {"families": ["clutter"], "fields": 1}}
    with pytest.raises(ConfigError) as err:
        parse_spec(table, base=tmp_path / "specs")
    message = str(err.value)
    assert message.startswith("plugins[0] = 'missing.py': no such file") and "\n" not in message
    assert str(tmp_path / "specs" / "missing.py") in message


def test_compare_spec_digest_does_not_depend_on_where_the_spec_lies(tmp_path):
    """A comparison's finished selections are kept by its spec's digest: the same spec read from two
    folders (its plugin with it) has one digest, so a moved study resumes instead of refusing."""
    from jaxapf.compare.select import spec_digest
    from jaxapf.compare.spec import load_compare_spec

    text = textwrap.dedent("""
        name = "moved"
        plugins = ["noop_plugin.py"]
        methods = ["basic", "direction"]
        [selection]
        families = ["trap"]
        seeds = [1, 2, 3]
        budget = 8
        candidates = 2
        [test]
        families = ["trap"]
        fields = 2
    """)
    digests = []
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "noop_plugin.py").write_text("LOADED = True\n")
        (tmp_path / folder / "spec.toml").write_text(text)
        spec, _ = load_compare_spec(tmp_path / folder / "spec.toml")
        assert spec.plugin_paths == (str((tmp_path / folder / "noop_plugin.py").resolve()),)
        digests.append(spec_digest(spec))
    assert digests[0] == digests[1]


def _registered_after(plugins):
    """In a fresh process: import ``plugins`` as the report's second process does; the planners then
    registered and what the process recorded as loaded."""
    import jaxapf
    from jaxapf.spec.plugins import LOADED, load_plugin

    for name, path in plugins:
        load_plugin(name, "plugin", path)
        load_plugin(name, "plugin", path)  # imported once, recorded once
    return jaxapf.PLANNERS.names(), list(LOADED)


def test_a_second_process_imports_the_plugins_this_one_imported():
    """The report draws figures in a spawned process (jaxapf.report.worker.RowWorker), which must see
    the planners of the plugins loaded in the report's process (by --plugin or by the sweep's spec):
    jaxapf.spec.plugins.LOADED records them once each. (Fresh processes: a plugin's registrations would
    outlive the test in this one.)"""
    import concurrent.futures
    import multiprocessing

    plugin = (str(PLUGIN), str(PLUGIN.resolve()))
    spawn = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=spawn) as pool:
        assert "sideways" not in pool.submit(_registered_after, ()).result()[0]
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=spawn) as pool:
        planners, loaded = pool.submit(_registered_after, (plugin,)).result()
    assert "sideways" in planners and loaded == [plugin]


CALLER = """
from jaxapf.stats import seed_interval


def own():
    return {}["missing"]  # OWN LINE


def unreadable(args):
    raise OSError("the calibration table is not there")  # OSERROR LINE


def into_jaxapf():
    return seed_interval([1.0, 2.0], confidence=5.0)
"""


def test_a_plugins_own_failure_is_told_from_jaxapfs_called_by_a_plugin(tmp_path, monkeypatch):
    """plugin_failure names the plugin, file, line and function where the deepest of an error's frames in jaxapf
    or a plugin is the plugin's, in this process or in a worker's (a remote traceback's text); a jaxapf function
    failing under a plugin's call keeps its traceback (None), as does an error without a plugin frame."""
    import concurrent.futures.process as cfp
    import importlib.util

    import jaxapf.spec.plugins as plugins

    path = tmp_path / "caller.py"
    path.write_text(CALLER)
    spec = importlib.util.spec_from_file_location("caller_plugin_test", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(plugins, "LOADED", [("caller.py", str(path))])
    line = next(i for i, text in enumerate(CALLER.splitlines(), 1) if "# OWN LINE" in text)
    with pytest.raises(KeyError) as own:
        module.own()
    said = plugins.plugin_failure(own.value)
    assert said == f"the plugin caller.py failed at caller.py:{line} in own: KeyError: 'missing'"
    with pytest.raises(ValueError) as inner:
        module.into_jaxapf()
    assert plugins.plugin_failure(inner.value) is None
    assert plugins.plugin_failure(ValueError("no frames")) is None
    # raised in a worker process: the parent's error carries the worker's traceback as text
    remote = RuntimeError("boom")
    text = f'Traceback:\n  File "{path}", line {line}, in own\n    x\nRuntimeError: boom'
    remote.__cause__ = cfp._RemoteTraceback(text)
    said = plugins.plugin_failure(remote)
    assert said == f"the plugin caller.py failed at caller.py:{line} in own: RuntimeError: boom"
    # a Ray task's error: the worker's traceback as text, the error it raised as its cause
    ray = pytest.importorskip("ray")
    task = ray.exceptions.RayTaskError("ChunkWorker.run", text, RuntimeError("boom"))
    assert plugins.plugin_failure(task) == said
    assert plugins.plugin_failure(task.as_instanceof_cause()) == said  # what ray.get raises: also a RuntimeError
    assert plugins.plugin_failure(ray.exceptions.RayTaskError("ChunkWorker.run", "Traceback:\n", KeyError(1))) is None
    # the command line: a plugin's OSError that is not the system's (no errno) is the plugin's line, no traceback
    from cli_capture import capture

    import jaxapf.cli.commands as commands

    monkeypatch.setattr(commands, "_list", module.unreadable)
    rc, _, stderr = capture(commands.main, ["list", "planners"])
    at = next(i for i, text in enumerate(CALLER.splitlines(), 1) if "# OSERROR LINE" in text)
    assert rc == 2 and stderr.strip() == (f"jaxapf list: error: the plugin caller.py failed at caller.py:{at} in "
                                          "unreadable: OSError: the calibration table is not there; "
                                          + commands._KEPT["list"]), stderr
