"""Study 15: at which dimension of the gain space, if any, do gradients reach the best black-box tuner?

Every tuner of ``jaxapf tune`` -- the gradient tuner (pathwise, clipped), random search, CMA-ES and
TPE (the grid too where the space has 3 gains) -- tunes ``direction_velocity`` with the CBF filter
in four gain spaces: 3 gains (``k_rep``, ``k_att``, ``eta``), the paper's 6, the 6 plus the MPC's
5 weight scales (11), and those plus the CBF's 2 rates (13, every tunable gain this stack reads), on
two training mixes (crossing + trap; head-on + clutter), with three seeds each (training fields
and the searches' seeds; validation and test fields fixed). Each black-box tuner gets the episodes
the gradient tuner used (its budget in episodes), and, in a second arm (``TUNER @ time``), the
gradient tuner's wall-clock time: ``⌊B · t_gradient / t_tuner⌋`` episodes, from the seconds each
spent on its first run (compilation included, as a user meets it).
Small episodes keep the study to half an hour on 2 cores: 14 s flights, horizon 5, 8 FISTA
iterations, 30 gradient steps of 8 fields. The tuned gains fly 48 held-out fields of each of the
four families: the training mix's own (held-out fields) and the other mix's (held-out families).

Each black-box tuner's success on the held-out fields is compared with the gradient tuner's of the
same run, paired on the fields: exact McNemar and TOST within a 2-point margin,
:func:`jaxapf.stats.verdicts` over all of the study's comparisons (Holm), the verdict function every
study uses; the cost of each tuner is its episodes and seconds per percentage point of success it
adds to the defaults.

    python analysis/tuner_study.py      # ~35 min on 2 cores
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import study

STUDY = "tuner_study"
MARGIN = 0.02
SEEDS = (1, 2, 3)
SPACES = {3: ["k_rep", "k_att", "eta"],
          6: ["gamma", "k", "k_rep", "d_s", "k_att", "eta"],
          11: ["gamma", "k", "k_rep", "d_s", "k_att", "eta", "mpc_pos", "mpc_vel", "mpc_terminal", "mpc_input",
               "mpc_speed"],
          13: ["gamma", "k", "k_rep", "d_s", "k_att", "eta", "mpc_pos", "mpc_vel", "mpc_terminal", "mpc_input",
               "mpc_speed", "cbf_p1", "cbf_p2"]}
MIXES = {"crossing+trap": ["crossing", "trap"], "head_on+clutter": ["head_on", "clutter"]}
FAMILIES = ["crossing", "trap", "head_on", "clutter"]
TEST_FIELDS = 48


def spec_data(dim: int, mix: str, seed: int) -> dict:
    """The tune spec of one run (module docstring)."""
    tuners = (["grid"] if dim == 3 else []) + ["random", "cmaes", "tpe"]
    return {
        "name": f"tuners-d{dim}-{mix}-s{seed}",
        "train": {"families": MIXES[mix], "fields_per_step": 8, "steps": 30, "seed": seed, "learning_rate": 0.05,
                  "validate_every": 10, "patience": 3},
        "validation": {"fields": 16, "seed": 101},
        "test": {"families": FAMILIES, "fields": TEST_FIELDS, "seed": 202},
        "tune": {"params": SPACES[dim]},
        "sim": {"method": "direction_velocity", "filter": "cbf", "t_max": 14.0, "horizon": 5, "iters": 8},
        "scenario": {"params": {f: {"distance": [8.0, 10.0]} for f in FAMILIES}},
        "search": {"tuners": tuners, "random_n": 16, "random_seed": seed, "fields_per_setting": 8, "tpe_batch": 8,
                   "grid": {"k_rep": [2.5, 10.0, 40.0], "k_att": [0.5, 1.0, 2.0], "eta": [0.25, 0.5, 1.0]}},
    }


def run_all() -> pd.DataFrame:
    """Every run (kept under ``runs/tuner-study/``, reused when finished); one row per test episode."""
    from jaxapf.tune import run_tune_spec
    from jaxapf.tune.spec import parse_tune_spec

    frames, costs = [], []
    for dim in SPACES:
        for mix in MIXES:
            for seed in SEEDS:
                data = spec_data(dim, mix, seed)
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


def write(table: pd.DataFrame, cost: pd.DataFrame, out) -> dict:
    pooled = table[table["held_out"] == "all"]
    mean = pooled.groupby(["dim", "tuner"], sort=False)[["success", "episodes", "seconds", "points_over_default"]
                                                        ].mean().reset_index()
    tuners = list(dict.fromkeys(pooled["tuner"]))
    counts = {f"d{d}/{t}": {k: int(v) for k, v in g["verdict"].value_counts().items()}
              for (d, t), g in pooled[pooled["tuner"] != "gradient"].groupby(["dim", "tuner"], sort=False)}
    def best_of(dim: int, timed: bool) -> tuple[str, float]:
        rows = mean[(mean["dim"] == dim) & (mean["tuner"] != "gradient")
                    & (mean["tuner"].str.endswith(" @ time") == timed)]
        return max(((r.tuner, r.success) for r in rows.itertuples()), key=lambda x: x[1])

    best = {dim: best_of(dim, False) for dim in SPACES}
    best_time = {dim: best_of(dim, True) for dim in SPACES}
    facts = {"success_mean": {f"d{r.dim}/{r.tuner}": round(100 * r.success, 1) for r in mean.itertuples()},
             "best_black_box": {f"d{d}": t for d, (t, _) in best.items()},
             "best_black_box_at_equal_time": {f"d{d}": t for d, (t, _) in best_time.items()},
             "seconds_mean": {f"d{r.dim}/{r.tuner}": round(r.seconds, 1) for r in mean.itertuples()},
             "episodes": {f"d{r.dim}/{r.tuner}": int(round(r.episodes)) for r in mean.itertuples()},
             "pooled_verdicts_vs_gradient": counts,
             "gradient_still_improving": int(cost["still_improving"].sum()),
             "runs": int((cost["tuner"] == "gradient").sum()),
             "verdicts": {k: int(v) for k, v in table["verdict"].value_counts().items()},
             "comparisons": int(table["verdict"].notna().sum())}
    lines = ["# Study 15: the tuners of `jaxapf tune` by dimension of the gain space", "",
             "`python analysis/tuner_study.py`", "", "Protocol: " + " ".join(__doc__.split("\n\n")[1].split()), "",
             " ".join(__doc__.split("\n\n")[2].split()), "",
             "## Findings", "",
             *(f"- {dim} gains: the gradient tuner {facts['success_mean'][f'd{dim}/gradient']:.1f} % held-out "
               f"success (mean over mixes and seeds), the best black-box tuner `{best[dim][0]}` "
               f"{facts['success_mean'][f'd{dim}/{best[dim][0]}']:.1f} %; pooled verdicts of each tuner against "
               "the gradient tuner over its 6 runs: "
               + "; ".join(f"`{t}` " + ", ".join(f"{k} {v}" for k, v in counts[f"d{dim}/{t}"].items())
                           for t in tuners if f"d{dim}/{t}" in counts and not t.endswith(" @ time")) + "."
               for dim in SPACES),
             *(f"- {dim} gains at equal wall-clock time: the best black-box tuner `{best_time[dim][0]}` "
               f"{facts['success_mean'][f'd{dim}/{best_time[dim][0]}']:.1f} %; its verdicts against the gradient "
               "tuner: " + ", ".join(f"{k} {v}" for k, v in counts[f"d{dim}/{best_time[dim][0]}"].items()) + "."
               for dim in SPACES),
             f"- Every tuner ran at its defaults (the gradient tuner: adam, learning rate 0.05, cosine decay). In "
             f"{facts['gradient_still_improving']} of the {facts['runs']} runs the gradient tuner's best validation "
             "loss was at its last step: at this budget it had not converged, while the black-box tuners had "
             "spent theirs.",
             "",
             f"Verdicts over all {facts['comparisons']} comparisons (Holm; pooled and per held-out kind): "
             + ", ".join(f"{k} {v}" for k, v in facts["verdicts"].items()) + ".", "",
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
    return study.write_results(out, lines, facts)


def main() -> None:
    args, out = study.begin(__doc__, STUDY)
    episodes, cost = run_all()
    cost.to_csv(out / "costs.csv", index=False)
    table = summarise(episodes, cost)
    table.to_csv(out / "summary.csv", index=False)
    print(json.dumps(write(table, cost, out), indent=1))


if __name__ == "__main__":
    study.entry(main)
