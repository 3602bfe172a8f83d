"""Study 15: at which dimension of the gain space, if any, do gradients reach the best black-box tuner?

Every tuner of ``jaxapf tune`` -- the gradient tuner (pathwise, clipped), random search, CMA-ES and
TPE (the grid too where the space has 3 gains) -- tunes ``direction_velocity_escape`` (the paper's
weight with the stall escape) with the CBF filter in four gain spaces: 3 gains (``k_rep``,
``k_att``, ``eta``), the paper's 6, the 6 plus the MPC's 5 weight scales (11), and those plus the
CBF's 2 rates and the escape's 3 gains (16, every tunable gain this stack reads), on two training
mixes (crossing + trap; head-on + clutter), with three seeds each (training fields and the searches'
seeds; validation and test fields fixed). Each black-box tuner gets the episodes the gradient tuner
used (its budget in episodes), and, in a second arm (``TUNER @ time``), the gradient tuner's
wall-clock time: ``⌊B · t_gradient / t_tuner⌋`` episodes, from the seconds each spent on its first
run (compilation included, as a user meets it). Small episodes keep the study to about an hour on
2 cores: 14 s flights, horizon 5, 8 FISTA iterations, 30 gradient steps of 8 fields. The tuned
gains fly 48 held-out fields of each of the four families: the training mix's own (held-out
fields) and the other mix's (held-out families).

Each tuner with a step size runs at its tuned best: before the study, per gain space, the gradient
tuner's learning rate (adam, cosine decay; 0.05, 0.1, 0.2, 0.4) and CMA-ES's initial step
(0.5, 1, 2, 4, 8 in ``θ``) are chosen on a selection problem of their own -- all four families in
training, three selection seeds (11, 12, 13), the full budget -- by the held-out success (ties:
the surrogate loss) of what each returns on 64 fresh check fields (seed 404), the rule the
black-box searches pick a setting by. Random search and TPE search the same fixed ranges and have
no step size; the grid is fixed.

Each black-box tuner's success on the held-out fields is compared with the gradient tuner's of the
same run, paired on the fields: exact McNemar and TOST within a 2-point margin,
:func:`jaxapf.stats.verdicts` over all of the study's comparisons (Holm), the verdict function every
study uses; the cost of each tuner is its episodes and seconds per percentage point of success it
adds to the defaults.

    python analysis/tuner_study.py      # ~1.5 h on 2 cores
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import study

STUDY = "tuner_study"
METHOD = "direction_velocity_escape"
MARGIN = 0.02
SEEDS = (1, 2, 3)
PAPER = ["gamma", "k", "k_rep", "d_s", "k_att", "eta"]
MPC = ["mpc_pos", "mpc_vel", "mpc_terminal", "mpc_input", "mpc_speed"]
SPACES = {3: ["k_rep", "k_att", "eta"], 6: PAPER, 11: PAPER + MPC,
          16: PAPER + MPC + ["cbf_p1", "cbf_p2", "t_detect", "t_escape", "d_escape"]}
FAMILIES = ["crossing", "trap", "head_on", "clutter"]
MIXES = {"crossing+trap": ["crossing", "trap"], "head_on+clutter": ["head_on", "clutter"]}
TEST_FIELDS = 48
#: The step sizes tried per gain space, the selection problem's seeds, check fields and their seed.
LEARNING_RATES = (0.05, 0.1, 0.2, 0.4)
SIGMAS = (0.5, 1.0, 2.0, 4.0, 8.0)
SELECTION_SEEDS = (11, 12, 13)
CHECK_FIELDS, CHECK_SEED = 64, 404


def spec_data(dim: int, families: list[str], seed: int, learning_rate: float, sigma: float, name: str) -> dict:
    """The tune spec of one run (module docstring)."""
    tuners = (["grid"] if dim == 3 else []) + ["random", "cmaes", "tpe"]
    return {
        "name": name,
        "train": {"families": families, "fields_per_step": 8, "steps": 30, "seed": seed,
                  "learning_rate": learning_rate, "validate_every": 10, "patience": 3},
        "validation": {"fields": 16, "seed": 101},
        "test": {"families": FAMILIES, "fields": TEST_FIELDS, "seed": 202},
        "tune": {"params": SPACES[dim]},
        "sim": {"method": METHOD, "filter": "cbf", "t_max": 14.0, "horizon": 5, "iters": 8},
        "scenario": {"params": {f: {"distance": [8.0, 10.0]} for f in FAMILIES}},
        "search": {"tuners": tuners, "random_n": 16, "random_seed": seed, "fields_per_setting": 8, "tpe_batch": 8,
                   "cmaes_sigma": sigma,
                   "grid": {"k_rep": [2.5, 10.0, 40.0], "k_att": [0.5, 1.0, 2.0], "eta": [0.25, 0.5, 1.0]}},
    }


def select_step_sizes() -> pd.DataFrame:
    """The selection runs of the module docstring (kept under ``runs/tuner-study/selection/``): one
    row per (space, seed, tuner, step size) with the check fields' success and loss."""
    from jaxapf.tune.proof import tuning_budget
    from jaxapf.tune.searches import SEARCHES
    from jaxapf.tune.spec import parse_tune_spec, split_count
    from jaxapf.tune.train import Tuner

    root = study.ROOT / "runs" / "tuner-study" / "selection"
    root.mkdir(parents=True, exist_ok=True)
    cache = root / "rows.json"
    done = json.loads(cache.read_text()) if cache.exists() else {}

    def check(tuner, gains) -> dict:
        r = tuner.report(tuner.fields(CHECK_SEED, split_count(CHECK_FIELDS, len(FAMILIES)), FAMILIES), [gains])
        return {"success": float(np.mean(r["success"])), "loss": float(np.mean(r["loss"]))}

    for dim in SPACES:
        for seed in SELECTION_SEEDS:
            budget = None
            for lr in LEARNING_RATES:
                name = f"select-d{dim}-s{seed}-lr{lr}"
                if name not in done:
                    spec = parse_tune_spec(spec_data(dim, FAMILIES, seed, lr, 1.0, name))
                    tuner = Tuner(spec)
                    (root / name).mkdir(exist_ok=True)
                    state = tuner.train(root / name, quiet=True)
                    done[name] = {"dim": dim, "seed": seed, "tuner": "gradient", "step": lr,
                                  "episodes": tuning_budget(spec, state)["episodes"],
                                  **check(tuner, spec.reparam.gains(state.best_theta))}
                    cache.write_text(json.dumps(done, indent=1) + "\n")
                budget = done[name]["episodes"]
            for sigma in SIGMAS:
                name = f"select-d{dim}-s{seed}-sigma{sigma}"
                if name not in done:
                    spec = parse_tune_spec(spec_data(dim, FAMILIES, seed, 0.05, sigma, name))
                    tuner = Tuner(spec)
                    (root / name).mkdir(exist_ok=True)
                    r = SEARCHES["cmaes"](tuner, budget, root / name, spec.digest())
                    done[name] = {"dim": dim, "seed": seed, "tuner": "cmaes", "step": sigma,
                                  "episodes": r["episodes"], **check(tuner, r["gains"])}
                    cache.write_text(json.dumps(done, indent=1) + "\n")
        print(f"  selection, {dim} gains: done", flush=True)
    rows = pd.DataFrame(done.values())
    grid = {"gradient": LEARNING_RATES, "cmaes": SIGMAS}
    return rows[[step in grid[t] for t, step in zip(rows["tuner"], rows["step"])]].reset_index(drop=True)


def chosen(selection: pd.DataFrame) -> dict[int, dict[str, float]]:
    """Per gain space, each tuner's step size of highest mean check success over the selection seeds
    (ties: lowest mean loss)."""
    mean = selection.groupby(["dim", "tuner", "step"], as_index=False)[["success", "loss"]].mean()
    best = mean.sort_values(["success", "loss"], ascending=[False, True]).groupby(["dim", "tuner"]).head(1)
    return {dim: dict(zip(g["tuner"], g["step"])) for dim, g in best.groupby("dim")}


def run_all(steps: dict[int, dict[str, float]]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Every run at the chosen step sizes (kept under ``runs/tuner-study/``, reused when finished); one
    row per test episode, and one per (run, tuner) with its cost."""
    from jaxapf.tune import run_tune_spec
    from jaxapf.tune.spec import parse_tune_spec

    frames, costs = [], []
    for dim in SPACES:
        for mix in MIXES:
            for seed in SEEDS:
                lr, sigma = steps[dim]["gradient"], steps[dim]["cmaes"]
                data = spec_data(dim, MIXES[mix], seed, lr, sigma, f"tuners-d{dim}-{mix}-s{seed}-lr{lr}-sigma{sigma}")
                out = study.ROOT / "runs" / "tuner-study" / data["name"]
                out.mkdir(parents=True, exist_ok=True)
                spec = parse_tune_spec(data)
                summary = run_tune_spec(spec, json.dumps(data), out, quiet=True)
                ep = pd.read_parquet(out / "test_episodes.parquet")
                frames.append(ep.assign(dim=dim, mix=mix, seed=seed,
                                        held_out=np.where(ep["family"].isin(MIXES[mix]), "fields", "families")))
                budgets, training = summary["budgets"], summary["training"]
                costs += [{"dim": dim, "mix": mix, "seed": seed, "tuner": name,
                           "episodes": budgets["tuning" if name == "tuned" else name]["episodes"],
                           "seconds": budgets["tuning" if name == "tuned" else name]["seconds"],
                           "still_improving": name == "tuned" and training["best_step"] == training["steps_run"]}
                          for name in summary["settings"] if name != "default"]
                wall, spent = equal_time(spec, summary, out)
                frames.append(wall.assign(dim=dim, mix=mix, seed=seed,
                                          held_out=np.where(wall["family"].isin(MIXES[mix]), "fields", "families")))
                costs += [{"dim": dim, "mix": mix, "seed": seed, "tuner": name, **r, "still_improving": False}
                          for name, r in spent.items()]
                print(f"  {data['name']}: done", flush=True)
    episodes = pd.concat(frames, ignore_index=True)
    episodes["family"] = episodes["family"].astype(str)
    episodes["setting"] = episodes["setting"].astype(str).replace({"tuned": "gradient"})
    cost = pd.DataFrame(costs).replace({"tuner": {"tuned": "gradient"}})
    return episodes, cost


def equal_time(spec, summary: dict, out) -> tuple[pd.DataFrame, dict]:
    """Each black-box tuner again with the gradient tuner's wall-clock time instead of its episodes:
    ``⌊B · t_gradient / t_tuner⌋`` episodes, ``t`` the seconds each spent on its ``B``-episode run
    (compilation included, as a user meets it), then tested on the same held-out fields. Kept in
    ``out/equal-time`` (reused when there). Returns the test rows (setting ``TUNER @ time``) and the
    episodes and seconds each spent."""
    from jaxapf.tune.proof import test_episodes
    from jaxapf.tune.searches import SEARCHES
    from jaxapf.tune.train import Tuner

    folder = out / "equal-time"
    folder.mkdir(exist_ok=True)
    done = folder / "results.json"
    budgets = summary["budgets"]
    tuner = Tuner(spec)
    if done.exists():
        stored = json.loads(done.read_text())
    else:
        stored = {}
        for name in spec.search.tuners:
            episodes = int(budgets["tuning"]["episodes"] * budgets["tuning"]["seconds"] / budgets[name]["seconds"])
            r = SEARCHES[name](tuner, episodes, folder, spec.digest() + "/equal-time")
            stored[name] = {"gains": r["gains"].floats(), "episodes": r["episodes"], "seconds": r["seconds"]}
        done.write_text(json.dumps(stored, indent=1) + "\n")
    gains = {f"{name} @ time": spec.reparam.base.replace(**r["gains"]) for name, r in stored.items()}
    path = folder / "test_episodes.parquet"
    if not path.exists():
        test_episodes(tuner, gains).to_parquet(path, index=False)
    return pd.read_parquet(path), {f"{name} @ time": {"episodes": r["episodes"], "seconds": r["seconds"]}
                                   for name, r in stored.items()}


def summarise(episodes: pd.DataFrame, cost: pd.DataFrame) -> pd.DataFrame:
    """Per (dimension, mix, seed, tuner, held-out kind, and pooled): success with Wilson intervals,
    the paired change against the gradient tuner of the same run, verdicts over the whole study, and
    the cost per point of success over the defaults."""
    both = pd.concat([episodes, episodes.assign(held_out="all")], ignore_index=True)
    rows = []
    for (dim, mix, seed, held), g in both.groupby(["dim", "mix", "seed", "held_out"], sort=False):
        base = g[g["setting"] == "gradient"].set_index(["family", "field"])["success"]
        default = g[g["setting"] == "default"]["success"].mean()
        for tuner, t in g.groupby("setting", sort=False):
            if tuner == "default":
                continue
            row = {"dim": dim, "mix": mix, "seed": seed, "held_out": held, "tuner": tuner, "n": len(t)}
            row |= study.rates(t)
            spent = cost[(cost["dim"] == dim) & (cost["mix"] == mix) & (cost["seed"] == seed)
                         & (cost["tuner"] == tuner)]
            gain = 100 * (row["success"] - default)
            row |= {"default_success": default, "episodes": int(spent["episodes"].iloc[0]),
                    "seconds": float(spent["seconds"].iloc[0]), "points_over_default": gain,
                    "seconds_per_point": float(spent["seconds"].iloc[0]) / gain if gain > 0 else np.nan}
            if tuner != "gradient":
                then = base.loc[list(zip(t["family"], t["field"]))].to_numpy(bool)
                row |= study.paired_success(t["success"].to_numpy(bool), then, MARGIN)
            rows.append(row)
    return study.mark_verdicts(rows, MARGIN)


MARK = {"better": "↑", "worse": "↓", "equivalent": "=", "inconclusive": "·"}


def means(table: pd.DataFrame) -> pd.DataFrame:
    """Per (dimension, tuner): success, episodes, seconds and points over the defaults, pooled over the
    held-out kinds and averaged over mixes and seeds."""
    pooled = table[table["held_out"] == "all"]
    return pooled.groupby(["dim", "tuner"], sort=False)[["success", "episodes", "seconds", "points_over_default"]
                                                        ].mean().reset_index()


def family_success(episodes: pd.DataFrame) -> pd.Series:
    """Held-out success [%] per (dimension, tuner, family) at equal episodes, mean over mixes and seeds."""
    equal = episodes[~episodes["setting"].str.endswith(" @ time")]
    return (100 * equal.groupby(["dim", "setting", "family"])["success"].mean()).round(1)


def committed_family_success(out) -> pd.Series:
    """:func:`family_success` as the committed ``README.md`` states it (its per-family table): the test
    episodes behind it are git-ignored, so ``--facts-only`` reads it there."""
    section = (out / "README.md").read_text().split("## Per family")[1].split("\n## ")[0]
    rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in section.splitlines()
            if line.startswith("| ") and line[2].isdigit()]
    return pd.Series({(int(r[0]), r[1], f): float(v) for r in rows for f, v in zip(FAMILIES, r[2:])})


def facts(table: pd.DataFrame, cost: pd.DataFrame, selection: pd.DataFrame, family: pd.Series) -> dict:
    """The named values the findings state, from the committed tables (``summary.csv``, ``costs.csv``,
    ``selection.csv``) and the per-family success: means per gain space and tuner, the best black-box tuner,
    every verdict against the gradient tuner (per run and held-out kind) and their counts, costs, the step
    sizes tried and chosen."""
    from jaxapf.tune.spec import TrainSpec

    mean = means(table)
    pooled = table[table["held_out"] == "all"]
    counts = {f"d{d}/{t}": {k: int(v) for k, v in g["verdict"].value_counts().items()}
              for (d, t), g in pooled[pooled["tuner"] != "gradient"].groupby(["dim", "tuner"], sort=False)}

    def best_of(dim: int, timed: bool) -> tuple[str, float]:
        rows = mean[(mean["dim"] == dim) & (mean["tuner"] != "gradient")
                    & (mean["tuner"].str.endswith(" @ time") == timed)]
        return max(((r.tuner, r.success) for r in rows.itertuples()), key=lambda x: x[1])

    best = {dim: best_of(dim, False) for dim in SPACES}
    best_time = {dim: best_of(dim, True) for dim in SPACES}
    gradient = mean[mean["tuner"] == "gradient"].set_index("dim")["success"]
    per_point = {f"d{r.dim}/{r.tuner}": r.seconds / r.points_over_default for r in mean.itertuples()
                 if r.points_over_default > 0}
    black_box = [v for k, v in per_point.items() if not k.endswith("/gradient") and not k.endswith(" @ time")]
    compared = table[table["verdict"].notna()]
    by_step = selection.groupby(["dim", "tuner", "step"], as_index=False)["success"].mean()
    split = table[table["held_out"] != "all"].groupby(["dim", "tuner", "held_out"], sort=False)["success"].mean()
    return {"success_mean": {f"d{r.dim}/{r.tuner}": round(100 * r.success, 1) for r in mean.itertuples()},
            "best_black_box": {f"d{d}": t for d, (t, _) in best.items()},
            "best_black_box_at_equal_time": {f"d{d}": t for d, (t, _) in best_time.items()},
            "best_black_box_lead": {f"d{d}": 100 * (s - gradient[d]) for d, (_, s) in best.items()},
            "best_black_box_lead_at_equal_time": {f"d{d}": 100 * (s - gradient[d]) for d, (_, s) in best_time.items()},
            "seconds_mean": {f"d{r.dim}/{r.tuner}": round(r.seconds, 1) for r in mean.itertuples()},
            "seconds_per_point": per_point,
            "seconds_per_point_range": {"gradient": {"min": min(per_point[f"d{d}/gradient"] for d in SPACES),
                                                     "max": max(per_point[f"d{d}/gradient"] for d in SPACES)},
                                        "black_box": {"min": min(black_box), "max": max(black_box)}},
            "episodes": {f"d{r.dim}/{r.tuner}": int(round(r.episodes)) for r in mean.itertuples()},
            "episodes_range": {t: {"min": int(g.min()), "max": int(g.max())}
                               for t, g in cost.groupby("tuner", sort=False)["episodes"]},
            "pooled_verdicts_vs_gradient": counts,
            "verdict": {f"d{d}": {t: {m: {f"s{s}": dict(zip(h["held_out"], h["verdict"]))
                                          for s, h in g.groupby("seed")} for m, g in gt.groupby("mix", sort=False)}
                                  for t, gt in gd.groupby("tuner", sort=False)}
                        for d, gd in compared.groupby("dim")},
            "verdicts_by_space": {f"d{d}": {k: int(v) for k, v in g["verdict"].value_counts().items()}
                                  for d, g in compared.groupby("dim")},
            "held_out_success": {f"d{d}/{t}": {h: 100 * split[(d, t, h)] for h in ("fields", "families")}
                                 for d, t in zip(mean["dim"], mean["tuner"])},
            "family_success": {f"d{d}": {t: {f: float(family[(d, t, f)]) for f in FAMILIES}
                                         for t in dict.fromkeys(family[d].index.get_level_values(0))}
                               for d in SPACES},
            "gradient_still_improving": int(cost["still_improving"].sum()),
            "chosen_steps": {f"d{d}": v for d, v in chosen(selection).items()},
            "steps_tried": {"gradient": list(LEARNING_RATES), "cmaes": list(SIGMAS)},
            "default_learning_rate": TrainSpec().learning_rate,
            "selection_success": {f"d{r.dim}/{r.tuner}/{r.step:g}": round(100 * r.success, 1)
                                  for r in by_step.itertuples()},
            "selection_success_range": {f"{t}/{step:g}": {"min": 100 * g.min(), "max": 100 * g.max()}
                                        for (t, step), g in by_step.groupby(["tuner", "step"])["success"]},
            "train": {k: spec_data(3, FAMILIES, 0, 0.05, 1.0, "")["train"][k] for k in ("steps", "fields_per_step")},
            "gains": {f"d{d}": d for d in SPACES}, "test_fields": TEST_FIELDS, "families": len(FAMILIES),
            "check_fields": CHECK_FIELDS, "runs_per_space": int((cost["tuner"] == "gradient").sum()) // len(SPACES),
            "runs": int((cost["tuner"] == "gradient").sum()),
            "verdicts": {k: int(v) for k, v in table["verdict"].value_counts().items()},
            "comparisons": int(table["verdict"].notna().sum())}


def write(table: pd.DataFrame, cost: pd.DataFrame, selection: pd.DataFrame, steps: dict[int, dict[str, float]],
          episodes: pd.DataFrame, out) -> dict:
    pooled = table[table["held_out"] == "all"]
    mean = means(table)
    tuners = list(dict.fromkeys(pooled["tuner"]))
    fam = family_success(episodes)
    found = facts(table, cost, selection, fam)
    counts = found["pooled_verdicts_vs_gradient"]
    best = {dim: found["best_black_box"][f"d{dim}"] for dim in SPACES}
    best_time = {dim: found["best_black_box_at_equal_time"][f"d{dim}"] for dim in SPACES}
    lines = ["# Study 15: the tuners of `jaxapf tune` by dimension of the gain space", "",
             "`python analysis/tuner_study.py`", "", "Protocol: " + " ".join(__doc__.split("\n\n")[1].split()), "",
             " ".join(__doc__.split("\n\n")[2].split()), "",
             "## Findings", "",
             *(f"- {dim} gains: the gradient tuner {found['success_mean'][f'd{dim}/gradient']:.1f} % held-out "
               f"success (mean over mixes and seeds), the best black-box tuner `{best[dim]}` "
               f"{found['success_mean'][f'd{dim}/{best[dim]}']:.1f} %; pooled verdicts of each tuner against "
               "the gradient tuner over its 6 runs: "
               + "; ".join(f"`{t}` " + ", ".join(f"{k} {v}" for k, v in counts[f"d{dim}/{t}"].items())
                           for t in tuners if f"d{dim}/{t}" in counts and not t.endswith(" @ time")) + "."
               for dim in SPACES),
             *(f"- {dim} gains at equal wall-clock time: the best black-box tuner `{best_time[dim]}` "
               f"{found['success_mean'][f'd{dim}/{best_time[dim]}']:.1f} %; its verdicts against the gradient "
               "tuner: " + ", ".join(f"{k} {v}" for k, v in counts[f"d{dim}/{best_time[dim]}"].items()) + "."
               for dim in SPACES),
             "- The step sizes chosen on the selection problem (learning rate of the gradient tuner / CMA-ES's "
             "initial step, per gain space): " + "; ".join(f"{d} gains {steps[d]['gradient']:g} / "
                                                            f"{steps[d]['cmaes']:g}" for d in SPACES) + ". At its "
             f"chosen learning rate the gradient tuner's best validation loss was at its last step in "
             f"{found['gradient_still_improving']} of the {found['runs']} runs (still improving when the budget "
             "ran out).",
             "",
             f"Verdicts over all {found['comparisons']} comparisons (Holm; pooled and per held-out kind): "
             + ", ".join(f"{k} {v}" for k, v in found["verdicts"].items()) + ".", "",
             "## Held-out success [%], all four families pooled, per seed (1 / 2 / 3), and the verdict against "
             "the gradient tuner of the same run (↑ better, ↓ worse, = equivalent, · inconclusive)", ""]
    for mix in MIXES:
        lines += [f"### Trained on {mix}", "", "| gains | " + " | ".join(tuners) + " |", "|---|" + "---|" * len(tuners)]
        for dim in SPACES:
            cells = []
            for tuner in tuners:
                r = pooled[(pooled["mix"] == mix) & (pooled["dim"] == dim)
                           & (pooled["tuner"] == tuner)].sort_values("seed")
                if not len(r):
                    cells.append("")
                    continue
                marks = "".join(MARK.get(v, "") for v in r.get("verdict", pd.Series(dtype=object))
                                if isinstance(v, str))
                cells.append(" / ".join(f"{100 * v:.1f}" for v in r["success"]) + (f" {marks}" if marks else ""))
            lines.append(f"| {dim} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["## Mean over mixes and seeds: held-out success [%], the points it adds to the defaults, episodes and "
              "seconds spent tuning, and seconds per point", "",
              "| gains | tuner | success | points over default | episodes | seconds | seconds per point |",
              "|---|---|---|---|---|---|---|"]
    for r in mean.itertuples():
        per = f"{r.seconds / r.points_over_default:.2f}" if r.points_over_default > 0 else "–"
        lines.append(f"| {r.dim} | {r.tuner} | {100 * r.success:.1f} | {r.points_over_default:.1f} | "
                     f"{r.episodes:.0f} | {r.seconds:.1f} | {per} |")
    lines += ["", "## Held-out fields vs held-out families (success [%], mean over mixes and seeds)", "",
              "| gains | tuner | held-out fields | held-out families |", "|---|---|---|---|"]
    split = table[table["held_out"] != "all"].groupby(["dim", "tuner", "held_out"], sort=False)["success"].mean()
    for (dim, tuner), _ in mean.set_index(["dim", "tuner"]).iterrows():
        lines.append(f"| {dim} | {tuner} | {100 * split[(dim, tuner, 'fields')]:.1f} | "
                     f"{100 * split[(dim, tuner, 'families')]:.1f} |")
    lines += ["", "## Per family: held-out success [%] of each tuner at equal episodes (mean over mixes and seeds; "
              "a family is held out of training for one mix)", "",
              "| gains | tuner | " + " | ".join(FAMILIES) + " |", "|---|---|" + "---|" * len(FAMILIES)]
    for dim in SPACES:
        for tuner in ["default", *(t for t in tuners if not t.endswith(" @ time"))]:
            if (dim, tuner, FAMILIES[0]) in fam.index:
                lines.append(f"| {dim} | {tuner} | " + " | ".join(f"{fam[(dim, tuner, f)]:.1f}" for f in FAMILIES)
                             + " |")
    lines += ["", "## Step-size selection: mean success [%] on the 64 check fields over the three selection seeds "
              "(chosen: bold)", "", "| gains | tuner | " + " | ".join(["step", "success"]) + " |", "|---|---|---|---|"]
    for r in selection.groupby(["dim", "tuner", "step"], as_index=False)["success"].mean().itertuples():
        mark = "**" if steps[r.dim][r.tuner] == r.step else ""
        lines.append(f"| {r.dim} | {r.tuner} | {mark}{r.step:g}{mark} | {100 * r.success:.1f} |")
    return study.write_results(out, lines, found)


def main() -> None:
    args, out = study.begin(__doc__, STUDY)
    if args.facts_only:
        study.write_facts(out, facts(pd.read_csv(out / "summary.csv"), pd.read_csv(out / "costs.csv"),
                                     pd.read_csv(out / "selection.csv"), committed_family_success(out)))
        return
    selection = select_step_sizes()
    selection.to_csv(out / "selection.csv", index=False)
    steps = chosen(selection)
    episodes, cost = run_all(steps)
    cost.to_csv(out / "costs.csv", index=False)
    table = summarise(episodes, cost)
    table.to_csv(out / "summary.csv", index=False)
    print(json.dumps(write(table, cost, selection, steps, episodes, out), indent=1))


if __name__ == "__main__":
    study.entry(main)
