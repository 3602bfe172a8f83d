"""Study 11: every planner, and the CBF safety filter, at its tuned best on the same held-out fields.

``jaxapf compare sweeps/planner-benchmark.toml``: the paper's three weightings, ``vortex``,
``ge_cui_bounded``, ``basic_escape``, ``velocity_obstacle``, and ``basic`` and ``direction_velocity`` under
the CBF filter (``+cbf``). For each of three selection seeds every method's gains (those it reads,
the filter's included) are chosen by a random search with the same budget (16 candidates × 32
training fields = 512 episode rollouts per method and seed); then every method at its defaults and
at each selection flies the same 128 held-out fields of each family (new seed). The report pairs
each setting with ``basic`` of the same selection; a second report pairs it with the paper's
``direction_velocity``. The leaderboard lists the tuned selections' mean over seeds [lowest,
highest]; the figures fly each method at its seed-1 selection on one trap and one overtake field.

    python analysis/planner_benchmark.py     # ~N min on 2 cores: selection, test sweep, two reports, figures
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import numpy as np
import pandas as pd
import study

from jaxapf import stats

STUDY = "planner_benchmark"
SPEC = "planner-benchmark.toml"
PAPER = "direction_velocity"
RATES = ("success", "collision", "stalled")
SEEDS = ("seed1", "seed2", "seed3")
#: The families whose obstacles move (where velocity obstacles are the natural competitor).
MOVING = ("crossing_fast", "head_on_fast", "overtake", "dynamic_fast")


def _rows(summary: pd.DataFrame, spec, method: str, group: str) -> pd.DataFrame:
    from jaxapf.compare.protocol import rows_of

    return rows_of(summary[summary["family"] == group], spec, method).set_index("selection")


def _tuned(summary: pd.DataFrame, spec, method: str, group: str, column: str) -> list[float]:
    rows = _rows(summary, spec, method, group)
    return [float(rows.at[s, column]) for s in SEEDS]


def _cell(values: list[float], scale: float = 100.0, digits: int = 1) -> str:
    finite = [v for v in values if np.isfinite(v)]
    if not finite:
        return "–"
    return f"{scale * np.mean(finite):.{digits}f} [{scale * min(finite):.{digits}f}, {scale * max(finite):.{digits}f}]"


def _verdicts(comparisons: pd.DataFrame, summary: pd.DataFrame, spec, method: str, group: str, metric: str) -> str:
    """The tuned seeds' verdicts, e.g. ``better 3/3`` or ``worse 2/3, inconclusive 1/3``."""
    rows = _rows(summary, spec, method, group)
    ids = {int(rows.at[s, "setting"]) for s in SEEDS}
    c = comparisons[(comparisons["family"] == group) & (comparisons["metric"] == metric)
                    & comparisons["setting"].isin(ids)]
    if not len(c):
        return "–"
    counts = c["verdict"].value_counts()
    return ", ".join(f"{v} {n}/{len(SEEDS)}" for v, n in counts.items())


def _unanimous(comparisons, summary, spec, method, group, metric) -> str | None:
    text = _verdicts(comparisons, summary, spec, method, group, metric)
    for verdict in ("better", "worse", "equivalent"):
        if text == f"{verdict} {len(SEEDS)}/{len(SEEDS)}":
            return verdict
    return None


def leaderboard(spec, summary: pd.DataFrame, vs_basic: pd.DataFrame, vs_paper: pd.DataFrame) -> str:
    from jaxapf.stats import VERDICT_RULE

    groups = [g for g in dict.fromkeys(summary["family"])]
    lines = ["## Leaderboard", "",
             "Per group (family, trap kind, and `all` pooled): each method's held-out rates in % at its tuned "
             "selections, mean over the three selection seeds [lowest, highest]; clearance is the median minimum "
             "clearance [m], time the median time to goal among successes [s] (each method's own successes; the "
             "paired verdicts compare it on the fields where both succeed). *vs basic* and *vs paper*: the three "
             "tuned seeds' verdicts on success (equivalent within the 2 pp margin; " + VERDICT_RULE + "), "
             "each against `basic` resp. `direction_velocity` of the same selection. "
             "Rows are sorted by the mean tuned success.", ""]
    for group in groups:
        rows = []
        for m in spec.methods:
            success = _tuned(summary, spec, m, group, "success_rate")
            rows.append((np.mean(success), {
                "method": f"`{m}`",
                "success": _cell(success),
                "collision": _cell(_tuned(summary, spec, m, group, "collision_rate")),
                "stalled": _cell(_tuned(summary, spec, m, group, "stalled_rate")),
                "clearance": _cell(_tuned(summary, spec, m, group, "min_clearance_median"), 1.0, 2),
                "time to goal": _cell(_tuned(summary, spec, m, group, "time_to_goal_median"), 1.0, 1),
                "vs basic": "–" if m == spec.baseline else _verdicts(vs_basic, summary, spec, m, group, "success"),
                "vs paper": "–" if m == PAPER else _verdicts(vs_paper, summary, spec, m, group, "success"),
            }))
        table = pd.DataFrame([r for _, r in sorted(rows, key=lambda x: -x[0])])
        lines += [f"### {group}", "", "| " + " | ".join(table.columns) + " |", "|---" * len(table.columns) + "|"]
        lines += ["| " + " | ".join(str(v) for v in r) + " |" for r in table.itertuples(index=False)] + [""]
    return "\n".join(lines)


def findings(spec, summary: pd.DataFrame, vs_basic: pd.DataFrame, vs_paper: pd.DataFrame) -> str:
    def mean(m, group, column="success_rate"):
        return float(np.mean(_tuned(summary, spec, m, group, column)))

    families = [g for g in dict.fromkeys(summary["family"]) if "/" not in g and g != "all"]
    kinds = [g for g in dict.fromkeys(summary["family"]) if "/" in g]
    ranking = sorted(spec.methods, key=lambda m: -mean(m, "all"))
    lines = ["## What the data says", "",
             "- Pooled held-out success at the tuned gains ranks the methods "
             + " > ".join(f"`{m}` ({100 * mean(m, 'all'):.1f} %)" for m in ranking) + "."]
    for base, table, name in ((spec.baseline, vs_basic, "`basic`"), (PAPER, vs_paper, f"the paper's `{PAPER}`")):
        for metric in ("success", "collision"):
            verdicts = {v: [m for m in spec.methods if m != base
                            and _unanimous(table, summary, spec, m, "all", metric) == v]
                        for v in ("better", "worse", "equivalent")}
            lines.append(f"- Pooled {metric} against {name}, the same verdict for all three selection seeds: "
                         + "; ".join(f"{v}: " + (", ".join(f"`{m}`" for m in ms) if ms else "none")
                                     for v, ms in verdicts.items()) + ".")
    lines.append("- Best tuned success per family: " + "; ".join(
        f"{g}: `{max(spec.methods, key=lambda m: mean(m, g))}` ({100 * max(mean(m, g) for m in spec.methods):.1f} %,"
        f" `basic` {100 * mean(spec.baseline, g):.1f} %)" for g in families) + ".")
    for kind in kinds:
        best = max(spec.methods, key=lambda m: mean(m, kind))
        above = [m for m in spec.methods if mean(m, kind) > 0.05]
        lines.append(f"- `{kind}`: best `{best}` at {100 * mean(best, kind):.1f} %; methods above 5 %: "
                     + (", ".join(f"`{m}` ({100 * mean(m, kind):.1f} %)" for m in above) if above else "none") + ".")
    filtered = [m for m in spec.methods if m.endswith("+cbf")]
    for m in filtered:
        plain = m.split("+")[0]
        pairs = [f"{g}: {100 * mean(plain, g, 'collision_rate'):.1f} → {100 * mean(m, g, 'collision_rate'):.1f} %"
                 for g in families]
        lines.append(f"- The CBF filter on `{plain}`, collisions per family (tuned means, without → with): "
                     + "; ".join(pairs) + f"; success pooled {100 * mean(plain, 'all'):.1f} → "
                     f"{100 * mean(m, 'all'):.1f} %.")
    vo = "velocity_obstacle"
    if vo in spec.methods:
        moving = [g for g in MOVING if g in families]
        lines.append(f"- `{vo}` against the paper's velocity term on moving obstacles (success / collision, tuned "
                     "means): " + "; ".join(
                         f"{g}: {100 * mean(vo, g):.1f} / {100 * mean(vo, g, 'collision_rate'):.1f} % vs "
                         f"{100 * mean(PAPER, g):.1f} / {100 * mean(PAPER, g, 'collision_rate'):.1f} %"
                         f" ({_verdicts(vs_paper, summary, spec, vo, g, 'success')} on success)"
                         for g in moving) + ".")
    return "\n".join(lines)


def _figure_field(test: pd.DataFrame, spec, family: str) -> int:
    """The lowest-numbered test field of ``family`` on which the methods' outcomes (at their seed-1
    selections) are not all the same: a field that shows a difference, chosen by a stated rule."""
    from jaxapf.compare.protocol import rows_of

    rows = test[(test["family"] == family) & (test["selection"] == "seed1")]
    outcome = {}
    for m in spec.methods:
        mine = rows_of(rows, spec, m).set_index("field")
        outcome[m] = mine["success"].astype(int) + 2 * mine["collision"].astype(int)
    table = pd.DataFrame(outcome)
    differing = table.index[table.nunique(axis=1) > 1]
    return int(differing.min() if len(differing) else table.index.min())


def trajectory_figures(spec, runs, out) -> list[tuple[str, str]]:
    """Each method at its seed-1 selection on one trap and one overtake test field."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxapf import Gains, MPCConfig, SimConfig
    from jaxapf.simulate.episodes import simulate_runs
    from jaxapf.simulate.figures import plot_trajectories
    from jaxapf.sweep import read_sweep

    test, _ = read_sweep(runs / "test.parquet")
    selections = {s["method"]: s["gains"] for s in
                  (json.loads((runs / "selection" / f"{m}-seed1.json").read_text())["selection"] for m in spec.methods)}
    figures = []
    for family in ("trap", "overtake"):
        field_index = _figure_field(test, spec, family)
        params = dict(spec.params.get(family, {}))
        base = params.pop("family", family)
        field, drawn = None, []
        for m in spec.methods:
            settings = spec.settings(m)
            sim = SimConfig.from_flat({**spec.sim, **settings})
            field, (run,), _ = simulate_runs(base, spec.test.seed, field_index, [settings["method"]],
                                             Gains(**selections[m]), sim, MPCConfig(), params)
            drawn.append(dataclasses.replace(run, label=m))
        fig = plot_trajectories(drawn, field)
        path = f"trajectories_{family}.png"
        fig.savefig(out / path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        figures.append((path, _caption(family, field_index)))
    return figures


def _caption(family: str, field_index: int) -> str:
    return (f"Every method at its seed-1 selection on {family} test field {field_index} (the lowest-numbered field "
            "where the outcomes differ)")


def kept_figures(spec, test: pathlib.Path) -> list[tuple[str, str]]:
    """The committed trajectory figures with their captions (the fields they show found again in ``test``)."""
    from jaxapf.sweep import read_sweep

    df, _ = read_sweep(test)
    return [(f"trajectories_{family}.png", _caption(family, _figure_field(df, spec, family)))
            for family in ("trap", "overtake")]


def facts(spec, summary: pd.DataFrame, vs_basic: pd.DataFrame, vs_paper: pd.DataFrame,
          selection: pd.DataFrame) -> dict:
    """The named values the findings and the leaderboard state: per group (family, trap kind, ``all``) and
    method the rates at the defaults (``default``) and the tuned rates' mean over the seeds, pooled the seeds'
    median clearance and time to goal (mean, lowest, highest), and the verdicts against ``basic`` and the
    paper's ``direction_velocity``: per selection pooled (``verdict``), per group at the defaults
    (``default_verdict``: with the same planner gains, ``basic+cbf`` against ``basic`` is the filter alone) and
    the one verdict all three seeds give (``all_seeds``; ``mixed`` where they differ); and per method what its
    selection spent (``selection_spent``: episodes, the fewest over the seeds, and seconds, mean, lowest and
    highest over the seeds; ``selection``: the rows of ``selection.csv``)."""
    groups = list(dict.fromkeys(summary["family"]))
    out: dict = {"methods": len(spec.methods), "seeds": len(SEEDS), "budget": spec.selection.budget,
                 "fields_per_family": spec.test.fields, "default": {}, "verdict": {}, "default_verdict": {},
                 "all_seeds": {}}
    for rate in RATES:
        out[rate] = {g: {m: float(np.mean(_tuned(summary, spec, m, g, f"{rate}_rate"))) for m in spec.methods}
                     for g in groups}
        # the mean over the seeds with its t interval over them: the seeds as a sample of selections
        out[f"{rate}_interval"] = {g: {m: dict(zip(("lo", "hi"), stats.seed_interval(
            _tuned(summary, spec, m, g, f"{rate}_rate"))[1:])) for m in spec.methods} for g in groups}
        out["default"][rate] = {g: {m: float(_rows(summary, spec, m, g).at["default", f"{rate}_rate"])
                                    for m in spec.methods} for g in groups}
    for name, column in (("clearance", "min_clearance_median"), ("time_to_goal", "time_to_goal_median")):
        for m in spec.methods:
            values = _tuned(summary, spec, m, "all", column)
            out.setdefault(name, {})[m] = {"mean": float(np.mean(values)), "min": min(values), "max": max(values)}
    out["methods_stopped"] = {g: sum(out["success"][g][m] == 0 for m in spec.methods) for g in groups}
    out["selection_spent"] = {
        m: {"episodes": int(rows["episodes"].min()),
            "seconds": {k: float(getattr(rows["seconds"], k)()) for k in ("mean", "min", "max")}}
        for m, rows in selection.groupby("method", sort=False)}
    for vs, base, table in (("basic", spec.baseline, vs_basic), ("paper", PAPER, vs_paper)):
        for metric in ("success", "collision", "min_clearance", "time_to_goal"):
            c = table[table["metric"] == metric].set_index(["family", "setting"])["verdict"]
            for g in groups:
                for m in spec.methods:
                    if m == base:
                        continue
                    rows = _rows(summary, spec, m, g)
                    marks = {s: c[(g, int(rows.at[s, "setting"]))] for s in ("default", *SEEDS)}
                    if g == "all":
                        out["verdict"].setdefault(vs, {}).setdefault(metric, {})[m] = marks
                    out["default_verdict"].setdefault(vs, {}).setdefault(metric, {}).setdefault(g, {})[m] = (
                        marks["default"])
                    out["all_seeds"].setdefault(vs, {}).setdefault(metric, {}).setdefault(g, {})[m] = (
                        study.unanimous(marks[s] for s in SEEDS))
    return out


def run_benchmark(doc: str, name: str, spec_file: str, title: str, extra=None, question=None,
                  flags: dict[str, str] | None = None) -> None:
    """Study 11's protocol on ``sweeps/<spec_file>`` into ``analysis/results/<name>``: the comparison, the
    second report against the paper's method, facts, findings, leaderboard and trajectory figures.
    ``extra(out, spec, args, runs)``, if given, returns more ``(sections, facts)`` (``runs``, the comparison's
    folder, is None with ``--facts-only``: from what it committed); ``question(facts)``, if given, the
    study's yes/no question's answer fact (:func:`study.answer_fact`) from the facts; ``flags``, the study's own
    switches (:func:`study.begin`)."""
    from jaxapf.compare.protocol import baseline_filter

    args, out = study.begin(doc, name, flags)
    if args.facts_only:
        from jaxapf.compare.spec import load_compare_spec

        spec = load_compare_spec(study.ROOT / "sweeps" / spec_file)[0]
        report = study.committed_report(out)
        vs_paper = pd.read_csv(out / "report_vs_paper" / "comparisons.csv")
        more = extra(out, spec, args, None)[1] if extra is not None else {}
        found = facts(spec, report.summary, report.comparisons, vs_paper, pd.read_csv(out / "selection.csv")) | more
        study.write_facts(out, found | ({"answer": question(found)} if question is not None else {}))
        return
    if args.from_episodes:  # the reports again from the committed episodes; the trajectory figures kept
        spec, runs, test = study.rebuild_comparison(args, out, spec_file), None, out / "episodes.parquet"
    else:
        spec, runs = study.run_compare_study(args, out, spec_file)
        test = runs / "test.parquet"
    paper = dataclasses.replace(spec, baseline=PAPER)
    vs_paper = study.report(test, out, resamples=args.resamples, folder="report_vs_paper",
                            baseline=baseline_filter(paper), pair_on=("selection",), heatmap=None).comparisons
    summary = pd.read_csv(out / "report" / "summary.csv")
    vs_basic = pd.read_csv(out / "report" / "comparisons.csv")
    sections = ["Budgets, selected gains and every verdict against `basic` seed by seed: [`compare.md`](compare.md); "
                "the full reports: [`report/report.md`](report/report.md) (against `basic`) and "
                "[`report_vs_paper/report.md`](report_vs_paper/report.md) (against `direction_velocity`).",
                findings(spec, summary, vs_basic, vs_paper), leaderboard(spec, summary, vs_basic, vs_paper)]
    more_sections, more = extra(out, spec, args, runs) if extra is not None else ([], {})
    found = facts(spec, summary, vs_basic, vs_paper, pd.read_csv(out / "selection.csv")) | more
    study.write_facts(out, found | ({"answer": question(found)} if question is not None else {}))
    command = study.command_line(name, args, flags)
    figures = trajectory_figures(spec, runs, out) if runs is not None else kept_figures(spec, test)
    study.write_readme(out, title, command, test, sections + more_sections, figures + [study.RATES_FIGURE])
    print(f"wrote {out}/README.md")


def main() -> None:
    run_benchmark(__doc__, STUDY, SPEC, "Study 11 — every planner and the CBF filter at its tuned best")


if __name__ == "__main__":
    study.entry(main)
