"""Study 12: how much of each planner's safety survives noise, latency, short range, wind, a quadrotor.

Every method of study 11 (the planner benchmark) flies at its tuned best: the gains each of its
three random searches (selection seeds 1, 2, 3, the same budget for every method,
``analysis/results/planner_benchmark/selection.csv``) chose there, so the comparison keeps study
11's protocol and changes only the world; one selection is an anecdote, three show the spread.
Each (method, selection) then flies the same held-out fields (48 per family of study 11's six,
seed 200, obstacle slots padded to one count) in the ideal world and with one imperfection at a time:

* obstacle position noise σ_p ∈ {0.1, 0.25, 0.5} m on each measured centre coordinate, and
  separately velocity noise σ_v ∈ {0.1, 0.25, 0.5} m/s on each measured velocity component
  (``sensor = "noisy"``): the two act differently and are reported apart;
* latency ∈ {0.1, 0.3, 0.6} s: the stack sees the obstacles as they were;
* sensing range ∈ {8, 4, 2} m of clearance;
* wind of {2, 4, 6} m/s (heading 90°) with gusts of half that standard deviation (τ = 2 s), through
  the linear drag 0.3 1/s (``disturbance = "wind"``);
* the quadrotor plant (AscTec Hummingbird, geometric attitude loop, ``plant = "quadrotor"``).

The ideal world and every sensing and wind level of the three selections are one compiled program
per method (the noisy sensor and the wind at the level's gains, zero for the others: at zero they
pass the truth on and push with exactly 0); the quadrotor is a second.

Every episode draws its noise and gusts from the field's key, so all methods, selections and levels
see the same draws (common random numbers). Rates come with Wilson intervals (95 %), clearance with
a bootstrap interval of the mean. The verdict of each (method, selection, world) on success against
the same selection in the ideal world is :func:`jaxapf.stats.verdicts` over all of the study's
comparisons at once (exact McNemar and TOST within the 2-point margin, both Holm-adjusted), the
verdict function every study uses.

    python analysis/robustness.py     # ~40 min on 2 cores (36 evaluate calls, 132,192 episodes)
"""

from __future__ import annotations

import dataclasses
import functools
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
          + [("position noise", f"σ_p = {s:g} m", WORLD, {"sigma_obs_p": s}) for s in (0.1, 0.25, 0.5)]
          + [("velocity noise", f"σ_v = {s:g} m/s", WORLD, {"sigma_obs_v": s}) for s in (0.1, 0.25, 0.5)]
          + [("latency", f"{d:g} s", WORLD, {"latency": d}) for d in (0.1, 0.3, 0.6)]
          + [("range", f"{r:g} m", WORLD, {"sense_range": r}) for r in (8.0, 4.0, 2.0)]
          + [("wind", f"{w:g} m/s", WORLD, {"wind_speed": w, "wind_heading": 90.0, "gust_sigma": w / 2})
             for w in (2.0, 4.0, 6.0)]
          + [("quadrotor", "quadrotor", {"plant": "quadrotor"}, {})])
#: The imperfections in table order, and the strongest level of each (the last one listed).
AXES = tuple(dict.fromkeys(axis for axis, _, _, _ in WORLDS if axis != "ideal"))
STRONGEST = tuple((axis, [lv for a, lv, _, _ in WORLDS if a == axis][-1]) for axis in AXES)
#: A verdict's mark in the tables (· inconclusive).
MARK = {"worse": "↓", "better": "↑", "equivalent": "=", "inconclusive": "·"}


@functools.cache
def selections(source: pathlib.Path = SELECTION) -> pd.DataFrame:
    """Study 11's selected gains (or those of another compare study's ``selection.csv``), one row per
    (method, seed); refuses gain columns that are no longer declared (they would be dropped silently
    and the method fly its defaults)."""
    from jaxapf.compare.select import Selection
    from jaxapf.gains import GAINS

    table = pd.read_csv(source)
    fixed = {f.name for f in dataclasses.fields(Selection)} - {"gains"}
    stale = sorted(set(table.columns) - fixed - set(GAINS.names()))
    if stale:
        raise SystemExit(f"{source}: columns {', '.join(stale)} are not declared gains; rerun "
                         "analysis/planner_benchmark.py to select with the current gains")
    return table


def seeds() -> list[int]:
    """The selection seeds of study 11 (three)."""
    return sorted(int(s) for s in selections()["seed"].unique())


def tuned_gains(method: str, seed: int, source: pathlib.Path = SELECTION) -> dict[str, float]:
    """The gains study 11's selection (or ``source``'s) with ``seed`` chose for ``method``."""
    from jaxapf.gains import GAINS

    table = selections(source)
    row = table[(table["method"] == method) & (table["seed"] == seed)].iloc[0]
    return {g: float(row[g]) for g in GAINS.names() if g in row and np.isfinite(row[g])}


def flow_gain(method: str, seed: int) -> float:
    """η·k_att of a selection: how hard its reference pulls toward the goal."""
    gains = tuned_gains(method, seed)
    return gains["eta"] * gains["k_att"]


def fields(spec, count: int, seed: int = SEED) -> list[tuple[object, np.ndarray]]:
    """The held-out fields (``count`` per test family of ``seed``, default this study's) and each field's
    family, in two groups: the families with few obstacle slots, padded to their largest count, and the
    rest (the exact solvers' cost grows steeply with the slots, so few-obstacle fields are not padded to
    many)."""
    from jaxapf.scenarios import make_scenarios
    from jaxapf.spec.scenario import spec_family_params
    from jaxapf.tune.train import pad_obstacles

    batches = {f: make_scenarios(seed, spec_family_params(f, spec.params.get(f, {})), count)
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


#: The columns of an episode the study reads (kept in ``episodes.parquet``).
READ = ("method", "seed", "axis", "level", "family", "field", "success", "collision", "stalled", "min_clearance",
        "max_tilt", "accel_error_rms", "unseen_steps", "final_distance")


def run(spec, count: int) -> pd.DataFrame:
    """One row per (method, selection seed, world, field) with the outcome metrics; the selections
    and worlds of one static setting are one vmap over gain settings."""
    from jaxapf import Gains
    from jaxapf.config import MPCConfig, SimConfig
    from jaxapf.engine import evaluate

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
        tuned = {s: tuned_gains(method, s) for s in seeds()}
        for static, worlds in variants.items():
            settings = [(s, w) for s in tuned for w in worlds]
            batch = jax.tree_util.tree_map(lambda *x: np.asarray(x, np.float32),
                                           *[Gains(**tuned[s], **w[3]) for s, w in settings])
            for scenarios, family in groups:
                metrics = jax.device_get(evaluate(scenarios, batch, base.replace(**dict(static)), mpc, metrics=(
                    "success", "collision", "stalled", "min_clearance", "time_to_goal", "final_distance", "max_tilt",
                    "accel_error_rms", "unseen_steps")))
                for i, (seed, (axis, level, _, _)) in enumerate(settings):
                    frame = pd.DataFrame({k: np.asarray(v[i]) for k, v in metrics.items()})
                    rows.append(frame.assign(method=method, seed=seed, axis=axis, level=level, family=family,
                                             field=[f"{f}/{j % count}" for j, f in enumerate(family)]))
        print(f"  {method}: done", flush=True)
    return pd.concat(rows, ignore_index=True)


def spec_t_max(spec, family: str) -> float:
    from jaxapf.spec.scenario import spec_family_params

    return spec_family_params(family, spec.params.get(family, {})).t_max


def summarise(df: pd.DataFrame, resamples: int) -> pd.DataFrame:
    """Per (method, seed, axis, level): rates with Wilson intervals, mean clearance with a bootstrap
    interval, and the paired change in success against the same selection in the ideal world with
    the study's verdict (:func:`jaxapf.stats.verdicts` over every such comparison at once)."""
    from jaxapf.stats import bootstrap_ci

    ideal = df[df["axis"] == "ideal"].set_index(["method", "seed", "field"])
    out = []
    for (method, seed, axis, level), g in df.groupby(["method", "seed", "axis", "level"], sort=False):
        row = {"method": method, "seed": seed, "axis": axis, "level": level, "n": len(g)} | study.rates(g)
        clear = np.clip(g["min_clearance"].to_numpy(np.float64), -1.0, 10.0)  # +inf without obstacles: capped
        row["min_clearance"] = float(clear.mean())
        row["min_clearance_lo"], row["min_clearance_hi"] = map(float, bootstrap_ci(clear, n_resamples=resamples))
        row["max_tilt"] = float(g["max_tilt"].mean())
        row["accel_error_rms"] = float(g["accel_error_rms"].mean())
        row["unseen_steps"] = float(g["unseen_steps"].mean())
        row["final_distance"] = float(g["final_distance"].median())
        base = ideal.loc[(method, seed)].loc[g["field"]]["success"].to_numpy(bool)
        if axis != "ideal":  # the ideal world is its own baseline: no test
            row |= study.paired_success(g["success"].to_numpy(bool), base)
        out.append(row)
    summary = study.mark_verdicts(out, MARGIN)
    summary["verdict"] = summary["verdict"].fillna("—")
    return summary


def over_seeds(summary: pd.DataFrame, metric: str) -> pd.DataFrame:
    """Per (method, axis, level): ``metric``'s mean, min and max over the selection seeds and the
    seeds' verdict marks in seed order."""
    key = ["method", "axis", "level"]
    g = summary.sort_values("seed").groupby(key, sort=False)
    out = g[metric].agg(["mean", "min", "max"])
    out["marks"] = g["verdict"].agg(lambda v: "".join(MARK.get(x, "") for x in v))
    return out


def figure(summary: pd.DataFrame, path: pathlib.Path) -> None:
    """Success, collision and mean minimum clearance against each imperfection's level, one column per
    axis: the mean over the three selections, the bar spanning the selections' min to max; methods side
    by side at each level."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    palette = plt.get_cmap("tab10").colors
    methods = list(summary["method"].unique())
    colors = {m: palette[i % len(palette)] for i, m in enumerate(methods)}
    rows = (("success", "success [%]", 100.0), ("collision", "collision [%]", 100.0),
            ("min_clearance", "mean min. clearance [m]", 1.0))
    fig, axes = plt.subplots(len(rows), len(AXES), figsize=(3.6 * len(AXES), 10), sharey="row")
    for row, (name, label, scale) in enumerate(rows):
        seeds_ = over_seeds(summary, name).to_dict("index")
        for col, axis in enumerate(AXES):
            ax = axes[row, col]
            worlds = [("ideal", "ideal")] + [(a, lv) for a, lv, _, _ in WORLDS if a == axis]
            for i, method in enumerate(methods):
                part = [seeds_[(method, *w)] for w in worlds]
                x = np.arange(len(part)) + 0.06 * (i - (len(methods) - 1) / 2)
                value = scale * np.array([r["mean"] for r in part])
                band = np.abs(scale * np.array([[r["min"] for r in part], [r["max"] for r in part]]) - value)
                ax.errorbar(x, value, yerr=band, label=method, capsize=1.5, marker="o", ms=3, lw=1,
                            linestyle="--" if "+" in method else "-", color=colors[method])
            ax.set_xticks(np.arange(len(worlds)), [lv for _, lv in worlds], rotation=20, fontsize=8)
            ax.set_ylabel(label if col == 0 else "")
            if row == 0:
                ax.set_title(axis)
    axes[0, -1].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def table(summary: pd.DataFrame, metric: str = "success") -> str:
    """Markdown: ``metric`` in % per method (rows) and world (columns) as the mean over the selection
    seeds with their [min, max]; for success the seeds' verdict marks against their ideal world."""
    seeds_ = over_seeds(summary, metric)
    worlds = [(a, lv) for a, lv, _, _ in WORLDS]
    names = [a if a in ("ideal", "quadrotor") else f"{a}: {lv}" for a, lv in worlds]
    lines = ["| method | " + " | ".join(names) + " |", "|---|" + "---|" * len(worlds)]
    for method in dict.fromkeys(summary["method"]):
        cells = []
        for axis, level in worlds:
            r = seeds_.loc[(method, axis, level)]
            mark = f" {r['marks']}" if metric == "success" and axis != "ideal" else ""
            cells.append(f"{100 * r['mean']:.1f} [{100 * r['min']:.1f}, {100 * r['max']:.1f}]{mark}")
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def counts(summary: pd.DataFrame, axis: str, level: str) -> dict[str, int]:
    """How many (method, selection) comparisons at one world got each verdict."""
    at = summary[(summary["axis"] == axis) & (summary["level"] == level)]
    return {v: int((at["verdict"] == v).sum()) for v in ("worse", "equivalent", "better", "inconclusive")}


def findings(summary: pd.DataFrame) -> list[str]:
    """One sentence per imperfection at its strongest level, built from the summary: the change in
    success of every method (mean over its three selections) against its ideal world, the verdicts
    of all (method, selection) pairs, the most and least affected."""
    out = []
    mean = summary.groupby(["method", "axis", "level"], sort=False)[["success", "collision", "final_distance"]].mean()
    ideal = mean.xs(("ideal", "ideal"), level=("axis", "level"))
    for axis, level in STRONGEST:
        at = mean.xs((axis, level), level=("axis", "level"))
        change = 100 * (at["success"] - ideal["success"])
        collide = 100 * (at["collision"] - ideal["collision"])
        n = counts(summary, axis, level)
        total = sum(n.values())
        line = (f"**{axis} ({level})**: success changes by {change.min():+.1f} to {change.max():+.1f} points "
                f"(mean over the three selections; most: `{change.idxmin()}`, least: `{change.idxmax()}`), "
                f"collisions by {collide.min():+.1f} to {collide.max():+.1f} points; of the {total} (method, "
                f"selection) pairs *worse* than the ideal world {n['worse']}, *equivalent* {n['equivalent']}, "
                f"*better* {n['better']}, inconclusive {n['inconclusive']}.")
        if axis == "wind":
            line += (f" Median final distance to the goal {ideal['final_distance'].min():.2f}–"
                     f"{ideal['final_distance'].max():.2f} m in calm air, {at['final_distance'].min():.2f}–"
                     f"{at['final_distance'].max():.2f} m in this wind (goal tolerance 0.5 m; per selection in "
                     "the table below). Hypothesis, not tested here: an MPC that plans without a disturbance "
                     "estimate keeps a steady offset under a steady push, the larger the weaker its pull toward "
                     "the goal; study 13's observer arm (analysis/offset_free.py) tests it.")
        out.append(line)
    return out


def wind_table(summary: pd.DataFrame) -> str:
    """Markdown: per method and selection seed at the strongest wind, success, the median final
    distance and the selection's flow gain η·k_att (the seed-to-seed spread of the wind finding)."""
    axis, level = STRONGEST[AXES.index("wind")]
    at = summary[(summary["axis"] == axis) & (summary["level"] == level)].set_index(["method", "seed"])
    lines = ["| method | " + " | ".join(f"seed {s}: success, final distance, η·k_att" for s in seeds()) + " |",
             "|---|" + "---|" * len(seeds())]
    for method in dict.fromkeys(summary["method"]):
        cells = [f"{100 * at.loc[(method, s), 'success']:.1f} %, {at.loc[(method, s), 'final_distance']:.2f} m, "
                 f"{flow_gain(method, s):.2f}" for s in seeds()]
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def family_table(df: pd.DataFrame) -> str:
    """Markdown: per method and family, the change in success [points] against the same selection in
    the ideal world at each imperfection's strongest level, mean over the three selections (the pooled
    numbers hide opposite signs)."""
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
    from jaxapf.stats import VERDICT_RULE

    n = int(summary["n"].iloc[0])
    s = seeds()
    tests = int((summary["axis"] != "ideal").sum())
    text = [f"# Study 12: robustness ({n} held-out fields per method, selection and world)", "",
            "`python analysis/robustness.py` (" + __doc__.split("\n")[0] + ")", "",
            f"Protocol: every method at the gains each of its {len(s)} random searches (selection seeds "
            f"{', '.join(map(str, s))}) chose in study 11 (equal budgets), {count} fields of each of study 11's six "
            f"test families (seed {SEED}), one imperfection at a time, common random numbers. Verdicts: paired "
            "success of each (method, selection) against the same selection in the ideal world, exact McNemar "
            f"test and TOST within a {100 * MARGIN:g}-point margin, Holm over all {tests} "
            f"comparisons of the study ({VERDICT_RULE}).", "", "## Findings", ""]
    text += [f"- {line}" for line in findings(summary)]
    text += ["", "## Success [%]: mean over the selections [min, max]; the selections' verdicts in seed order "
             "(↓ worse, ↑ better, = equivalent, · inconclusive against the ideal world)", "", table(summary), "",
             "## Collision [%]: mean over the selections [min, max]", "", table(summary, "collision"), "",
             "## Strongest wind, per selection", "", wind_table(summary), "",
             f"## Change in success per family [points] at each imperfection's strongest level ({count} fields per "
             "family, mean over the selections; the pooled numbers above hide changes of opposite sign)", "",
             family_table(df), "",
             "![success, collision and clearance against each imperfection](robustness.png)", "",
             "`summary.csv` has, per method, selection seed and world, every rate with its Wilson interval, the "
             "mean minimum clearance with its bootstrap interval, the paired change in success with its interval, "
             "raw and Holm-adjusted p-values and the verdict, and the mean `unseen_steps`, `max_tilt` and "
             "`accel_error_rms`."]
    (out / "README.md").write_text("\n".join(text) + "\n")


def family_change_max(readme: str) -> dict:
    """Per imperfection (``latency``, ...) and family, the largest absolute change in success [points] of
    any method there, read from the per-family tables of the committed ``README.md`` (the episode rows
    behind them are git-ignored)."""
    out = {}
    for block in readme.split("\n### ")[1:]:
        axis = block.split(" (")[0].replace(" ", "_")
        rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in block.splitlines()
                if line.startswith("| ")]
        families, values = rows[0][1:], rows[1:]  # the header, then a row per method (the rule line has no "| ")
        out[axis] = {f: max(abs(float(r[1 + i])) for r in values) for i, f in enumerate(families)}
    return out


def facts(summary: pd.DataFrame, families: int) -> dict:
    """The named values the findings state, per imperfection at its strongest level (``wind``, ``latency``, ...):
    its gains, the change in success and collisions against the ideal world per method (mean over the
    selections) with their range and the most and least affected method, the per-selection range of the change,
    the verdict counts (all and per method) and each method's success there (mean, lowest, highest); for the
    wind also every selection's success, median final distance and η·k_att, their rank correlations, and the
    final distances in calm air and in the wind (per selection and as per-method means)."""
    from jaxapf.config import SimConfig

    ideal = summary[summary["axis"] == "ideal"]
    calm = ideal.groupby("method", sort=False)[["success", "collision", "final_distance"]].mean()
    out = {"methods": len(calm), "seeds": len(seeds()), "fields": int(summary["n"].iloc[0]),
           "goal_tolerance": SimConfig().episode.r_goal,
           "fields_per_family": int(summary["n"].iloc[0]) // families,
           "comparisons": int((summary["axis"] != "ideal").sum()), "ideal": calm["success"].to_dict()}
    for axis, level in STRONGEST:
        at = summary[(summary["axis"] == axis) & (summary["level"] == level)]
        mean = at.groupby("method", sort=False)[["success", "collision", "final_distance"]].mean()
        change, collide = mean["success"] - calm["success"], mean["collision"] - calm["collision"]
        spread = over_seeds(at, "success")
        out[axis.replace(" ", "_")] = {
            "gains": next(w[3] for w in WORLDS if w[:2] == (axis, level)), "selections": len(at),
            "change": change.to_dict(), "change_min": change.min(), "change_max": change.max(),
            "most": change.idxmin(), "least": change.idxmax(),
            "selection_change": {"min": at["success_change"].min(), "max": at["success_change"].max()},
            "collision_change": {"min": collide.min(), "max": collide.max()},
            "verdicts": counts(summary, axis, level),
            "worse": {m: int((g["verdict"] == "worse").sum()) for m, g in at.groupby("method", sort=False)},
            "success": {m: {"mean": r["mean"], "min": r["min"], "max": r["max"]}
                        for (m, _, _), r in spread.iterrows()}}
    wind = out["wind"]
    at = summary[(summary["axis"] == "wind") & (summary["level"] == STRONGEST[AXES.index("wind")][1])]
    flow = pd.Series([flow_gain(m, s) for m, s in zip(at["method"], at["seed"])], index=at.index)
    wind["selection"] = {m: {str(r.seed): {"success": r.success, "change": r.success_change, "flow_gain": flow[i],
                                           "final_distance": r.final_distance} for i, r in g.iterrows()}
                         for m, g in at.groupby("method", sort=False)}
    wind["flow_gain"] = {m: {"min": g.min(), "max": g.max()} for m, g in flow.groupby(at["method"], sort=False)}
    wind["rank_correlation"] = {name: float(np.corrcoef(flow.rank(), at[column].rank())[0, 1])
                                for name, column in (("flow_change", "success_change"),
                                                     ("flow_final_distance", "final_distance"))}
    wind["final_distance"] = {world: {"selection_min": t["final_distance"].min(),
                                      "selection_max": t["final_distance"].max(),
                                      "method_mean_min": t.groupby("method")["final_distance"].mean().min(),
                                      "method_mean_max": t.groupby("method")["final_distance"].mean().max()}
                              for world, t in (("calm", ideal), ("wind", at))}
    return out


def main() -> None:
    args, out = study.begin(__doc__, STUDY)
    from jaxapf.compare.spec import load_compare_spec

    spec, _ = load_compare_spec(SPEC)
    if args.facts_only:  # the verdicts derived again from the committed table's counts
        summary = study.rederive(pd.read_csv(out / "summary.csv"), MARGIN, change="success_change")
        summary["verdict"] = summary["verdict"].fillna("—")
        summary.to_csv(out / "summary.csv", index=False)
        study.write_facts(out, facts(summary, len(spec.test.families))
                          | {"family_change_max": family_change_max((out / "README.md").read_text())})
        return
    count = args.fields or FIELDS
    data = study.ROOT / "runs" / f"robustness-s{len(seeds())}-f{count}.parquet"  # git-ignored; a rerun only redraws
    if args.from_episodes:
        df = study.kept_rows(out)
    elif data.exists():
        df = pd.read_parquet(data)
    else:
        df = run(spec, count)
        data.parent.mkdir(exist_ok=True)
        df.to_parquet(data, index=False)
    if not args.from_episodes:
        study.keep_rows(df, out, READ)
    summary = summarise(df, args.resamples)
    summary.to_csv(out / "summary.csv", index=False)
    figure(summary, out / "robustness.png")
    write_readme(summary, df, out, count)
    study.write_facts(out, facts(summary, len(spec.test.families))
                      | {"family_change_max": family_change_max((out / "README.md").read_text())})
    print("\n".join(findings(summary)))


if __name__ == "__main__":
    study.entry(main)
