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

Every episode draws its noise and gusts from the field's key, so all methods and levels see the
same draws (common random numbers). Rates come with Wilson intervals (95 %), clearance with a
bootstrap interval of the mean; the verdict per method and condition against the same method in the
ideal world is the exact McNemar test on the paired fields with the report's 2-point margin.

    python analysis/robustness.py     # ~20 min on 2 cores (36 compiled programs, 36,288 episodes)
"""

from __future__ import annotations

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
#: (axis, level, static settings, gains) of every world; levels of one static variant form one vmap.
WORLDS = ([("ideal", "ideal", {}, {})]
          + [("noise", f"σ = {s:g}", {"sensor": "noisy"}, {"sigma_obs_p": s, "sigma_obs_v": s})
             for s in (0.1, 0.25, 0.5)]
          + [("latency", f"{d:g} s", {"sensor": "noisy"}, {"latency": d}) for d in (0.1, 0.3, 0.6)]
          + [("range", f"{r:g} m", {"sensor": "noisy"}, {"sense_range": r}) for r in (8.0, 4.0, 2.0)]
          + [("wind", f"{w:g} m/s", {"disturbance": "wind"},
              {"wind_speed": w, "wind_heading": 90.0, "gust_sigma": w / 2}) for w in (2.0, 4.0, 6.0)]
          + [("quadrotor", "quadrotor", {"plant": "quadrotor"}, {})])


def tuned_gains(method: str) -> dict[str, float]:
    """The gains study 11's seed-1 selection chose for ``method``."""
    from jaxapf.gains import GAINS

    table = pd.read_csv(SELECTION)
    row = table[(table["method"] == method) & (table["seed"] == 1)].iloc[0]
    return {g: float(row[g]) for g in GAINS.names() if g in row and np.isfinite(row[g])}


def fields(spec, count: int) -> tuple[object, np.ndarray]:
    """The held-out fields of every test family, padded to one obstacle count, and each field's family."""
    from jaxapf.scenarios import make_scenarios
    from jaxapf.sweep.spec import spec_family_params
    from jaxapf.tune.train import pad_obstacles

    batches = [make_scenarios(SEED, spec_family_params(f, spec.params.get(f, {})), count)
               for f in spec.test.families]
    slots = max(b.obstacles.size for b in batches)
    batches = [pad_obstacles(b, slots) for b in batches]
    merged = jax.tree_util.tree_map(lambda *x: np.concatenate(x), *batches)
    return merged, np.repeat(np.asarray(spec.test.families), count)


def run(spec, count: int) -> pd.DataFrame:
    """One row per (method, world, field) with the outcome metrics."""
    from jaxapf import Gains
    from jaxapf.config import MPCConfig, SimConfig
    from jaxapf.rollout import evaluate

    scenarios, family = fields(spec, count)
    mpc = MPCConfig()
    t_max = max(spec_t_max(spec, f) for f in spec.test.families)
    rows = []
    for method in spec.methods:
        planner, _, safety = method.partition("+")
        base = SimConfig.from_flat(method=planner, filter=safety or "none", t_max=t_max)
        tuned = tuned_gains(method)
        variants: dict[tuple, list] = {}
        for world in WORLDS:
            variants.setdefault(tuple(sorted(world[2].items())), []).append(world)
        for static, worlds in variants.items():
            batch = jax.tree_util.tree_map(lambda *x: np.asarray(x, np.float32),
                                           *[Gains(**tuned, **w[3]) for w in worlds])
            metrics = evaluate(scenarios, batch, base.replace(**dict(static)), mpc,
                               metrics=("success", "collision", "stalled", "min_clearance", "time_to_goal",
                                        "max_tilt", "accel_error_rms", "unseen_steps"))
            metrics = jax.device_get(metrics)
            for i, (axis, level, _, _) in enumerate(worlds):
                frame = pd.DataFrame({k: np.asarray(v[i]) for k, v in metrics.items()})
                rows.append(frame.assign(method=method, axis=axis, level=level, family=family,
                                         field=np.arange(len(family))))
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
    """Success and collision against each imperfection's level, one panel per axis, with Wilson intervals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes_names = ["noise", "latency", "range", "wind", "quadrotor"]
    palette = plt.get_cmap("tab10").colors
    colors = {m: palette[i % len(palette)] for i, m in enumerate(summary["method"].unique())}
    fig, axes = plt.subplots(2, len(axes_names), figsize=(4.2 * len(axes_names), 7.5), sharey="row")
    for col, axis in enumerate(axes_names):
        for method, g in summary.groupby("method", sort=False):
            ideal = g[g["axis"] == "ideal"]
            part = pd.concat([ideal, g[g["axis"] == axis]])
            x = np.arange(len(part))
            for row, rate in enumerate(("success", "collision")):
                ax = axes[row, col]
                ax.errorbar(x, 100 * part[rate], yerr=100 * np.abs(part[[f"{rate}_lo", f"{rate}_hi"]].to_numpy().T
                                                                   - part[rate].to_numpy()),
                            label=method, capsize=2, marker="o", ms=3, linestyle="--" if "+" in method else "-",
                            color=colors[method])
                ax.set_xticks(x, part["level"], rotation=20)
        axes[0, col].set_title(axis)
    axes[0, 0].set_ylabel("success [%]")
    axes[1, 0].set_ylabel("collision [%]")
    axes[0, -1].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table(summary: pd.DataFrame) -> str:
    """Markdown: success [Wilson] per method (rows) and world (columns), the verdict's mark."""
    mark = {"worse": " ↓", "better": " ↑", "equivalent": " =", "inconclusive": "", "—": ""}
    worlds = [f"{a}: {lv}" if a not in ("ideal", "quadrotor") else a for a, lv, _, _ in WORLDS]
    head = "| method | " + " | ".join(worlds) + " |\n|---|" + "---|" * len(worlds)
    lines = [head]
    for method, g in summary.groupby("method", sort=False):
        cells = []
        for axis, level, _, _ in WORLDS:
            r = g[(g["axis"] == axis) & (g["level"] == level)].iloc[0]
            cells.append(f"{100 * r['success']:.1f}{mark[r['verdict']]}")
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


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
    (out / "table.md").write_text(table(summary) + "\n")
    print(table(summary))


if __name__ == "__main__":
    main()
