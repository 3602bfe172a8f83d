"""Study 16: which planners deadlock or collide as the swarm grows, and what reciprocity buys.

Every method of study 11 (the planner benchmark: the paper's three, ``vortex``, ``ge_cui_bounded``,
``basic_escape``, ``velocity_obstacle``, and the CBF filter on ``basic`` and ``direction_velocity``)
flies at its tuned best: the gains each of its three random searches (selection seeds 1, 2, 3, equal
budgets, ``analysis/results/planner_benchmark/selection.csv``) chose for a UAV flying alone. To them
comes ``velocity_obstacle_unilateral``, ``velocity_obstacle`` without ORCA's reciprocity (each UAV
takes the whole avoidance, as against a passive obstacle), at ``velocity_obstacle``'s selections: the
two differ in nothing else, so their paired difference is what reciprocity buys.

Every UAV of a swarm flies the same stack and sees its 8 nearest neighbours (``max_neighbours = 8``,
RVO2's ``maxNeighbors``) as obstacles of radius ``r_uav``. Swarms of A = 2, 4, 8, 16 and 32 UAVs fly
held-out fields (seed 300, 64 per family and A) of the four swarm families, every method on each:
``circle_swap``, ``crossing_flows`` (two flows), ``formation_gap`` (formation columns: min(4, A)) and
``swarm_clutter``. The CBF filter and the velocity obstacles solve an exact projection every step whose
work grows with the fourth power of its rows (:mod:`jaxapf.projection`); among the 24 obstacle slots and
8 neighbours of the last two families they solve with a few rows at a time (``sim.projection_rows``: 8
for the CBF filter, 16 for the velocity obstacles; on the open families, at most 8 neighbours and a padded
slot, every row): those that bind soonest, then, while a row left out is violated at the answer, the rows
active there and the most violated, and once twice the rows if that cycles. Every UAV-step whose answer
a row left out still violates is counted (``truncated_steps``: ``cbf_truncated_steps`` plus
``vo_truncated_steps``). A method whose projections on a family were not all certified exact is flown
and its count reported, but it is left out of that family's tables and comparisons: its answers were
not the method's.

Verdicts (:func:`jaxapf.stats.decide`, the verdict function every study uses: exact McNemar and TOST
within the metric's margin, 2 points), paired on the same fields, per (family, A, selection seed): every
method against ``basic`` at the same selection seed, and ``velocity_obstacle`` against
``velocity_obstacle_unilateral``, on the swarm's success (every UAV at its goal), a collision between two
UAVs and deadlock; Holm within each question's declared families (success and collision primary, deadlock
exploratory), each interval at the level that decided its verdict.

    python analysis/swarm_study.py     # cached per cell under runs/swarm-study-fN/ (the 40 cells with a
                                       # projection among obstacles: 77 min on 2 cores)
"""

from __future__ import annotations

import pathlib

import numpy as np
import pandas as pd
import robustness
import study

STUDY = "swarm_study"
FIELDS, SEED = 64, 300
AGENTS = (2, 4, 8, 16, 32)
NEIGHBOURS = 8
#: The methods of study 11 and the unilateral velocity obstacles (``velocity_obstacle``'s selections).
UNILATERAL = "velocity_obstacle_unilateral"
#: The rows each exact projection keeps among obstacles (``sim.projection_rows``); the other methods solve none.
ROWS = {"velocity_obstacle": 16, UNILATERAL: 16, "basic+cbf": 8, "direction_velocity+cbf": 8}
FAMILIES = ("circle_swap", "crossing_flows", "formation_gap", "swarm_clutter")
#: The families with obstacles, where the projections keep :data:`ROWS` rows (elsewhere every row).
CLUTTERED = ("formation_gap", "swarm_clutter")
#: The outcomes compared, each with its direction (higher is better?).
OUTCOMES = (("swarm_success", True), ("agent_collision", False), ("deadlock", False))
MARK = {"worse": "↓", "better": "↑", "equivalent": "=", "inconclusive": "·"}
#: The per-swarm columns the pages and facts read, kept as ``episodes.parquet`` (``--from-episodes``).
READ = ("method", "family", "agents", "seed", "field", *(m for m, _ in OUTCOMES), "at_goal", "min_agent_clearance",
        "truncated_steps")


def methods() -> list[str]:
    return list(dict.fromkeys(robustness.selections()["method"])) + [UNILATERAL]


def tuned(method: str, seed: int, source: pathlib.Path = robustness.SELECTION) -> dict[str, float]:
    """The gains study 11's selection (or ``source``'s) with ``seed`` chose for ``method``
    (``velocity_obstacle``'s for the unilateral variant)."""
    return robustness.tuned_gains("velocity_obstacle" if method == UNILATERAL else method, seed, source)


def params(family: str, agents: int):
    from jaxapf.scenarios.swarms import swarm_params

    return swarm_params(family, agents=agents, **({"columns": min(4, agents)} if family == "formation_gap" else {}))


def cell(method: str, family: str, agents: int, count: int, tracking: str = "mpc",
         tau: float | None = None, neighbours: int = NEIGHBOURS,
         source: pathlib.Path = robustness.SELECTION) -> pd.DataFrame:
    """One row per (selection seed, field) of ``method`` on ``count`` fields of ``family`` with ``agents``
    UAVs: the swarm metrics (one :func:`~jaxapf.engine.swarm.evaluate_swarms` call, the seeds as settings).
    ``tracking``, ``tau`` (the velocity obstacles' ``vo_tau`` in place of the selections') and ``neighbours``
    serve the reciprocity ablation (``reciprocity_ablation.py``); ``source``: the ``selection.csv`` the gains
    come from (study 11's by default)."""
    import jax

    from jaxapf import Gains
    from jaxapf.config import MPCConfig, SimConfig
    from jaxapf.engine.swarm import evaluate_swarms
    from jaxapf.scenarios.swarms import make_swarms

    planner, _, safety = method.partition("+")
    p = params(family, agents)
    crowded = family in CLUTTERED or neighbours > NEIGHBOURS
    sim = SimConfig.from_flat(method=planner, filter=safety or "none", t_max=p.t_max, max_neighbours=neighbours,
                              projection_rows=ROWS.get(method, 0) if crowded else 0, tracking=tracking)
    seeds = robustness.seeds()
    chosen = [tuned(method, s, source) | ({"vo_tau": tau} if tau is not None else {}) for s in seeds]
    gains = jax.tree_util.tree_map(lambda *x: np.asarray(x, np.float32), *[Gains(**g) for g in chosen])
    metrics = jax.device_get(evaluate_swarms(make_swarms(SEED, p, count), gains, sim, MPCConfig(),
                                             max(1, 2048 // agents)))
    frames = [pd.DataFrame({k: np.asarray(v[i]) for k, v in metrics.items()}).assign(seed=s, field=np.arange(count))
              for i, s in enumerate(seeds)]
    df = pd.concat(frames, ignore_index=True).assign(method=method, family=family, agents=agents)
    return df.assign(truncated_steps=df["cbf_truncated_steps"] + df["vo_truncated_steps"])


def run(count: int, cache: pathlib.Path) -> pd.DataFrame:
    """Every cell, each cached in ``cache`` as soon as it is done (a rerun computes only what is missing;
    the missing ones smallest swarm first)."""
    cache.mkdir(parents=True, exist_ok=True)
    cells = [(family, agents, method) for family in FAMILIES for agents in AGENTS for method in methods()]
    path = {c: cache / f"{c[0]}-a{c[1]:02d}-{c[2].replace('+', '_')}.parquet" for c in cells}
    for family, agents, method in sorted((c for c in cells if not path[c].exists()), key=lambda c: c[1]):
        cell(method, family, agents, count).to_parquet(path[family, agents, method], index=False)
        print(f"  {family} A={agents} {method}: done", flush=True)
    # cells flown before ``truncated_steps`` existed kept every row: none was truncated
    return pd.concat([pd.read_parquet(path[c]) for c in cells], ignore_index=True).fillna({"truncated_steps": 0})


def paired(now: pd.DataFrame, then: pd.DataFrame) -> list[dict]:
    """The paired comparison of ``now`` against ``then`` (same fields) on every outcome, ready for
    :func:`verdicts`."""
    from jaxapf.metrics import SWARM_METRICS
    from jaxapf.stats import RatePairs

    rows = []
    for metric, up in OUTCOMES:
        r = RatePairs.of(now[metric].to_numpy(bool), then[metric].to_numpy(bool))
        rows.append({"metric": metric, "higher_is_better": up, "change": r.estimate, "b": r.b, "c": r.c,
                     "n_pairs": r.n, "margin": SWARM_METRICS.get(metric).margin})
    return rows


def verdicts(comparisons: pd.DataFrame) -> pd.DataFrame:
    """``comparisons`` (rows of :func:`paired` with a ``question``; or committed rows, with ``n`` pairs, whose
    counts :func:`study.rederive` finds again) with their verdicts: Holm within each question's primary family
    (swarm success and collision between UAVs) and, exploratory, within each of its other outcomes."""
    primary = {m for m, _ in OUTCOMES[:2]}
    family = [f"{q}: primary" if m in primary else f"{q}: exploratory {m}"
              for q, m in zip(comparisons["question"], comparisons["metric"])]
    return study.rederive(comparisons, comparisons["margin"], family, comparisons["higher_is_better"]).drop(
        columns=["n"], errors="ignore")


def committed_tables(folder: pathlib.Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``folder``'s committed ``rates.csv`` and ``comparisons.csv``, the verdicts derived again by :func:`verdicts`
    (a table committed before it kept the counts gets ``n`` from the rates) and written back."""
    rates, comparisons = pd.read_csv(folder / "rates.csv"), pd.read_csv(folder / "comparisons.csv")
    if "b" not in comparisons.columns:
        n = rates.set_index(["method", "family", "agents", "seed"])["n"]
        comparisons["n"] = [int(n[k]) for k in zip(comparisons["method"], comparisons["family"],
                                                      comparisons["agents"], comparisons["seed"])]
    comparisons = verdicts(comparisons)
    comparisons.to_csv(folder / "comparisons.csv", index=False)
    return rates, comparisons


def summarise(df: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(rates, comparisons)``: per (method, family, A, seed) every outcome's rate with its Wilson interval;
    and every paired comparison (method vs ``basic``, reciprocal vs unilateral) with its verdict
    (:func:`verdicts`: Holm within each question's families)."""
    from jaxapf.stats import rate_row

    rates = []
    key = ["method", "family", "agents", "seed"]
    for (method, family, agents, seed), g in df.groupby(key, sort=False):
        row = {"method": method, "family": family, "agents": agents, "seed": seed, "n": len(g),
               "at_goal": float(g["at_goal"].mean()), "min_agent_clearance": float(g["min_agent_clearance"].median())}
        for metric, _ in OUTCOMES:
            r = rate_row(g[metric].to_numpy())
            row |= {metric: r.rate, f"{metric}_lo": r.lo, f"{metric}_hi": r.hi}
        rates.append(row)
    by = df.set_index(key + ["field"]).sort_index()
    comparisons = []
    for method, family, agents, seed in df[key].drop_duplicates().itertuples(index=False):
        against = [("basic", "vs basic")] if method != "basic" else []
        if method == "velocity_obstacle":
            against.append((UNILATERAL, "reciprocity"))
        for base, question in against:
            if (base, family, agents, seed) not in by.index.droplevel("field"):
                continue
            then = by.loc[(base, family, agents, seed)]
            now = by.loc[(method, family, agents, seed)]
            for r in paired(now, then):
                comparisons.append({"method": method, "baseline": base, "question": question, "family": family,
                                    "agents": agents, "seed": seed} | r)
    comparisons = verdicts(pd.DataFrame(comparisons))
    return pd.DataFrame(rates), comparisons


def rate_table(rates: pd.DataFrame, comparisons: pd.DataFrame, family: str, metric: str) -> str:
    """Markdown: ``metric`` in % per method (rows) and A (columns), mean over the selection seeds [min, max],
    with the seeds' verdict marks against ``basic``."""
    part = rates[rates["family"] == family]
    marks = comparisons[(comparisons["family"] == family) & (comparisons["metric"] == metric)
                        & (comparisons["question"] == "vs basic")]
    lines = ["| method | " + " | ".join(f"A = {a}" for a in AGENTS) + " |", "|---|" + "---|" * len(AGENTS)]
    for method in dict.fromkeys(part["method"]):
        cells = []
        for a in AGENTS:
            v = part[(part["method"] == method) & (part["agents"] == a)].sort_values("seed")[metric]
            m = marks[(marks["method"] == method) & (marks["agents"] == a)].sort_values("seed")["verdict"]
            tag = f" {''.join(MARK[x] for x in m)}" if len(m) else ""
            cells.append(f"{100 * v.mean():.1f} [{100 * v.min():.0f}, {100 * v.max():.0f}]{tag}")
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def reciprocity_table(rates: pd.DataFrame, comparisons: pd.DataFrame) -> str:
    """Markdown: per family and A, each outcome of the reciprocal and the unilateral velocity obstacles
    (mean over the seeds) and the seeds' verdicts of reciprocal against unilateral."""
    lines = ["| family | A | " + " | ".join(f"{m}: reciprocal / unilateral, verdicts" for m, _ in OUTCOMES) + " |",
             "|---|---|" + "---|" * len(OUTCOMES)]
    rec = comparisons[comparisons["question"] == "reciprocity"]
    mean = rates.groupby(["method", "family", "agents"])[[m for m, _ in OUTCOMES]].mean()
    for family in FAMILIES:
        for a in AGENTS:
            cells = []
            for metric, _ in OUTCOMES:
                marks = rec[(rec["family"] == family) & (rec["agents"] == a) & (rec["metric"] == metric)]
                marks = "".join(MARK[v] for v in marks.sort_values("seed")["verdict"])
                cells.append(f"{100 * mean.loc[('velocity_obstacle', family, a), metric]:.1f} / "
                             f"{100 * mean.loc[(UNILATERAL, family, a), metric]:.1f} {marks}")
            lines.append(f"| {family} | {a} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def truncation(df: pd.DataFrame) -> dict:
    """Per method that keeps rows (:data:`ROWS`) and family with obstacles: the UAV-steps not certified exact
    and the swarm episodes holding any, of how many."""
    part = df[df["method"].isin(list(ROWS)) & df["family"].isin(CLUTTERED)]
    return {f"{m}/{f}": {"uav_steps": int(g["truncated_steps"].sum()),
                         "episodes": int((g["truncated_steps"] > 0).sum()), "of": len(g)}
            for (m, f), g in part.groupby(["method", "family"], sort=False)}


def exact(df: pd.DataFrame) -> pd.Series:
    """Whether each row's (method, family) had every projection certified exact (module docstring)."""
    return df.groupby(["method", "family"])["truncated_steps"].transform("sum") == 0


def facts(df: pd.DataFrame | None, rates: pd.DataFrame, comparisons: pd.DataFrame) -> dict:
    """The numbers the README and the project README quote (``facts.json``)."""
    mean = rates.groupby(["method", "family", "agents"])[[m for m, _ in OUTCOMES]].mean()
    out = {"comparisons": int(len(comparisons)),
           "verdicts": {v: int((comparisons["verdict"] == v).sum()) for v in MARK}}
    for metric, _ in OUTCOMES:
        out[metric] = {f"{m}/{f}/{a}": round(100 * float(v), 1) for (m, f, a), v in mean[metric].items()}
    rec = comparisons[comparisons["question"] == "reciprocity"]
    out["reciprocity_verdicts"] = {f"{m}/{v}": int(((rec["metric"] == m) & (rec["verdict"] == v)).sum())
                                   for m, _ in OUTCOMES for v in MARK}
    if df is not None:  # the per-swarm rows; --facts-only (tables only) keeps the committed facts' count
        out["truncated_steps"] = truncation(df)
    vs = comparisons[comparisons["question"] == "vs basic"]
    out["vs_basic_verdicts"] = {f"{m}/{v}": int(((vs["metric"] == m) & (vs["verdict"] == v)).sum())
                                for m, _ in OUTCOMES for v in MARK}
    return out | {"setting": setting()} | totals(out)


def totals(out: dict) -> dict:
    """How many comparisons of each outcome each question made (the sum of its verdict counts)."""
    return {f"{question}_comparisons": {m: sum(n for k, n in out[f"{question}_verdicts"].items()
                                              if k.startswith(f"{m}/")) for m, _ in OUTCOMES}
            for question in ("reciprocity", "vs_basic")}


def setting() -> dict:
    """The protocol's numbers: swarm sizes, neighbours seen, held-out fields, the rows each projection keeps."""
    return {"agents": list(AGENTS), "neighbours": NEIGHBOURS, "fields": FIELDS, "rows": dict(ROWS)}


def findings(df: pd.DataFrame, rates: pd.DataFrame, comparisons: pd.DataFrame) -> list[str]:
    """Sentences computed from the tables: who keeps the swarm whole as it grows, who collides, who
    deadlocks, and what reciprocity changes."""
    mean = rates.groupby(["method", "family", "agents"])[[m for m, _ in OUTCOMES]].mean()
    out = []
    for family in FAMILIES:
        at = mean.xs(family, level="family")
        big = max(AGENTS)
        top = at.xs(big, level="agents")
        small = at.xs(min(AGENTS), level="agents")

        def most(metric: str, top: pd.DataFrame = top) -> str:
            return f" (most: `{top[metric].idxmax()}`)" if top[metric].max() > 0 else ""

        best = top["swarm_success"].idxmax()
        out.append(
            f"**{family}**: from A = {min(AGENTS)} to A = {big}, swarm success (mean over the three selections) "
            f"goes from {100 * small['swarm_success'].min():.1f}–{100 * small['swarm_success'].max():.1f} % to "
            f"{100 * top['swarm_success'].min():.1f}–{100 * top['swarm_success'].max():.1f} % across the methods "
            f"(highest at A = {big}: `{best}`, {100 * top.loc[best, 'swarm_success']:.1f} %); two UAVs collide in "
            f"{100 * top['agent_collision'].min():.1f}–{100 * top['agent_collision'].max():.1f} % of the swarms"
            f"{most('agent_collision')}, and {100 * top['deadlock'].min():.1f}–{100 * top['deadlock'].max():.1f} % "
            f"deadlock{most('deadlock')}.")
    cut = truncation(df)
    out.append("**Exact projections among obstacles**: UAV-steps whose answer a row left out violated "
               "(`truncated_steps`), per method and family: "
               + "; ".join(f"`{k}` {t['uav_steps']:,} (in {t['episodes']} of {t['of']} swarms)" for k, t in cut.items())
               + ". " + ("Left out of the tables and comparisons, not being the methods' answers: "
                         + ", ".join(f"`{k}`" for k, t in cut.items() if t["uav_steps"]) + "."
                         if any(t["uav_steps"] for t in cut.values()) else "Every one was exact."))
    for question in ("vs basic", "reciprocity"):
        part = comparisons[comparisons["question"] == question]
        for metric, _ in OUTCOMES:
            r = part[part["metric"] == metric]
            n = {v: int((r["verdict"] == v).sum()) for v in MARK}
            counts = (f"better {n['better']}, worse {n['worse']}, equivalent {n['equivalent']}, "
                      f"inconclusive {n['inconclusive']}.")
            if question == "vs basic":
                out.append(f"**Against `basic`, {metric}** (each method at the same selection seed, every family and "
                           f"A): {len(r)} comparisons, {counts}")
            else:
                change = 100 * r["change"]
                out.append(f"**Reciprocity, {metric}**: `velocity_obstacle` against `{UNILATERAL}` over {len(r)} "
                           f"(family, A, selection) cells: change {change.min():+.1f} to {change.max():+.1f} points; "
                           f"{counts}")
    return out


def figure(rates: pd.DataFrame, path: pathlib.Path) -> None:
    """Swarm success, UAV–UAV collision and deadlock against A, one column per family: the mean over the
    three selections, the bar spanning their min to max."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    palette = plt.get_cmap("tab10").colors
    names = list(dict.fromkeys(rates["method"]))
    colors = {m: palette[i % len(palette)] for i, m in enumerate(names)}
    fig, axes = plt.subplots(len(OUTCOMES), len(FAMILIES), figsize=(4.2 * len(FAMILIES), 3.2 * len(OUTCOMES) + 1.2),
                             sharex=True, sharey="row", squeeze=False)
    for col, family in enumerate(FAMILIES):
        for row, (metric, _) in enumerate(OUTCOMES):
            ax = axes[row, col]
            part = rates[rates["family"] == family]
            for i, method in enumerate(dict.fromkeys(part["method"])):
                g = part[part["method"] == method].groupby("agents")[metric].agg(["mean", "min", "max"])
                x = np.log2(g.index.to_numpy()) + 0.03 * (i - len(names) / 2)
                ax.errorbar(x, 100 * g["mean"], yerr=[100 * (g["mean"] - g["min"]), 100 * (g["max"] - g["mean"])],
                            color=colors[method], linestyle="--" if "+" in method or method == UNILATERAL else "-",
                            marker="o", ms=3, lw=1, capsize=1.5, label=method)
            ax.set_xticks(np.log2(AGENTS), [str(a) for a in AGENTS])
            ax.grid(True, linewidth=0.4, alpha=0.5)
            if row == 0:
                ax.set_title(family)
            if row == len(OUTCOMES) - 1:
                ax.set_xlabel("UAVs in the swarm (A)")
            if col == 0:
                ax.set_ylabel(f"{metric} [%]")
    handles = [plt.Line2D([], [], color=colors[m], linestyle="--" if "+" in m or m == UNILATERAL else "-", marker="o",
                          ms=3, label=m) for m in names]
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> None:
    args, out = study.begin(__doc__, STUDY)
    if args.facts_only:  # the verdicts derived again from the tables' counts, joining the committed facts
        import json

        committed = json.loads((out / "facts.json").read_text())
        rates, comparisons = committed_tables(out)
        found = {k: v for k, v in facts(None, rates, comparisons).items() if k != "truncated_steps"}
        study.write_facts(out, committed | found)
        return
    if args.from_episodes:
        flown = study.kept_rows(out)
        count = int(flown.groupby(["method", "family", "agents", "seed"]).size().max())
    else:
        count = args.fields or FIELDS
        flown = run(count, study.ROOT / "runs" / f"swarm-study-f{count}")
        study.keep_rows(flown, out, READ)
    df = flown[exact(flown)]
    rates, comparisons = summarise(df)
    rates.to_csv(out / "rates.csv", index=False)
    comparisons.to_csv(out / "comparisons.csv", index=False)
    figure(rates, out / "swarm_study.png")
    from jaxapf.stats import VERDICT_RULE

    lines = [f"# Study 16: swarms of 2 to 32 UAVs ({count} held-out fields per family, A and selection)", "",
             "`python analysis/swarm_study.py` (" + __doc__.split("\n")[0] + ")", "",
             "Protocol: " + " ".join(__doc__.split("\n\n")[1:4]).replace("\n", " ").replace("``", "`")
             .replace(":func:", "").replace(":mod:", ""), "",
             f"{len(comparisons)} paired comparisons; {VERDICT_RULE}.", "", "## Findings", ""]
    found = findings(flown, rates, comparisons)
    lines += [f"- {line}" for line in found]
    for metric, _ in OUTCOMES:
        lines += ["", f"## {metric} [%]: mean over the three selections [min, max]; the selections' verdicts "
                      "against `basic` in seed order (↑ better, ↓ worse, = equivalent, · inconclusive)", ""]
        for family in FAMILIES:
            lines += [f"### {family}", "", rate_table(rates, comparisons, family, metric), ""]
    lines += ["## What reciprocity buys: `velocity_obstacle` (ORCA's ½) / `velocity_obstacle_unilateral` [%], and "
              "the selections' verdicts of reciprocal against unilateral", "", reciprocity_table(rates, comparisons),
              "", "![swarm success, UAV-UAV collision and deadlock against A](swarm_study.png)", "",
              "`rates.csv`: per method, family, A and selection every outcome's rate with its Wilson interval, the "
              "mean fraction of UAVs at their goals and the median closest approach between UAVs; `comparisons.csv`: "
              "every paired comparison with its interval, raw and Holm-adjusted p-values and verdict; "
              "`episodes.parquet`: every swarm's outcomes (`--from-episodes` rebuilds this page from them)."]
    study.write_results(out, lines, facts(flown, rates, comparisons))
    print("\n".join(found))


if __name__ == "__main__":
    study.entry(main)
