"""A dataset is data: opening one (verify, merge, read, report) imports nothing it names.

A part's metadata records the spec's plugins and where their files lay; it used to be imported on
opening, so a shared dataset could run code (a plugin that wrote a file proved it).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest
from cli_capture import capture

from jaxapf.cli import main
from jaxapf.sweep import read_sweep
from jaxapf.sweep.merge import merge_outputs
from jaxapf.validation import ConfigError

SPEC = textwrap.dedent("""
    name = "inert"
    plugins = ["{plugin}"]
    [scenario]
    families = ["trap"]
    fields = 4
    seed = 2
    [sim]
    t_max = 2.0
    horizon = 3
    iters = 3
    [grid]
    method = ["basic", {method}]
""")
#: A plugin that writes a marker file when imported (and registers the planner ``marked``).
PLUGIN = textwrap.dedent("""
    import pathlib
    pathlib.Path(__file__).with_name("MARKER").write_text("imported")
    import jaxapf
    from jaxapf.planners.weights import Basic
    jaxapf.register_planner("marked_{tag}", jaxapf.APF(Basic(), description="basic, from a plugin that marks"))
""")


def _write(tmp_path, method: str):
    """A dataset written (in another process) by a spec naming the marker plugin; the marker removed."""
    tag = tmp_path.name.replace("-", "_")
    plugin = tmp_path / f"marker_{tag}.py"
    plugin.write_text(PLUGIN.replace("{tag}", tag))
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.format(plugin=plugin.name, method=method.replace("{tag}", tag)))
    out = tmp_path / "data.parquet"
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    run = subprocess.run([sys.executable, "-m", "jaxapf", "sweep", str(spec), "--out", str(out), "--quiet",
                          "--no-cache"], env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    marker = tmp_path / "MARKER"
    assert marker.read_text() == "imported"  # the writer imported it, as its spec asked
    marker.unlink()
    return out, plugin, marker, tag


@pytest.mark.slow
def test_a_dataset_naming_a_plugin_is_verified_merged_read_and_reported_without_importing_it(tmp_path):
    out, plugin, marker, _ = _write(tmp_path, '"direction"')
    rc, stdout, _ = capture(main, ["sweep", "verify", str(out)])
    assert rc == 0 and "complete and sound" in stdout and not marker.exists()
    merge_outputs([out], tmp_path / "merged")
    assert not marker.exists()
    df, meta = read_sweep(tmp_path / "merged")
    assert meta["complete"] and len(df) == 8 and not marker.exists()
    assert meta["plugin_files"][0]["path"] == str(plugin.resolve())  # named, as text
    rc, _, err = capture(main, ["report", str(out), "--out", str(tmp_path / "report"), "--resamples", "100",
                                "--gallery", "1", "--heatmap", "none", "--no-cache"])
    assert rc == 0, err
    assert (tmp_path / "report" / "report.html").is_file() and not marker.exists()


@pytest.mark.slow
def test_a_dataset_needing_a_plugin_is_refused_naming_it_until_the_user_names_it(tmp_path):
    out, plugin, marker, tag = _write(tmp_path, '"marked_{tag}"')
    with pytest.raises(ConfigError) as err:
        read_sweep(out)
    line = str(err.value)
    assert f"'marked_{tag}' is not a registered planner" in line and "\n" not in line
    assert f"written with the plugin(s) {plugin.resolve()}, which opening a dataset never imports" in line
    rc, _, stderr = capture(main, ["sweep", "verify", str(out)])
    assert rc == 2 and str(plugin.resolve()) in stderr and stderr.count("\n") == 1
    assert not marker.exists()
    from jaxapf.spec.plugins import load_plugin

    load_plugin(str(plugin))  # the user trusts it
    assert marker.exists()
    df, meta = read_sweep(out)
    assert meta["complete"] and set(df["method"]) == {"basic", f"marked_{tag}"}
