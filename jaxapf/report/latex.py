"""The report's LaTeX tables (booktabs), generated from the summary and comparison tables."""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import pandas as pd

from .. import stats
from ..gains import GAINS
from .load import roles
from .select import Selection, format_value, ignored_columns
from .tables import _with_ci

__all__ = ["latex_tables"]

#: Greek gain symbols as LaTeX.
_GREEK = {"γ": r"\gamma", "η": r"\eta", "ρ": r"\rho", "σ": r"\sigma", "α": r"\alpha", "β": r"\beta",
          "κ": r"\kappa", "λ": r"\lambda", "ω": r"\omega", "τ": r"\tau"}


_TEX_ESCAPE = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
               "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}


def _tex(text: Any) -> str:
    return "".join(_TEX_ESCAPE.get(ch, ch) for ch in str(text))


def _tex_symbol(column: str) -> str:
    """A gain's symbol in math mode (``$\\gamma$``, ``$k$``), any other column as escaped text."""
    label = GAINS.get(column).label if column in GAINS else column
    if label in _GREEK:
        return f"${_GREEK[label]}$"
    return f"${label}$" if len(label) == 1 else _tex(label)


def _tex_label(s: int, table: pd.DataFrame, swept: Sequence[str]) -> str:
    method = str(table.at[s, "method"]) if "method" in table.columns else ""
    ignored = ignored_columns(table.loc[s])
    parts = [_tex(f"#{s}"), _tex(method)]
    parts += [f"{_tex_symbol(c)}={_tex(format_value(table.at[s, c]))}" for c in swept
              if c != "method" and c not in ignored]
    return " ".join(p for p in parts if p)


def _tex_ci(est: float, lo: float, hi: float, fmt: Callable[[float], str]) -> str:
    return _with_ci(est, lo, hi, fmt, missing="--", space=" \\,")


def _tex_num(v: float) -> str:
    v = float(v)
    return "--" if not math.isfinite(v) else f"{v:.3g}"


def _tex_pct(v: float) -> str:
    v = float(v)
    return "--" if not math.isfinite(v) else f"{100 * v:.1f}"


def _tex_signed_pct(v: float) -> str:
    v = float(v)
    return "--" if not math.isfinite(v) else f"{100 * v:+.1f}"


def _tex_p(v: float) -> str:
    v = float(v)
    return "--" if not math.isfinite(v) else ("$<$0.001" if v < 0.001 else f"{v:.3f}")


def latex_tables(summary: pd.DataFrame, comparisons: pd.DataFrame, sel: Selection, group: str,
                 options: Any, spec_name: str, rates: Sequence[str]) -> str:
    """The outcome, time-to-goal and paired-comparison tables of ``group`` as LaTeX."""
    conf = f"{100 * options.confidence:g}"
    role = roles(sel.data.columns)
    near, time = role.clearance, role.time
    lines = [
        f"% jaxapf report table: {_tex(spec_name)} (needs \\usepackage{{booktabs}}); generated from the sweep, "
        "do not edit by hand",
        r"\begin{table}[t]", r"\centering", r"\small",
        rf"\caption{{Outcomes per setting ({_tex(group)}; $n$ episodes). Rates in \% with {conf}\,\% Wilson "
        rf"intervals; {'min.' if not role.swarm else 'closest UAV--UAV'}\ clearance: IQM [m] and "
        rf"{'time to goal' if not role.swarm else 'makespan'}: median [s] (successful episodes) with "
        rf"{conf}\,\% stratified bootstrap intervals ({options.resamples} resamples).}}",
        r"\label{tab:jaxapf-outcomes}",
        rf"\begin{{tabular}}{{lr{'l' * (len(rates) + 1)}}}", r"\toprule",
        "Setting & $n$ & " + " & ".join(_tex(m.replace("_", " ").capitalize()) + r" [\%]" for m in rates)
        + r" & Clearance [m] \\ \midrule",
    ]
    sub = summary[summary["family"] == group]
    for _, r in sub.iterrows():
        cells = [_tex_label(int(r["setting"]), sel.table, sel.swept), str(int(r["n"]))]
        cells += [_tex_ci(r[f"{m}_rate"], r[f"{m}_lo"], r[f"{m}_hi"], _tex_pct) for m in rates]
        cells.append(_tex_ci(r[f"{near}_iqm"], r[f"{near}_iqm_lo"], r[f"{near}_iqm_hi"], _tex_num))
        lines.append(" & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    # time to goal as an extra table keeps the first one narrow enough for one column
    lines += [
        r"\begin{table}[t]", r"\centering", r"\small",
        rf"\caption{{{'Time to goal' if not role.swarm else 'Makespan'} [s] over successful episodes: median with "
        rf"{conf}\,\% stratified bootstrap "
        rf"interval and the number of successful episodes ({_tex(group)}).}}",
        r"\label{tab:jaxapf-time}", r"\begin{tabular}{lrl}", r"\toprule",
        rf"Setting & $n_{{\mathrm{{success}}}}$ & {'Time to goal' if not role.swarm else 'Makespan'} [s] \\ \midrule",
    ]
    for _, r in sub.iterrows():
        lines.append(" & ".join([_tex_label(int(r["setting"]), sel.table, sel.swept), str(int(r[f"{time}_n"])),
                                 _tex_ci(r[f"{time}_median"], r[f"{time}_median_lo"], r[f"{time}_median_hi"],
                                         _tex_num)]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    if len(comparisons):
        comp = comparisons[comparisons["family"] == group]
        lines += [
            r"\begin{table}[t]", r"\centering", r"\small",
            rf"\caption{{Paired comparison with the baseline ({_tex(options.baseline)}; {_tex(group)}): "
            rf"difference in rate (percentage points, Tango score interval at the level Holm allows it within "
            rf"the primary family of {int((comparisons['holm_family'] == 'primary').sum())} tests, which decides "
            rf"its verdict), the level, paired probability of improvement (PoI) and Holm-adjusted score $p$.}}",
            r"\label{tab:jaxapf-paired}", r"\begin{tabular}{llllll}", r"\toprule",
            r"Setting & Baseline & $\Delta$ success [pp] & $\Delta$ collision [pp] & PoI success & $p_{\mathrm{Holm}}$ "
            r"(succ./coll.) \\ \midrule",
        ]
        for s in sorted(set(comp["setting"])):
            cs = comp[comp["setting"] == s].set_index("metric")
            if role.success not in cs.index:
                continue
            succ, coll = cs.loc[role.success], cs.loc[role.collision]
            lines.append(" & ".join([
                _tex_label(int(s), sel.table, sel.swept), _tex(f"#{int(succ['baseline'])}"),
                _tex_ci(succ["delta"], succ["delta_lo"], succ["delta_hi"], _tex_signed_pct)
                + rf" ({_tex(stats.format_level(succ['confidence']))})",
                _tex_ci(coll["delta"], coll["delta_lo"], coll["delta_hi"], _tex_signed_pct)
                + rf" ({_tex(stats.format_level(coll['confidence']))})",
                _tex_num(succ["poi"]), f"{_tex_p(succ['p_holm'])} / {_tex_p(coll['p_holm'])}"]) + r" \\")
        lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    return "\n".join(lines)


