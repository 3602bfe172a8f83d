"""Tuning study: does gradient tuning through the closed loop beat a grid search, and where does it overfit?

Runs ``jaxapf tune`` on ``sweeps/tune-crossing-trap.toml`` (train on crossing + trap, test on every
randomized family), optionally at smaller sizes, measures what ``jax.checkpoint`` on the control
step does to the memory and time of a gradient, and writes ``README.md`` with the numbers and the
figures to ``analysis/results/tuning/``. Every number in the markdown is computed here from the run.

    python analysis/tuning_study.py                      # the spec's sizes
    python analysis/tuning_study.py --steps 120 --test-fields 128   # a ~10 min run on 2 CPU cores

The tune run itself (checkpoint, per-episode Parquet) goes to ``--run-dir`` (default
``runs/tuning-study``); rerunning resumes it.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import shutil
import sys
import time
import tomllib

import jax
import numpy as np
import pandas as pd
import study

from jaxapf import stats
from jaxapf.tune import run_tune_spec
from jaxapf.tune.spec import TuneSpec, parse_tune_spec, split_count
from jaxapf.tune.train import Tuner, batch_gradient, episode_loss

ROOT = pathlib.Path(__file__).resolve().parents[1]
OVERRIDES = {  # flag: (section, key)
    "steps": ("train", "steps"),
    "fields_per_step": ("train", "fields_per_step"),
    "validate_every": ("train", "validate_every"),
    "validation_fields": ("validation", "fields"),
    "test_fields": ("test", "fields"),
    "random_n": ("search", "random_n"),
}


def load_spec(path: pathlib.Path, args: argparse.Namespace) -> tuple[TuneSpec, str, dict]:
    """The spec file with the size flags applied; returns the spec, the text recorded with the run
    (file + the overrides as a comment) and the overrides."""
    text = path.read_text()
    data = tomllib.loads(text)
    changed = {}
    for flag, (section, key) in OVERRIDES.items():
        value = getattr(args, flag)
        if value is not None:
            data.setdefault(section, {})[key] = value
            changed[f"{section}.{key}"] = value
    note = "".join(f"\n# tuning_study override: {k} = {v}" for k, v in changed.items())
    return parse_tune_spec(data), text + note, changed


# --------------------------------------------------------------------------------------------
# jax.checkpoint: memory and time of one gradient
# --------------------------------------------------------------------------------------------


def remat_effect(spec: TuneSpec, fields: int, t_max: float, rounds: int = 5) -> list[dict]:
    """Compiled temporary memory (XLA's ``memory_analysis``) and the median wall time of one batch
    gradient (``fields`` training fields, episodes of ``t_max``) without and with remat; the two
    are timed in alternation so that load from other processes hits both alike."""
    small = dataclasses.replace(spec, sim=spec.sim.replace(t_max=t_max),
                                train=dataclasses.replace(spec.train, fields_per_step=fields))
    tuner = Tuner(small)
    batch = tuner.fields(small.train.seed, tuner.step_counts())
    theta = small.reparam.theta(small.init)
    compiled = {}
    for remat in (False, True):
        case = dataclasses.replace(small, train=dataclasses.replace(small.train, remat=remat))
        compiled[remat] = jax.jit(batch_gradient, static_argnames="spec").lower(theta, batch, spec=case).compile()
        jax.block_until_ready(compiled[remat](theta, batch))
    times = {False: [], True: []}
    for _ in range(rounds):
        for remat, fn in compiled.items():
            start = time.perf_counter()
            jax.block_until_ready(fn(theta, batch))
            times[remat].append(time.perf_counter() - start)
    return [{"remat": remat, "fields": fields, "t_max": t_max, "steps": small.sim.episode.steps,
             "horizon": small.mpc.horizon, "iters": small.mpc.iters,
             "temp_mb": fn.memory_analysis().temp_size_in_bytes / 2**20,
             "seconds": float(np.median(times[remat]))} for remat, fn in compiled.items()]


def gradient_diagnosis(spec: TuneSpec, gains_theta: dict, fields: int) -> pd.DataFrame:
    """Per-episode gradient norms of the surrogate at ``gains_theta`` on the first ``fields``
    training fields, grouped by the episode's true outcome (success / collision / stalled / other)."""
    tuner = Tuner(spec)
    batch = tuner.fields(spec.train.seed, split_count(fields, len(spec.train.families)))
    per_episode = jax.vmap(jax.grad(lambda th, s: episode_loss(th, s, spec)[0]), in_axes=(None, 0))
    grads = jax.jit(per_episode)(gains_theta, batch)
    norms = np.sqrt(sum(np.asarray(g, np.float64) ** 2 for g in grads.values()))
    r = tuner.report(batch, [spec.reparam.gains(gains_theta)])
    outcome = np.select([r["success"][0], r["collision"][0], r["stalled"][0]], ["success", "collision", "stalled"],
                        "other (timeout)")
    frame = pd.DataFrame({"outcome": outcome, "norm": norms})
    return frame.groupby("outcome").norm.agg(
        episodes="size", median="median", largest="max",
        clipped=lambda x: float(np.mean(~(x <= spec.train.episode_clip)))).reset_index()


# --------------------------------------------------------------------------------------------
# analysis of the run
# --------------------------------------------------------------------------------------------


#: Relevance margin of a success-rate difference (the registry's, 2 percentage points).
MARGIN = 0.02


def paired(episodes: pd.DataFrame, a: str, b: str, families: list[str]) -> pd.DataFrame:
    """Success of setting ``a`` vs ``b`` on the same fields, per family and pooled: the difference of rates
    (``wins``: ``a`` succeeds where ``b`` fails, ``losses`` the reverse) with its verdict
    (:func:`study.mark_verdicts`, Holm over these rows: the question's family), the interval that decided it
    and its level."""
    rows = []
    for family in families + ["all"]:
        sub = episodes if family == "all" else episodes[episodes.family == family]
        x = sub[sub.setting == a].sort_values(["family", "field"]).success.to_numpy()
        y = sub[sub.setting == b].sort_values(["family", "field"]).success.to_numpy()
        r = study.paired_success(x.astype(bool), y.astype(bool))
        rows.append({"family": family, "n": len(x), f"{a}": x.mean(), f"{b}": y.mean(),
                     "difference": r["success_change"], "wins": r["b"], "losses": r["c"]} | r)
    table = study.mark_verdicts(rows, MARGIN).rename(columns={"change_lo": "lo", "change_hi": "hi",
                                                               "p_equivalent": "p_equivalence",
                                                               "p_equivalent_holm": "p_equivalence_holm"})
    return table.drop(columns=["success_change", "b", "c"])


def rederive(table: pd.DataFrame) -> pd.DataFrame:
    """A committed paired table (:func:`paired`) with its verdicts derived again from its counts (``wins``,
    ``losses``, ``n``) by today's verdict function: what the statistics need is in the table."""
    counts = table.assign(b=table["wins"], c=table["losses"], n_pairs=table["n"])
    kept = [c for c in table.columns if c not in ("lo", "hi", "p", "p_equivalence", "p_holm", "p_equivalence_holm",
                                                   "verdict", "confidence")]
    found = study.mark_verdicts(counts[kept + ["b", "c", "n_pairs"]], MARGIN)
    return found.rename(columns={"change_lo": "lo", "change_hi": "hi", "p_equivalent": "p_equivalence",
                                 "p_equivalent_holm": "p_equivalence_holm"}).drop(columns=["b", "c", "n_pairs"])


def markdown_table(frame: pd.DataFrame, floats: str = "{:.3f}") -> str:
    cols = list(frame.columns)
    fmt = lambda v: floats.format(v) if isinstance(v, (float, np.floating)) else str(v)  # noqa: E731
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in frame.itertuples(index=False)]
    return "\n".join(lines)


def rate_table(table: pd.DataFrame) -> pd.DataFrame:
    """The test table in print form: rates with 95 % CIs and Holm-adjusted McNemar p vs default."""
    out = pd.DataFrame({"family": table.family, "setting": table.setting, "n": table.n})
    for o in ("success", "collision"):
        out[o] = [f"{r:.3f} [{lo:.3f}, {hi:.3f}]" for r, lo, hi in zip(table[o], table[f"{o}_lo"], table[f"{o}_hi"])]
        out[f"p vs default ({o})"] = ["" if s == "default" else f"{p:.3g}"
                                      for s, p in zip(table.setting, table[f"{o}_p_holm"])]
    out["stalled"] = table.stalled.map("{:.3f}".format)
    out["median time to goal [s]"] = table.time_to_goal.map("{:.1f}".format)
    out["surrogate J"] = table.loss.map("{:.2f}".format)
    return out


def gain_ci(episodes: pd.DataFrame, families: list[str]) -> tuple[float, float, float]:
    """Paired success difference tuned − default over ``families`` with a family-stratified bootstrap CI."""
    sub = episodes[episodes.family.isin(families)].sort_values(["family", "field"])
    tuned, default = sub[sub.setting == "tuned"], sub[sub.setting == "default"]
    return stats.paired_bootstrap_ci(tuned.success.to_numpy(), default.success.to_numpy(),
                                     strata=tuned.family.astype(str).to_numpy())


def transfer(spec: TuneSpec, episodes: pd.DataFrame) -> dict:
    """The tuned − default success gain with its interval (:func:`gain_ci`) on the training families and on
    the held-out ones."""
    held = [f for f in spec.test.families if f not in spec.train.families]
    return {name: dict(zip(("gain", "lo", "hi"), map(float, gain_ci(episodes, group))))
            for name, group in (("train", list(spec.train.families)), ("held", held))}


#: The columns of a test episode the study reads (kept in ``episodes.parquet``).
EPISODE_COLUMNS = ("setting", "family", "field", "success")


def verdicts(spec: TuneSpec, summary: dict, history: pd.DataFrame, episodes: pd.DataFrame, table: pd.DataFrame,
             vs_grid: pd.DataFrame, vs_default: pd.DataFrame) -> list[str]:
    """Plain-language findings, each computed from the run (no number is typed in by hand)."""
    train = list(spec.train.families)
    held = [f for f in spec.test.families if f not in train]
    pooled = vs_grid[vs_grid.family == "all"].iloc[0]
    sig = lambda t, sign: [r.family for r in t.itertuples()  # noqa: E731
                           if r.family != "all" and r.verdict == ("better" if sign > 0 else "worse")]
    lines = []
    verdict = {"better": "beats", "worse": "loses to", "equivalent": "is equivalent (within 2 pp) to",
               "inconclusive": "cannot be told apart from"}[pooled.verdict]
    lines.append(f"**Tuning {verdict} the grid search** on the pooled test set: success {pooled.tuned:.3f} vs "
                 f"{pooled.grid:.3f} (difference {pooled.difference:+.3f} [{pooled.lo:+.3f}, {pooled.hi:+.3f}], "
                 f"Newcombe 95 %; McNemar {pooled.wins} wins / {pooled.losses} losses, Holm p = {pooled.p_holm:.3g}; "
                 f"verdict *{pooled.verdict}*). Relevantly better per family: {', '.join(sig(vs_grid, 1)) or 'none'}; "
                 f"relevantly worse: {', '.join(sig(vs_grid, -1)) or 'none'}.")
    pooled_d = vs_default[vs_default.family == "all"].iloc[0]
    lines.append(f"Against the paper-style defaults, tuning changes pooled success by {pooled_d.difference:+.3f} "
                 f"[{pooled_d.lo:+.3f}, {pooled_d.hi:+.3f}] (Holm p = {pooled_d.p_holm:.3g}; verdict "
                 f"*{pooled_d.verdict}*); relevantly better on {', '.join(sig(vs_default, 1)) or 'no family'}, "
                 f"worse on {', '.join(sig(vs_default, -1)) or 'no family'}.")
    gain = {name: (g["gain"], g["lo"], g["hi"]) for name, g in transfer(spec, episodes).items()}
    (g_train, lo_train, hi_train), (g_held, lo_held, hi_held) = gain["train"], gain["held"]
    overfit = hi_held < g_train
    lines.append(f"Success gain over the defaults (paired, stratified bootstrap 95 % CI) on the training families "
                 f"({', '.join(train)}): {g_train:+.3f} [{lo_train:+.3f}, {hi_train:+.3f}]; on the held-out families "
                 f"({', '.join(held)}): {g_held:+.3f} [{lo_held:+.3f}, {hi_held:+.3f}]. "
                 + ("The held-out interval lies below the training gain: on average the gain does not transfer, "
                    "the tuned gains overfit the training families." if overfit else
                    "The held-out interval contains (or exceeds) the training gain: on average no evidence that the "
                    "gain is specific to the training families."))
    worse = [r for r in vs_default.itertuples() if r.family != "all" and r.verdict == "worse"]
    if worse:
        lines.append("Where it overfits: tuned is relevantly worse than the defaults on "
                     + ", ".join(f"{r.family} ({'held out' if r.family in held else 'trained on'}; "
                                 f"{r.difference:+.3f}, {r.losses} losses / {r.wins} wins, Holm p = {r.p_holm:.3g})"
                                 for r in worse)
                     + ". The gains moved from the defaults (" + ", ".join(
                         f"{n} {summary['gains']['default'][n]:.3g} → {summary['gains']['tuned'][n]:.3g}"
                         for n in spec.reparam.names) + ") toward what the training families reward.")
    else:
        lines.append("No test family is relevantly worse with the tuned gains than with the defaults.")
    val = history[np.isfinite(history.val_loss)]
    best = val.loc[val.val_loss.idxmin()]
    tuned_train = episodes[(episodes.setting == "tuned") & episodes.family.isin(train)].success
    _, _, _, lo, hi = stats.rate_row(tuned_train.to_numpy())
    v_lo, v_hi = stats.wilson_interval(round(best.val_success * spec.validation.fields), spec.validation.fields)
    overlap = v_lo <= hi and lo <= v_hi
    lines.append(f"Validation success of the selected gains (best of {len(val)} validations, step {int(best.step)}): "
                 f"{best.val_success:.3f} [{float(v_lo):.3f}, {float(v_hi):.3f}] on {spec.validation.fields} fields; "
                 f"test success of the same gains on fresh fields of the training families: {tuned_train.mean():.3f} "
                 f"[{float(lo):.3f}, {float(hi):.3f}]. "
                 + ("The intervals overlap: no evidence of overfitting to the validation fields beyond the optimism "
                    "of keeping the best validation." if overlap else
                    "The intervals are disjoint: " + ("the selection overfit the validation fields."
                                                      if best.val_success > hi else "the test fields are easier.")))
    all_rows = table[table.family == "all"].set_index("setting")
    order = all_rows.loss.sort_values().index
    faster = all_rows.time_to_goal["tuned"] < all_rows.time_to_goal["default"]
    lines.append(("On its own objective tuning wins" if order[0] == "tuned" else
                  "Even on its own objective tuning does not win") + ": pooled surrogate J " + " < ".join(
        f"{s} {all_rows.loss[s]:.2f}" for s in order) + ". Median time to goal: " + ", ".join(
        f"{s} {all_rows.time_to_goal[s]:.1f} s" for s in all_rows.index) + "; stalled: "
        + ", ".join(f"{s} {all_rows.stalled[s]:.3f}" for s in all_rows.index) + "; collision: "
        + ", ".join(f"{s} {all_rows.collision[s]:.3f}" for s in all_rows.index) + "."
        + (" The loss is dominated by the progress term, so the gradient mostly buys speed; whether a run "
           "succeeds hinges on escaping a trap or dodging a fast obstacle, discrete events whose gradients "
           "explode (see the gradient point below) and that clipping therefore mutes." if faster else ""))
    t = summary["training"]
    lines.append(f"Training ran {t['steps_run']} steps ({'stopped early' if t['stopped_early'] else 'to the end'}); "
                 f"the best validation loss {t['best_val_loss']:.4g} came at step {t['best_step']} "
                 f"(start {float(val.val_loss.iloc[0]):.4g}).")
    return lines


def write_markdown(out: pathlib.Path, spec_path: str, spec: TuneSpec, summary: dict, history: pd.DataFrame,
                   episodes: pd.DataFrame, table: pd.DataFrame, vs_grid: pd.DataFrame, vs_default: pd.DataFrame,
                   remat: list[dict], diagnosis: pd.DataFrame, command: str, changed: dict, seconds: float) -> None:
    b = summary["budgets"]
    gains = pd.DataFrame(summary["gains"]).T.reset_index(names="setting")
    t = summary["training"]
    train_rows = history[history.step > 0]
    text = [
        f"# Tuning study: {spec.name}",
        "",
        f"Command: `{command}` ({seconds / 60:.1f} min on {summary['versions']['cpu_count']} CPU cores, "
        f"{summary['versions']['device']}; jax {summary['versions']['jax']}).",
        f"Spec: `{spec_path}`{' with ' + ', '.join(f'{k} = {v}' for k, v in changed.items()) if changed else ''}. "
        f"Train on {', '.join(spec.train.families)} ({spec.train.fields_per_step} fields per step, seed "
        f"{spec.train.seed}); validation {spec.validation.fields} fields (seed {spec.validation.seed}); test "
        f"{spec.test.fields} fields per family (seed {spec.test.seed}) on {', '.join(spec.test.families)}. "
        f"Episodes of {spec.sim.episode.t_max:g} s, MPC horizon {spec.mpc.horizon}, {spec.mpc.iters} FISTA iterations, "
        f"method {spec.sim.planner.method}.",
        "",
        "## Findings",
        "",
        *[f"- {line}" for line in verdicts(spec, summary, history, episodes, table, vs_grid, vs_default)],
        f"- Gradients: the per-episode gradient norm had median {train_rows.grad_norm_median.median():.3g} over the "
        f"steps, its largest value per step had median {train_rows.grad_norm_max.median():.3g} (max "
        f"{train_rows.grad_norm_max.max():.3g}); {100 * train_rows.clipped.mean():.0f} % of training episodes "
        f"were clipped by train.episode_clip = {spec.train.episode_clip:g}. By outcome (the start gains on the "
        "first training fields):",
        "",
        markdown_table(diagnosis, "{:.3g}"),
        "",
        "## Budgets (episode rollouts) and wall-clock",
        "",
        markdown_table(pd.DataFrame([
            {"search": "gradient tuning", "settings tried": f"{t['steps_run']} steps",
             "episodes": b["tuning"]["episodes"], "seconds": b["tuning"]["seconds"]},
            {"search": "grid", "settings tried": b["grid"]["settings"], "episodes": b["grid"]["episodes"],
             "seconds": b["grid"]["seconds"]},
            {"search": "random", "settings tried": b["random"]["settings"], "episodes": b["random"]["episodes"],
             "seconds": b["random"]["seconds"]},
        ]), "{:.1f}"),
        "",
        "Tuning episodes = steps × fields per step + validations × validation fields; grid and random search "
        "fly ⌊budget / settings⌋ training fields per setting and keep the best success rate (ties: lowest "
        "surrogate loss). A gradient episode costs several forward episodes, so the seconds differ.",
        "",
        "## Gains",
        "",
        markdown_table(gains, "{:.4g}"),
        "",
        "## Held-out test (success / collision rates with Wilson 95 % CIs; exact McNemar vs default, Holm)",
        "",
        markdown_table(rate_table(table)),
        "",
        "### Tuned vs grid and tuned vs default (paired success; wins = tuned succeeds where the other fails)",
        "",
        markdown_table(vs_grid),
        "",
        markdown_table(vs_default),
        "",
        "![test rates](test.png)",
        "",
        "## Training curves",
        "",
        "![training](training.png)",
        "",
        "## jax.checkpoint on the control step (one batch gradient)",
        "",
        markdown_table(pd.DataFrame(remat), "{:.3g}"),
        "",
        "`temp_mb` is XLA's compiled temporary buffer size (`memory_analysis().temp_size_in_bytes`): without "
        "remat it holds every step's residuals (reference flow and FISTA iterations); with remat only the "
        "scan carry per step, and the step is recomputed on the way back.",
        "",
    ]
    (out / "README.md").write_text("\n".join(text))


def facts(out: pathlib.Path, run: dict) -> dict:
    """The named values the findings state, from the results folder's tables (``summary.json``, ``history.csv``,
    ``test_results.csv``, the two paired tables, ``remat.json``); ``run`` holds those only a run computes (the
    bootstrap intervals of the transfer gains, the gradient norms by outcome) and is kept as it is."""
    summary = json.loads((out / "summary.json").read_text())
    history = pd.read_csv(out / "history.csv")
    table = pd.read_csv(out / "test_results.csv")
    pairs = {name: rederive(pd.read_csv(out / f"tuned_vs_{name}.csv")) for name in ("grid", "default")}
    spec = summary["spec"]
    train = spec["train"]["families"]
    held = [f for f in spec["test"]["families"] if f not in train]
    val = history[np.isfinite(history.val_loss)]
    best = val.loc[val.val_loss.idxmin()]
    fields = spec["validation"]["fields"]
    v_lo, v_hi = stats.wilson_interval(round(best.val_success * fields), fields)
    tuned_train = table[(table.setting == "tuned") & table.family.isin(train)]
    t_lo, t_hi = stats.wilson_interval(round((tuned_train.success * tuned_train.n).sum()), tuned_train.n.sum())
    vs_default = pairs["default"].set_index("family")
    steps = history[history.step > 0]
    remat = {}
    for r in json.loads((out / "remat.json").read_text()):
        remat.setdefault(f"t{r['t_max']:g}", {"t_max": r["t_max"], "steps": r["steps"], "fields": r["fields"]})[
            "with" if r["remat"] else "without"] = {"temp_mb": r["temp_mb"], "seconds": r["seconds"]}
    columns = {"success": "success", "collision": "collision", "stalled": "stalled", "time_to_goal": "time_to_goal",
               "surrogate_loss": "loss"}
    return {
        "method": spec["sim"]["planner"]["method"], "learning_rate": spec["train"]["learning_rate"],
        "fields": {"test": spec["test"]["fields"], "validation": fields, "per_step": spec["train"]["fields_per_step"]},
        "families": {"train": len(train), "test": len(spec["test"]["families"]), "held_out": len(held)},
        "episodes_pooled": int(table[table.family == "all"].n.iloc[0]), "margin": MARGIN,
        **{name: {f: dict(zip(rows.setting, rows[column].astype(float))) for f, rows in table.groupby("family")}
           for name, column in columns.items()},
        **{f"vs_{name}": {r.family: {"difference": r.difference, "lo": r.lo, "hi": r.hi, "wins": r.wins,
                                     "losses": r.losses, "verdict": r.verdict} for r in frame.itertuples()}
           for name, frame in pairs.items()},
        "answer": study.answer_fact({"pooled": pairs["grid"].set_index("family").at["all", "verdict"]}),
        "verdicts": {f"vs_{name}": {v: int((frame[frame.family != "all"].verdict == v).sum())
                                    for v in ("better", "worse", "equivalent", "inconclusive")}
                     for name, frame in pairs.items()},
        "transfer": {name: float(np.average(vs_default.loc[group, "difference"], weights=vs_default.loc[group, "n"]))
                     for name, group in (("train", train), ("held", held))},
        "validation": {"validations": len(val), "best_step": int(best.step), "success": float(best.val_success),
                       "lo": float(v_lo), "hi": float(v_hi)},
        "test_on_train_families": {"success": float(np.average(tuned_train.success, weights=tuned_train.n)),
                                   "lo": float(t_lo), "hi": float(t_hi)},
        "training": {k: summary["training"][k] for k in ("steps_run", "best_step", "best_val_loss", "validations")}
        | {"steps_max": spec["train"]["steps"], "start_val_loss": float(val.val_loss.iloc[0])},
        "gains": {s: {n: summary["gains"][s][n] for n in spec["reparam"]["names"]} for s in summary["gains"]},
        "budgets": {s: {k: v for k, v in b.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
                    for s, b in summary["budgets"].items()},
        "gradients": {"norm_median": float(steps.grad_norm_median.median()),
                      "max_median": float(steps.grad_norm_max.median()), "clipped": float(steps.clipped.mean()),
                      "episode_clip": spec["train"]["episode_clip"]},
        "remat": remat,
        "run": run,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", type=pathlib.Path, default=ROOT / "sweeps" / "tune-crossing-trap.toml")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "analysis" / "results" / "tuning")
    parser.add_argument("--run-dir", type=pathlib.Path, default=ROOT / "runs" / "tuning-study")
    for flag in OVERRIDES:
        parser.add_argument(f"--{flag.replace('_', '-')}", type=int, help=f"override {'.'.join(OVERRIDES[flag])}")
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--facts-only", action="store_true",
                        help="rewrite facts.json from the results in --out, simulating nothing (keeps the values "
                             "only a run computes, under 'run', from the facts.json there)")
    args = parser.parse_args(argv)
    if args.facts_only:
        committed = args.out / "facts.json"
        run = json.loads(committed.read_text()).get("run", {}) if committed.exists() else {}
        kept = args.out / "episodes.parquet"
        if kept.exists():  # the paired tables and the transfer interval again from the committed episodes
            spec = load_spec(args.spec, args)[0]
            episodes = study.kept_rows(args.out)
            for name in ("grid", "default"):
                paired(episodes, "tuned", name, list(spec.test.families)).to_csv(
                    args.out / f"tuned_vs_{name}.csv", index=False)
            run["transfer"] = transfer(spec, episodes)
        else:
            for name in ("grid", "default"):  # the paired tables' verdicts derived again from their counts
                path = args.out / f"tuned_vs_{name}.csv"
                rederive(pd.read_csv(path)).to_csv(path, index=False)
        study.write_facts(args.out, facts(args.out, run))
        return 0
    start = time.perf_counter()
    spec, text, changed = load_spec(args.spec, args)
    args.out.mkdir(parents=True, exist_ok=True)

    remat = remat_effect(spec, fields=4, t_max=10.0) + remat_effect(spec, fields=4, t_max=20.0)
    diagnosis = gradient_diagnosis(spec, spec.reparam.theta(spec.init), fields=2 * spec.train.fields_per_step)
    summary = run_tune_spec(spec, text, args.run_dir, quiet=args.quiet)
    history = pd.read_csv(args.run_dir / "history.csv")
    episodes = pd.read_parquet(args.run_dir / "test_episodes.parquet")
    table = pd.read_csv(args.run_dir / "test_results.csv")
    families = list(spec.test.families)
    vs_grid = paired(episodes, "tuned", "grid", families)
    vs_default = paired(episodes, "tuned", "default", families)
    for name in ("training.png", "test.png", "gains.toml", "summary.json", "test_results.csv", "history.csv"):
        shutil.copy(args.run_dir / name, args.out / name)
    study.keep_rows(episodes, args.out, EPISODE_COLUMNS)
    vs_grid.to_csv(args.out / "tuned_vs_grid.csv", index=False)
    vs_default.to_csv(args.out / "tuned_vs_default.csv", index=False)
    (args.out / "remat.json").write_text(json.dumps(remat, indent=2) + "\n")
    command = " ".join(["python analysis/tuning_study.py", *(sys.argv[1:] if argv is None else argv)])
    spec_path = args.spec.resolve().relative_to(ROOT) if args.spec.resolve().is_relative_to(ROOT) else args.spec
    write_markdown(args.out, str(spec_path), spec, summary, history, episodes, table, vs_grid, vs_default, remat,
                   diagnosis, command, changed, time.perf_counter() - start)
    run = {"transfer": transfer(spec, episodes),
           "diagnosis": {r.outcome: {"episodes": int(r.episodes), "median": float(r.median),
                                     "largest": float(r.largest), "clipped": float(r.clipped)}
                         for r in diagnosis.itertuples()}}
    study.write_facts(args.out, facts(args.out, run))
    print(f"wrote {args.out / 'README.md'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    study.entry(main)
