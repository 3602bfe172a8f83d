"""Study 16's ablation: does ORCA's reciprocity fail through the MPC's tracking or through its time horizon?

Study 16 found ``velocity_obstacle`` (ORCA: each UAV takes half of the avoidance of another UAV) no better
than ``velocity_obstacle_unilateral`` (each takes all of it), and worse in some cells. Two explanations
compete: the MPC tracks the chosen velocity under the acceleration box, so each UAV's half comes too
late; or ORCA's half-spaces at the time horizon τ the single-UAV selections chose (1.2–1.6 s) have no
common point in a crowded crossing, so the fallback (least violation) takes over. This ablation flies
both velocity obstacles on study 16's held-out ``circle_swap`` fields (seed 300, 64 per A) with A = 4, 8
and 32 UAVs, each of study 11's three selections, in six arms: the MPC tracking the chosen velocity (study
16's stack) or ideal tracking (``sim.tracking = "ideal"``: the chosen velocity reached within the step,
no box), each at the selections' τ, τ = 3 s and τ = 5 s (every other gain the selection's). Every UAV sees
its 8 nearest neighbours, as in study 16; one more arm, at A = 32 with ideal tracking and τ = 5 s, lets each
see all 31 (16 half-spaces at a time, every step certified exact or counted).

Verdicts (:func:`jaxapf.stats.decide`, the verdict function of every study: exact McNemar and TOST
within the metric's margin, 2 points), paired on the same fields, per (arm, A, selection): reciprocal
against unilateral on swarm success, a collision between two UAVs and deadlock; ideal tracking against the
MPC, and every UAV seen against 8 neighbours (same method, τ, A and selection); Holm within each question's
declared families (success and collision primary, deadlock exploratory).

    python analysis/reciprocity_ablation.py   # cached per cell under runs/reciprocity-ablation-fN/ (37 min on
                                              # 2 cores, 31 of them the two cells with every UAV seen)
"""

from __future__ import annotations

import pathlib

import pandas as pd
import study
import swarm_study as swarm

STUDY = "reciprocity_ablation"
FAMILY = "circle_swap"
AGENTS = (4, 8, 32)
METHODS = ("velocity_obstacle", swarm.UNILATERAL)
TRACKING = ("mpc", "ideal")
#: The time horizons flown: the selections' own (``None``) and two longer ones [s].
TAUS = (None, 3.0, 5.0)
#: Every UAV seen (A - 1 neighbours, 16 rows at a time, certified) with ideal tracking and τ = 5 s, at A = 32.
EVERYONE = 31


def arm(tracking: str, tau: float | None, neighbours: int = swarm.NEIGHBOURS) -> str:
    """An arm's name (``ideal_tau5``, ``mpc_selected``, ``ideal_tau5_n31``): its rows, tables and facts."""
    name = f"{tracking}_{'selected' if tau is None else f'tau{tau:g}'}"
    return name + (f"_n{neighbours}" if neighbours != swarm.NEIGHBOURS else "")


def label(tracking: str, tau: float | None, neighbours: int = swarm.NEIGHBOURS) -> str:
    text = f"{'ideal tracking' if tracking == 'ideal' else 'MPC'}, τ = {'selected' if tau is None else f'{tau:g} s'}"
    return text + (f", every UAV seen ({neighbours} neighbours)" if neighbours != swarm.NEIGHBOURS else "")


#: The per-swarm columns the tables and facts read, kept as ``episodes.parquet`` (``--from-episodes``).
READ = ("method", "arm", "tracking", "tau", "neighbours", "agents", "seed", "field", *(m for m, _ in swarm.OUTCOMES),
        "min_agent_clearance", "truncated_steps")
#: The cells: (A, tracking, τ, neighbours seen).
CELLS = [(a, tracking, tau, swarm.NEIGHBOURS) for a in AGENTS for tracking in TRACKING for tau in TAUS] + [
    (32, "ideal", 5.0, EVERYONE)]


def run(count: int, cache: pathlib.Path) -> pd.DataFrame:
    """Every cell, each cached as soon as it is done (a rerun computes only what is missing)."""
    cache.mkdir(parents=True, exist_ok=True)
    frames = []
    for agents, tracking, tau, seen in CELLS:
        for method in METHODS:
            suffix = "" if seen == swarm.NEIGHBOURS else f"-n{seen}"
            path = cache / f"a{agents:02d}-{method}-{tracking}-tau{tau or 0:g}{suffix}.parquet"
            if not path.exists():
                swarm.cell(method, FAMILY, agents, count, tracking, tau, seen).to_parquet(path, index=False)
                print(f"  A={agents} {method} {label(tracking, tau, seen)}: done", flush=True)
            frames.append(pd.read_parquet(path).assign(arm=arm(tracking, tau, seen), tracking=tracking,
                                                       tau="selected" if tau is None else f"{tau:g}",
                                                       neighbours=seen))
    return pd.concat(frames, ignore_index=True)


def summarise(df: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(rates, comparisons)``: per (method, arm, A, selection) each outcome's rate; every paired comparison
    (reciprocal vs unilateral per arm; ideal vs MPC tracking per method and τ) with its verdict
    (:func:`swarm_study.verdicts`: Holm within each question's families)."""
    key = ["method", "arm", "agents", "seed"]
    rates = (df.groupby(key + ["tracking", "tau", "neighbours"], sort=False)
             [[m for m, _ in swarm.OUTCOMES] + ["min_agent_clearance", "truncated_steps", "field"]]
             .agg({**{m: "mean" for m, _ in swarm.OUTCOMES}, "min_agent_clearance": "median",
                   "truncated_steps": "sum", "field": "size"})
             .rename(columns={"field": "n"}).reset_index())
    by = df.set_index(key + ["field"]).sort_index()
    rows = []

    def compare(question: str, method: str, now: str, then: str, agents: int, seed: int) -> None:
        nonlocal rows
        rows += [{"question": question, "method": method, "arm": now, "baseline": then, "agents": agents,
                  "seed": seed} | r for r in swarm.paired(by.loc[(method, now, agents, seed)],
                                                          by.loc[(method if question != "reciprocity" else
                                                                  swarm.UNILATERAL, then, agents, seed)])]

    for agents, tracking, tau, seen in CELLS:
        here = arm(tracking, tau, seen)
        for seed in sorted(df["seed"].unique()):
            compare("reciprocity", "velocity_obstacle", here, here, agents, seed)
            for method in METHODS:
                if tracking == "ideal" and seen == swarm.NEIGHBOURS:
                    compare("ideal tracking", method, here, arm("mpc", tau), agents, seed)
                if seen != swarm.NEIGHBOURS:
                    compare("every UAV seen", method, here, arm(tracking, tau), agents, seed)
    comparisons = swarm.verdicts(pd.DataFrame(rows))
    return rates, comparisons


def facts(rates: pd.DataFrame, comparisons: pd.DataFrame) -> dict:
    """The named values the findings state: each outcome per method, arm and A (mean over the selections,
    and each selection's), the selections' verdicts of every comparison, their tally per cell and their
    counts per question."""
    out: dict = {"fields": int(rates["n"].min()), "comparisons": len(comparisons), "agents": list(AGENTS),
                 "selections": int(rates["seed"].nunique()), "everyone": EVERYONE, "taus": [t for t in TAUS if t],
                 "neighbours": swarm.NEIGHBOURS,
                 "truncated_steps": int(rates["truncated_steps"].sum()),
                 "selected_tau": {f"seed{s}": swarm.tuned("velocity_obstacle", s)["vo_tau"]
                                  for s in sorted(rates["seed"].unique())},
                 "selected_margin": {f"seed{s}": swarm.tuned("velocity_obstacle", s)["vo_margin"]
                                     for s in sorted(rates["seed"].unique())}}
    for metric, _ in swarm.OUTCOMES:
        table: dict = {}
        for (method, name, agents), g in rates.groupby(["method", "arm", "agents"]):
            g = g.sort_values("seed")
            table.setdefault(method, {}).setdefault(name, {})[str(agents)] = {
                "mean": float(g[metric].mean()), **{f"seed{int(s)}": float(v) for s, v in zip(g["seed"], g[metric])}}
        out[metric] = table
    verdict: dict = {}
    tally: dict = {}
    for r in comparisons.itertuples():
        node = verdict.setdefault(r.question, {}).setdefault(r.metric, {}).setdefault(r.method, {})
        node.setdefault(r.arm, {}).setdefault(str(r.agents), {})[f"seed{int(r.seed)}"] = r.verdict
        node = tally.setdefault(r.question, {}).setdefault(r.metric, {}).setdefault(r.method, {})
        node = node.setdefault(r.arm, {}).setdefault(str(r.agents), dict.fromkeys(swarm.MARK, 0))
        node[r.verdict] += 1
    out["verdict"], out["verdict_tally"] = verdict, tally
    out["verdict_counts"] = {q: {m: {v: int(((c["metric"] == m) & (c["verdict"] == v)).sum()) for v in swarm.MARK}
                                 for m, _ in swarm.OUTCOMES}
                             for q, c in comparisons.groupby("question")}
    return out


def table(rates: pd.DataFrame, comparisons: pd.DataFrame, metric: str) -> str:
    """Markdown: ``metric`` in % of reciprocal / unilateral per arm (rows) and A (columns), mean over the
    selections, with the selections' verdicts of reciprocal against unilateral."""
    lines = ["| arm | " + " | ".join(f"A = {a}" for a in AGENTS) + " |", "|---|" + "---|" * len(AGENTS)]
    mean = rates.groupby(["method", "arm", "agents"])[metric].mean()
    rec = comparisons[(comparisons["question"] == "reciprocity") & (comparisons["metric"] == metric)]
    for tracking, tau, seen in dict.fromkeys((t, tau, n) for _, t, tau, n in CELLS):
        name, cells = arm(tracking, tau, seen), []
        for a in AGENTS:
            if ("velocity_obstacle", name, a) not in mean.index:
                cells.append("")
                continue
            marks = rec[(rec["arm"] == name) & (rec["agents"] == a)]
            marks = "".join(swarm.MARK[v] for v in marks.sort_values("seed")["verdict"])
            cells.append(f"{100 * mean[('velocity_obstacle', name, a)]:.1f} / "
                         f"{100 * mean[(swarm.UNILATERAL, name, a)]:.1f} {marks}")
        lines.append(f"| {label(tracking, tau, seen)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    args, out = study.begin(__doc__, STUDY)
    count = args.fields or swarm.FIELDS
    if args.facts_only:
        rates, comparisons = pd.read_csv(out / "rates.csv"), pd.read_csv(out / "comparisons.csv")
        if "b" not in comparisons.columns:  # committed before the tables kept the counts: n from the rates
            n = rates.set_index(["method", "arm", "agents", "seed"])["n"]
            comparisons["n"] = [int(n[k]) for k in zip(comparisons["method"], comparisons["arm"],
                                                          comparisons["agents"], comparisons["seed"])]
        comparisons = swarm.verdicts(comparisons)
        comparisons.to_csv(out / "comparisons.csv", index=False)
        study.write_facts(out, facts(rates, comparisons))
        return
    if args.from_episodes:
        flown = study.kept_rows(out)
        count = int(flown.groupby(["method", "arm", "agents", "seed"]).size().max())
    else:
        flown = run(count, study.ROOT / "runs" / f"reciprocity-ablation-f{count}")
        study.keep_rows(flown, out, READ)
    rates, comparisons = summarise(flown)
    rates.to_csv(out / "rates.csv", index=False)
    comparisons.to_csv(out / "comparisons.csv", index=False)
    from jaxapf.stats import VERDICT_RULE

    lines = [f"# Study 16's ablation: reciprocity under ideal tracking and longer time horizons ({count} held-out "
             f"`{FAMILY}` fields per A and selection)", "", f"`python analysis/{STUDY}.py`", "",
             "Protocol: " + " ".join(__doc__.split("\n\n")[1:3]).replace("\n", " ").replace("``", "`")
             .replace(":func:", ""), "", f"{len(comparisons)} paired comparisons; {VERDICT_RULE}.", ""]
    for metric, _ in swarm.OUTCOMES:
        lines += [f"## {metric} [%]: `velocity_obstacle` (ORCA's ½) / `{swarm.UNILATERAL}`, mean over the three "
                  "selections; the selections' verdicts of reciprocal against unilateral in seed order (↑ better, "
                  "↓ worse, = equivalent, · inconclusive)", "", table(rates, comparisons, metric), ""]
    counts = facts(rates, comparisons)["verdict_counts"]
    lines += ["## Verdict counts", "",
              "| comparison | outcome | better | worse | equivalent | inconclusive |", "|---|---|---|---|---|---|"]
    order = ("better", "worse", "equivalent", "inconclusive")
    lines += [f"| {q} | {m} | " + " | ".join(str(n[v]) for v in order) + " |"
              for q, by_metric in counts.items() for m, n in by_metric.items()]
    lines += ["", f"UAV-steps not certified exact: {int(rates['truncated_steps'].sum())}.", ""]
    lines += ["`rates.csv`: per method, arm, A and selection every outcome's rate, the median closest "
              "approach between UAVs; `comparisons.csv`: every paired comparison with its interval, raw and "
              "Holm-adjusted p-values and verdict; `episodes.parquet`: every swarm's outcomes (`--from-episodes` "
              "rebuilds this page from them)."]
    study.write_results(out, lines, facts(rates, comparisons))
    print("\n".join(lines))


if __name__ == "__main__":
    study.entry(main)
