"""Study 8: the paper's weights each at its tuned best, under equal budgets, on held-out fields.

``jaxapf compare sweeps/tuned-comparison.toml``: for each of three selection seeds, every method's
gains (those it reads of k_rep, d_s, k_att, η, γ, k) are chosen by a random search with the same
budget (32 candidates × 64 training fields = 2,048 episode rollouts per method and seed); then every
method at its defaults and at each selection flies the same 256 held-out fields of each test family
(new seed; three families and variants the selection never saw), paired against ``basic`` of the
same selection. docs/compare.md describes the protocol.

    python analysis/tuned_comparison.py       # ~6 min: selection ~1.5 min, test sweep ~3.5 min, report
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import study

from jaxapf import stats

STUDY = "tuned_comparison"
SPEC = "tuned-comparison.toml"
METRICS = ("success", "collision", "stalled")


def _tuned(summary: pd.DataFrame, group: str, method: str, metric: str) -> tuple[float, list[float]]:
    rows = summary[(summary["family"] == group) & (summary["method"] == method)].set_index("selection")
    seeds = [s for s in rows.index if s != "default"]
    return float(rows.at["default", f"{metric}_rate"]), [float(rows.at[s, f"{metric}_rate"]) for s in seeds]


def findings(spec, summary: pd.DataFrame, comparisons: pd.DataFrame) -> str:
    from jaxapf.stats import VERDICT_RULE

    methods, base = spec.methods, spec.baseline
    groups = [g for g in dict.fromkeys(summary["family"]) if "/" not in g]
    lines = ["## Does tuning help, and does it change the ranking?", "",
             "Pooled over the test families (`all`): rate in % at the defaults, and the mean over the three "
             "selection seeds [lowest, highest] at the tuned gains.", "",
             "| method | " + " | ".join(f"{m} default | {m} tuned" for m in METRICS) + " |",
             "|---|" + "---|" * (2 * len(METRICS))]
    gains = {}
    for m in methods:
        cells = []
        for metric in METRICS:
            default, tuned = _tuned(summary, "all", m, metric)
            cells += [f"{100 * default:.1f}", f"{100 * np.mean(tuned):.1f} [{100 * min(tuned):.1f}, "
                                              f"{100 * max(tuned):.1f}]"]
            if metric == "success":
                gains[m] = (default, tuned)
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    by_default = sorted(methods, key=lambda m: -gains[m][0])
    by_tuned = sorted(methods, key=lambda m: -np.mean(gains[m][1]))
    lines += ["", "## Verdicts against `basic`, seed by seed", "",
              "For every test family (and pooled), the verdicts of each method against `basic` of the same "
              "selection on success, collision and stall rates: *better*, *worse*, *equivalent* within the "
              "2 pp margin, *inconclusive* (" + VERDICT_RULE + "). A cell lists the defaults' verdict, then "
              "the three tuned seeds'.", "",
              "| group | " + " | ".join(f"{m}: {metric}" for m in methods if m != base for metric in METRICS) + " |",
              "|---|" + "---|" * (len(METRICS) * (len(methods) - 1))]
    consistent, contradicted = [], []
    label = summary.groupby("setting")[["method", "selection"]].first()
    for group in groups:
        cells = []
        for m in methods:
            if m == base:
                continue
            for metric in METRICS:
                c = comparisons[(comparisons["family"] == group) & (comparisons["metric"] == metric)]
                verdict = {label.at[s, "selection"]: v for s, v in zip(c["setting"], c["verdict"])
                           if label.at[s, "method"] == m}
                tuned = [verdict[f"seed{s}"] for s in spec.selection.seeds]
                cells.append(f"{verdict['default']} / " + ", ".join(tuned))
                if len(set(tuned)) == 1 and tuned[0] in ("better", "worse"):
                    consistent.append(f"`{m}` {tuned[0]} on {metric} ({group})")
                if "better" in tuned and "worse" in tuned:
                    contradicted.append(f"`{m}` on {metric} ({group})")
        lines.append(f"| {group} | " + " | ".join(cells) + " |")
    lines += ["", "## What the data says", ""]
    lines.append("- Pooled success at the defaults ranks the methods " + " > ".join(f"`{m}`" for m in by_default)
                 + "; at the tuned gains (mean over seeds) " + " > ".join(f"`{m}`" for m in by_tuned) + ".")
    for m in methods:
        default, tuned = gains[m]
        change, lo, hi = (round(100 * (x - default), 1) + 0.0 for x in (np.mean(tuned), min(tuned), max(tuned)))
        lines.append(f"- Tuning `{m}` changes its pooled held-out success by {change:+.1f} pp on average over the "
                     f"seeds ({lo:+.1f} to {hi:+.1f} pp).")
    lines.append("- Differences to `basic` that hold for all three selection seeds (the same relevant verdict each "
                 "time): " + ("; ".join(consistent) if consistent else "none") + ".")
    lines.append("- Differences whose sign flips between selection seeds (better for one, worse for another): "
                 + ("; ".join(contradicted) if contradicted else "none") + ".")
    spread = max(100 * (max(t) - min(t)) for _, t in gains.values())
    lines += ["", f"The pooled held-out success of one method moves by up to {spread:.1f} pp between selection seeds "
              "with the same budget: a conclusion drawn from one selection must survive that spread, which is why "
              "the protocol repeats it."]
    return "\n".join(lines)


def facts(spec, summary: pd.DataFrame, comparisons: pd.DataFrame) -> dict:
    """The named values the findings state: per rate and method the pooled held-out rate at the defaults and
    at each seed's selection (mean, lowest, highest), the seeds' largest spread, every verdict against
    ``basic`` per group, method, rate and selection, and how often the three seeds agree on one."""
    methods = [m for m in spec.methods if m != spec.baseline]
    seeds = [f"seed{s}" for s in spec.selection.seeds]
    groups = [g for g in dict.fromkeys(summary["family"]) if "/" not in g]
    rates: dict = {}
    for metric in METRICS:
        for m in spec.methods:
            default, per_seed = _tuned(summary, "all", m, metric)
            _, lo, hi = stats.seed_interval(per_seed)  # the seeds as a sample of selections
            rates.setdefault(metric, {})[m] = {"default": default, "mean": float(np.mean(per_seed)), "mean_lo": lo,
                                               "mean_hi": hi, "min": min(per_seed), "max": max(per_seed),
                                               **dict(zip(seeds, per_seed))}
    spread = {m: r["max"] - r["min"] for m, r in rates["success"].items()}
    label = summary.groupby("setting")[["method", "selection"]].first()
    verdict: dict = {}
    for c in comparisons[comparisons["metric"].isin(METRICS) & comparisons["family"].isin(groups)].itertuples():
        m, selection = label.at[c.setting, "method"], label.at[c.setting, "selection"]
        verdict.setdefault(c.family, {}).setdefault(m, {}).setdefault(c.metric, {})[selection] = c.verdict
    tuned = {(g, m, metric): {verdict[g][m][metric][s] for s in seeds}
             for g in groups for m in methods for metric in METRICS}
    agree = {key: next(iter(v)) if len(v) == 1 else "mixed" for key, v in tuned.items()}
    seeds_agree: dict = {}
    for (g, m, metric), v in agree.items():
        seeds_agree.setdefault(g, {}).setdefault(m, {})[metric] = v
    cells = list(agree.values())
    return {"methods": len(spec.methods), "seeds": len(seeds), "groups": len(groups),
            "budget": spec.selection.budget, "fields_per_family": spec.test.fields, **rates,
            "tuning_change": {m: {k: r[k] - r["default"] for k in ("mean", "min", "max")}
                              for m, r in rates["success"].items()},
            "spread": {"max": max(spread.values()), "method": max(spread, key=spread.get), **spread},
            "verdict": verdict, "all_seeds": seeds_agree,
            "answer": study.answer_fact({f"{m} {s}": verdict["all"][m]["success"][s] for m in methods for s in seeds}),
            "all_seeds_count": {"cells": len(cells), "flips": sum({"better", "worse"} <= v for v in tuned.values()),
                                **{v: cells.count(v) for v in ("better", "worse", "equivalent", "inconclusive")}}}


def main() -> None:
    args, out = study.begin(__doc__, STUDY)
    if args.facts_only:
        from jaxapf.compare.spec import load_compare_spec

        report = study.committed_report(out)
        study.write_facts(out, facts(load_compare_spec(study.ROOT / "sweeps" / SPEC)[0], report.summary,
                                     report.comparisons))
        return
    if args.from_episodes:
        spec, test = study.rebuild_comparison(args, out, SPEC), out / "episodes.parquet"
    else:
        spec, runs = study.run_compare_study(args, out, SPEC)
        test = runs / "test.parquet"
    summary = pd.read_csv(out / "report" / "summary.csv")
    comparisons = pd.read_csv(out / "report" / "comparisons.csv")
    study.write_facts(out, facts(spec, summary, comparisons))
    sections = ["Budgets, selected gains, the test rates of every selection and every verdict seed by seed: "
                "[`compare.md`](compare.md); the full report of the test: [`report/report.md`](report/report.md).",
                findings(spec, summary, comparisons)]
    command = "python analysis/tuned_comparison.py" + (f" --fields {args.fields}" if args.fields else "") + (
        " --from-episodes" if args.from_episodes else "")
    study.write_readme(out, "Study 8 — each method at its tuned best, under equal budgets", command, test, sections,
                       [study.RATES_FIGURE])
    print(f"wrote {out}/README.md")


if __name__ == "__main__":
    study.entry(main)
