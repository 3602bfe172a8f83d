"""Study 10: how many FISTA iterations the MPC needs (the default ``iters`` from evidence).

The MPC's box-constrained QP (spec.md §5) is solved per axis by FISTA with a fixed iteration count,
30 by default. ``sweeps/fista-iterations.toml`` flies the same episodes (6 randomized families ×
128 fields, ``basic`` and ``direction_velocity``) with 5, 10, 15, 20, 30, 50, 400 and 800
iterations. 800 is the converged reference (400 → 800 is reported as the check that it is). For
each count the study gives, against the reference on the same episode,

- the fraction of episodes whose outcome (success / collision / stall / none) changes, and
- the paired shift of every continuous metric (Hodges–Lehmann, from the report) and its verdict
  against the metric's relevance margin,

and names the smallest count whose outcomes agree on >= 99.5 % of all episodes with no continuous
metric relevantly worse or better than the reference (pooled over families; the families where
fewer agree are listed, since a pooled share can hide one sensitive family). It then
times the engine's standard case (1,024 clutter fields, 16 obstacle slots, N = 20, 300 steps) at
that count and at the default, in one process, interleaved.

    python analysis/fista_iterations.py     # ~10 min on 2 CPU cores (cold compilation cache)
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import study

STUDY = "fista_iterations"
SPEC = "fista-iterations"
REFERENCE = 800
COUNTS = (5, 10, 15, 20, 30, 50, 400)
AGREEMENT = 0.995
#: The continuous metrics the report compares (``jaxapf report``'s default comparison set).
CONTINUOUS = ("min_clearance", "time_to_goal", "path_ratio", "control_effort", "jerk_rms")


def outcome(df: pd.DataFrame) -> np.ndarray:
    """One label per episode: success, collision, stalled or none (in that precedence)."""
    return np.select([df["success"], df["collision"], df["stalled"]], ["success", "collision", "stalled"], "none")


def agreement(df: pd.DataFrame) -> pd.DataFrame:
    """Per (iters, family, and pooled 'all'): episodes, outcome changes against the reference and
    the fraction that agrees."""
    keyed = df.assign(outcome=outcome(df))[["method", "family", "field", "iters", "outcome"]]
    ref = keyed[keyed["iters"] == REFERENCE].drop(columns="iters")
    rows = []
    for iters in COUNTS:
        mine = keyed[keyed["iters"] == iters].merge(ref, on=["method", "family", "field"], suffixes=("", "_ref"))
        changed = mine["outcome"] != mine["outcome_ref"]
        for family, group in [*mine.groupby("family", sort=False), ("all", mine)]:
            ch = changed[group.index]
            rows.append({"iters": iters, "family": family, "episodes": len(group), "changed": int(ch.sum()),
                         "agree": 1.0 - float(ch.mean())})
    return pd.DataFrame(rows)


def choose(table: pd.DataFrame, n: study.Numbers) -> tuple[int | None, dict[int, list[str]]]:
    """The smallest count meeting the criterion (module docstring), and per count what fails it."""
    fails: dict[int, list[str]] = {}
    for iters in COUNTS:
        why = []
        pooled = table[(table["iters"] == iters) & (table["family"] == "all")].iloc[0]
        if pooled["agree"] < AGREEMENT:
            why.append(f"outcomes agree on {100 * pooled['agree']:.2f} % of the episodes")
        for method in ("basic", "direction_velocity"):
            for metric in CONTINUOUS:
                d = n.delta({"method": method, "iters": iters}, "all", metric)
                if d.better or d.worse:
                    why.append(f"{method} {metric} {d.text()}")
        fails[iters] = why
    chosen = next((i for i in COUNTS if not fails[i]), None)
    return chosen, fails


def speed(chosen: int | None) -> list[str]:
    """The standard case at the default and at the chosen count, interleaved in one process."""
    from jaxapf.bench.engine import run_benchmark
    from jaxapf.config import MPCConfig

    default = MPCConfig().iters
    counts = [default] if chosen in (None, default) else [default, chosen]
    runs = {c: [] for c in counts}
    for _ in range(3):
        for c in counts:
            runs[c].append(run_benchmark(iters=c, oracle_fields=0)["engine"]["steps_per_s"])
    lines = ["## Speed of the standard case", "",
             "1,024 clutter fields, 16 obstacle slots, N = 20, 300 steps, float32, one process, runs "
             "interleaved (median of 3; `jaxapf.bench.engine.run_benchmark`):", "",
             "| FISTA iterations | scenario-steps/s |", "|---:|---:|"]
    lines += [f"| {c}{' (default)' if c == default else ''} | {np.median(runs[c]):,.0f} |" for c in counts]
    if len(counts) == 2:
        ratio = np.median(runs[chosen]) / np.median(runs[default])
        lines += ["", f"{chosen} iterations run the standard case {ratio:.2f}× as fast as the default {default}."]
    return lines


def findings(n: study.Numbers, table: pd.DataFrame) -> str:
    from jaxapf.config import MPCConfig

    default = MPCConfig().iters
    families = [f for f in dict.fromkeys(table["family"]) if f != "all"]
    lines = ["## Outcomes that change against the converged solve (800 iterations)", "",
             "Share of episodes whose outcome (success / collision / stall / none) is the same as with 800 "
             "iterations, both methods together (2 × 128 episodes per family):", "",
             "| iterations | " + " | ".join(families) + " | all |", "|---:|" + "---:|" * (len(families) + 1)]
    for iters in COUNTS:
        rows = table[table["iters"] == iters].set_index("family")
        lines.append(f"| {iters} | " + " | ".join(f"{100 * rows.loc[f, 'agree']:.1f} %" for f in families)
                     + f" | {100 * rows.loc['all', 'agree']:.1f} % ({rows.loc['all', 'changed']} changed) |")
    lines += ["", "## Metric shifts against the converged solve, pooled over families", "",
              "Hodges–Lehmann shift (iterations − 800) with its signed-rank interval and the report's verdict "
              "against the metric's relevance margin (`jaxapf list metrics`); rates in percentage points.", "",
              "| iterations | method | success | collision | min clearance | time to goal | control effort |",
              "|---:|---|---|---|---|---|---|"]
    for iters in COUNTS:
        for method in ("basic", "direction_velocity"):
            s = {"method": method, "iters": iters}
            lines.append(f"| {iters} | {method} | " + " | ".join(
                n.delta(s, "all", m).text() for m in ("success", "collision", "min_clearance", "time_to_goal",
                                                       "control_effort")) + " |")
    chosen, fails = choose(table, n)
    lines += ["", "## Choice", ""]
    converged = table[(table["iters"] == 400) & (table["family"] == "all")].iloc[0]
    lines.append(f"- 400 iterations agree with 800 on {100 * converged['agree']:.2f} % of the episodes "
                 f"({converged['changed']} of {converged['episodes']} outcomes differ): the reference is converged "
                 "as far as outcomes go.")
    for iters in COUNTS[:-1]:
        rows = table[(table["iters"] == iters) & (table["family"] != "all") & (table["agree"] < AGREEMENT)]
        below = (f" Families below {100 * AGREEMENT:g} %: "
                 + ", ".join(f"{r.family} {100 * r.agree:.1f} % ({r.changed} of {r.episodes})"
                             for r in rows.itertuples())
                 + "." if len(rows) else "")
        lines.append(f"- {iters} iterations: " + ("meets the criterion." + below if not fails[iters] else
                                                 "fails: " + "; ".join(fails[iters][:4])
                                                 + (f"; and {len(fails[iters]) - 4} more" if len(fails[iters]) > 4
                                                    else "") + "." + below))
    if chosen is None:
        lines.append(f"- No count up to 400 meets the criterion (outcomes agree on >= {100 * AGREEMENT:g} % of "
                     "the episodes, no continuous metric relevantly shifted).")
    elif chosen == default:
        lines.append(f"- **The default of {default} iterations is the smallest count that meets the criterion**; "
                     "it stays.")
    elif chosen < default:
        lines.append(f"- **{chosen} iterations is the smallest count that meets the criterion**, fewer than the "
                     f"default {default}.")
    else:
        lines.append(f"- **The default of {default} iterations does not meet the criterion; {chosen} is the "
                     "smallest count that does.**")
    return "\n".join(lines), chosen


def facts(table: pd.DataFrame, n: study.Numbers) -> dict:
    """The named values the study's findings (and docs/performance.md) state: per count the outcome
    agreement and, pooled over families, each metric's shift against the reference and its verdict."""
    from jaxapf.config import MPCConfig

    families = [f for f in dict.fromkeys(table["family"]) if f != "all"]
    pooled = table[table["family"] == "all"].set_index("iters")
    methods = ("basic", "direction_velocity")
    metrics = (*study.RATE_METRICS, *CONTINUOUS)
    deltas = {i: {m: {x: n.delta({"method": m, "iters": i}, "all", x) for x in metrics} for m in methods}
              for i in COUNTS}
    return {"shift": {str(i): {m: {x: d.delta for x, d in v.items()} for m, v in deltas[i].items()} for i in COUNTS},
            "verdict": {str(i): {m: {x: d.verdict for x, d in v.items()} for m, v in deltas[i].items()}
                        for i in COUNTS},
            "continuous_equivalent": {str(i): sum(deltas[i][m][x].equivalent for m in methods for x in CONTINUOUS)
                                      for i in COUNTS},
            "continuous_shifted": {str(i): sum(deltas[i][m][x].better or deltas[i][m][x].worse for m in methods
                                               for x in CONTINUOUS) for i in COUNTS},
            "continuous_compared": len(methods) * len(CONTINUOUS),
            "margin": n.comparisons.groupby("metric")["margin"].first().loc[list(metrics)].to_dict(),
            "reference": REFERENCE, "counts": list(COUNTS), "families": len(families),
            "methods": 2, "fields_per_family": int(pooled["episodes"].iloc[0]) // (2 * len(families)),
            "criterion": AGREEMENT, "default": MPCConfig().iters, "chosen": choose(table, n)[0],
            "agree": {str(i): {r.family: float(r.agree) for r in table[table["iters"] == i].itertuples()}
                      for i in COUNTS},
            "changed": {str(i): {r.family: int(r.changed) for r in table[table["iters"] == i].itertuples()}
                        for i in COUNTS},
            "episodes": {str(i): int(pooled.loc[i, "episodes"]) for i in COUNTS}}


def main() -> None:
    args, out = study.begin(__doc__, STUDY)
    if args.facts_only:
        study.write_facts(out, facts(pd.read_csv(out / "agreement.csv"), study.Numbers(study.committed_report(out))))
        return
    parquet = study.sweep_source(args, out, SPEC)
    result = study.report(parquet, out, resamples=args.resamples, baseline=f"iters={REFERENCE}", heatmap=None,
                          gallery=0)
    from jaxapf.sweep import read_sweep

    df, _ = read_sweep(parquet)
    table = agreement(df)
    table.to_csv(out / "agreement.csv", index=False)
    text, chosen = findings(study.Numbers(result), table)
    study.write_facts(out, facts(table, study.Numbers(result)))
    sections = [text, "\n".join(speed(chosen))]
    command = f"python analysis/{STUDY}.py" + (f" --fields {args.fields}" if args.fields else "")
    study.write_readme(out, "Study 10 — how many FISTA iterations the MPC needs", command, parquet, sections,
                       [("report/figures/differences.png", "Paired differences against 800 iterations "
                                                          "(filled: Holm-significant)")])
    print(f"wrote {out}/README.md")


if __name__ == "__main__":
    study.entry(main)
