"""Study 15: at which dimension of the gain space, if any, do gradients reach the best black-box tuner?

Every tuner of ``jaxapf tune`` -- the gradient tuner (pathwise, clipped), random search, CMA-ES and
TPE -- tunes ``direction_velocity_escape`` (the paper's weight with the stall escape) with the CBF
filter in four gain spaces: 3 gains (``k_rep``, ``k_att``, ``eta``), the paper's 6, the 6 plus the
MPC's 5 weight scales (11), and those plus the CBF's 2 rates and the escape's 3 gains (16, every
tunable gain this stack reads), on two training mixes (crossing + trap; head-on + clutter), with
three seeds each (training fields and the searches' seeds; validation and test fields fixed), at two
budgets: the gradient tuner's 32 steps of 8 fields (full) and 16 steps (half), validated every 8
steps on 16 fields. Every black-box tuner gets the episodes the gradient tuner used in the same run,
to within 2 %: CMA-ES's population (near its default ``4 + 3 ln d``) and fields per candidate, TPE's
batch and fields per trial and random search's fields per setting (16 settings) are chosen so that
whole generations, batches and settings add up to that count (the grid, whose 27 settings do not
split it, is left out). Seconds are each run's CPU seconds (every thread of the process) less the
time JAX spent tracing and compiling in it (JAX's compile events), so that no tuner pays or skips
compilation because another ran first and other load on the machine does not inflate them.
Small episodes keep the study to about two hours on 2 cores: 14 s flights, horizon 5, 8
FISTA iterations. The tuned gains fly 48 held-out fields of each of the four families: the training
mix's own (held-out fields) and the other mix's (held-out families).

Each tuner with a step size runs at its tuned best: before the study, per gain space and training mix,
the gradient tuner's learning rate (adam, cosine decay; 0.05, 0.1, 0.2, 0.4) and CMA-ES's initial step
(0.25 … 8 in ``θ``) are chosen on a selection problem of the mix's own families -- the families its
test then holds out never enter the choice -- with three selection seeds (11, 12, 13) at the full
budget, by the success (ties: the surrogate loss) of what each returns on 64 fresh check fields of
those families (seed 404), the rule the black-box searches pick a setting by. A step chosen at an end
of its range extends the range by a factor of 2 beyond it until the choice is interior (at most three
times). Random search and TPE search the same fixed ranges and have no step size.

Each black-box tuner's success on the held-out fields is compared with the gradient tuner's of the
same run and budget, paired on the fields: exact McNemar and TOST within a 2-point margin,
:func:`jaxapf.stats.decide`, the verdict function every study uses, with one declared Holm family, every
comparison of the study, each interval at the level that decided its verdict. The headline is read from
the per-run verdicts against the best black-box tuner.

    python analysis/tuner_study.py      # ~2 h on 2 cores
"""

from __future__ import annotations

import json
import math
import shutil
import time

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
BUDGETS = {"full": 32, "half": 16}  # gradient steps
VALIDATE_EVERY = 8
TEST_FIELDS = 48
TUNERS = ("random", "cmaes", "tpe")
RANDOM_SETTINGS = 16
TOLERANCE = 0.02  # a black-box tuner's episodes may differ from the gradient tuner's by this fraction
#: The step sizes tried first per gain space, the selection problem's seeds, check fields and their seed.
LEARNING_RATES = (0.05, 0.1, 0.2, 0.4)
SIGMAS = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0)
EXTENSIONS = 3
SELECTION_SEEDS = (11, 12, 13)
CHECK_FIELDS, CHECK_SEED = 64, 404


def spec_data(dim: int, families: list[str], seed: int, learning_rate: float, steps: int, name: str,
              search: dict | None = None) -> dict:
    """The tune spec of one run (module docstring); ``search``: the black-box tuner's own settings."""
    return {
        "name": name,
        "train": {"families": families, "fields_per_step": 8, "steps": steps, "seed": seed,
                  "learning_rate": learning_rate, "validate_every": VALIDATE_EVERY, "patience": 3},
        "validation": {"fields": 16, "seed": 101},
        "test": {"families": FAMILIES, "fields": TEST_FIELDS, "seed": 202},
        "tune": {"params": SPACES[dim]},
        "sim": {"method": METHOD, "filter": "cbf", "t_max": 14.0, "horizon": 5, "iters": 8},
        "scenario": {"params": {f: {"distance": [8.0, 10.0]} for f in FAMILIES}},
        "search": {"tuners": list(TUNERS), "random_n": RANDOM_SETTINGS, "random_seed": seed} | (search or {}),
    }


def matched(tuner: str, dim: int, budget: int) -> tuple[dict, int]:
    """The black-box ``tuner``'s settings whose whole generations (CMA-ES: population × fields per
    candidate), batches (TPE: trials × fields) or settings (random: 16 × fields) spend ``budget``
    episodes to within :data:`TOLERANCE`, nearest CMA-ES's default population (TPE: 8 trials a batch) and 8
    fields per candidate, and that count."""
    if tuner == "random":
        per = max(round(budget / RANDOM_SETTINGS), 1)
        found = ({}, RANDOM_SETTINGS * per)
    else:
        default = 4 + math.floor(3 * math.log(dim))
        options = []
        for size in (range(max(4, default - 2), default + 5) if tuner == "cmaes" else range(4, 17)):
            for m in range(4, 13):
                rounds = max(round(budget / (size * m)), 2)
                used = rounds * size * m
                miss = abs(used - budget)
                options.append((miss if miss > TOLERANCE * budget else 0, abs(size - (default if tuner == "cmaes"
                                                                                      else 8)), abs(m - 8), miss,
                                size, m, used))
        *_, size, m, used = min(options)
        found = ({"popsize" if tuner == "cmaes" else "tpe_batch": size, "fields_per_setting": m}, used)
    if abs(found[1] - budget) > TOLERANCE * budget:
        raise ValueError(f"{tuner}: no setting spends {budget} episodes within {TOLERANCE:.0%} (best {found[1]})")
    return found


class CompileClock:
    """Seconds JAX spends tracing, lowering and compiling, from its compile events (one listener)."""

    EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration",
              "/jax/core/compile/backend_compile_duration")
    total = 0.0

    @classmethod
    def install(cls) -> None:
        from jax import monitoring

        def listen(event, duration, **_):
            if event in cls.EVENTS:
                cls.total += duration
        monitoring.register_event_duration_secs_listener(listen)


def timed(run):
    """``run()`` and the CPU seconds (every thread of this process) it took, less JAX's compile time: a
    cost that other load on the machine does not inflate and that no tuner pays or skips for compiling."""
    cpu, compiled = time.process_time(), CompileClock.total
    result = run()
    return result, time.process_time() - cpu - (CompileClock.total - compiled)


def check(tuner, gains, families) -> dict:
    """The success and surrogate loss of ``gains`` on the check fields of ``families``."""
    from jaxapf.tune.spec import split_count

    r = tuner.report(tuner.fields(CHECK_SEED, split_count(CHECK_FIELDS, len(families)), families), [gains])
    return {"success": float(np.mean(r["success"])), "loss": float(np.mean(r["loss"]))}


def select_step_sizes() -> pd.DataFrame:
    """The selection runs of the module docstring (kept under ``runs/tuner-study/selection/``): one
    row per (space, mix, seed, tuner, step size) with the check fields' success and loss."""
    from jaxapf.tune.proof import tuning_budget
    from jaxapf.tune.searches import SEARCHES
    from jaxapf.tune.spec import parse_tune_spec
    from jaxapf.tune.train import Tuner

    root = study.ROOT / "runs" / "tuner-study" / "selection"
    root.mkdir(parents=True, exist_ok=True)
    cache = root / "rows.json"
    done = json.loads(cache.read_text()) if cache.exists() else {}

    def run(dim, mix, seed, tuner, step) -> dict:
        name = f"select-d{dim}-{mix}-s{seed}-{tuner}{step:g}"
        if name not in done:
            families = MIXES[mix]
            folder = root / name
            folder.mkdir(exist_ok=True)
            if tuner == "gradient":
                spec = parse_tune_spec(spec_data(dim, families, seed, step, BUDGETS["full"], name))
                t = Tuner(spec)
                state = t.train(folder, quiet=True)
                episodes, gains = tuning_budget(spec, state)["episodes"], spec.reparam.gains(state.best_theta)
            else:
                budget = run(dim, mix, seed, "gradient", LEARNING_RATES[0])["episodes"]
                search, used = matched("cmaes", dim, budget)
                spec = parse_tune_spec(spec_data(dim, families, seed, 0.05, BUDGETS["full"], name,
                                                 search | {"cmaes_sigma": step}))
                t = Tuner(spec)
                r = SEARCHES["cmaes"](t, used, folder, spec.digest())
                episodes, gains = r["episodes"], r["gains"]
            done[name] = {"dim": dim, "mix": mix, "seed": seed, "tuner": tuner, "step": step, "episodes": episodes,
                          **check(t, gains, families)}
            cache.write_text(json.dumps(done, indent=1) + "\n")
        return done[name]

    for dim in SPACES:
        for mix in MIXES:
            for tuner, steps in (("gradient", list(LEARNING_RATES)), ("cmaes", list(SIGMAS))):
                for _ in range(EXTENSIONS + 1):
                    rows = [run(dim, mix, seed, tuner, s) for s in steps for seed in SELECTION_SEEDS]
                    best = best_step(pd.DataFrame(rows))
                    if best == steps[0]:
                        steps.insert(0, steps[0] / 2)
                    elif best == steps[-1]:
                        steps.append(steps[-1] * 2)
                    else:
                        break
            print(f"  selection, {dim} gains, {mix}: done", flush=True)
    return pd.DataFrame(done.values())


def best_step(rows: pd.DataFrame) -> float:
    """The step of highest mean check success over the selection seeds (ties: lowest mean loss)."""
    mean = rows.groupby("step", as_index=False)[["success", "loss"]].mean()
    return float(mean.sort_values(["success", "loss"], ascending=[False, True])["step"].iloc[0])


def chosen(selection: pd.DataFrame) -> dict[tuple[int, str], dict[str, float]]:
    """Per (gain space, mix), each tuner's chosen step size (:func:`best_step`) and whether it is interior
    to the steps tried."""
    out = {}
    for (dim, mix, tuner), rows in selection.groupby(["dim", "mix", "tuner"]):
        best = best_step(rows)
        out.setdefault((int(dim), mix), {})[tuner] = best
        out[(int(dim), mix)][f"{tuner}_interior"] = bool(rows["step"].min() < best < rows["step"].max())
    return out


def run_all(steps: dict) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Every run at the chosen step sizes and both budgets (kept under ``runs/tuner-study/``, reused when
    finished); one row per test episode, and one per (run, budget, tuner) with its episodes and seconds."""
    from jaxapf.tune.proof import test_episodes, tuning_budget
    from jaxapf.tune.searches import SEARCHES
    from jaxapf.tune.spec import parse_tune_spec
    from jaxapf.tune.train import Tuner

    frames, costs = [], []
    for dim in SPACES:
        for mix in MIXES:
            lr, sigma = steps[(dim, mix)]["gradient"], steps[(dim, mix)]["cmaes"]
            for seed in SEEDS:
                for budget, n_steps in BUDGETS.items():
                    name = f"tuners-d{dim}-{mix}-s{seed}-{budget}-lr{lr:g}-sigma{sigma:g}"
                    out = study.ROOT / "runs" / "tuner-study" / name
                    out.mkdir(parents=True, exist_ok=True)
                    done = out / "costs.json"
                    if not done.exists():  # a run cut short starts again: its seconds must be one run's
                        shutil.rmtree(out)
                        out.mkdir(parents=True)
                        spec = parse_tune_spec(spec_data(dim, MIXES[mix], seed, lr, n_steps, name))
                        tuner = Tuner(spec)
                        state, seconds = timed(lambda tuner=tuner, out=out: tuner.train(out, quiet=True))
                        used = tuning_budget(spec, state)["episodes"]
                        arms = {"gradient": {"gains": spec.reparam.gains(state.best_theta).floats(), "episodes": used,
                                             "seconds": seconds, "gradient_episodes": used,
                                             "still_improving": state.history[-1]["val_loss"] == min(
                                                 r["val_loss"] for r in state.history
                                                 if math.isfinite(r["val_loss"]))}}
                        for t in TUNERS:
                            search, count = matched(t, dim, used)
                            variant = parse_tune_spec(spec_data(dim, MIXES[mix], seed, lr, n_steps, name,
                                                                search | {"cmaes_sigma": sigma}))
                            r, seconds = timed(lambda t=t, v=variant, n=count, out=out:
                                               SEARCHES[t](Tuner(v), n, out, v.digest()))
                            arms[t] = {"gains": r["gains"].floats(), "episodes": r["episodes"], "seconds": seconds,
                                       "gradient_episodes": used, "still_improving": False, **search}
                        settings = {"default": spec.init} | {
                            a: spec.reparam.base.replace(**r["gains"]) for a, r in arms.items()}
                        test_episodes(tuner, settings).to_parquet(out / "test_episodes.parquet", index=False)
                        done.write_text(json.dumps(arms, indent=1) + "\n")
                    arms = json.loads(done.read_text())
                    ep = pd.read_parquet(out / "test_episodes.parquet")
                    frames.append(ep.assign(dim=dim, mix=mix, seed=seed, budget=budget,
                                            held_out=np.where(ep["family"].isin(MIXES[mix]), "fields", "families")))
                    costs += [{"dim": dim, "mix": mix, "seed": seed, "budget": budget, "tuner": t,
                               **{k: v for k, v in r.items() if k != "gains"}} for t, r in arms.items()]
                    print(f"  {name}: done", flush=True)
    episodes = pd.concat(frames, ignore_index=True)
    episodes["family"] = episodes["family"].astype(str)
    episodes["setting"] = episodes["setting"].astype(str)
    return episodes, pd.DataFrame(costs)


def summarise(episodes: pd.DataFrame, cost: pd.DataFrame) -> pd.DataFrame:
    """Per (dimension, mix, seed, budget, tuner, held-out kind, and pooled): success with Wilson intervals,
    the paired change against the gradient tuner of the same run, verdicts over the whole study, and the
    episodes and seconds the tuner spent."""
    both = pd.concat([episodes, episodes.assign(held_out="all")], ignore_index=True)
    rows = []
    for (dim, mix, seed, budget, held), g in both.groupby(["dim", "mix", "seed", "budget", "held_out"], sort=False):
        base = g[g["setting"] == "gradient"].set_index(["family", "field"])["success"]
        default = g[g["setting"] == "default"]["success"].mean()
        for tuner, t in g.groupby("setting", sort=False):
            if tuner == "default":
                continue
            spent = cost[(cost["dim"] == dim) & (cost["mix"] == mix) & (cost["seed"] == seed)
                         & (cost["budget"] == budget) & (cost["tuner"] == tuner)].iloc[0]
            row = {"dim": dim, "mix": mix, "seed": seed, "budget": budget, "held_out": held, "tuner": tuner,
                   "n": len(t), **study.rates(t), "default_success": default,
                   "points_over_default": 100 * (study.rates(t)["success"] - default),
                   "episodes": int(spent["episodes"]), "seconds": float(spent["seconds"]),
                   "gradient_episodes": int(spent["gradient_episodes"])}
            if tuner != "gradient":
                then = base.loc[list(zip(t["family"], t["field"]))].to_numpy(bool)
                row |= study.paired_success(t["success"].to_numpy(bool), then)
            rows.append(row)
    return study.mark_verdicts(rows, MARGIN)


MARK = {"better": "↑", "worse": "↓", "equivalent": "=", "inconclusive": "·"}


def means(table: pd.DataFrame) -> pd.DataFrame:
    """Per (budget, dimension, tuner): success, episodes, seconds and points over the defaults, pooled over
    the held-out kinds and averaged over mixes and seeds."""
    pooled = table[table["held_out"] == "all"]
    return pooled.groupby(["budget", "dim", "tuner"], sort=False)[
        ["success", "episodes", "seconds", "points_over_default"]].mean().reset_index()


def family_success(episodes: pd.DataFrame) -> pd.Series:
    """Held-out success [%] per (budget, dimension, tuner, family), mean over mixes and seeds."""
    return (100 * episodes.groupby(["budget", "dim", "setting", "family"])["success"].mean()).round(1)


def committed_family_success(out) -> pd.Series:
    """:func:`family_success` as the committed ``README.md`` states it (its per-family table), which
    ``--facts-only`` reads where the results keep no test episodes (a run before they were kept)."""
    section = (out / "README.md").read_text().split("## Per family")[1].split("\n## ")[0]
    rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in section.splitlines()
            if line.startswith(tuple(f"| {b} |" for b in BUDGETS))]
    return pd.Series({(r[0], int(r[1]), r[2], f): float(v) for r in rows for f, v in zip(FAMILIES, r[3:])})


def facts(table: pd.DataFrame, cost: pd.DataFrame, selection: pd.DataFrame, family: pd.Series) -> dict:
    """The named values the findings state, from the committed tables (``summary.csv``, ``costs.csv``,
    ``selection.csv``) and the per-family success: per budget, gain space and tuner the mean success,
    episodes and seconds; the best black-box tuner and its per-run verdicts against the gradient tuner;
    every verdict and their counts; the realised budgets' largest mismatch; the step sizes tried, chosen
    and whether each choice is interior."""
    from jaxapf.tune.spec import TrainSpec

    mean = means(table)
    pooled = table[(table["held_out"] == "all") & (table["tuner"] != "gradient")]
    key = lambda b, d, t: f"{b}/d{d}/{t}"  # noqa: E731
    best = {}
    for (b, d), g in mean[mean["tuner"] != "gradient"].groupby(["budget", "dim"], sort=False):
        top = g.sort_values("success", ascending=False, kind="stable").iloc[0]
        best[f"{b}/d{d}"] = top["tuner"]
    gradient = mean[mean["tuner"] == "gradient"].set_index(["budget", "dim"])["success"]
    success = mean.set_index(["budget", "dim", "tuner"])["success"]
    counts = {key(b, d, t): {v: int((g["verdict"] == v).sum()) for v in MARK}
              for (b, d, t), g in pooled.groupby(["budget", "dim", "tuner"], sort=False)}
    per_run = {f"{b}/d{d}": {f"{m}/s{s}": v for m, s, v in zip(g["mix"], g["seed"], g["verdict"])}
               for (b, d), g in pooled.groupby(["budget", "dim"], sort=False)
               for g in [g[g["tuner"] == best[f"{b}/d{d}"]]]}
    ratio = cost.assign(r=cost["episodes"] / cost["gradient_episodes"])
    steps = chosen(selection)
    by_step = selection.groupby(["dim", "mix", "tuner", "step"], as_index=False)["success"].mean()
    split = table[table["held_out"] != "all"].groupby(["budget", "dim", "tuner", "held_out"], sort=False)[
        "success"].mean()
    return {"success_mean": {key(r.budget, r.dim, r.tuner): round(100 * r.success, 1) for r in mean.itertuples()},
            "episodes_mean": {key(r.budget, r.dim, r.tuner): round(r.episodes, 1) for r in mean.itertuples()},
            "seconds_mean": {key(r.budget, r.dim, r.tuner): round(r.seconds, 1) for r in mean.itertuples()},
            "best_black_box": best,
            "best_black_box_lead": {f"{b}/d{d}": 100 * (success[(b, d, best[f"{b}/d{d}"])] - gradient[(b, d)])
                                    for b, d in gradient.index},
            "best_black_box_verdicts": {k: counts[f"{k}/{t}"] for k, t in best.items()},
            "best_black_box_per_run": per_run,
            "verdicts_vs_gradient": counts,
            "budget_ratio": {"min": float(ratio["r"].min()), "max": float(ratio["r"].max())},
            "episodes_range": {f"{b}/{t}": {"min": int(g.min()), "max": int(g.max())}
                               for (b, t), g in cost.groupby(["budget", "tuner"], sort=False)["episodes"]},
            "held_out_success": {key(b, d, t): {h: 100 * split[(b, d, t, h)] for h in ("fields", "families")}
                                 for b, d, t in zip(mean["budget"], mean["dim"], mean["tuner"])},
            "family_success": {f"{b}/d{d}": {t: {f: float(family[(b, d, t, f)]) for f in FAMILIES}
                                             for t in dict.fromkeys(family[b][d].index.get_level_values(0))}
                               for b in BUDGETS for d in SPACES},
            "gradient_still_improving": {b: int(cost[(cost["tuner"] == "gradient") & (cost["budget"] == b)][
                "still_improving"].sum()) for b in BUDGETS},
            "chosen_steps": {f"d{d}/{m}": {t: v for t, v in s.items()} for (d, m), s in steps.items()},
            "all_interior": all(v for s in steps.values() for k, v in s.items() if k.endswith("_interior")),
            "steps_tried": {t: sorted(float(x) for x in g.unique()) for t, g in selection.groupby("tuner")["step"]},
            "default_learning_rate": TrainSpec().learning_rate,
            "selection_success": {f"d{r.dim}/{r.mix}/{r.tuner}/{r.step:g}": round(100 * r.success, 1)
                                  for r in by_step.itertuples()},
            "gains": {f"d{d}": d for d in SPACES}, "test_fields": TEST_FIELDS, "families": len(FAMILIES),
            "budget_steps": BUDGETS, "check_fields": CHECK_FIELDS,
            "runs_per_space": len(MIXES) * len(SEEDS), "tolerance": TOLERANCE,
            "verdicts": {v: int((table["verdict"] == v).sum()) for v in MARK},
            "comparisons": int(table["verdict"].notna().sum())}


def write(table: pd.DataFrame, cost: pd.DataFrame, selection: pd.DataFrame, episodes: pd.DataFrame, out) -> dict:
    pooled = table[table["held_out"] == "all"]
    mean = means(table)
    tuners = ["gradient", *TUNERS]
    fam = family_success(episodes)
    found = facts(table, cost, selection, fam)
    lines = ["# Study 15: the tuners of `jaxapf tune` by dimension of the gain space", "",
             "`python analysis/tuner_study.py`", "", "Protocol: " + " ".join(__doc__.split("\n\n")[1].split()), "",
             " ".join(__doc__.split("\n\n")[2].split()), "", " ".join(__doc__.split("\n\n")[3].split()), "",
             "## Findings", ""]
    for b in BUDGETS:
        for d in SPACES:
            k = f"{b}/d{d}"
            t = found["best_black_box"][k]
            v = found["best_black_box_verdicts"][k]
            lines.append(f"- {b} budget, {d} gains: gradient {found['success_mean'][f'{k}/gradient']:.1f} % held-out "
                         f"success ({found['episodes_mean'][f'{k}/gradient']:.0f} episodes, "
                         f"{found['seconds_mean'][f'{k}/gradient']:.1f} s), the best black-box tuner `{t}` "
                         f"{found['success_mean'][f'{k}/{t}']:.1f} % "
                         f"({found['episodes_mean'][f'{k}/{t}']:.0f} episodes, "
                         f"{found['seconds_mean'][f'{k}/{t}']:.1f} s); its verdicts against the gradient tuner over "
                         f"the {found['runs_per_space']} runs: " + ", ".join(f"{w} {n}" for w, n in v.items() if n)
                         + ".")
    lines += ["", f"Every black-box arm spent {100 * found['budget_ratio']['min']:.1f}–"
              f"{100 * found['budget_ratio']['max']:.1f} % of its run's gradient episodes. Step sizes chosen (learning "
              "rate / CMA-ES's initial step) per gain space and mix: "
              + "; ".join(f"{d} {m}: {s['gradient']:g} / {s['cmaes']:g}" for (d, m), s in chosen(selection).items())
              + f"; every choice interior to the steps tried: {found['all_interior']}. The gradient tuner's best "
              "validation loss was at its last validation in " + ", ".join(
                  f"{n} of {len(SPACES) * found['runs_per_space']} {b}-budget runs"
                  for b, n in found["gradient_still_improving"].items()) + ".", "",
              f"Verdicts over all {found['comparisons']} comparisons (Holm; pooled and per held-out kind): "
              + ", ".join(f"{k} {v}" for k, v in found["verdicts"].items()) + ".", ""]
    for b in BUDGETS:
        lines += [f"## {b.capitalize()} budget: held-out success [%], all four families pooled, per seed (1 / 2 / 3), "
                  "and the verdict against the gradient tuner of the same run (↑ better, ↓ worse, = equivalent, "
                  "· inconclusive)", ""]
        for mix in MIXES:
            lines += [f"### Trained on {mix}", "", "| gains | " + " | ".join(tuners) + " |",
                      "|---|" + "---|" * len(tuners)]
            for dim in SPACES:
                cells = []
                for tuner in tuners:
                    r = pooled[(pooled["budget"] == b) & (pooled["mix"] == mix) & (pooled["dim"] == dim)
                               & (pooled["tuner"] == tuner)].sort_values("seed")
                    marks = "".join(MARK.get(v, "") for v in r["verdict"] if isinstance(v, str))
                    cells.append(" / ".join(f"{100 * v:.1f}" for v in r["success"]) + (f" {marks}" if marks else ""))
                lines.append(f"| {dim} | " + " | ".join(cells) + " |")
            lines.append("")
    lines += ["## Mean over mixes and seeds: held-out success [%], points over the defaults, episodes and seconds "
              "spent tuning (CPU seconds, compilation excluded)", "",
              "| budget | gains | tuner | success | points over default | episodes | seconds |",
              "|---|---|---|---|---|---|---|"]
    for r in mean.itertuples():
        lines.append(f"| {r.budget} | {r.dim} | {r.tuner} | {100 * r.success:.1f} | {r.points_over_default:.1f} | "
                     f"{r.episodes:.0f} | {r.seconds:.1f} |")
    lines += ["", "## Per family: held-out success [%] (mean over mixes and seeds; a family is held out of "
              "training for one mix)", "", "| budget | gains | tuner | " + " | ".join(FAMILIES) + " |",
              "|---|---|---|" + "---|" * len(FAMILIES)]
    for b in BUDGETS:
        for dim in SPACES:
            for tuner in ["default", *tuners]:
                lines.append(f"| {b} | {dim} | {tuner} | " + " | ".join(f"{fam[(b, dim, tuner, f)]:.1f}"
                                                                      for f in FAMILIES) + " |")
    lines += ["", "## Step-size selection: mean success [%] on the 64 check fields of the mix's families over the "
              "three selection seeds (chosen: bold)", "", "| gains | mix | tuner | step | success |",
              "|---|---|---|---|---|"]
    steps = chosen(selection)
    for r in selection.groupby(["dim", "mix", "tuner", "step"], as_index=False)["success"].mean().itertuples():
        mark = "**" if steps[(r.dim, r.mix)][r.tuner] == r.step else ""
        lines.append(f"| {r.dim} | {r.mix} | {r.tuner} | {mark}{r.step:g}{mark} | {100 * r.success:.1f} |")
    lines += ["", "`episodes.parquet`: every held-out test episode's outcomes (`--from-episodes` rebuilds this page "
              "from them, `costs.csv` and `selection.csv`)."]
    return study.write_results(out, lines, found)


#: The test episodes' columns the pages and facts read, kept as ``episodes.parquet`` (``--from-episodes``).
READ = ("dim", "mix", "seed", "budget", "held_out", "setting", "family", "field", *study.RATE_COLUMNS)


def main() -> None:
    args, out = study.begin(__doc__, STUDY)
    if args.from_episodes:  # the runs' selections and costs from the committed tables, their episodes kept
        episodes, cost = study.kept_rows(out), study.kept_table(out, "costs.csv", "--from-episodes")
        table = summarise(episodes, cost)
        table.to_csv(out / "summary.csv", index=False)
        selection = study.kept_table(out, "selection.csv", "--from-episodes")
        print(json.dumps(write(table, cost, selection, episodes, out), indent=1))
        return
    if args.facts_only:  # the verdicts derived again from the committed table's counts
        summary = study.rederive(pd.read_csv(out / "summary.csv"), MARGIN, change="success_change")
        summary.to_csv(out / "summary.csv", index=False)
        study.write_facts(out, facts(summary, pd.read_csv(out / "costs.csv"),
                                     pd.read_csv(out / "selection.csv"),
                                     family_success(study.kept_rows(out)) if (out / "episodes.parquet").exists()
                                     else committed_family_success(out)))
        return
    CompileClock.install()
    selection = select_step_sizes()
    selection.to_csv(out / "selection.csv", index=False)
    episodes, cost = run_all(chosen(selection))
    study.keep_rows(episodes, out, READ)
    cost.to_csv(out / "costs.csv", index=False)
    table = summarise(episodes, cost)
    table.to_csv(out / "summary.csv", index=False)
    print(json.dumps(write(table, cost, selection, episodes, out), indent=1))


if __name__ == "__main__":
    study.entry(main)
