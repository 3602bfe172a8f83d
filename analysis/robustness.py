"""Study 12: how much of each planner's safety survives noisy sensing, latency, limited range, wind
and the paper's quadrotor.

Every method of study 11 (the planner benchmark) flies at its tuned best: the gains its seed-1
random search chose there (the same budget for every method, ``analysis/results/planner_benchmark/
selection.csv``), so the comparison keeps study 11's protocol and changes only the world. Each
method then flies the same held-out fields (48 per family of study 11's six, seed 200, obstacle slots
padded to one count) in the ideal world and with one imperfection at a time:

* obstacle noise σ ∈ {0.1, 0.25, 0.5}: each measured centre coordinate [m] and velocity
  component [m/s] with that standard deviation (``sensor = "noisy"``);
* latency ∈ {0.1, 0.3, 0.6} s: the stack sees the obstacles as they were;
* sensing range ∈ {8, 4, 2} m of clearance;
* wind of {2, 4, 6} m/s (heading 90°) with gusts of half that standard deviation (τ = 2 s), through
  the linear drag 0.3 1/s (``disturbance = "wind"``);
* the quadrotor plant (AscTec Hummingbird, geometric attitude loop, ``plant = "quadrotor"``).

The ideal world and every sensing and wind level are one compiled program per method (the noisy
sensor and the wind at the level's gains, zero for the others: at zero they pass the truth on and
push with exactly 0); the quadrotor is a second.

Every episode draws its noise and gusts from the field's key, so all methods and levels see the
same draws (common random numbers). Rates come with Wilson intervals (95 %), clearance with a
bootstrap interval of the mean; the verdict per method and condition against the same method in the
ideal world is the exact McNemar test on the paired fields with the report's 2-point margin.

    python analysis/robustness.py     # ~10.5 min on 2 cores (36 compiled programs, 36,288 episodes)
"""

from __future__ import annotations

import dataclasses
import pathlib

import jax
import numpy as np
import pandas as pd
import study

STUDY = "robustness"
SELECTION = study.RESULTS / "planner_benchmark" / "selection.csv"
SPEC = study.ROOT / "sweeps" / "planner-benchmark.toml"
FIELDS, SEED = 48, 200
#: The relevance margin of a change in success (the ``success`` metric's, 2 points).
MARGIN = 0.02
#: The world of every level but the quadrotor: the noisy sensor and the wind, each at the level's
#: gains (zero for the others). At zero levels both pass the truth on and push with exactly 0, so one
#: compiled program flies the ideal world and every sensing and wind level as one vmap.
WORLD = {"sensor": "noisy", "disturbance": "wind"}
#: (axis, level, static settings, gains) of every world.
WORLDS = ([("ideal", "ideal", WORLD, {})]
          + [("noise", f"σ = {s:g}", WORLD, {"sigma_obs_p": s, "sigma_obs_v": s}) for s in (0.1, 0.25, 0.5)]
          + [("latency", f"{d:g} s", WORLD, {"latency": d}) for d in (0.1, 0.3, 0.6)]
          + [("range", f"{r:g} m", WORLD, {"sense_range": r}) for r in (8.0, 4.0, 2.0)]
          + [("wind", f"{w:g} m/s", WORLD, {"wind_speed": w, "wind_heading": 90.0, "gust_sigma": w / 2})
             for w in (2.0, 4.0, 6.0)]
          + [("quadrotor", "quadrotor", {"plant": "quadrotor"}, {})])

def tuned_gains(method: str) -> dict[str, float]:
    """The gains study 11's seed-1 selection chose for ``method``."""
    from jaxapf.compare.select import Selection
    from jaxapf.gains import GAINS

    table = pd.read_csv(SELECTION)
    # a gain column that is no longer declared (cbf_k0/cbf_k1 before the CBF filter took the rates
    # cbf_p1/cbf_p2) would be dropped silently and the method fly its defaults: rerun study 11 first
    fixed = {f.name for f in dataclasses.fields(Selection)} - {"gains"}
    stale = sorted(set(table.columns) - fixed - set(GAINS.names()))
    if stale:
        raise SystemExit(f"{SELECTION}: columns {', '.join(stale)} are not declared gains; rerun "
                         "analysis/planner_benchmark.py to select with the current gains")
    row = table[(table["method"] == method) & (table["seed"] == 1)].iloc[0]
    return {g: float(row[g]) for g in GAINS.names() if g in row and np.isfinite(row[g])}


def flow_gain(method: str) -> float:
    """η·k_att of ``method``'s selected gains: how hard the reference pulls toward the goal."""
    gains = tuned_gains(method)
    return gains["eta"] * gains["k_att"]


def fields(spec, count: int) -> list[tuple[object, np.ndarray]]:
    """The held-out fields of every test family and each field's family, in two groups: the families
    with few obstacle slots, padded to their largest count, and the rest (the exact solvers' cost grows
    steeply with the slots, so few-obstacle fields are not padded to many)."""
    from jaxapf.scenarios import make_scenarios
    from jaxapf.sweep.spec import spec_family_params
    from jaxapf.tune.train import pad_obstacles

    batches = {f: make_scenarios(SEED, spec_family_params(f, spec.params.get(f, {})), count)
               for f in spec.test.families}
    groups = {}
    for f, b in batches.items():
        groups.setdefault(b.obstacles.size <= 5, []).append(f)
    out = []
    for members in groups.values():
        slots = max(batches[f].obstacles.size for f in members)
        merged = jax.tree_util.tree_map(lambda *x: np.concatenate(x),
                                        *[pad_obstacles(batches[f], slots) for f in members])
        out.append((merged, np.repeat(np.asarray(members), count)))
    return out


def run(spec, count: int) -> pd.DataFrame:
    """One row per (method, world, field) with the outcome metrics."""
    from jaxapf import Gains
    from jaxapf.config import MPCConfig, SimConfig
    from jaxapf.rollout import evaluate

    groups = fields(spec, count)
    mpc = MPCConfig()
    t_max = max(spec_t_max(spec, f) for f in spec.test.families)
    variants: dict[tuple, list] = {}
    for world in WORLDS:
        variants.setdefault(tuple(sorted(world[2].items())), []).append(world)
    rows = []
    for method in spec.methods:
        planner, _, safety = method.partition("+")
        base = SimConfig.from_flat(method=planner, filter=safety or "none", t_max=t_max)
        tuned = tuned_gains(method)
        for static, worlds in variants.items():
            batch = jax.tree_util.tree_map(lambda *x: np.asarray(x, np.float32),
                                           *[Gains(**tuned, **w[3]) for w in worlds])
            for scenarios, family in groups:
                metrics = jax.device_get(evaluate(scenarios, batch, base.replace(**dict(static)), mpc, metrics=(
                    "success", "collision", "stalled", "min_clearance", "time_to_goal", "final_distance", "max_tilt",
                    "accel_error_rms", "unseen_steps")))
                for i, (axis, level, _, _) in enumerate(worlds):
                    frame = pd.DataFrame({k: np.asarray(v[i]) for k, v in metrics.items()})
                    rows.append(frame.assign(method=method, axis=axis, level=level, family=family,
                                             field=[f"{f}/{j % count}" for j, f in enumerate(family)]))
        print(f"  {method}: done", flush=True)
    return pd.concat(rows, ignore_index=True)


def spec_t_max(spec, family: str) -> float:
    from jaxapf.sweep.spec import spec_family_params

    return spec_family_params(family, spec.params.get(family, {})).t_max


def summarise(df: pd.DataFrame, resamples: int) -> pd.DataFrame:
    """Per (method, axis, level): rates with Wilson intervals, mean clearance with a bootstrap
    interval, and the paired verdict on success against the same method in the ideal world."""
    from jaxapf.stats import (
        bootstrap_ci,
        equivalence_test,
        mcnemar_exact,
        paired_proportion_difference,
        verdict,
        wilson_interval,
    )

    ideal = df[df["axis"] == "ideal"].set_index(["method", "field"])
    out = []
    for (method, axis, level), g in df.groupby(["method", "axis", "level"], sort=False):
        row = {"method": method, "axis": axis, "level": level, "n": len(g)}
        for rate in ("success", "collision", "stalled"):
            k = int(g[rate].sum())
            lo, hi = wilson_interval(k, len(g))
            row |= {rate: k / len(g), f"{rate}_lo": float(lo), f"{rate}_hi": float(hi)}
        clear = np.clip(g["min_clearance"].to_numpy(np.float64), -1.0, 10.0)  # +inf without obstacles: capped
        row["min_clearance"] = float(clear.mean())
        row["min_clearance_lo"], row["min_clearance_hi"] = map(float, bootstrap_ci(clear, n_resamples=resamples))
        row["max_tilt"] = float(g["max_tilt"].mean())
        row["accel_error_rms"] = float(g["accel_error_rms"].mean())
        row["unseen_steps"] = float(g["unseen_steps"].mean())
        row["final_distance"] = float(g["final_distance"].median())
        base = ideal.loc[method].loc[g["field"]]["success"].to_numpy(bool)
        now = g["success"].to_numpy(bool)
        diff, lo, hi = paired_proportion_difference(now, base)
        p = mcnemar_exact(now, base).pvalue
        p_equivalent = equivalence_test(now, base, MARGIN, kind="rate").p
        row |= {"success_change": diff, "change_lo": lo, "change_hi": hi, "p": p,
                "verdict": "—" if axis == "ideal" else verdict(lo, hi, p, p_equivalent, MARGIN, True)}
        out.append(row)
    return pd.DataFrame(out)


def figure(summary: pd.DataFrame, path: pathlib.Path) -> None:
    """Success, collision and mean minimum clearance against each imperfection's level, one column per
    axis, with Wilson (rates) and bootstrap (clearance) intervals; methods side by side at each level."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes_names = ["noise", "latency", "range", "wind", "quadrotor"]
    palette = plt.get_cmap("tab10").colors
    methods = list(summary["method"].unique())
    colors = {m: palette[i % len(palette)] for i, m in enumerate(methods)}
    rows = (("success", "success [%]", 100.0), ("collision", "collision [%]", 100.0),
            ("min_clearance", "mean min. clearance [m]", 1.0))
    fig, axes = plt.subplots(len(rows), len(axes_names), figsize=(4.2 * len(axes_names), 10), sharey="row")
    for col, axis in enumerate(axes_names):
        for i, (method, g) in enumerate(summary.groupby("method", sort=False)):
            part = pd.concat([g[g["axis"] == "ideal"], g[g["axis"] == axis]])
            x = np.arange(len(part)) + 0.05 * (i - (len(methods) - 1) / 2)
            for row, (name, label, scale) in enumerate(rows):
                ax = axes[row, col]
                value = scale * part[name].to_numpy()
                band = np.abs(scale * part[[f"{name}_lo", f"{name}_hi"]].to_numpy().T - value)
                ax.errorbar(x, value, yerr=band, label=method, capsize=1.5, marker="o", ms=3, lw=1,
                            linestyle="--" if "+" in method else "-", color=colors[method])
                ax.set_xticks(np.arange(len(part)), part["level"], rotation=20)
                ax.set_ylabel(label if col == 0 else "")
        axes[0, col].set_title(axis)
    axes[0, -1].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def table(summary: pd.DataFrame, metric: str = "success") -> str:
    """Markdown: ``metric`` in % per method (rows) and world (columns); for success the verdict's mark
    against the same method in the ideal world (↓ worse, ↑ better, = equivalent within 2 points)."""
    mark = {"worse": " ↓", "better": " ↑", "equivalent": " =", "inconclusive": "", "—": ""}
    worlds = [f"{a}: {lv}" if a not in ("ideal", "quadrotor") else a for a, lv, _, _ in WORLDS]
    lines = ["| method | " + " | ".join(worlds) + " |", "|---|" + "---|" * len(worlds)]
    for method, g in summary.groupby("method", sort=False):
        cells = []
        for axis, level, _, _ in WORLDS:
            r = g[(g["axis"] == axis) & (g["level"] == level)].iloc[0]
            cells.append(f"{100 * r[metric]:.1f}" + (mark[r["verdict"]] if metric == "success" else ""))
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def findings(summary: pd.DataFrame) -> list[str]:
    """One sentence per imperfection at its strongest level, built from the summary: the change in
    success of every method against its ideal world, the verdicts, the most and least affected."""
    out = []
    ideal = summary[summary["axis"] == "ideal"].set_index("method")
    for axis, level in STRONGEST:
        at = summary[(summary["axis"] == axis) & (summary["level"] == level)].set_index("method")
        change = 100 * (at["success"] - ideal["success"])
        collide = 100 * (at["collision"] - ideal["collision"])
        worse = int((at["verdict"] == "worse").sum())
        same = int((at["verdict"] == "equivalent").sum())
        line = (f"**{axis} ({level})**: success changes by {change.min():+.1f} to {change.max():+.1f} points "
                f"(most: `{change.idxmin()}`, least: `{change.idxmax()}`), collisions by {collide.min():+.1f} to "
                f"{collide.max():+.1f} points; *worse* than the ideal world for {worse} of {len(at)} methods, "
                f"*equivalent* for {same}.")
        if axis == "wind":
            line += (f" Median final distance to the goal {ideal['final_distance'].min():.2f}–"
                     f"{ideal['final_distance'].max():.2f} m in calm air, {at['final_distance'].min():.2f}–"
                     f"{at['final_distance'].max():.2f} m in this wind (goal tolerance 0.5 m), as expected of an "
                     "MPC that plans without a disturbance estimate: a steady push leaves a steady offset. "
                     "Per method, final distance against the selected attraction flow gain η·k_att: "
                     + ", ".join(f"`{m}` {d:.2f} m ({flow_gain(m):.2f})"
                                 for m, d in at["final_distance"].sort_values(ascending=False).items()) + ".")
        out.append(line)
    return out


#: The strongest level of every imperfection (the columns of the per-family table).
STRONGEST = (("noise", WORLDS[3][1]), ("latency", WORLDS[6][1]), ("range", WORLDS[9][1]),
             ("wind", WORLDS[12][1]), ("quadrotor", "quadrotor"))


def family_table(df: pd.DataFrame) -> str:
    """Markdown: per method and family, the change in success [points] against the same method in
    the ideal world at each imperfection's strongest level (the pooled numbers hide opposite signs)."""
    ideal = df[df["axis"] == "ideal"].groupby(["method", "family"], sort=False)["success"].mean()
    families = list(dict.fromkeys(df["family"]))
    lines = ["| method | " + " | ".join(families) + " |", "|---|" + "---|" * len(families)]
    blocks = []
    for axis, level in STRONGEST:
        at = df[(df["axis"] == axis) & (df["level"] == level)].groupby(["method", "family"], sort=False)["success"]
        change = 100 * (at.mean() - ideal)
        rows = [f"| {m} | " + " | ".join(f"{change[(m, f)]:+.1f}" for f in families) + " |"
                for m in dict.fromkeys(df["method"])]
        blocks.append("\n".join([f"### {axis} ({level})", "", *lines, *rows]))
    return "\n\n".join(blocks)


def write_readme(summary: pd.DataFrame, df: pd.DataFrame, out: pathlib.Path, count: int) -> None:
    n = int(summary["n"].iloc[0])
    text = [f"# Study 12: robustness ({n} held-out fields per method and world)", "",
            "`python analysis/robustness.py` (" + __doc__.split("\n")[0] + ")", "",
            "Protocol: every method at the gains its seed-1 random search chose in study 11 (equal budgets), "
            f"{count} fields of each of study 11's six test families (seed {SEED}), one imperfection at a time, "
            "common random numbers. Verdicts: paired success against the same method in the ideal world, exact "
            f"McNemar test and a {100 * MARGIN:g}-point equivalence margin.", "", "## Findings", ""]
    text += [f"- {line}" for line in findings(summary)]
    text += ["", "## Success [%] (↓ worse, ↑ better, = equivalent to the ideal world)", "", table(summary), "",
             "## Collision [%]", "", table(summary, "collision"), "",
             f"## Change in success per family [points] at each imperfection's strongest level ({count} fields per "
             "family; the pooled numbers above hide changes of opposite sign)", "", family_table(df), "",
             "![success, collision and clearance against each imperfection](robustness.png)", "",
             "`summary.csv` has every rate with its Wilson interval, the mean minimum clearance with its "
             "bootstrap interval, the paired change in success with its interval and p-value, and the mean "
             "`unseen_steps`, `max_tilt` and `accel_error_rms` of every method and world."]
    (out / "README.md").write_text("\n".join(text) + "\n")


def main() -> None:
    args, out = study.begin(__doc__, STUDY)
    from jaxapf.compare.spec import load_compare_spec

    spec, _ = load_compare_spec(SPEC)
    count = args.fields or FIELDS
    data = study.ROOT / "runs" / f"robustness-f{count}.parquet"  # git-ignored; a rerun only redraws
    if data.exists():
        df = pd.read_parquet(data)
    else:
        df = run(spec, count)
        data.parent.mkdir(exist_ok=True)
        df.to_parquet(data, index=False)
    summary = summarise(df, args.resamples)
    summary.to_csv(out / "summary.csv", index=False)
    figure(summary, out / "robustness.png")
    write_readme(summary, df, out, count)
    print("\n".join(findings(summary)))


if __name__ == "__main__":
    main()
