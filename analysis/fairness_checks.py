"""Study 9: do jaxapf's comparisons compare what they say? The checks of issue 15, rerun.

Issue 15 listed four ways the headline comparisons misled: repulsion strength confounded with the
weighting, families averaging kinds that behave oppositely (and clutter silently including GNRON
fields), metrics that reward failure or repeat another metric, and significance without relevance.
This script measures each on the current code, so the fixes can be checked and the problems seen:

1. strength: ``sweeps/strength.toml`` (each method at k_rep = 10, 20, 30 on the same fields);
2. kinds and ceilings: ``sweeps/family-variants.toml`` (shared with study 7);
3. GNRON in clutter: the clutter fields' goal clearance with the old endpoint margin (0.25 m) and
   the current ``goal_margin`` default (4 m);
4. metrics: the old BARN ``score`` recomputed from the rows next to ``spl``, and ``time_near`` /
   ``min_ttc`` / ``path_ratio`` in stalled and failed episodes against successful ones;
5. relevance: comparisons of study 7's report that are Holm-significant yet *equivalent* (inside
   the metric's margin) -- run ``python analysis/family_variants.py`` first.

    python analysis/fairness_checks.py        # ~1.5 min for the strength sweep, the rest is shared
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import study

STUDY = "fairness_checks"
METHODS = ("basic", "direction", "direction_velocity")
#: Study 7's results: section 5 and the facts read its committed report.
VARIANTS = study.RESULTS / "family_variants"


def _rows(path) -> pd.DataFrame:
    from jaxapf.sweep import read_sweep

    return read_sweep(path)[0]


def _outcome(df: pd.DataFrame) -> pd.Series:
    return np.select([df["success"], df["collision"], df["stalled"]], ["success", "collision", "stalled"], "timeout")


def same_outcome(df: pd.DataFrame) -> dict[str, float]:
    """On ``trap``, the share of fields where ``direction_velocity`` at ``k_rep`` = 10 has the same outcome as
    ``basic`` at ``k_rep`` = 10 and at 30."""
    trap = df[df["family"] == "trap"].assign(outcome=lambda d: _outcome(d))
    pick = lambda m, k: trap[(trap["method"] == m) & (trap["k_rep"] == k)].set_index("field")["outcome"]  # noqa: E731
    dv10 = pick("direction_velocity", 10.0)
    return {f"basic_k{k:g}": float((dv10 == pick("basic", k)).mean()) for k in (10.0, 30.0)}


def strength(df: pd.DataFrame) -> str:
    lines = ["## 1. Repulsion strength and the weighting", "",
             "At equal `k_rep` the weight is 1 for `basic`, 1.5 for `direction` (γ = 1) and about 3 for "
             "`direction_velocity` at hover (up to ≈ 4.9 when closing on an obstacle ahead). Rates in % per "
             "method and `k_rep` on the same fields:", "",
             "| family | rate | " + " | ".join(f"{m} k_rep={k:g}" for m in METHODS for k in (10, 20, 30)) + " |",
             "|---|---|" + "---|" * 9]
    for family in ("trap", "overtake", "clutter"):
        sub = df[df["family"] == family]
        for rate in ("success", "stalled", "collision"):
            cells = [100 * sub[(sub["method"] == m) & (sub["k_rep"] == k)][rate].mean()
                     for m in METHODS for k in (10.0, 20.0, 30.0)]
            lines.append(f"| {family} | {rate} | " + " | ".join(f"{c:.1f}" for c in cells) + " |")
    same = same_outcome(df)
    same10, same30 = same["basic_k10"], same["basic_k30"]
    reading = ("so the issue's reading holds: on `trap` \"the weighted APF stalls more\" is, field by field, "
               "\"stronger repulsion stalls more\"" if same30 > same10 else
               "so the data does not bear out the issue's reading on `trap`")
    lines += ["", f"On `trap`, `direction_velocity` at `k_rep` = 10 has the same outcome (success, collision, stall "
              f"or timeout) as `basic` at `k_rep` = 30 on **{100 * same30:.1f} %** of the fields, and as `basic` at "
              f"its own `k_rep` = 10 on {100 * same10:.1f} %, {reading}. Within every method, raising `k_rep` moves "
              "the rates the way switching to a more strongly weighted method does. jaxapf now compares at matched "
              "strength (the normalised weights, study 7) and at each method's tuned best (`jaxapf compare`, "
              "study 8)."]
    return "\n".join(lines)


def kinds_and_ceilings(df: pd.DataFrame) -> str:
    lines = ["## 2. Kinds that behave oppositely, and families at the ceiling", "",
             "Success rate in % at the paper's default gains, per kind of `trap` and for the moving families at "
             "their defaults (`family-variants` sweep):", "",
             "| group | " + " | ".join(METHODS) + " |", "|---|" + "---|" * len(METHODS)]
    groups = [("trap", k) for k in ("on_line", "concave", "narrow_gap", "gnron")]
    groups += [(f, f) for f in ("crossing", "head_on", "dynamic")]
    for family, kind in groups:
        sub = df[(df["family"] == family) & (df["kind"] == kind)]
        label = f"{family}/{kind}" if family != kind else family
        lines.append(f"| {label} | " + " | ".join(f"{100 * sub[sub['method'] == m]['success'].mean():.1f}"
                                                   for m in METHODS) + " |")
    lines += ["", "A pooled `trap` rate averages a kind every method solves, two no method solves and the one "
              "kind that separates them; reports now give every kind its own rows and say what a pooled row "
              "pools. The moving families at their defaults cannot separate the methods; their harder variants "
              "(study 7, docs/scenarios.md) can."]
    return "\n".join(lines)


def goal_clearance_shares(fields: int = 1024) -> dict:
    """Shares of ``fields`` clutter fields of seed 0 (drawn, none flown) whose goal clearance (UAV clearance to the
    nearest obstacle at t = 0) is below 1 m and below d_s = 4 m, with the old endpoint margin and the current
    ``goal_margin`` default."""
    import jax
    import jax.numpy as jnp

    from jaxapf.datatypes import clearance
    from jaxapf.scenarios import family_params, make_scenarios

    def goal_clearance(params) -> np.ndarray:
        s = make_scenarios(0, params, np.arange(fields))
        return np.asarray(jax.vmap(lambda g, o: jnp.min(clearance(g, o, 0.0, params.r_uav)))(s.goal, s.obstacles))

    near, d_s, old_margin = 1.0, 4.0, 0.25
    params = family_params("clutter")
    old, new = goal_clearance(family_params("clutter", goal_margin=old_margin)), goal_clearance(params)
    return {"fields": fields, "near_m": near, "d_s": d_s, "old_margin": old_margin,
            "new_margin": float(params.goal_margin),
            "old": {"within_1m": float(np.mean(old < near)), "within_d_s": float(np.mean(old < d_s))},
            "new": {"within_1m": float(np.mean(new < near)), "within_d_s": float(np.mean(new < d_s - 1e-4))}}


def gnron_in_clutter(shares: dict) -> str:
    old, new = shares["old"], shares["new"]
    return "\n".join([
        "## 3. GNRON hidden in `clutter`", "",
        f"Goal clearance (UAV clearance to the nearest obstacle at t = 0) over {shares['fields']} clutter fields of "
        "seed 0:", "",
        f"| endpoint margin at the goal | clearance < {shares['near_m']:g} m | clearance < d_s = {shares['d_s']:g} m |",
        "|---|---|---|",
        f"| {shares['old_margin']:g} m (before) | {100 * old['within_1m']:.1f} % | {100 * old['within_d_s']:.1f} % |",
        f"| {shares['new_margin']:g} m (`goal_margin` default now) | {100 * new['within_1m']:.1f} % | "
        f"{100 * new['within_d_s']:.1f} % |",
        "", f"With the old margin {100 * old['within_1m']:.0f} % of the clutter fields put an obstacle within "
        f"{shares['near_m']:g} m of the goal, i.e. were `trap`'s `gnron` kind in disguise; `goal_margin` (a family "
        "parameter) now keeps the goal outside the default influence distance in every family that does not mean "
        "GNRON."])


def old_score(ok: pd.DataFrame) -> pd.Series:
    """The old BARN ``score`` of successful episodes: ``1 / clip(t / t_opt, 2, 8)``, ``t_opt`` = distance / v_max."""
    straight = ok["path_length"] / ok["path_ratio"]
    return 1.0 / np.clip(ok["time_to_goal"] / (straight / 2.0), 2.0, 8.0)  # v_max = 2 m/s


def metrics(df: pd.DataFrame, time_near: tuple[pd.Series, pd.Series]) -> str:
    ok = df[df["success"]]
    score = old_score(ok)
    by = df.assign(outcome=_outcome(df)).groupby("outcome")
    table = by[["time_near", "min_ttc", "path_ratio", "control_effort"]].median()
    lines = ["## 4. Metrics that mean what they say", "",
             "- The old BARN `score` (`1 / clip(t / t_opt, 2, 8)` on success, `t_opt` = distance / v_max) is "
             f"exactly 0.5 in **{100 * np.isclose(score, 0.5).mean():.1f} %** of the {len(ok):,} successful "
             "episodes of this sweep: it repeats the success rate. Its replacement `spl` (success weighted by "
             f"path length, Anderson et al. 2018) takes {ok['spl'].round(4).nunique():,} distinct values there (median "
             f"{ok['spl'].median():.3f}, 5–95 % {ok['spl'].quantile(0.05):.3f}–{ok['spl'].quantile(0.95):.3f}).",
             "- Medians per outcome (`time_near`: time inside d_safe while closing, now; `min_ttc`: smallest "
             "time to collision; `path_ratio` and `control_effort` over whatever was flown):", "",
             "| outcome | episodes | time_near [s] | min_ttc [s] | path_ratio | control_effort |",
             "|---|---|---|---|---|---|"]
    for outcome, r in table.iterrows():
        lines.append(f"| {outcome} | {int(by.size()[outcome]):,} | {r['time_near']:.2f} | {r['min_ttc']:.2f} | "
                     f"{r['path_ratio']:.3f} | {r['control_effort']:.2f} |")
    old_time, new_time = time_near
    stalled, success = old_time["stalled"], old_time["success"]
    lines += ["", "`time_near` and `min_ttc` are diagnostics, not in the default report. `time_near` used to count "
              "every interval within d_safe = 1 m of an obstacle, so a stalled UAV hovering in front of a trap "
              "piled it up; it now counts only intervals spent closing in. Both definitions on the same episodes "
              "(`basic` at the default gains on 256 `trap` and 256 `clutter` fields; mean [s]):", "",
              "| outcome | old: within d_safe | new: within d_safe and closing |", "|---|---|---|"]
    for outcome in old_time.index:
        lines.append(f"| {outcome} | {old_time[outcome]:.2f} | {new_time[outcome]:.2f} |")
    ttc_stalled, ttc_success = table.at["stalled", "min_ttc"], table.at["success", "min_ttc"]
    ttc = ("is still larger in stalled episodes than in successful ones (median "
           f"{ttc_stalled:.2f} s against {ttc_success:.2f} s: a stalled UAV stops short, so nothing closes fast)"
           if ttc_stalled > ttc_success else f"is smaller in stalled episodes (median {ttc_stalled:.2f} s against "
           f"{ttc_success:.2f} s)")
    lines += ["", f"Stalled episodes had {stalled / success:.1f}× the old `time_near` of successful ones, and have "
              f"{new_time['stalled'] / new_time['success']:.1f}× the new one: a stall no longer dominates it, but a "
              f"UAV rocking in front of a trap still closes in again and again. `min_ttc` {ttc}; it measures the "
              "sharpest encounter, not safety. Both stay out of the default report. A failed episode's path is cut "
              "short or never ends, so `path_ratio`, `time_to_goal`, `control_effort` and `jerk_rms` are summarised "
              "over successes and compared on the pairs where both settings succeed, with that count shown."]
    return "\n".join(lines)


def _time_near_both_ways(fields: int = 256) -> tuple[pd.Series, pd.Series]:
    """Mean old and new ``time_near`` per outcome of ``basic`` on trap and clutter fields (the old
    definition registered here as a metric, after the sweeps so their outputs stay resumable)."""
    import jax.numpy as jnp

    from jaxapf import evaluate
    from jaxapf.config import MPCConfig, SimConfig
    from jaxapf.gains import Gains
    from jaxapf.metrics import Metric, register_metric
    from jaxapf.scenarios import family_params, make_scenarios
    from jaxapf.tune.train import stack_gains

    def within(ctx):
        return ctx.dt * jnp.sum(ctx.interval_valid & (ctx.swept < ctx.sim.metrics.d_safe))

    register_metric(Metric("time_within_d_safe", within, unit="s", higher_is_better=False,
                           doc="old time_near: time within d_safe"), replace=True)
    frames = []
    for family in ("trap", "clutter"):
        fields_ = make_scenarios(0, family_params(family, max_obstacles=16), np.arange(fields))
        m = evaluate(fields_, stack_gains([Gains()]), SimConfig.from_flat(method="basic"), MPCConfig(),
                     metrics=("success", "collision", "stalled", "time_near", "time_within_d_safe"))
        frames.append(pd.DataFrame({k: np.asarray(v)[0] for k, v in m.items()}))
    df = pd.concat(frames, ignore_index=True)
    df["outcome"] = _outcome(df)
    means = df.groupby("outcome")[["time_within_d_safe", "time_near"]].mean()
    return means["time_within_d_safe"], means["time_near"]


def significant_and_equivalent(c: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame, pd.Series | None]:
    """Of a report's comparisons: the Holm-significant ones, those of them that are *equivalent*, and the one of
    those on minimum clearance with the smallest shift (None if there is none)."""
    sig = c[c["significant"]]
    eq = sig[sig["verdict"] == "equivalent"]
    clearance = eq[eq["metric"] == "min_clearance"]
    return sig, eq, clearance.loc[clearance["delta"].abs().idxmin()] if len(clearance) else None


def relevance() -> str:
    path = VARIANTS / "report" / "comparisons.csv"
    if not path.exists():
        return "## 5. Significance and relevance\n\nRun `python analysis/family_variants.py` first."
    c = pd.read_csv(path)
    sig, eq, small = significant_and_equivalent(c)
    lines = ["## 5. Significance without relevance", "",
             f"Of the {len(c):,} paired comparisons in study 7's report, {len(sig):,} are Holm-significant; "
             f"**{len(eq):,}** of those are nonetheless *equivalent*: the whole interval of the difference lies "
             "inside the metric's relevance margin (2 pp for rates, 0.05 m for clearance, ...). The report "
             "calls them equivalent, not better or worse."]
    if small is not None:
        lines.append(f"For example the minimum clearance of {small['label']} against #{int(small['baseline'])} on "
                     f"{small['family']}: a shift of {small['delta']:+.4g} m [{small['delta_lo']:+.4g}, "
                     f"{small['delta_hi']:+.4g}], Holm p = {small['p_holm']:.2g}, against a margin of "
                     f"{small['margin']:g} m: significant, and irrelevant.")
    return "\n".join(lines)


def run_facts(strength_rows: pd.DataFrame, variants: pd.DataFrame, time_near: tuple[pd.Series, pd.Series]) -> dict:
    """The values only a run computes, from the episodes of the two sweeps and of ``time_near``."""
    ok = variants[variants["success"]]
    by = variants.assign(outcome=_outcome(variants)).groupby("outcome")
    old_time, new_time = time_near
    return {"same_outcome": same_outcome(strength_rows),
            "score": {"at_half": float(np.isclose(old_score(ok), 0.5).mean()), "successes": len(ok),
                      "spl_distinct": int(ok["spl"].round(4).nunique()), "spl_median": float(ok["spl"].median()),
                      "spl_q05": float(ok["spl"].quantile(0.05)), "spl_q95": float(ok["spl"].quantile(0.95))},
            "outcomes": {o: {"episodes": len(rows), **{m: float(rows[m].median()) for m in
                                                       ("time_near", "min_ttc", "path_ratio", "control_effort")}}
                         for o, rows in by},
            "time_near": {"old": old_time.to_dict(), "new": new_time.to_dict(),
                          "old_ratio": float(old_time["stalled"] / old_time["success"]),
                          "new_ratio": float(new_time["stalled"] / new_time["success"])}}


#: What facts.json keeps of the example of section 5.
EXAMPLE = ["label", "family", "delta", "delta_lo", "delta_hi", "margin", "verdict"]


def facts(shares: dict, run: dict) -> dict:
    """The named values the findings state: the goal clearances of the clutter fields (``shares``), the episode
    counts and the significant-but-equivalent comparisons of study 7's committed report, and ``run``: those only a
    run computes (kept from the committed facts.json by ``--facts-only``)."""
    report = study.committed_report(VARIANTS)
    rows = report.summary[(report.summary["family"] != "all") & ~report.summary["family"].str.contains("/")]
    sig, eq, example = significant_and_equivalent(report.comparisons)
    return {"goal_clearance": shares,
            "variants": {"episodes": int(rows["n"].sum()), "successes": int(rows["success_k"].sum()),
                         "collisions": int(rows["collision_k"].sum())},
            "relevance": {"comparisons": len(report.comparisons), "significant": len(sig), "equivalent": len(eq),
                          **({} if example is None else {"example": example[EXAMPLE].to_dict()})},
            "run": run}


def main() -> None:
    args, out = study.begin(__doc__, STUDY)
    shares = goal_clearance_shares()
    if args.facts_only:
        committed = out / "facts.json"
        run = json.loads(committed.read_text()).get("run", {}) if committed.exists() else {}
        study.write_facts(out, facts(shares, run))
        return
    strength_path = study.run_spec("strength", args.fields)
    variants_path = study.run_spec("family-variants", args.fields)
    variants, strength_rows = _rows(variants_path), _rows(strength_path)
    time_near = _time_near_both_ways()
    sections = [strength(strength_rows), kinds_and_ceilings(variants), gnron_in_clutter(shares),
                metrics(variants, time_near), relevance()]
    command = "python analysis/fairness_checks.py" + (f" --fields {args.fields}" if args.fields else "")
    study.write_readme(out, "Study 9 — do the comparisons compare what they say? (issue 15's checks)", command,
                       strength_path, sections, [])
    study.write_facts(out, facts(shares, run_facts(strength_rows, variants, time_near)))
    print(f"wrote {out}/README.md")


if __name__ == "__main__":
    study.entry(main)
