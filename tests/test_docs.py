"""The code in the docs runs: docs/extending.md's Python blocks are one plugin module, used as the
page says (its spec, verbatim, beside the plugin; the CLI with --plugin), in a fresh process."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap

import pytest

CHECK = textwrap.dedent("""
    import contextlib, io, json, pathlib, sys
    import jax, jax.numpy as jnp, pandas as pd
    from jaxapf.cli import main

    root, plugin = pathlib.Path(sys.argv[1]), sys.argv[2]
    # "Using them": the page's spec, verbatim, beside the plugin, names it as the page says
    from jaxapf.sweep import load_spec
    (root / "my-study.toml").write_text(sys.argv[3])
    study = load_spec(root / "my-study.toml")
    listing = io.StringIO()
    with contextlib.redirect_stdout(listing):
        assert main(["--plugin", plugin, "list", "planners"]) == 0
        assert main(["--plugin", plugin, "list", "sensors"]) == 0
        assert main(["--plugin", plugin, "list", "disturbances"]) == 0
        assert main(["--plugin", plugin, "list", "estimators"]) == 0
    (root / "spec.toml").write_text(f'''
    name = "doc-example"
    plugins = ["{plugin}"]
    [scenario]
    families = ["slalom"]
    fields = 4
    [sim]
    plant = "lagged"
    filter = "governor"
    sensor = "flicker"
    disturbance = "downdraft"
    estimator = "downdraft_forecast"
    t_max = 2.0
    horizon = 3
    iters = 3
    [grid]
    method = ["closing", "closing_damped", "smoothed_dv", "closing_goal_normalised", "ttc"]
    tau = [0.05, 0.2]
    [gains]
    flicker = 0.3
    downdraft = 0.5
    ''')
    assert main(["sweep", str(root / "spec.toml"), "--out", str(root / "out.parquet"), "--quiet", "--no-cache"]) == 0
    rows = pd.concat([pd.read_parquet(p) for p in sorted((root / "out.parquet").glob("part-*.parquet"))])
    # "Using them": the report of a dataset whose components come from a plugin, the plugin named (its gallery
    # re-simulates episodes with them)
    reported = main(["--plugin", plugin, "report", str(root / "out.parquet"), "--out", str(root / "report"),
                     "--baseline", "method=closing", "--gallery", "1", "--resamples", "200"])
    page = (root / "report" / "report.md").read_text()
    lag = rows.groupby("tau")["mean_speed"].mean()
    # a weight is also called with no goal (sight.goal None): its reference value, the functional API
    import jaxapf
    from jaxapf.planners.potentials import weight
    gains = jaxapf.Gains()
    p, v, p_o = jnp.array([0.0, 0.0, 2.0]), jnp.array([1.0, 0.0, 0.0]), jnp.array([3.0, 0.5, 2.0])
    no_goal = [float(weight(p, v, p_o, jnp.zeros(3), method=m, convention="intent", **gains.floats()))
               for m in ("closing_goal", "closing_goal_normalised")]
    at_goal = float(weight(p, v, p_o, jnp.zeros(3), method="closing_goal", convention="intent", goal=p,
                           **gains.floats()))
    print("RESULT " + json.dumps({
        "no_goal": no_goal, "at_goal": at_goal,
        "reference": float(jaxapf.PLANNERS.get("closing_goal").weight.reference(gains)),
        "listing": listing.getvalue(), "rows": len(rows), "columns": list(rows.columns),
        "finite": bool(rows[["mean_speed", "final_distance"]].notna().all().all()),
        "methods": sorted(set(rows["method"])), "lag_matters": bool(lag.loc[0.05] != lag.loc[0.2]),
        "report": [reported, "could not re-simulate" in page, "## " in page],
        "study": [study.name, sorted(dict(study.grid)["method"])],
    }))
""")


@pytest.mark.slow
def test_extending_examples_run_as_documented(tmp_path, repo_root):
    page = (repo_root / "docs" / "extending.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", page, flags=re.S)
    assert len(blocks) >= 8
    plugin = tmp_path / "my_components.py"
    plugin.write_text("\n\n".join(blocks), encoding="utf-8")
    (study,) = [b for b in re.findall(r"```toml\n(.*?)```", page, flags=re.S) if "[scenario]" in b]
    commands = re.findall(r"```bash\n(.*?)```", page, flags=re.S)
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"} | {"JAX_PLATFORMS": "cpu"}
    proc = subprocess.run([sys.executable, "-c", CHECK, str(tmp_path), str(plugin), study], env=env,
                          capture_output=True, text=True, timeout=540)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(next(line for line in proc.stdout.splitlines() if line.startswith("RESULT "))[7:])
    assert {"closing", "closing_damped", "smoothed_dv", "closing_goal", "closing_goal_normalised", "flicker",
            "downdraft", "downdraft_forecast", "ttc"} <= set(out["listing"].split())
    assert out["rows"] == 5 * 2 * 4 and out["finite"]
    assert out["methods"] == ["closing", "closing_damped", "closing_goal_normalised", "smoothed_dv", "ttc"]
    # sight.goal None: the weight is the closing one (> 1: the obstacle closes in); at the goal it fades to 1
    assert out["no_goal"][0] > 1.0 and out["at_goal"] == 1.0 and out["reference"] == 1.0
    assert out["no_goal"][1] == out["no_goal"][0]  # normalised by its reference value 1
    for column in ("k_c", "b_damp", "alpha", "tau", "plant", "filter", "sensor", "disturbance", "estimator", "flicker",
                   "downdraft", "mean_speed"):
        assert column in out["columns"], column
    assert out["lag_matters"]  # the plant's traced time constant reaches the episodes
    reported, failed, written = out["report"]
    assert reported == 0 and written and not failed
    assert out["study"] == ["my-study", ["basic", "closing", "closing_damped", "smoothed_dv"]]
    # the commands run the spec from the folder it lies in, and name the plugin where the spec does not
    (lines,) = commands
    assert "jaxapf sweep my-study.toml" in lines and "runs/my-study.parquet" in lines


def test_spec_examples_in_the_docs_parse(repo_root):
    """Every sweep-spec example (a TOML block with [scenario]) of README and docs/sweep.md is a valid spec."""
    import tomllib

    from jaxapf.sweep import parse_spec

    checked = 0
    for page in ("README.md", "docs/sweep.md"):
        for block in re.findall(r"```toml\n(.*?)```", (repo_root / page).read_text(encoding="utf-8"), flags=re.S):
            if "[scenario]" in block:
                parse_spec(tomllib.loads(block))
                checked += 1
    assert checked >= 2
