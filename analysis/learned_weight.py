"""Study 19: a repulsive weight learned through the closed loop against the paper's.

``jaxapf compare sweeps/learned-weight.toml``: study 17's protocol (its selection families, seeds, budget of
512 episode rollouts per method and seed, held-out fields of seed 100) with ``learned_weight`` (the paper's
potential, ω replaced by a 1,217-parameter network ω_θ of cos θ, tanh c and d/d_s; docs/spec.md §3) trained
by ``jaxapf tune``'s gradient descent, beside the paper's ``basic``, ``direction`` and ``direction_velocity``
each tuned by study 17's random search. Then the black-box arm, ``sweeps/learned-weight-cmaes.toml``: the
same network and gains chosen by separable CMA-ES under the same budget, flown on the same held-out fields;
gradient against black box is paired field by field, seed by seed (the one verdict function, Holm over
those comparisons). The ceiling is study 17's ``mppi`` and ``keepout_mpc`` on the same held-out fields (its
facts, not flown again); the cost per control step of each planner is measured here, interleaved
(``jaxapf.bench.world``). A figure draws each seed's ω_θ beside the paper's ω at its selected γ and k. Every
selection is flown again on the paper's own two scenarios, families no selection saw. The input ablation,
``sweeps/learned-weight-ablation.toml``, retrains the network with each input fed as 0 under the same budget;
``sweeps/learned-weight-budget.toml`` selects the learned weight and the paper's method again with twice it.

    python analysis/learned_weight.py     # the four comparisons, the held-out families and the cost, resumable
                                          # under runs/
"""

from __future__ import annotations

import json
import pathlib
import shutil

import numpy as np
import pandas as pd
import study
from planner_benchmark import PAPER, SEEDS, _rows, _tuned, _unanimous, leaderboard, run_benchmark
from planner_benchmark import facts as benchmark_facts

NAME = "learned_weight"
SPEC = "learned-weight.toml"
BLACK_BOX_SPEC = "learned-weight-cmaes.toml"
ABLATION_SPEC = "learned-weight-ablation.toml"
BUDGET_SPEC = "learned-weight-budget.toml"
LEARNED = "learned_weight"
#: The held-out families: the paper's own two scenarios, which no selection flies (``paper_static`` one fixed
#: field unless jittered: 10 cm on every centre, as study 1).
HELD_OUT = {"paper_static": {"jitter": 0.1}, "paper_dynamic": {}}
#: What the ablation leaves out, one input at a time (its spec's plugin registers the planners), and the
#: symbol a table heads it with.
INPUTS = {"direction": "cos θ", "closing": "c", "clearance": "d/d_s"}
#: The equivalence margin of the gradient-against-black-box verdicts (as studies 12-15).
MARGIN = 0.02
#: The planners whose cost per control step is measured (against the ideal world's basic).
COSTED = ("direction_velocity", "learned_weight", "mppi", "keepout_mpc")
#: The ceiling: study 17's planners that fly the field, on the same held-out fields.
CEILING = ("mppi", "keepout_mpc")


def _episodes(parquet: pathlib.Path, method: str = LEARNED) -> pd.DataFrame:
    from jaxapf.sweep import read_sweep

    rows = read_sweep(parquet)[0]
    return rows[rows["method"] == method][["selection", "family", "field", "success", "collision"]]


def paired_arms(arms: dict[str, pd.DataFrame], groups: list[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per seed and group (each test family and ``all``): every arm's success and collision rates, and the
    first arm's success against each other arm's on the same fields (verdicts, Holm over all of them)."""
    first = next(iter(arms))
    rates, rows = [], []
    for tag in SEEDS:
        for group in groups:
            pick = lambda frame, tag=tag, group=group: (frame[frame["selection"] == tag] if group == "all" else  # noqa: E731
                                                        frame[(frame["selection"] == tag) & (frame["family"] == group)])
            frames = {arm: pick(frame).sort_values(["family", "field"]) for arm, frame in arms.items()}
            a = frames[first]
            for arm, frame in frames.items():
                if not (a[["family", "field"]].to_numpy() == frame[["family", "field"]].to_numpy()).all():
                    raise RuntimeError(f"the arms {first} and {arm} flew different fields for {tag} {group}")
                rates.append({"arm": arm, "seed": tag, "group": group, "n": len(frame),
                              "success": frame["success"].mean(), "collision": frame["collision"].mean()})
                if arm != first:
                    rows.append({"arm": arm, "seed": tag, "group": group, "n": len(a)}
                                | study.paired_success(a["success"].to_numpy(bool), frame["success"].to_numpy(bool)))
    return pd.DataFrame(rates), study.mark_verdicts(rows, MARGIN)


def omega_figure(runs: pathlib.Path, out: pathlib.Path) -> dict[str, dict[str, float]]:
    """Each seed's ω_θ beside the paper's ω at that seed's selected γ, k, over the direction cosine and the
    closing speed at half the influence distance, each divided by its value abeam at zero closing speed (the
    overall scale trades against k_rep)."""
    import jax
    import jax.numpy as jnp
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm

    from jaxapf.planners.learned import network
    from jaxapf.planners.weights import direction_weight, velocity_weight

    cos, closing = np.meshgrid(np.linspace(-1.0, 1.0, 81), np.linspace(-3.0, 3.0, 81))
    x = jnp.stack([jnp.asarray(cos), jnp.tanh(jnp.asarray(closing)), jnp.full(cos.shape, 0.5)])
    fig, axes = plt.subplots(2, len(SEEDS), figsize=(3.3 * len(SEEDS), 6.0), sharex=True, sharey=True,
                             constrained_layout=True)
    spans = {}
    for j, tag in enumerate(SEEDS):
        seed = tag.removeprefix("seed")
        learned = json.loads((runs / "selection" / f"{LEARNED}-seed{seed}.json").read_text())["selection"]["gains"]
        paper = json.loads((runs / "selection" / f"{PAPER}-seed{seed}.json").read_text())["selection"]["gains"]
        theta = jnp.asarray(learned["omega_params"])
        omega = np.asarray(jax.nn.softplus(network(theta, x)))
        ref = float(jax.nn.softplus(network(theta, jnp.array([0.0, 0.0, 0.5]))))
        hand = np.asarray(direction_weight(cos, paper["gamma"]) * velocity_weight(closing, paper["k"]))
        hand_ref = float(direction_weight(0.0, paper["gamma"]) * velocity_weight(0.0, paper["k"]))
        spans[tag] = {}
        for name, values in (("learned", omega / ref), ("paper", hand / hand_ref)):
            # the slopes: ahead (cos θ = 1) minus behind (-1), averaged over c; closing (c = 3) minus receding (-3)
            spans[tag] |= {f"{name}_min": float(values.min()), f"{name}_max": float(values.max()),
                           f"{name}_ahead": float(np.mean(values[:, -1] - values[:, 0])),
                           f"{name}_closing": float(np.mean(values[-1, :] - values[0, :]))}
        for i, (values, title) in enumerate(((hand / hand_ref, f"paper's ω, γ = {paper['gamma']:.2f}, "
                                                              f"k = {paper['k']:.2f}"),
                                             (omega / ref, "learned ω_θ"))):
            ax = axes[i, j]
            image = ax.imshow(values, origin="lower", extent=(-1, 1, -3, 3), aspect="auto", cmap="RdBu_r",
                              norm=TwoSlopeNorm(vmin=0.4, vcenter=1.0, vmax=2.5))
            lines = ax.contour(cos, closing, values, levels=(0.5, 0.75, 0.9, 1.1, 1.25, 1.5, 2.0), colors="k",
                               linewidths=0.6)
            ax.clabel(lines, fontsize=7)
            ax.set_title(f"{title} ({tag})", fontsize=9)
            if i == 1:
                ax.set_xlabel("cos θ (1: heading at it)")
            if j == 0:
                ax.set_ylabel("closing speed c [m/s]")
    fig.colorbar(image, ax=axes, shrink=0.8, label="ω / ω(abeam, c = 0)")
    fig.savefig(out / "omega.png", dpi=110)
    plt.close(fig)
    return spans


def _ceiling() -> dict:
    return json.loads((study.RESULTS / "flown_planners" / "facts.json").read_text())["success"]


def _run_comparison(spec_file: str, folder: pathlib.Path, args, suffix: str = "") -> pathlib.Path:
    """One of the study's other comparisons (:func:`study.run_comparison`: the study's ``--fields`` and
    ``--resamples``), its ``compare.md`` and ``selection.csv`` copied into ``folder`` (names ending in
    ``suffix``). Returns its runs folder."""
    runs = study.run_comparison(args, spec_file, folder / f"selection{suffix}.csv")[1]
    folder.mkdir(exist_ok=True)
    shutil.copy(runs / "compare.md", folder / f"compare{suffix}.md")
    shutil.copy(runs / "selection.csv", folder / f"selection{suffix}.csv")
    return runs


def arms(out: pathlib.Path, spec, args, runs: pathlib.Path | None) -> tuple[list[str], dict]:
    """The black-box arm, the ceiling, the cost per step and the weight's figure: sections and facts (computed
    beside the comparison in ``runs``, or read back from ``out/arms/`` with ``--facts-only``, ``runs`` None)."""
    from jaxapf.planners.learned import SIZE

    folder = out / "arms"
    summary = pd.read_csv(out / "report" / "summary.csv")
    groups = [*spec.test.families, "all"]  # (the trap kinds are the report's)
    if runs is not None:
        from jaxapf.bench.world import run_world_benchmark

        black_runs = _run_comparison(BLACK_BOX_SPEC, folder, args, "_sep_cmaes")
        rates, comparisons = paired_arms({"gradient": _episodes(runs / "test.parquet"),
                                          "sep_cmaes": _episodes(black_runs / "test.parquet")}, groups)
        rates.to_csv(folder / "rates.csv", index=False)
        comparisons.to_csv(folder / "comparisons.csv", index=False)
        cost = run_world_benchmark(fields=64, steps=100, variants=COSTED)
        (folder / "cost.json").write_text(json.dumps(cost, indent=1) + "\n")
        (folder / "omega.json").write_text(json.dumps(omega_figure(runs, out), indent=1) + "\n")
    rates, comparisons = pd.read_csv(folder / "rates.csv"), pd.read_csv(folder / "comparisons.csv")
    cost = json.loads((folder / "cost.json").read_text())["variants"]
    black_selection = pd.read_csv(folder / "selection_sep_cmaes.csv")
    selection = pd.read_csv(out / "selection.csv")
    ceiling = _ceiling()
    facts: dict = {"arms": {}, "arm_verdict": {}, "arm_all_seeds": {}, "gap_closed": {}, "ceiling": {},
                   "omega": json.loads((folder / "omega.json").read_text()), "comparisons": len(comparisons),
                   "cost_us": {k: cost[k]["us_per_scenario_step"] for k in COSTED},
                   "cost_ratio": {k: cost[k]["us_per_scenario_step"] / cost[PAPER]["us_per_scenario_step"]
                                  for k in COSTED},
                   "parameters": SIZE}
    for arm, frame in (("gradient", selection), ("sep_cmaes", black_selection)):
        rows = frame[frame["method"] == LEARNED]
        facts["arms"][arm] = {"episodes": int(rows["episodes"].sum()), "episodes_min": int(rows["episodes"].min()),
                              "seconds": float(rows["seconds"].sum()), "budget": int(rows["budget"].max())}
    for arm, part in rates.groupby("arm"):
        for group, g in part.groupby("group"):
            facts["arms"][arm].setdefault("success", {})[group] = float(g["success"].mean())
    for group, g in comparisons.groupby("group"):
        facts["arm_verdict"][group] = dict(zip(g["seed"], g["verdict"]))
        facts["arm_all_seeds"][group] = study.unanimous(g["verdict"])
    for group in groups:
        learned = float(np.mean(_tuned(summary, spec, LEARNED, group, "success_rate")))
        paper = float(np.mean(_tuned(summary, spec, PAPER, group, "success_rate")))
        facts["ceiling"][group] = {m: ceiling[group][m] for m in CEILING if group in ceiling}
        top = ceiling.get(group, {}).get("mppi")
        facts["gap_closed"][group] = (learned - paper) / (top - paper) if top is not None and top > paper else None
    families, facts["held_out"] = held_out(out, spec, args, runs)
    longer, facts["twice_budget"] = budget(out, spec, summary, args, runs is not None)
    text, facts["ablation"] = ablation(out, spec, summary, groups, args, runs)
    return [section(facts, groups), families, longer, text], facts


def held_out(out: pathlib.Path, spec, args, runs: pathlib.Path | None) -> tuple[str, dict]:
    """Every selection of the comparison (defaults and the three seeds' choices) flown on :data:`HELD_OUT`,
    families no selection saw, with the test's fields per family and seed; reported against ``basic`` and
    against the paper's method of the same selection, as the held-out fields are (facts of the same shape)."""
    import dataclasses

    from jaxapf.compare.protocol import baseline_filter, test_sweep_spec
    from jaxapf.compare.select import saved_selection

    held = dataclasses.replace(spec, test=dataclasses.replace(spec.test, families=tuple(HELD_OUT)),
                               params={**spec.params, **HELD_OUT})
    if runs is not None:
        from jaxapf.sweep import run_sweep

        selections = [saved_selection(spec, m, seed, runs / "selection") for seed in spec.selection.seeds
                      for m in spec.methods]
        parquet = runs / "held_out.parquet"
        run_sweep(test_sweep_spec(held, selections), parquet, quiet=True)
        for folder, base in (("held_out/report", spec), ("held_out/report_vs_paper",
                                                        dataclasses.replace(spec, baseline=PAPER))):
            study.report(parquet, out, resamples=args.resamples, folder=folder, baseline=baseline_filter(base),
                         pair_on=("selection",), heatmap=None)
    vs_basic, vs_paper = (study.committed_report(out, f) for f in ("held_out/report", "held_out/report_vs_paper"))
    facts = benchmark_facts(held, vs_basic.summary, vs_basic.comparisons, vs_paper.comparisons,
                            pd.read_csv(out / "selection.csv"))
    board = leaderboard(held, vs_basic.summary, vs_basic.comparisons, vs_paper.comparisons)
    intro = ("## On families no selection saw: the paper's scenarios\n\nEvery selection above flown on the paper's "
             f"own two scenarios, {spec.test.fields} fields each of the test seed (`paper_static` with a 10 cm jitter "
             "of every centre): no selection flew them. Full reports: [`held_out/report/report.md`]"
             "(held_out/report/report.md) (against `basic`), [`held_out/report_vs_paper/report.md`]"
             "(held_out/report_vs_paper/report.md) (against `direction_velocity`).")
    return intro + board.removeprefix("## Leaderboard"), facts


def budget(out: pathlib.Path, spec, summary: pd.DataFrame, args, compute: bool) -> tuple[str, dict]:
    """Study 19 at twice the budget (``sweeps/learned-weight-budget.toml``): the learned weight by gradient
    against ``direction_velocity`` by random search, each with twice the episode rollouts. Its facts: both
    methods' held-out success per group (mean of the seeds), the learned weight's verdicts against the paper's
    seed by seed (that comparison's own report, Holm over it), the realised budgets and the steps chosen."""
    from jaxapf.compare import load_compare_spec

    folder = out / "budget"
    if compute:
        runs = _run_comparison(BUDGET_SPEC, folder, args)
        for name in ("summary.csv", "comparisons.csv"):
            shutil.copy(runs / "report" / name, folder / name)
    longer = load_compare_spec(study.ROOT / "sweeps" / BUDGET_SPEC)[0]
    table, comparisons = pd.read_csv(folder / "summary.csv"), pd.read_csv(folder / "comparisons.csv")
    selection = pd.read_csv(folder / "selection.csv")
    groups = [*longer.test.families, "all"]
    success = comparisons[comparisons["metric"] == "success"].set_index(["family", "setting"])["verdict"]
    facts: dict = {"budget": longer.selection.budget, "success": {}, "study_success": {}, "verdict": {},
                   "all_seeds": {}, "spent": {}, "chosen": {}}
    for group in groups:
        for method in longer.methods:
            facts["success"].setdefault(group, {})[method] = float(np.mean(_tuned(table, longer, method, group,
                                                                                  "success_rate")))
            facts["study_success"].setdefault(group, {})[method] = float(np.mean(_tuned(summary, spec, method, group,
                                                                                        "success_rate")))
        rows = _rows(table, longer, LEARNED, group)
        facts["verdict"][group] = {tag: success[(group, int(rows.at[tag, "setting"]))] for tag in SEEDS}
        facts["all_seeds"][group] = study.unanimous(facts["verdict"][group].values())
    for method, rows in selection.groupby("method", sort=False):
        facts["spent"][method] = {"episodes": int(rows["episodes"].sum()), "seconds": float(rows["seconds"].sum())}
        facts["chosen"][method] = dict(zip((f"seed{s}" for s in rows["seed"]), rows["chosen"]))
    lines = ["## Twice the budget", "",
             f"`sweeps/{BUDGET_SPEC}`: the learned weight and `direction_velocity` selected again with "
             f"{longer.selection.budget:,} episode rollouts per method and seed (the same gradient options, so twice "
             f"the steps; the same 16 random candidates on twice the fields), tested on the same held-out fields. "
             f"Held-out success in %, mean of the three seeds, beside this study's at {spec.selection.budget:,}; "
             f"*vs paper*: the learned weight against `direction_velocity` of the same selection, seed by seed "
             f"(that comparison's report, Holm over it).", "",
             "| group | learned, twice the budget | paper, twice the budget | vs paper | learned | paper |",
             "|---|---|---|---|---|---|"]
    for group in groups:
        now, then = facts["success"][group], facts["study_success"][group]
        lines.append(f"| {group} | {_pct(now[LEARNED])} | {_pct(now[PAPER])} | "
                     f"{', '.join(facts['verdict'][group][t] for t in SEEDS)} | {_pct(then[LEARNED])} | "
                     f"{_pct(then[PAPER])} |")
    lines += ["", "Budgets as realised, over the three seeds: " + ", ".join(
        f"`{m}` {v['episodes']:,} episode rollouts in {v['seconds']:.0f} s" for m, v in facts["spent"].items())
        + "; the learned weight's validation chose " + ", ".join(
            f"{v} ({k})" for k, v in facts["chosen"][LEARNED].items()) + "."]
    return "\n".join(lines), facts


def ablation(out: pathlib.Path, spec, summary: pd.DataFrame, groups: list[str], args,
             runs: pathlib.Path | None) -> tuple[str, dict]:
    """The input ablation (``sweeps/learned-weight-ablation.toml``): the network retrained with each input fed
    as 0, under the same budget and held-out fields. Its facts: each arm's realised budget, success and
    collisions; the full network's success against each variant's, seed by seed (Holm over all); and the share
    of the full network's change over ``basic`` (study 19's, tuned) that leaving the input out takes away, where
    study 19 finds that change *better* for every seed (elsewhere there is no shown change to share)."""
    folder = out / "ablation"
    variants = {f"{LEARNED}_without_{name}": name for name in INPUTS}
    if runs is not None:
        ablated = _run_comparison(ABLATION_SPEC, folder, args)
        flown = {method: _episodes(ablated / "test.parquet", method) for method in (LEARNED, *variants)}
        rates, comparisons = paired_arms(flown, groups)
        rates.to_csv(folder / "rates.csv", index=False)
        comparisons.to_csv(folder / "comparisons.csv", index=False)
        keys = ["selection", "family", "field"]
        same = (flown[LEARNED].sort_values(keys).reset_index(drop=True)
                .equals(_episodes(runs / "test.parquet")
                        .sort_values(keys).reset_index(drop=True)))
        (folder / "reproduced.json").write_text(json.dumps({"same_episodes": same}) + "\n")
    rates, comparisons = pd.read_csv(folder / "rates.csv"), pd.read_csv(folder / "comparisons.csv")
    selection = pd.read_csv(folder / "selection.csv")
    facts: dict = {"reproduced": json.loads((folder / "reproduced.json").read_text())["same_episodes"],
                   "comparisons": len(comparisons), "arms": {}, "verdict": {}, "all_seeds": {}, "share": {},
                   "change_over_basic": {}}
    for arm, part in rates.groupby("arm"):
        rows = selection[selection["method"] == arm]
        facts["arms"][arm] = {"episodes": int(rows["episodes"].sum()), "seconds": float(rows["seconds"].sum()),
                              "success": {g: float(r["success"].mean()) for g, r in part.groupby("group")},
                              "collision": {g: float(r["collision"].mean()) for g, r in part.groupby("group")}}
    for (arm, group), g in comparisons.groupby(["arm", "group"]):
        facts["verdict"].setdefault(variants[arm], {})[group] = dict(zip(g["seed"], g["verdict"]))
        facts["all_seeds"].setdefault(variants[arm], {})[group] = study.unanimous(g["verdict"])
    full = facts["arms"][LEARNED]["success"]
    vs_basic = pd.read_csv(out / "report" / "comparisons.csv")
    for group in groups:
        change = full[group] - float(np.mean(_tuned(summary, spec, "basic", group, "success_rate")))
        shown = _unanimous(vs_basic, summary, spec, LEARNED, group, "success") == "better"
        facts["change_over_basic"][group] = {"points": change, "shown": shown}
        for arm, name in variants.items():
            drop = full[group] - facts["arms"][arm]["success"][group]
            facts["share"].setdefault(name, {})[group] = drop / change if shown else None
    return ablation_section(facts, groups, variants), facts


def ablation_section(facts: dict, groups: list[str], variants: dict[str, str]) -> str:
    """The ablation's table: per group the full network's success, each variant's with its three verdicts
    (the full network against it), and the full network's change over ``basic``."""
    full = facts["arms"][LEARNED]
    lines = ["## Which input carries what: the ablation", "",
             f"`learned_weight` retrained with one input fed as 0 (`sweeps/{ABLATION_SPEC}`: the same selection "
             f"families, seeds, budget, gradient options and held-out fields). Held-out success in %, mean of the "
             f"three seeds; in brackets the full network's success against the variant's on the same fields, "
             f"seed by seed (*better*: the input carried success; Holm over {facts['comparisons']} comparisons, "
             f"margin {MARGIN:g}). *Over basic*: the full network's success minus study 19's tuned `basic`, in "
             f"points; *share*: the part of it the variant loses, given only where study 19 finds the full network "
             f"*better* than `basic` for every seed (–: no change shown to share).", "",
             "| group | full network | " + " | ".join(f"without {INPUTS[n]}" for n in variants.values())
             + " | over basic | share " + " / ".join(INPUTS[n] for n in variants.values()) + " |",
             "|---|---|" + "---|" * len(variants) + "---|---|"]
    for group in groups:
        cells = [f"{_pct(facts['arms'][arm]['success'][group])} "
                 f"({', '.join(facts['verdict'][name][group][s] for s in SEEDS)})" for arm, name in variants.items()]
        shares = [facts["share"][name][group] for name in variants.values()]
        lines.append(f"| {group} | {_pct(full['success'][group])} | " + " | ".join(cells)
                     + f" | {100 * facts['change_over_basic'][group]['points']:+.1f} | "
                     + " / ".join("–" if x is None else f"{100 * x:.0f} %" for x in shares) + " |")
    lines += ["", "Budgets as realised, over the three seeds: " + ", ".join(
        f"`{arm}` {a['episodes']:,} episode rollouts in {a['seconds']:.0f} s" for arm, a in facts["arms"].items())
        + ". The full network's held-out episodes are study 19's, field by field: "
        + ("yes." if facts["reproduced"] else "**no**.")]
    return "\n".join(lines)


def _pct(x: float) -> str:
    return f"{100 * x:.1f}"


def section(facts: dict, groups: list[str]) -> str:
    """The study's own findings: the learned weight against the paper's, the black box and the ceiling."""
    g, b = facts["arms"]["gradient"], facts["arms"]["sep_cmaes"]
    lines = ["## The learned weight, its black-box control and the ceiling", "",
             f"Held-out success in %, mean of the three selection seeds. `mppi` and `keepout_mpc` are study 17's "
             f"(the same held-out fields, not flown again). *Gap closed*: (learned − paper) / (mppi − paper) "
             f"with both of this study's tuned rates. *vs black box*: the gradient-trained network's success "
             f"against the separable CMA-ES one's on the same fields, the three seeds' verdicts (Holm over "
             f"{facts['comparisons']} comparisons, margin {MARGIN:g}).", "",
             "| group | learned (gradient) | learned (sep. CMA-ES) | vs black box | mppi | keepout_mpc | gap closed |",
             "|---|---|---|---|---|---|---|"]
    for group in groups:
        closed = facts["gap_closed"][group]
        marks = ", ".join(facts["arm_verdict"][group][s] for s in SEEDS)
        ceiling = facts["ceiling"].get(group, {})
        lines.append(f"| {group} | {_pct(g['success'][group])} | {_pct(b['success'][group])} | {marks} | "
                     f"{_pct(ceiling['mppi']) if 'mppi' in ceiling else '–'} | "
                     f"{_pct(ceiling['keepout_mpc']) if 'keepout_mpc' in ceiling else '–'} | "
                     f"{'–' if closed is None else f'{100 * closed:.0f} %'} |")
    lines += ["", f"Budgets as realised: the gradient arm {g['episodes']:,} episode rollouts in {g['seconds']:.0f} s "
                  f"over the three seeds, the black-box arm {b['episodes']:,} in {b['seconds']:.0f} s (budget "
                  f"{g['budget']:,} per seed each).", "",
              "Cost per control step (µs per scenario-step, 64 fields × 100 steps of `dynamic`, interleaved, fastest "
              "of three): " + ", ".join(f"`{k}` {facts['cost_us'][k]:.1f} ({facts['cost_ratio'][k]:.1f}× the "
                                        f"paper's)" for k in COSTED) + ".",
              "", "What each seed's network learned: over the drawn range (cos θ from −1 to 1, closing speed from −3 "
                  "to 3 m/s, d = d_s/2) ω_θ divided by its abeam value spans " + ", ".join(
                      f"{o['learned_min']:.2f}–{o['learned_max']:.2f} ({tag})" for tag, o in facts["omega"].items())
              + "; the paper's ω at its selected γ and k spans " + ", ".join(
                  f"{o['paper_min']:.2f}–{o['paper_max']:.2f} ({tag})" for tag, o in facts["omega"].items()) + ".",
              "", f"![{OMEGA_CAPTION}](omega.png)", "", f"*{OMEGA_CAPTION}*"]
    return "\n".join(lines)


OMEGA_CAPTION = ("Each selection seed's weight over the direction cosine and the closing speed at d = d_s/2, divided "
                 "by its value abeam at zero closing speed (the overall scale trades against k_rep): top the paper's ω "
                 "at the γ and k its random search chose, bottom the learned ω_θ")


def question(facts: dict) -> dict:
    """Can the learned weight beat the paper's? Its pooled success against ``direction_velocity``, every
    selection seed, at study 17's budget and at twice it."""
    verdicts = {f"{s}": facts["verdict"]["paper"]["success"][LEARNED][s] for s in SEEDS}
    verdicts |= {f"twice the budget {s}": v for s, v in facts["twice_budget"]["verdict"]["all"].items()}
    return study.answer_fact(verdicts)


def main() -> None:
    run_benchmark(__doc__, NAME, SPEC, "Study 19 — a weight learned through the closed loop against the paper's",
                  extra=arms, question=question)


if __name__ == "__main__":
    study.entry(main)
