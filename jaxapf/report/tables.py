"""The report's statistics tables (per setting, and paired with the baseline) and their text."""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from .. import stats
from ..metrics import METRICS
from .load import ROW_COLUMNS, report_metrics

__all__ = ["ALL", "groups", "group_rows", "summarize", "compare", "rates_table", "continuous_table",
           "comparison_table", "findings"]

#: The name of the group that pools every family of a report.
ALL = "all"


def groups(data: pd.DataFrame) -> list[str]:
    families = sorted(str(f) for f in pd.unique(data["family"]))
    return families + ([ALL] if len(families) > 1 else [])


def group_rows(frame: pd.DataFrame, group: str) -> pd.DataFrame:
    return frame if group == ALL else frame[frame["family"] == group]


def _strata(frame: pd.DataFrame, group: str) -> np.ndarray | None:
    return frame["family"].to_numpy() if group == ALL else None


def summarize(data: pd.DataFrame, settings: Sequence[int], table: pd.DataFrame, labels: Mapping[int, str],
              options: Any) -> pd.DataFrame:
    """One row per (setting, family group) — each family and, with several, ``all`` pooled.

    Columns: ``setting, label``, the setting columns, ``family, n``; per rate ``r``: ``r_k`` (count),
    ``r_rate``, ``r_lo``, ``r_hi`` (Wilson); per continuous metric ``m``: ``m_n`` (finite values;
    ``time_to_goal``: successful episodes), ``m_median``, ``m_median_lo``, ``m_median_hi``,
    ``m_iqm``, ``m_iqm_lo``, ``m_iqm_hi`` (percentile bootstrap, stratified by family for ``all``).
    """
    records = []
    boot = dict(n_resamples=options.resamples, confidence=options.confidence, seed=options.seed)
    rates, continuous = report_metrics(data.columns)
    for s in settings:
        rows_s = data[data["setting"] == s]
        for group in groups(data):
            sub = group_rows(rows_s, group)
            n = len(sub)
            if n == 0:
                continue
            rec: dict[str, Any] = {"setting": int(s), "label": labels[s]}
            rec.update({c: table.at[s, c] for c in table.columns})
            rec.update(family=group, n=n)
            for r in rates:
                k = int(sub[r].sum())
                lo, hi = stats.wilson_interval(k, n, options.confidence)
                rec.update({f"{r}_k": k, f"{r}_rate": k / n, f"{r}_lo": float(lo), f"{r}_hi": float(hi)})
            strata = _strata(sub, group)
            for m in continuous:
                v = sub[m].to_numpy(dtype=np.float64)
                keep = np.isfinite(v)
                x = v[keep]
                st = strata[keep] if strata is not None else None
                rec[f"{m}_n"] = int(keep.sum())
                for name, fn in (("median", stats.median), ("iqm", stats.iqm)):
                    lo, hi = stats.bootstrap_ci(x, fn, strata=st, **boot)
                    rec.update({f"{m}_{name}": float(fn(x)), f"{m}_{name}_lo": lo, f"{m}_{name}_hi": hi})
            records.append(rec)
    return pd.DataFrame.from_records(records)


def compare(data: pd.DataFrame, pairs: Mapping[int, int], labels: Mapping[int, str],
            options: Any) -> pd.DataFrame:
    """Paired comparisons of every setting with its baseline, per family group and metric.

    Rows are paired on (family, field, seed). Rates: exact McNemar test, difference in rates (mean
    paired difference). Continuous metrics, on the pairs where both values are finite
    (``time_to_goal``: both successful): Wilcoxon signed-rank test, difference of IQMs. Both with
    paired bootstrap CIs, and the paired probability of improvement with its bootstrap CI.
    ``p_holm``: Holm-adjusted over every p-value of the table; ``significant``: ``p_holm <= alpha``.
    """
    key = [c for c in ROW_COLUMNS if c in data.columns]
    boot = dict(n_resamples=options.resamples, confidence=options.confidence, seed=options.seed)
    rates, continuous = report_metrics(data.columns)
    records = []
    for s, b in pairs.items():
        merged = pd.merge(data[data["setting"] == s], data[data["setting"] == b], on=key, suffixes=("_x", "_y"))
        for group in groups(data):
            sub = group_rows(merged, group)
            if len(sub) == 0:
                continue
            strata = _strata(sub, group)
            for metric in rates + continuous:
                hib = METRICS.get(metric).higher_is_better
                x = sub[f"{metric}_x"].to_numpy(dtype=np.float64)
                y = sub[f"{metric}_y"].to_numpy(dtype=np.float64)
                rec: dict[str, Any] = {"setting": int(s), "label": labels[s], "baseline": int(b),
                                       "baseline_label": labels[b], "family": group, "metric": metric,
                                       "higher_is_better": hib}
                if metric in rates:
                    st = strata
                    test = stats.mcnemar_exact(x.astype(bool), y.astype(bool))
                    d, lo, hi = stats.paired_bootstrap_ci(x, y, stats.mean, strata=st, **boot)
                    rec.update(test="mcnemar", n_pairs=len(x), value=stats.mean(x), baseline_value=stats.mean(y),
                               delta=d, delta_lo=lo, delta_hi=hi, statistic=float(test.b),
                               discordant=f"b={test.b}, c={test.c}", p=test.pvalue)
                else:
                    keep = np.isfinite(x) & np.isfinite(y)
                    x, y = x[keep], y[keep]
                    st = strata[keep] if strata is not None else None
                    w = stats.wilcoxon_paired(x, y)
                    d, lo, hi = stats.paired_bootstrap_ci(x, y, stats.iqm, strata=st, **boot)
                    rec.update(test="wilcoxon", n_pairs=len(x), value=float(stats.iqm(x)),
                               baseline_value=float(stats.iqm(y)), delta=d, delta_lo=lo, delta_hi=hi,
                               statistic=w.statistic, discordant=f"nonzero={w.n_nonzero}", p=w.pvalue)
                scores = stats.pair_scores(x, y, hib)
                poi_lo, poi_hi = stats.bootstrap_ci(scores, stats.mean, strata=st, **boot)
                rec.update(poi=float(stats.mean(scores)) if len(scores) else math.nan, poi_lo=poi_lo, poi_hi=poi_hi)
                records.append(rec)
    frame = pd.DataFrame.from_records(records)
    if len(frame):
        frame["p_holm"] = stats.holm(frame["p"].to_numpy(dtype=np.float64))
        frame["significant"] = frame["p_holm"] <= options.alpha
    return frame


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


def _p(v: float) -> str:
    v = float(v)
    if not math.isfinite(v):
        return "–"
    return "<0.001" if v < 0.001 else f"{v:.3f}"


def _signed(v: float, scale: float = 1.0, digits: int = 3) -> str:
    v = float(v) * scale
    if not math.isfinite(v):
        return _num(v)
    return f"{v:+.{digits}g}"


def rates_table(summary: pd.DataFrame, rates: Sequence[str]) -> pd.DataFrame:
    rows = []
    for _, r in summary.iterrows():
        rows.append({"setting": r["label"], "family": r["family"], "n": int(r["n"]),
                     **{f"{m} % [CI]": _with_ci(r[f"{m}_rate"], r[f"{m}_lo"], r[f"{m}_hi"], _pct) for m in rates}})
    return pd.DataFrame(rows)


def continuous_table(summary: pd.DataFrame, metric: str) -> pd.DataFrame:
    rows = []
    for _, r in summary.iterrows():
        rows.append({"setting": r["label"], "family": r["family"], "n": int(r[f"{metric}_n"]),
                     "median [CI]": _with_ci(r[f"{metric}_median"], r[f"{metric}_median_lo"], r[f"{metric}_median_hi"]),
                     "IQM [CI]": _with_ci(r[f"{metric}_iqm"], r[f"{metric}_iqm_lo"], r[f"{metric}_iqm_hi"])})
    return pd.DataFrame(rows)


def comparison_table(comp: pd.DataFrame, metric: str) -> pd.DataFrame:
    rows = []
    rate = METRICS.get(metric).kind == "rate"
    for _, r in comp[comp["metric"] == metric].iterrows():
        fmt = (lambda v: _signed(v, 100.0, 3)) if rate else (lambda v: _signed(v))
        value = (_pct(r["value"]) + " vs " + _pct(r["baseline_value"])) if rate else (
            _num(r["value"]) + " vs " + _num(r["baseline_value"]))
        rows.append({
            "setting": r["label"], "baseline": f"#{int(r['baseline'])}", "family": r["family"],
            "pairs": int(r["n_pairs"]),
            ("rate %" if rate else "IQM") + " (setting vs baseline)": value,
            ("Δ pp [CI]" if rate else "Δ IQM [CI]"): _with_ci(r["delta"], r["delta_lo"], r["delta_hi"], fmt),
            "PoI [CI]": _with_ci(r["poi"], r["poi_lo"], r["poi_hi"], lambda v: f"{float(v):.2f}"),
            "test": f"{r['test']} ({r['discordant']})",
            "p": _p(r["p"]), "p Holm": _p(r["p_holm"]) + (" *" if bool(r["significant"]) else ""),
        })
    return pd.DataFrame(rows)


def findings(summary: pd.DataFrame, comparisons: pd.DataFrame, group: str, options: Any) -> list[str]:
    """Headline sentences for the pooled group, every number taken from the two tables."""
    sub = summary[summary["family"] == group]
    out = []
    picks = (("success", "rate", True, "Highest success rate"), ("collision", "rate", False, "Lowest collision rate"),
             ("stalled", "rate", False, "Lowest stall rate"),
             ("min_clearance", "iqm", True, "Largest IQM of the minimum clearance"))
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
            value = _with_ci(r[col], r[f"{col}_lo"], r[f"{col}_hi"]) + f" {METRICS.get(metric).unit}".rstrip()
        names = ", ".join(rows["label"].head(3)) + (f" and {len(rows) - 3} more" if len(rows) > 3 else "")
        out.append(f"{text} ({group}): {names}: {value}.")
    if len(comparisons):
        comp = comparisons[(comparisons["family"] == group) & comparisons["significant"].astype(bool)]
        total = int(comparisons["p"].notna().sum())
        if len(comp) == 0:
            out.append(f"No paired difference to the baseline is significant at {options.alpha:.3g} after Holm "
                       f"correction over {total} tests.")
        else:
            out.append(f"{len(comp)} paired difference(s) to the baseline are significant ({group}, Holm over "
                       f"{total} tests, α = {options.alpha:.3g}); the strongest:")
            for _, r in comp.sort_values(["p_holm", "setting"]).head(10).iterrows():
                rate = METRICS.get(r["metric"]).kind == "rate"
                delta = _with_ci(r["delta"], r["delta_lo"], r["delta_hi"],
                                 (lambda v: _signed(v, 100.0, 3)) if rate else _signed)
                better = "better" if (r["delta"] > 0) == bool(r["higher_is_better"]) else "worse"
                out.append(f"  {r['label']} vs #{int(r['baseline'])}: {r['metric']} "
                           f"{'Δ ' + delta + ' pp' if rate else 'Δ IQM ' + delta} ({better}), "
                           f"PoI {float(r['poi']):.2f}, p Holm {_p(r['p_holm'])}")
    return out


