"""Study 4: the paper's prose ("intent") against its printed formulas ("literal").

The paper defines ``r_e = p - p_o`` and ``G = (v - v_o)·r_e/|r_e|`` but describes ω as largest for
obstacles *ahead* and *approaching*; read literally, the formulas weight obstacles behind and
receding ones the most (SPEC 3). Both readings are implemented; this study runs both for the two
weighted methods on the same fields of ``trap``, ``crossing``, ``head_on``, ``overtake`` and
``dynamic`` (``sweeps/convention.toml``) and pairs ``literal`` against ``intent`` per method.

    python analysis/sign_convention.py     # ~2 min on 2 CPU cores
"""

from __future__ import annotations

import study

STUDY = "sign_convention"
METHODS = ("direction", "direction_velocity")


def findings(n: study.Numbers) -> str:
    families = n.families()
    lines = ["## `literal` − `intent`, paired per method and family", "",
             "| family | method | success intent → literal | collision intent → literal | Δ success | Δ collision "
             "| Δ min clearance (HL shift) |",
             "|---|---|---|---|---|---|---|"]
    deltas = {}
    for family in (*families, "all"):
        for method in METHODS:
            intent = {"method": method, "convention": "intent"}
            literal = {"method": method, "convention": "literal"}
            d = {m: n.delta(literal, family, m) for m in ("success", "collision", "min_clearance")}
            deltas[family, method] = d
            lines.append(f"| {family} | {method} | {n.rate(intent, family, 'success')} → "
                         f"{n.rate(literal, family, 'success')} | {n.rate(intent, family, 'collision')} → "
                         f"{n.rate(literal, family, 'collision')} | {d['success'].text()} | "
                         f"{d['collision'].text()} | {d['min_clearance'].text()} |")
    lines += ["", "## Conclusion", ""]
    for method in METHODS:
        d = deltas["all", method]
        worse = [f for f in families if deltas[f, method]["success"].worse or deltas[f, method]["collision"].worse]
        better = [f for f in families if deltas[f, method]["success"].better or deltas[f, method]["collision"].better]
        lines.append(
            f"- `{method}`: pooled, the literal formulas change success by {d['success'].text()} and collisions "
            f"by {d['collision'].text()}. "
            + (f"Relevantly worse on {', '.join(worse)}. " if worse else "")
            + (f"Relevantly better on {', '.join(better)}. " if better else "")
            + ("No family or kind shows a relevant difference (better or worse by more than the 2 pp margin, "
               "Holm-significant) in success or collisions." if not worse and not better else ""))
    wider = sorted({f for (f, m), d in deltas.items() if f != "all" and d["min_clearance"].better})
    narrower = sorted({f for (f, m), d in deltas.items() if f != "all" and d["min_clearance"].worse})
    lines.append(f"- Minimum clearance under `literal` is relevantly larger (by more than its 0.05 m margin) on "
                 f"{', '.join(wider) or 'no family'} and smaller on {', '.join(narrower) or 'no family'} (for at least "
                 "one method).")
    intent_worse = [m for m in METHODS if deltas["all", m]["success"].better or deltas["all", m]["collision"].better]
    intent_better = [m for m in METHODS if deltas["all", m]["success"].worse or deltas["all", m]["collision"].worse]
    if intent_worse and not intent_better:
        lines.append(f"- The prose's reading is **not** the better planner: pooled, `literal` is relevantly "
                     f"better for {', '.join(f'`{m}`' for m in intent_worse)} and never relevantly worse.")
    lines += ["", "Which reading the authors ran cannot be told from the paper. Where the two differ "
                  "relevantly above, a reimplementation from the printed formulas would not reproduce a "
                  "planner built from the prose; where they do not, the convention matters less than the "
                  "paper's contradiction suggests. `direction` has no velocity term, so its difference comes "
                  "from the sign of cos θ alone."]
    return "\n".join(lines)


def facts(n: study.Numbers) -> dict:
    """The named values the findings state, for the docs to bind to: per family (and pooled, ``all``) and method
    the success and collision rates of each convention, the paired difference ``literal`` − ``intent`` (rates
    as fractions; interval and the report's verdict), and how many families and kinds each verdict covers."""
    groups = (*n.families(), "all")
    metrics = ("success", "collision", "min_clearance")
    deltas = {(g, m, k): n.delta({"method": m, "convention": "literal"}, g, k)
              for g in groups for m in METHODS for k in metrics}

    def compared(value) -> dict:
        return {g: {m: {k: value(deltas[g, m, k]) for k in metrics} for m in METHODS} for g in groups}

    def families(of: tuple[str, ...], verdict: str) -> dict:
        return {m: sum(any(deltas[g, m, k].verdict == verdict for k in of) for g in groups[:-1])
                for m in METHODS}

    return {"fields": {g: int(n.row({"method": METHODS[0], "convention": "intent"}, g)["n"]) for g in groups},
            **{k: {g: {m: {c: n.rate_value({"method": m, "convention": c}, g, k) for c in ("intent", "literal")}
                       for m in METHODS} for g in groups} for k in ("success", "collision")},
            "delta": compared(lambda d: d.delta), "delta_lo": compared(lambda d: d.lo),
            "delta_hi": compared(lambda d: d.hi), "verdict": compared(lambda d: d.verdict),
            "margin": {k: float(n.comparisons.loc[n.comparisons["metric"] == k, "margin"].iloc[0]) for k in metrics},
            "groups": len(groups) - 1,
            "groups_better": families(("success", "collision"), "better"),
            "groups_worse": families(("success", "collision"), "worse"),
            "groups_wider": families(("min_clearance",), "better"),
            "groups_narrower": families(("min_clearance",), "worse")}


def main() -> None:
    study.run_study(__doc__, name=STUDY, spec="convention",
                    title="Study 4 — sign convention: the paper's prose (intent) vs its formulas (literal)",
                    findings=findings,
                    figures=[study.RATES_FIGURE,
                             ("report/figures/differences.png",
                              "Paired differences literal − intent (filled: Holm-significant)")],
                    baseline="convention=intent", heatmap=None, gallery=2, facts=lambda n, _: facts(n))


if __name__ == "__main__":
    study.entry(main)
