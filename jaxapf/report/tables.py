"""The report's statistics tables (per setting, and paired with the baseline) and their text.

Groups. Rows are summarised and compared per family, per kind of a family that draws several kinds
(``trap/gnron``), and pooled over families (``all``); a pooled row says what it pools (``pools``).

Comparisons. Each comparison reports the estimate its test is about, with an interval and the tests
that interval implies (:func:`jaxapf.stats.decide`): for a rate, the paired difference in proportions
(Tango's score interval, the asymptotic McNemar test); for a continuous metric, the Hodges–Lehmann
shift of the paired differences (its Walsh-average interval, the signed-rank test). A metric that is
meaningful only on successful episodes (``Metric.on_success``: time to goal, path ratio, effort,
jerk, TTC) is compared on the pairs where both settings succeed (``conditioning``), unless the report
asks for all pairs. Holm runs within declared families (:func:`holm_family`): the primary one (success
and collision, or ``--primary``, per family and pooled) and one exploratory family per other metric;
each interval is at the level Holm allows its comparison, and the verdict — better, worse, equivalent
within the metric's relevance margin, or inconclusive (:func:`jaxapf.stats.verdict`) — is read from it.
Each states the smallest difference it could detect at that level (power 0.8).
"""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from .. import stats
from ..metrics import all_metrics, find_metric
from .document import VERDICT_MARKS
from .load import ROW_COLUMNS, SINGLE_ROLES, SWARM_ROLES, report_metrics, roles

__all__ = ["ALL", "groups", "group_rows", "pools", "summarize", "compare", "holm_family", "primary_metrics",
           "rates_table", "continuous_table", "comparison_table", "findings", "margins", "REPORT_COLUMNS", "swept_name"]

#: The name of the group that pools every family of a report.
ALL = "all"
#: The report's own columns of a setting's rows; a swept column of one of these names (a sweep's tag) is
#: shown as ``NAME (swept)`` beside them (:func:`swept_name`).
REPORT_COLUMNS = frozenset({"setting", "label", "role", "family", "pools", "n", "n_solvable"})


def swept_name(column: str) -> str:
    """How a swept column is named beside the report's own (:data:`REPORT_COLUMNS`)."""
    return f"{column} (swept)" if column in REPORT_COLUMNS else column


def groups(data: pd.DataFrame) -> list[str]:
    """Each family; ``family/kind`` for each kind of a family with several kinds in the data; ``all``."""
    out = []
    families = sorted(str(f) for f in pd.unique(data["family"]))
    for family in families:
        out.append(family)
        if "kind" in data.columns:
            kinds = sorted(str(k) for k in pd.unique(data.loc[data["family"] == family, "kind"]))
            if len(kinds) > 1:
                out += [f"{family}/{kind}" for kind in kinds]
    return out + ([ALL] if len(families) > 1 else [])


def headline(names: Sequence[str]) -> str:
    """The group a report's key findings, LaTeX table and differences figure are about: ``all``
    when families are pooled, else the one family (not one of its kinds)."""
    return ALL if ALL in names else next(g for g in names if "/" not in g)


def group_rows(frame: pd.DataFrame, group: str) -> pd.DataFrame:
    """The rows of ``group`` (a family, ``family/kind`` or ``all``)."""
    if group == ALL:
        return frame
    family, _, kind = group.partition("/")
    rows = frame[frame["family"] == family]
    return rows[rows["kind"] == kind] if kind else rows


def pools(data: pd.DataFrame, group: str) -> str:
    """What a group pools: ``""`` for one kind, else its kinds or families with their field counts."""
    rows = group_rows(data, group)
    by = "family" if group == ALL else "kind"
    if group != ALL and ("/" in group or by not in rows.columns):
        return ""
    counts = rows.drop_duplicates([c for c in ROW_COLUMNS if c in rows.columns]).groupby(by).size()
    if len(counts) < 2:
        return ""
    return ", ".join(f"{name} ({n} fields)" for name, n in counts.items())


def _strata(frame: pd.DataFrame, group: str) -> np.ndarray | None:
    """Bootstrap strata of a pooled group: its families and kinds."""
    if "/" in group or (group != ALL and "kind" not in frame.columns):
        return None
    keys = frame["family"].astype(str)
    if "kind" in frame.columns:
        keys = keys + "/" + frame["kind"].astype(str)
    return keys.to_numpy()


def margins(options: Any) -> dict[str, float | None]:
    """The relevance margin of every metric: the registry's, overridden by ``options.margins``."""
    return {name: metric.margin for name, metric in all_metrics()} | dict(options.margins)


def _success_mask(frame: pd.DataFrame, suffix: str = "") -> np.ndarray:
    """The success column (a swarm's ``swarm_success``) of ``frame`` with ``suffix``; all True without one."""
    column = next((f"{r.success}{suffix}" for r in (SWARM_ROLES, SINGLE_ROLES) if f"{r.success}{suffix}" in frame),
                  None)
    return frame[column].to_numpy(dtype=bool) if column is not None else np.ones(len(frame), bool)


def summarize(data: pd.DataFrame, settings: Sequence[int], table: pd.DataFrame, labels: Mapping[int, str],
              options: Any) -> pd.DataFrame:
    """One row per (setting, group) (:func:`groups`), with ``pools`` saying what a pooled row pools.

    Columns: ``setting, label``, the setting columns, ``family`` (the group), ``pools``, ``n``; per
    rate ``r``: ``r_k`` (count), ``r_rate``, ``r_lo``, ``r_hi`` (Wilson); with a ``solvable`` column,
    ``n_solvable`` and ``r_solvable_rate`` (the rate among solvable fields); per continuous metric
    ``m``: ``m_n`` (finite values; successful episodes for a metric meaningful only there),
    ``m_median``, ``m_median_lo``, ``m_median_hi``, ``m_iqm``, ``m_iqm_lo``, ``m_iqm_hi``
    (percentile bootstrap, stratified by family and kind for a pooled group).
    """
    records = []
    boot = dict(n_resamples=options.resamples, confidence=options.confidence, seed=options.seed)
    rates, continuous = report_metrics(data.columns)
    names = groups(data)
    pooled = {g: pools(data, g) for g in names}
    for s in settings:
        rows_s = data[data["setting"] == s]
        for group in names:
            sub = group_rows(rows_s, group)
            n = len(sub)
            if n == 0:
                continue
            rec: dict[str, Any] = {"setting": int(s), "label": labels[s]}
            rec.update({swept_name(c): table.at[s, c] for c in table.columns})
            rec.update(family=group, pools=pooled[group], n=n)
            solvable = sub["solvable"].to_numpy(dtype=bool) if "solvable" in sub.columns else None
            if solvable is not None:
                rec["n_solvable"] = int(solvable.sum())
            for r in rates:
                row = stats.rate_row(sub[r].to_numpy(), options.confidence)
                rec.update({f"{r}_k": row.k, f"{r}_rate": row.rate, f"{r}_lo": row.lo, f"{r}_hi": row.hi})
                if solvable is not None:
                    among = sub[r].to_numpy(dtype=bool)[solvable]
                    rec[f"{r}_solvable_rate"] = float(among.mean()) if among.size else math.nan
            strata = _strata(sub, group)
            success = _success_mask(sub)
            for m in continuous:
                v = sub[m].to_numpy(dtype=np.float64)
                keep = np.isfinite(v) & (success if find_metric(m).on_success else True)
                x = v[keep]
                st = strata[keep] if strata is not None else None
                rec[f"{m}_n"] = int(keep.sum())
                locations = (("median", stats.median), ("iqm", stats.iqm))
                intervals = stats.bootstrap_cis(x, [fn for _, fn in locations], strata=st, **boot)
                for (name, fn), (lo, hi) in zip(locations, intervals):
                    rec.update({f"{m}_{name}": float(fn(x)), f"{m}_{name}_lo": lo, f"{m}_{name}_hi": hi})
            records.append(rec)
    return pd.DataFrame.from_records(records)


def _compare_one(metric: str, x: np.ndarray, y: np.ndarray, rate: bool) -> tuple[dict[str, Any], stats.Evidence]:
    """What one paired comparison shows before its family's Holm (``x``: the setting, ``y``: its baseline),
    and its evidence for :func:`~jaxapf.stats.decide`."""
    if rate:
        x, y = x.astype(bool), y.astype(bool)
        found = stats.RatePairs.of(x, y)
        out = dict(test="score", statistic=float(found.b), discordant=f"b={found.b}, c={found.c}",
                   value=float(np.mean(x)) if len(x) else math.nan,
                   baseline_value=float(np.mean(y)) if len(y) else math.nan)
    else:
        found = stats.ShiftPairs.of(x, y)
        out = dict(test="signed rank", statistic=float(np.count_nonzero(x != y)),
                   discordant=f"nonzero={int(np.count_nonzero(x != y))}",
                   value=float(np.median(x)) if len(x) else math.nan,
                   baseline_value=float(np.median(y)) if len(y) else math.nan)
    return out, found


def holm_family(metric: str, group: str, primary: Sequence[str], pooled: str | None = None) -> str:
    """The Holm family of a comparison: ``primary`` for a ``primary`` metric in a family or the pooled group
    (with ``pooled``, the headline group's name, in that group alone: a question about the whole benchmark),
    else ``exploratory: METRIC`` (a kind of a family is always exploratory, so adding one changes no
    primary verdict)."""
    inside = group == pooled if pooled is not None else "/" not in group
    return "primary" if metric in primary and inside else f"exploratory: {metric}"


def compare(data: pd.DataFrame, pairs: Mapping[int, int], labels: Mapping[int, str],
            options: Any) -> pd.DataFrame:
    """Paired comparisons of every setting with its baseline, per group and metric (module docstring).

    Rows are paired on (family, kind, field, seed). Columns: ``setting, label, baseline,
    baseline_label, family`` (the group), ``metric, higher_is_better, holm_family, test, conditioning``
    (``all pairs`` or ``both succeed``), ``n_pairs, value, baseline_value`` (rates, or medians over
    the pairs), ``delta`` (the estimate), ``confidence`` (the level Holm allows the row within its family),
    ``delta_lo, delta_hi`` (the interval at that level, which decided ``verdict``; NaN where the pairs allow
    none), ``delta_lo_95, delta_hi_95`` (the unadjusted interval at ``options.confidence``), ``statistic,
    discordant, p, margin, p_equivalence, mde`` (at the row's level), ``poi, poi_lo, poi_hi`` (paired
    probability of improvement), ``p_holm``, ``p_equivalence_holm``, ``significant``, ``verdict``.
    """
    key = [c for c in ROW_COLUMNS if c in data.columns]
    boot = dict(n_resamples=options.resamples, confidence=options.confidence, seed=options.seed)
    rates, continuous = report_metrics(data.columns)
    margin_of = margins(options)
    primary = primary_metrics(options, data.columns)
    names = groups(data)
    pooled = headline(names) if options.primary_pooled else None
    records, found, samples = [], [], []
    for s, b in pairs.items():
        merged = pd.merge(data[data["setting"] == s], data[data["setting"] == b], on=key, suffixes=("_x", "_y"))
        for group in names:
            sub = group_rows(merged, group)
            if len(sub) == 0:
                continue
            strata = _strata(sub, group)
            both = _success_mask(sub, "_x") & _success_mask(sub, "_y")
            for metric in rates + continuous:
                entry = find_metric(metric)
                rate = metric in rates
                x = sub[f"{metric}_x"].to_numpy(dtype=np.float64)
                y = sub[f"{metric}_y"].to_numpy(dtype=np.float64)
                keep = np.ones(len(x), bool) if rate else np.isfinite(x) & np.isfinite(y)
                conditioning = "all pairs"
                if entry.on_success and options.efficiency == "both-success":
                    keep &= both
                    conditioning = "both succeed"
                x, y = x[keep], y[keep]
                st = strata[keep] if strata is not None else None
                margin = margin_of.get(metric)
                rec: dict[str, Any] = {"setting": int(s), "label": labels[s], "baseline": int(b),
                                       "baseline_label": labels[b], "family": group, "metric": metric,
                                       "higher_is_better": entry.higher_is_better,
                                       "holm_family": holm_family(metric, group, primary, pooled),
                                       "conditioning": conditioning, "n_pairs": len(x),
                                       "margin": math.nan if margin is None else margin}
                shown, evidence = _compare_one(metric, x, y, rate)
                rec.update(shown)
                lo95, hi95 = evidence.interval(options.confidence) if len(x) else (math.nan, math.nan)
                rec.update(delta_lo_95=lo95 if math.isfinite(lo95) else math.nan,
                           delta_hi_95=hi95 if math.isfinite(hi95) else math.nan)
                scores = stats.pair_scores(x, y, entry.higher_is_better)
                poi_lo, poi_hi = stats.bootstrap_ci(scores, stats.mean, strata=st, **boot)
                rec.update(poi=float(stats.mean(scores)) if len(scores) else math.nan, poi_lo=poi_lo, poi_hi=poi_hi)
                records.append(rec)
                found.append(evidence)
                samples.append((x, y, "rate" if rate else "continuous"))
    frame = pd.DataFrame.from_records(records)
    if len(frame):
        alpha = 1.0 - options.confidence
        decision = stats.decide(found, frame["margin"].to_numpy(np.float64), frame["higher_is_better"].to_numpy(bool),
                                frame["holm_family"].to_numpy(object), alpha)
        frame["delta"], frame["p"], frame["p_equivalence"] = decision.estimate, decision.p, decision.p_equivalence
        frame["p_holm"], frame["p_equivalence_holm"] = decision.p_holm, decision.p_equivalence_holm
        frame["confidence"], frame["delta_lo"], frame["delta_hi"] = decision.confidence, decision.lo, decision.hi
        frame["verdict"] = decision.verdict
        frame["significant"] = frame["p_holm"] <= alpha
        frame["mde"] = [stats.minimum_detectable_difference(x, y, kind=kind, alpha=1.0 - c)
                        if len(x) > 1 and math.isfinite(c) else math.inf
                        for (x, y, kind), c in zip(samples, decision.confidence)]
    return frame


def primary_metrics(options: Any, columns: Sequence[str]) -> tuple[str, ...]:
    """The metrics of the primary Holm family: ``options.primary``, by default the report's success and
    collision (a swarm's ``swarm_success`` and ``agent_collision``)."""
    if options.primary:
        return tuple(options.primary)
    role = roles(columns)
    return (role.success, role.collision)


def _num(v: Any, digits: int = 3) -> str:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return str(v)
    if math.isnan(v):
        return "–"
    if math.isinf(v):
        return "∞" if v > 0 else "−∞"
    return f"{v:.{digits}g}"


def _pct(v: float) -> str:
    return "–" if not math.isfinite(float(v)) else f"{100 * float(v):.1f}"


def _with_ci(est: float, lo: float, hi: float, fmt: Callable[[float], str] = _num, *, missing: str = "–",
             space: str = " ") -> str:
    """``est [lo, hi]``; ``missing`` for a non-finite estimate, ``est`` alone for a non-finite interval."""
    if not math.isfinite(float(est)):
        return missing
    if not (math.isfinite(float(lo)) and math.isfinite(float(hi))):
        return fmt(est)
    return f"{fmt(est)}{space}[{fmt(lo)}, {fmt(hi)}]"


def _signed(v: float, scale: float = 1.0, digits: int = 3) -> str:
    v = float(v) * scale
    if not math.isfinite(v):
        return _num(v)
    return f"{v:+.{digits}g}"


def _group(r: Any) -> str:
    """A group's name, with what it pools."""
    return f"{r['family']} (pools {r['pools']})" if isinstance(r.get("pools"), str) and r["pools"] else r["family"]


def rates_table(summary: pd.DataFrame, rates: Sequence[str]) -> pd.DataFrame:
    """Rates per setting and group with Wilson intervals; among solvable fields where known."""
    rows = []
    solvable = "n_solvable" in summary.columns
    for _, r in summary.iterrows():
        row = {"setting": r["label"], "group": _group(r), "n": int(r["n"]),
               **{f"{m} % [CI]": _with_ci(r[f"{m}_rate"], r[f"{m}_lo"], r[f"{m}_hi"], _pct) for m in rates}}
        if solvable:
            row["solvable fields"] = int(r["n_solvable"])
            row.update({f"{m} % among solvable": _pct(r[f"{m}_solvable_rate"]) for m in rates})
        rows.append(row)
    return pd.DataFrame(rows)


def continuous_table(summary: pd.DataFrame, metric: str) -> pd.DataFrame:
    """Median and IQM of one continuous metric per setting and group, with bootstrap intervals."""
    rows = []
    for _, r in summary.iterrows():
        rows.append({"setting": r["label"], "group": _group(r), "n": int(r[f"{metric}_n"]),
                     "median [CI]": _with_ci(r[f"{metric}_median"], r[f"{metric}_median_lo"], r[f"{metric}_median_hi"]),
                     "IQM [CI]": _with_ci(r[f"{metric}_iqm"], r[f"{metric}_iqm_lo"], r[f"{metric}_iqm_hi"])})
    return pd.DataFrame(rows)


def _delta_text(r: Any, rate: bool) -> str:
    """The estimate with the interval that decided the verdict (``at 99.6 %``), or why there is none."""
    fmt = (lambda v: _signed(v, 100.0, 3)) if rate else _signed
    if not math.isfinite(float(r["delta"])):
        return "–"
    level = stats.format_level(r["confidence"])
    if not (math.isfinite(float(r["delta_lo"])) and math.isfinite(float(r["delta_hi"]))):
        return f"{fmt(r['delta'])} [no {level} CI from {int(r['n_pairs'])} pairs]"
    return f"{fmt(r['delta'])} [{fmt(r['delta_lo'])}, {fmt(r['delta_hi'])}] at {level}"


def _decided_by(r: Any, rate: bool) -> str:
    """:func:`~jaxapf.stats.verdict_basis` of one comparison, with its Holm family; for a continuous metric
    whose medians differ by more than the interval of the paired shift allows, also that the test compared
    paired differences."""
    basis = stats.verdict_basis(float(r["delta_lo"]), float(r["delta_hi"]), float(r["confidence"]),
                                float(np.nan_to_num(r["margin"], nan=0.0)), bool(r["higher_is_better"]))
    gap = float(r["value"]) - float(r["baseline_value"])
    bounded = math.isfinite(float(r["delta_lo"])) and math.isfinite(float(r["delta_hi"]))
    if not rate and bounded and math.isfinite(gap) and not float(r["delta_lo"]) <= gap <= float(r["delta_hi"]):
        basis += f"; medians differ by {_signed(gap)}, the test compares paired differences"
    return basis


def comparison_table(comp: pd.DataFrame, metric: str) -> pd.DataFrame:
    """The paired comparisons of one metric: the estimate with the interval at the level Holm allows it in
    its family (which decides the verdict), the family, tests, margin, MDE."""
    rows = []
    rate = find_metric(metric).kind == "rate"
    scale = (lambda v: _signed(v, 100.0, 3)) if rate else (lambda v: _num(v))
    for _, r in comp[comp["metric"] == metric].iterrows():
        value = (_pct(r["value"]) + " vs " + _pct(r["baseline_value"])) if rate else (
            _num(r["value"]) + " vs " + _num(r["baseline_value"]))
        rows.append({
            "setting": r["label"], "baseline": f"#{int(r['baseline'])}", "group": r["family"],
            "pairs": f"{int(r['n_pairs'])}" + (" (both succeed)" if r["conditioning"] == "both succeed" else ""),
            ("rate %" if rate else "median") + " (setting vs baseline)": value,
            ("Δ pp [CI at its level]" if rate else "HL shift [CI at its level]"): _delta_text(r, rate),
            "verdict": r["verdict"],
            "decided by": _decided_by(r, rate),
            "Holm family": r["holm_family"],
            "p Holm": stats.format_p(r["p_holm"]) + (" *" if bool(r["significant"]) else ""),
            "margin": "–" if not math.isfinite(float(r["margin"])) else scale(r["margin"]).lstrip("+"),
            "p equiv. Holm": stats.format_p(r["p_equivalence_holm"]),
            "MDE": scale(r["mde"]).lstrip("+") if math.isfinite(float(r["mde"])) else "none",
            "PoI [CI]": _with_ci(r["poi"], r["poi_lo"], r["poi_hi"], lambda v: f"{float(v):.2f}"),
            "test": f"{r['test']} ({r['discordant']})",
        })
    return pd.DataFrame(rows)


def findings(summary: pd.DataFrame, comparisons: pd.DataFrame, group: str, options: Any) -> list[str]:
    """Headline sentences for the pooled group, every number taken from the two tables."""
    sub = summary[summary["family"] == group]
    out = []
    role = SWARM_ROLES if f"{SWARM_ROLES.success}_rate" in sub.columns else SINGLE_ROLES
    picks = ((role.success, "rate", True, "Highest success rate"),
             (role.collision, "rate", False, "Lowest collision rate"),
             (role.stalled, "rate", False, "Lowest stall rate" if not role.swarm else "Lowest deadlock rate"),
             (role.clearance, "iqm", True, "Largest IQM of the minimum clearance" if not role.swarm else
              "Largest IQM of the closest approach between UAVs"))
    for metric, kind, high, text in picks:
        col = f"{metric}_{kind}"
        if col not in sub.columns:
            continue
        values = sub[col].to_numpy(dtype=np.float64)
        if not np.any(np.isfinite(values)):
            continue
        best = np.nanmax(values) if high else np.nanmin(values)
        rows = sub[np.isclose(values, best, rtol=0, atol=1e-12)]
        r = rows.iloc[0]
        if kind == "rate":
            value = f"{_pct(r[col])} % [{_pct(r[f'{metric}_lo'])}, {_pct(r[f'{metric}_hi'])}]"
        else:
            value = _with_ci(r[col], r[f"{col}_lo"], r[f"{col}_hi"]) + f" {find_metric(metric).unit}".rstrip()
        names = ", ".join(rows["label"].head(3)) + (f" and {len(rows) - 3} more" if len(rows) > 3 else "")
        out.append(f"{text} ({group}): {names}: {value}.")
    if len(comparisons):
        comp = comparisons[comparisons["family"] == group]
        primary = comparisons[comparisons["holm_family"] == "primary"]
        metrics = ", ".join(pd.unique(primary["metric"])) or "none"
        for family, rows in (("primary", comp[comp["holm_family"] == "primary"]),
                             ("exploratory", comp[comp["holm_family"] != "primary"])):
            if not len(rows):
                continue
            counts = rows["verdict"].value_counts()
            scope = (f"{metrics}, Holm over its {int(primary['p'].notna().sum())} tests" if family == "primary"
                     else "Holm within each metric")
            out.append(f"{family.capitalize()} verdicts against the baseline ({group}, {len(rows)} comparisons; "
                       f"{scope}, α = {options.alpha:.3g}): "
                       + ", ".join(f"{counts.get(v, 0)} {v}" for v in stats.VERDICTS) + ".")
        relevant = comp[comp["verdict"].isin(("better", "worse"))]
        relevant = relevant.assign(order=relevant["holm_family"] != "primary")
        for _, r in relevant.sort_values(["order", "p_holm", "setting"]).head(10).iterrows():
            rate = find_metric(r["metric"]).kind == "rate"
            what = "Δ " + _delta_text(r, rate).replace(" [", " pp [", 1) if rate else "shift " + _delta_text(r, rate)
            unit = "" if rate else f" {find_metric(r['metric']).unit}".rstrip()
            pairs = f"{int(r['n_pairs'])} pairs" + (", both succeed" if r["conditioning"] == "both succeed" else "")
            tag = "" if r["holm_family"] == "primary" else " (exploratory)"
            out.append(f"{r['verdict'].capitalize()}{tag}: {r['label']} vs #{int(r['baseline'])}, {r['metric']} "
                       f"{what}{unit} ({pairs}; p Holm {stats.format_p(r['p_holm'])}).")
    return out


def verdict_matrix(comparisons: pd.DataFrame, metrics: Sequence[str], groups: Sequence[str]) -> pd.DataFrame:
    """One row per compared setting (its baseline named where settings have their own), one column per
    (group, metric), each cell the verdict's mark (:data:`VERDICT_MARKS`; empty where not compared);
    columns are a two-level index (group, metric), a metric outside the primary Holm family marked
    ``(exploratory)``."""
    comp = comparisons[comparisons["family"].isin(groups)]
    verdict = comp.set_index(["setting", "family", "metric"])["verdict"]
    settings = list(pd.unique(comp["setting"]))
    label = comp.drop_duplicates("setting").set_index("setting")
    each_own = label["baseline_label"].nunique() > 1
    other = comp[comp["holm_family"] != "primary"]
    exploratory = set(zip(other["family"], other["metric"]))
    columns = [("", "setting")] + [(g, f"{m} (exploratory)" if (g, m) in exploratory else m) for g in groups
                                   for m in metrics]
    rows = []
    for s in settings:
        row = [label.at[s, "label"] + (f" (vs #{int(label.at[s, 'baseline'])})" if each_own else "")]
        row += [VERDICT_MARKS.get(verdict.get((s, g, m), ""), "") for g in groups for m in metrics]
        rows.append(row)
    return pd.DataFrame(rows, columns=pd.MultiIndex.from_tuples(columns))


#: The rule of :func:`bottom_line`, stated under it on every report.
BOTTOM_LINE_RULE = ("Rates in %, each setting against its baseline on the same fields: the paired difference in "
                    "percentage points with the interval that decided its verdict (at the level Holm allows it in its "
                    "family) and the verdict; the settings with the most better "
                    "minus worse verdicts first (at most two of each end); then each family where a setting is "
                    "better or worse on a rate than it is pooled.")


def _rate_clause(r: Any) -> str:
    """``success 55.0 vs 57.5 (-2.5 [-4.1, -0.9] at 99.6 %, worse)``: one rate of one setting against its
    baseline, with the interval that decided the verdict; an exploratory one says so."""
    tag = "" if r["holm_family"] == "primary" else ", exploratory"
    if not (math.isfinite(float(r["delta_lo"])) and math.isfinite(float(r["delta_hi"]))):
        return f"{r['metric']} {_pct(r['value'])} vs {_pct(r['baseline_value'])} (no pairs{tag}, {r['verdict']})"
    return (f"{r['metric']} {_pct(r['value'])} vs {_pct(r['baseline_value'])} ({_signed(r['delta'], 100.0, 2)} "
            f"[{_signed(r['delta_lo'], 100.0, 2)}, {_signed(r['delta_hi'], 100.0, 2)}] at "
            f"{stats.format_level(r['confidence'])}{tag}, {r['verdict']})")


def bottom_line(comparisons: pd.DataFrame, group: str, families: Sequence[str], rates: Sequence[str],
                most: int = 2) -> list[str]:
    """The report's summary, one paragraph per group (each under sixty words at ``most = 2``): in ``group``
    (the pooled one) the first two ``rates`` of the settings with the most *better* minus *worse* verdicts
    (``most`` of each end) against their baseline, with the difference's interval and verdict; then each
    family where a setting is better or worse on a rate than it is pooled (``most`` of them).
    :data:`BOTTOM_LINE_RULE` states the rule."""
    comp = comparisons[comparisons["family"] == group] if len(comparisons) else comparisons
    if not len(comp):
        return ["Nothing to compare: every reported setting is a baseline setting."]
    score = comp.groupby("setting", sort=False)["verdict"].agg(
        lambda v: int((v == "better").sum()) - int((v == "worse").sum()))
    order = list(score.sort_values(ascending=False, kind="stable").index)
    shown = order if len(order) <= 2 * most else order[:most] + order[-most:]
    bases = pd.unique(comp["baseline_label"])
    against = f"against {bases[0]}" if len(bases) == 1 else "each against its baseline"
    first = list(rates)[:2]

    def clauses(sub: pd.DataFrame, settings: Sequence[int], metrics: Sequence[str]) -> list[str]:
        out = []
        for s in settings:
            rows = sub[(sub["setting"] == s) & sub["metric"].isin(metrics)]
            if len(rows):
                out.append(f"{rows['label'].iloc[0]}: " + ", ".join(_rate_clause(r) for _, r in rows.iterrows()))
        return out

    head = group.capitalize() if group != ALL else "Pooled over the families"
    text = [f"{head} ({against}): " + "; ".join(clauses(comp, shown, first))
            + ("" if len(shown) == len(order) else f" ({len(order) - len(shown)} settings in between)") + "."]
    pooled = comp.set_index(["setting", "metric"])["verdict"]
    for f in families:
        sub = comparisons[(comparisons["family"] == f) & comparisons["metric"].isin(rates)]
        moved = sub[[pooled.get((r.setting, r.metric)) != r.verdict and r.verdict in ("better", "worse")
                     for r in sub.itertuples()]]
        if len(moved):
            picked = moved.head(most)
            text.append(f"In {f}: " + "; ".join(f"{r['label']}: {_rate_clause(r)}" for _, r in picked.iterrows())
                        + (f" (and {len(moved) - most} more)" if len(moved) > most else "") + ".")
    return text
