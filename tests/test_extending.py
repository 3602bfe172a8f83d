"""Components registered from outside the package run through list → sweep → report → tune.

The plugin (tests/plugins/sideways.py) registers a weight with a force term, a safety filter, a
scenario family and a metric, each declaring its own gains; nothing in jaxapf names them. The
whole chain runs in a fresh process (registries are process-wide), through the CLI as a user
would, at tiny sizes.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest
from conftest import ROOT

PLUGIN = ROOT / "tests" / "plugins" / "sideways.py"

SCRIPT = textwrap.dedent("""
    import json, pathlib, sys, contextlib, io
    import pandas as pd
    from jaxapf.cli import main

    root, plugin = pathlib.Path(sys.argv[1]), sys.argv[2]
    out = {}
    listing = io.StringIO()
    with contextlib.redirect_stdout(listing):
        for what in ("planners", "filters", "families", "metrics", "gains"):
            assert main(["--plugin", plugin, "list", what]) == 0
    out["listing"] = listing.getvalue()
    help_text = io.StringIO()
    with contextlib.redirect_stdout(help_text), contextlib.suppress(SystemExit):
        main(["--plugin", plugin, "simulate", "--help"])
    out["simulate_help"] = help_text.getvalue()

    (root / "spec.toml").write_text(f'''
    name = "ext"
    plugins = ["{plugin}"]
    [scenario]
    families = ["pillar"]
    fields = 6
    [sim]
    t_max = 3.0
    horizon = 3
    iters = 3
    filter = "damped"
    [grid]
    method = ["basic", "sideways_drift"]
    beta = [0.0, 2.0]
    ''')
    assert main(["sweep", str(root / "spec.toml"), "--out", str(root / "ext.parquet"), "--quiet", "--no-cache"]) == 0
    rows = pd.concat([pd.read_parquet(p) for p in sorted((root / "ext.parquet").glob("part-*.parquet"))])
    out["columns"] = list(rows.columns)
    out["rows"] = len(rows)
    out["filters"] = sorted(set(rows["filter"]))
    out["mean_speed_positive"] = bool((rows["mean_speed"] > 0).all())
    out["kinds"] = sorted(set(rows["kind"]))
    clearance = lambda method, beta: rows[(rows.method == method) & (rows.beta == beta)].sort_values(
        "field")["min_clearance"].to_numpy()
    out["beta_changes_sideways"] = bool((clearance("sideways_drift", 0.0) != clearance("sideways_drift", 2.0)).any())
    out["basic_ignores_beta"] = bool((clearance("basic", 0.0) == clearance("basic", 2.0)).all())

    # a fresh report process would import the plugin from the sweep's metadata; here it is loaded already
    assert main(["report", str(root / "ext.parquet"), "--out", str(root / "report"), "--resamples", "100",
                 "--gallery", "1", "--heatmap", "none"]) == 0
    summary = pd.read_csv(root / "report" / "summary.csv")
    out["report_has_metric"] = "mean_speed_iqm" in summary.columns
    out["report_labels"] = sorted(set(summary["label"]))
    md = (root / "report" / "report.md").read_text()
    out["report_mentions_metric"] = "mean_speed [m/s]" in md

    (root / "tune.toml").write_text(f'''
    name = "ext-tune"
    plugins = ["{plugin}"]
    [train]
    families = ["pillar"]
    fields_per_step = 2
    steps = 2
    validate_every = 1
    [validation]
    fields = 2
    [test]
    families = ["pillar"]
    fields = 2
    [sim]
    method = "sideways_drift"
    filter = "damped"
    t_max = 2.0
    horizon = 3
    iters = 3
    [search]
    grid = {{ beta = [0.0, 1.0] }}
    random_n = 2
    ''')
    assert main(["tune", str(root / "tune.toml"), "--out", str(root / "tune"), "--quiet"]) == 0
    tuned = json.loads((root / "tune" / "summary.json").read_text())
    out["tuned_params"] = tuned["spec"]["reparam"]["names"]
    out["tuned_gains"] = tuned["gains"]["tuned"]
    print("RESULT " + json.dumps(out))
""")


@pytest.mark.slow
def test_out_of_package_components_run_through_sweep_report_and_tune(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"} | {"JAX_PLATFORMS": "cpu"}
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path), str(PLUGIN)], env=env, capture_output=True,
                          text=True, timeout=540)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(next(line for line in proc.stdout.splitlines() if line.startswith("RESULT "))[7:])
    # listed, with their declared gains, and offered as choices and flags
    for name in ("sideways", "sideways_drift", "damped", "pillar", "mean_speed", "beta", "c_d", "drift"):
        assert name in out["listing"], name
    assert "--beta" in out["simulate_help"] and "--c-d" in out["simulate_help"] and "damped" in out["simulate_help"]
    # the sweep: gain columns of what the spec uses, the new metric, the filter's column
    assert out["rows"] == 2 * 2 * 6
    for column in ("beta", "drift", "c_d", "mean_speed", "filter"):
        assert column in out["columns"], column
    assert out["filters"] == ["damped"] and out["mean_speed_positive"]
    assert out["kinds"] == ["thick", "thin"]  # the family's kinds reach every row
    assert out["beta_changes_sideways"] and out["basic_ignores_beta"]
    # the report: the metric's statistics and unit, and labels that leave out what basic ignores
    assert out["report_has_metric"] and out["report_mentions_metric"]
    assert any(label.endswith("basic") for label in out["report_labels"])
    assert any("sideways_drift beta=2" in label for label in out["report_labels"])
    # tune: the tunable gains of the planner and the filter, by default
    assert out["tuned_params"] == ["k_rep", "d_s", "k_att", "eta", "beta", "drift", "c_d"]
    assert 0.0 <= out["tuned_gains"]["c_d"] <= 1.0


MISTAKES = ROOT / "tests" / "plugins" / "mistakes.py"
#: The line of the plugin whose own code fails while traced.
BROKEN = next(i for i, line in enumerate(MISTAKES.read_text().splitlines(), 1) if "# BROKEN LINE" in line)

CALLS = textwrap.dedent("""
    import contextlib, io, pathlib, sys
    from jaxapf.cli import main

    root, plugin = pathlib.Path(sys.argv[1]), sys.argv[2]
    for method in ("wide", "misspelled", "short", "not_a_number", "flat", "broken"):
        spec = root / f"{method}.toml"
        t_max = 20.0 if method == "not_a_number" else 0.5  # long enough to come within d_s of an obstacle
        stack = 'method = "basic"\\nfilter = "flat"' if method == "flat" else f'method = "{method}"'
        spec.write_text(f'name = "m"\\nplugins = ["{plugin}"]\\n[scenario]\\nfamilies = ["trap"]\\nfields = 2\\n'
                        f'[sim]\\nt_max = {t_max}\\nhorizon = 3\\niters = 2\\n{stack}\\n')
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            code = main(["sweep", str(spec), "--out", str(root / method), "--quiet"])
        print(f"{method} {code} {err.getvalue()!r}")
""")


def test_a_plugins_wrong_shapes_misspelled_gains_and_nan_are_one_line_each(tmp_path):
    """A weight of shape (3, M), a gain read that no component declares, a planner's reference one point
    short: each refused while the program is traced, in one line naming what was wrong (before: a weight's
    wrong shape broadcast into other obstacles' ω without a word, a misspelled gain was a 102-line traceback).
    A weight that is NaN near obstacles: refused on the variant's first chunk, naming the setting's planner,
    the family and the field (before: exit 0, episodes neither success, collision nor stall)."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"} | {"JAX_PLATFORMS": "cpu"}
    proc = subprocess.run([sys.executable, "-c", CALLS, str(tmp_path), str(MISTAKES)], env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    said = {line.split(" ", 2)[0]: line.split(" ", 2)[1:] for line in proc.stdout.splitlines()}
    for method, words in (("wide", "the weight ω of 'Wide' returned shape (3, "),
                          ("misspelled", "no gain 'k_cc' here (misspelled"),
                          ("short", "planner 'short' returned shape (3, 6) where the closed loop reads its reference"),
                          ("not_a_number", "(method = 'not_a_number') flew field 0 of trap into a non-finite state"),
                          ("flat", "safety filter 'flat' returned shape (2,) where the closed loop reads the"),
                          ("broken", f"the plugin {MISTAKES.name} failed at {MISTAKES.name}:{BROKEN} in __call__: "
                                     "AttributeError: ")):
        code, err = said[method]
        assert code == "2" and err.count("\\n") == 1 and words in err and "Traceback" not in err, (method, err)
