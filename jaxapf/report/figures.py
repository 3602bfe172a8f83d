"""Figures of ``jaxapf report``, drawn from the report's tables (pandas) without ``pyplot``.

Every ``plot_*`` function returns a :class:`matplotlib.figure.Figure` (rendered through the Agg
canvas that ``Figure.savefig`` attaches), so nothing here selects or depends on a GUI backend. The
numbers come from the summary and comparison tables (:mod:`jaxapf.report.tables`) or from the
episode rows directly (:func:`table_figures`, :func:`row_figures`: together every figure of a
report). Line styles come from the registered planners.
"""

from __future__ import annotations

import math
import pathlib
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from .. import stats
from ..metrics import find_metric
from ..planners import PLANNERS
from ..simulate.figures import panel_grid, plain_text
from .document import VERDICT_COLORS, FigureFile, save_figure
from .load import SINGLE_ROLES, SWARM_ROLES, ReportError, report_metrics, roles
from .select import Selection, format_value, ignored_columns, swept_columns, symbol
from .tables import ALL, group_rows, groups, headline

__all__ = [
    "setting_colors",
    "plot_heatmaps",
    "plot_ecdf",
    "plot_rates",
    "plot_continuous",
    "plot_differences",
    "plot_performance_profile",
    "check_heatmap",
    "row_figures",
    "table_figures",
    "DEFAULT_HEATMAP",
]

#: The heatmaps' gains unless ``--heatmap`` names others; a sweep without them gets a note instead.
DEFAULT_HEATMAP = ("gamma", "k")

_GROUP_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "h")


def _linestyle(method: str) -> str:
    """The registered planner's line style, solid for others."""
    return (PLANNERS.get(method).linestyle if method in PLANNERS else None) or "-"


def setting_colors(settings: Sequence[int]) -> dict[int, tuple]:
    """A colour per setting index: tab10 up to 10 settings, tab20 up to 20, viridis beyond."""
    settings = list(settings)
    n = len(settings)
    if n <= 10:
        cmap = colormaps["tab10"]
        return {s: cmap(i) for i, s in enumerate(settings)}
    if n <= 20:
        cmap = colormaps["tab20"]
        return {s: cmap(i) for i, s in enumerate(settings)}
    cmap = colormaps["viridis"]
    return {s: cmap(i / (n - 1)) for i, s in enumerate(settings)}


def _group_colors(groups: Sequence[str]) -> dict[str, object]:
    cmap = colormaps["tab10"]
    out, i = {}, 0
    for g in groups:
        if g == ALL:
            out[g] = "black"
        else:
            out[g] = cmap(i % 10)
            i += 1
    return out


def _legend_below(fig: Figure, handles, ncol: int | None = None) -> None:
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncol=ncol or min(len(handles), 4), fontsize=7)


# --------------------------------------------------------------------------------------------
# heatmaps
# --------------------------------------------------------------------------------------------


def plot_heatmaps(cells: pd.DataFrame, x: str, y: str, value: str, title: str) -> Figure:
    """Grid of heatmaps of a rate over two gains: one column per family group, one row per panel.

    Args:
      cells: one row per cell with columns ``row`` (family group), ``panel`` (text naming the
        values of the other swept columns), ``x``, ``y`` values, ``value`` (rate in [0, 1]) and ``n``.
      x, y: the two gain columns (axes).
      value: the column of ``cells`` with the rate.
    """
    groups = list(dict.fromkeys(cells["row"]))
    panels = list(dict.fromkeys(cells["panel"]))
    xs = np.sort(cells[x].unique())
    ys = np.sort(cells[y].unique())
    fig = Figure(figsize=(1.4 + (0.55 * len(xs) + 1.1) * len(groups), 1.3 + (0.45 * len(ys) + 1.0) * len(panels)),
                 layout="constrained")
    axes = fig.subplots(len(panels), len(groups), squeeze=False)
    image = None
    for i, panel in enumerate(panels):
        for j, group in enumerate(groups):
            ax = axes[i][j]
            sub = cells[(cells["row"] == group) & (cells["panel"] == panel)]
            grid = np.full((len(ys), len(xs)), np.nan)
            for _, c in sub.iterrows():
                grid[np.searchsorted(ys, c[y]), np.searchsorted(xs, c[x])] = c[value]
            image = ax.imshow(grid, origin="lower", cmap="viridis", vmin=0.0, vmax=1.0, aspect="auto")
            for (a, b), v in np.ndenumerate(grid):
                if math.isfinite(v):
                    ax.text(b, a, f"{100 * v:.0f}", ha="center", va="center", fontsize=7,
                            color="white" if v < 0.6 else "black")
            ax.set_xticks(range(len(xs)), [f"{v:g}" for v in xs], fontsize=7)
            ax.set_yticks(range(len(ys)), [f"{v:g}" for v in ys], fontsize=7)
            ax.set_xlabel(x)
            ax.set_ylabel(y)
            ax.set_title(group if len(panels) == 1 else f"{group} · {panel}", fontsize=8)
    if image is not None:
        fig.colorbar(image, ax=axes, shrink=0.8, label=f"{value} (cells in %)")
    fig.suptitle(title, fontsize=9)
    return fig


# --------------------------------------------------------------------------------------------
# distributions
# --------------------------------------------------------------------------------------------


def _group_panels(n: int, ylabel: str) -> tuple[Figure, np.ndarray]:
    """``n`` panels, one per family group, sharing a fraction axis (0 to 1) whose label and ticks
    only the first column carries."""
    fig, axes = panel_grid(n, (4.0, 3.3), (0.4, 1.0), sharey=True)
    for ax in axes:
        if ax.get_subplotspec().is_first_col():
            ax.set_ylabel(ylabel)
    return fig, axes


def plot_ecdf(values: Mapping[str, Mapping[int, np.ndarray]], labels: Mapping[int, str],
              methods: Mapping[int, str], metric: str, unit: str = "", vline: float | None = 0.0) -> Figure:
    """ECDF of ``metric`` per setting; one panel per family group (``values[group][setting]``)."""
    groups = list(values)
    settings = list(labels)
    colors = setting_colors(settings)
    fig, axes = _group_panels(len(groups), "fraction of episodes ≤ x")
    for ax, group in zip(axes, groups):
        for s in settings:
            x, f = stats.ecdf(values[group].get(s, np.empty(0)))
            x = x[np.isfinite(x)]
            if x.size == 0:
                continue
            f = f[: x.size]
            ax.step(np.concatenate([[x[0]], x]), np.concatenate([[0.0], f]), where="post",
                    color=colors[s], linestyle=_linestyle(methods[s]), linewidth=1.2)
        if vline is not None:
            ax.axvline(vline, color="red", linewidth=0.8, alpha=0.6)
        ax.set_title(group)
        ax.set_xlabel(f"{metric} [{unit}]" if unit else metric)
        ax.set_ylim(0, 1.02)
        ax.grid(True, linewidth=0.4, alpha=0.5)
    handles = [Line2D([], [], color=colors[s], linestyle=_linestyle(methods[s]), label=labels[s])
               for s in settings]
    _legend_below(fig, handles, ncol=min(len(handles), 3))
    fig.suptitle(f"Empirical CDF of {metric} per setting"
                 + (" (red line: collision)" if vline == 0.0 and metric in (SINGLE_ROLES.clearance,
                                                                             SWARM_ROLES.clearance) else ""),
                 fontsize=10)
    return fig


def plot_performance_profile(taus: np.ndarray, curves: Mapping[str, Mapping[int, tuple]],
                             labels: Mapping[int, str], methods: Mapping[int, str], metric: str,
                             bands: bool) -> Figure:
    """Fraction of episodes with ``metric > τ`` against τ; ``curves[group][setting] = (frac, lo, hi)``."""
    groups = list(curves)
    settings = list(labels)
    colors = setting_colors(settings)
    fig, axes = _group_panels(len(groups), f"fraction of episodes with {metric} > τ")
    for ax, group in zip(axes, groups):
        for s in settings:
            if s not in curves[group]:
                continue
            frac, lo, hi = curves[group][s]
            ax.plot(taus, frac, color=colors[s], linestyle=_linestyle(methods[s]), linewidth=1.2,
                    drawstyle="steps-post")
            if bands:
                ax.fill_between(taus, lo, hi, color=colors[s], alpha=0.15, linewidth=0, step="post")
        ax.set_title(group)
        ax.set_xlabel(f"threshold τ on {metric}")
        ax.set_ylim(-0.02, 1.02)
        ax.grid(True, linewidth=0.4, alpha=0.5)
    handles = [Line2D([], [], color=colors[s], linestyle=_linestyle(methods[s]), label=labels[s])
               for s in settings]
    _legend_below(fig, handles, ncol=min(len(handles), 3))
    fig.suptitle(f"Performance profile of {metric} ({find_metric(metric).doc})"
                 + (" (bands: pointwise Wilson CI)" if bands else ""), fontsize=9)
    return fig


# --------------------------------------------------------------------------------------------
# point charts with whiskers
# --------------------------------------------------------------------------------------------


def _setting_ticks(axes: np.ndarray, names: Sequence[str]) -> None:
    """The settings' names down the first column of panels that share their y axis, first on top."""
    for ax in axes:
        if ax.get_subplotspec().is_first_col():
            ax.set_yticks(range(len(names)), names, fontsize=7)
    axes[0].invert_yaxis()


def _point_panels(summary: pd.DataFrame, columns: Sequence[tuple[str, str, str, str]], labels: Mapping[int, str],
                  title: str, percent: bool) -> Figure:
    """One panel per (estimate, lower, upper, axis label); settings on y, family groups offset."""
    settings = list(labels)
    groups = list(dict.fromkeys(summary["family"]))
    gcolors = _group_colors(groups)
    height = 0.8 + 0.32 * len(settings) * max(1.0, len(groups) / 3)
    fig, axes = panel_grid(len(columns), (3.6, height), (2.6, 1.0), max_height=40.0, sharey=True)
    offsets = np.linspace(-0.3, 0.3, len(groups)) if len(groups) > 1 else np.zeros(1)
    scale = 100.0 if percent else 1.0
    for ax, (est, lo, hi, name) in zip(axes, columns):
        for off, group, marker in zip(offsets, groups, _GROUP_MARKERS * 10):
            sub = summary[summary["family"] == group].set_index("setting")
            ys, xs, err_lo, err_hi = [], [], [], []
            for i, s in enumerate(settings):
                if s not in sub.index or not math.isfinite(float(sub.at[s, est])):
                    continue
                v = float(sub.at[s, est]) * scale
                a, b = float(sub.at[s, lo]) * scale, float(sub.at[s, hi]) * scale
                ys.append(i + off)
                xs.append(v)
                err_lo.append(max(v - a, 0.0) if math.isfinite(a) else 0.0)
                err_hi.append(max(b - v, 0.0) if math.isfinite(b) else 0.0)
            ax.errorbar(xs, ys, xerr=[err_lo, err_hi], fmt=marker, color=gcolors[group], markersize=4,
                        elinewidth=1, capsize=2, label=group)
        ax.set_xlabel(name)
        ax.grid(True, axis="x", linewidth=0.4, alpha=0.5)
    _setting_ticks(axes, [labels[s] for s in settings])
    handles = [Line2D([], [], marker=m, color=gcolors[g], linestyle="", label=g)
               for g, m in zip(groups, _GROUP_MARKERS * 10)]
    _legend_below(fig, handles, ncol=min(len(handles), 6))
    fig.suptitle(title, fontsize=10)
    return fig


def plot_rates(summary: pd.DataFrame, labels: Mapping[int, str], rates: Sequence[str], confidence: float) -> Figure:
    """Rates per setting (%) with Wilson score intervals, one panel per rate."""
    cols = [(f"{r}_rate", f"{r}_lo", f"{r}_hi", f"{r} rate [%]") for r in rates]
    return _point_panels(summary, cols, labels, f"Rates with {100 * confidence:g} % Wilson score intervals",
                         percent=True)


def plot_continuous(summary: pd.DataFrame, labels: Mapping[int, str], metrics: Sequence[str],
                    units: Mapping[str, str], confidence: float) -> Figure:
    """IQM per setting with stratified-bootstrap CIs, one panel per continuous metric."""
    cols = [(f"{m}_iqm", f"{m}_iqm_lo", f"{m}_iqm_hi", f"IQM {m}" + (f" [{units[m]}]" if units.get(m) else ""))
            for m in metrics]
    return _point_panels(summary, cols, labels,
                         f"Interquartile means with {100 * confidence:g} % stratified bootstrap CIs", percent=False)


def plot_differences(comparisons: pd.DataFrame, labels: Mapping[int, str], metrics: Sequence[str],
                     alpha: float, baseline: str) -> Figure:
    """Forest plot: paired difference (setting − ``baseline``) with the interval that decided its verdict (at
    the level Holm allows it in its family), one panel per metric; rates
    in percentage points as in the tables, continuous metrics in their units; grey band: the relevance
    margin. Colour: the comparison's verdict (:data:`~jaxapf.report.document.VERDICT_COLORS`, the words
    of the key findings); filled markers: a verdict other than inconclusive."""
    settings = [s for s in labels if s in set(comparisons["setting"])]
    fig, axes = panel_grid(len(metrics), (3.4, 0.8 + 0.3 * max(len(settings), 1)), (2.6, 1.0), sharey=True)
    for ax, metric in zip(axes, metrics):
        sub = comparisons[comparisons["metric"] == metric].set_index("setting")
        rate = find_metric(metric).kind == "rate"
        scale = 100.0 if rate else 1.0
        if len(sub) and math.isfinite(float(sub["margin"].iloc[0])):
            margin = scale * float(sub["margin"].iloc[0])
            ax.axvspan(-margin, margin, color="0.88", zorder=0, linewidth=0)
        for i, s in enumerate(settings):
            if s not in sub.index:
                continue
            r = sub.loc[s]
            d, lo, hi = (scale * float(r[c]) for c in ("delta", "delta_lo", "delta_hi"))
            if not math.isfinite(d):
                continue
            color = VERDICT_COLORS[str(r["verdict"])]
            decided = str(r["verdict"]) != "inconclusive"
            ax.errorbar([d], [i], xerr=[[max(d - lo, 0.0)], [max(hi - d, 0.0)]] if math.isfinite(lo) else None,
                        fmt="o", color=color, markerfacecolor=color if decided else "white", capsize=2)
        ax.axvline(0.0, color="black", linewidth=0.8)
        unit = "pp" if rate else find_metric(metric).unit
        name = f"Δ {metric}" if rate else f"HL shift {metric}"
        name += f" [{unit}]" if unit else ""
        if len(sub):
            name += " (↑ better)" if bool(sub["higher_is_better"].iloc[0]) else " (↓ better)"
            name += "" if (sub["holm_family"] == "primary").all() else ", exploratory"
        else:
            name += " (no pairs)"
        ax.set_xlabel(name, fontsize=8)
        ax.grid(True, axis="x", linewidth=0.4, alpha=0.5)
    _setting_ticks(axes, [labels[s] for s in settings])
    handles = [Line2D([], [], color=c, marker="o", linestyle="", markerfacecolor=c if v != "inconclusive" else "white",
                      label=v) for v, c in VERDICT_COLORS.items()]
    _legend_below(fig, handles, ncol=4)
    fig.suptitle(f"Paired differences, setting − baseline ({baseline}), each interval at the level Holm allows it "
                 f"(α = {alpha:g} per family); colour: its verdict; grey band: relevance margin", fontsize=9)
    return fig


# --------------------------------------------------------------------------------------------
# every figure of a report
# --------------------------------------------------------------------------------------------


def check_heatmap(sel: Selection, options: Any) -> None:
    """A ``--heatmap`` naming a column the sweep does not have is an error, raised before any work
    (without the default's columns, the heatmaps are skipped with a note instead)."""
    if options.heatmap is None or tuple(options.heatmap) == DEFAULT_HEATMAP:
        return
    x, y = options.heatmap
    for c in (x, y):
        if c not in sel.table.columns:
            raise ReportError(f"--heatmap {x},{y}: no setting column {c!r}; use two of "
                              f"{', '.join(sel.swept) or 'the swept gains (none here)'}")


def _heatmap_figures(sel: Selection, options: Any, figdir: pathlib.Path) -> tuple[list[FigureFile], list[str]]:
    if options.heatmap is None:
        return [], ["heatmaps skipped (--heatmap none)"]
    check_heatmap(sel, options)
    x, y = options.heatmap
    for c in (x, y):
        if c not in sel.table.columns:
            return [], [f"heatmaps skipped: the sweep has no {c} column (--heatmap X,Y names two swept gains)"]
    table = sel.table.loc[sel.settings]
    swept_here = [c for c in swept_columns(table)]
    if x not in swept_here or y not in swept_here:
        return [], [f"heatmaps skipped: fewer than 2 swept gains among {x}, {y} "
                    f"(swept here: {', '.join(swept_here) or 'none'})"]
    figures, notes = [], []
    for method in sorted(pd.unique(table["method"])):
        mt = table[table["method"] == method]
        ignored = ignored_columns(mt.iloc[0])
        if x in ignored or y in ignored:
            continue
        if mt[x].nunique() < 2 or mt[y].nunique() < 2:
            notes.append(f"heatmap for {method} skipped: {x} or {y} takes a single value")
            continue
        if mt[x].nunique() > 15 or mt[y].nunique() > 15:
            notes.append(f"heatmap for {method} skipped: more than 15 values of {x} or {y} (not a grid)")
            continue
        others = [c for c in swept_columns(mt) if c not in (x, y, "method") and c not in ignored]
        combos = mt.groupby(others, sort=True).groups if others else {(): mt.index}
        keys = list(combos)[:6]
        if len(combos) > 6:
            notes.append(f"heatmaps for {method}: only the first 6 of {len(combos)} combinations of "
                         f"{', '.join(others)} are drawn")
        role = roles(sel.data.columns)
        for rate in (role.success, role.collision):
            cells = []
            for combo in keys:
                ids = list(combos[combo])
                combo = combo if isinstance(combo, tuple) else (combo,)
                panel = " ".join(f"{symbol(c)}={format_value(v)}" for c, v in zip(others, combo)) or method
                rows = sel.data[sel.data["setting"].isin(ids)].merge(
                    mt.loc[ids, [x, y]], left_on="setting", right_index=True, suffixes=("", "_setting"))
                xc, yc = (f"{x}_setting" if f"{x}_setting" in rows.columns else x,
                          f"{y}_setting" if f"{y}_setting" in rows.columns else y)
                for group in groups(sel.data):
                    g = group_rows(rows, group)
                    for (xv, yv), cell in g.groupby([xc, yc]):
                        cells.append({"row": group, "panel": panel, x: xv, y: yv,
                                      f"{rate} rate": float(cell[rate].mean()), "n": len(cell)})
            if not cells:
                continue
            fig = plot_heatmaps(pd.DataFrame(cells), x, y, f"{rate} rate",
                                f"{rate} rate [%] of {method} over {x} × {y}")
            figures.append(save_figure(fig, f"heatmap_{rate}_{method}", f"{rate.capitalize()} rate of {method} "
                                       f"over {x} × {y}, per family", figdir, options.svg))
    if not figures and not notes:
        notes.append(f"heatmaps skipped: no method varies both {x} and {y}")
    return figures, notes


def _profile_taus(values: np.ndarray) -> np.ndarray:
    v = values[np.isfinite(values)]
    if v.size == 0:
        return np.linspace(0.0, 1.0, 2)
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        hi = lo + 1.0
    pad = 0.02 * (hi - lo)
    return np.linspace(lo - pad, hi + pad, 200)


@plain_text
def row_figures(sel: Selection, options: Any, figdir: pathlib.Path) -> tuple[list[FigureFile], list[str]]:
    """The figures drawn from the episode rows alone (heatmaps, ECDF of the clearance, performance
    profile), written to ``figdir``, and notes on what was skipped. They need no statistics, so a
    report draws them in its second process (:class:`jaxapf.report.worker.RowWorker`)."""
    labels = {s: sel.labels[s] for s in sel.settings}
    methods = {s: str(sel.table.at[s, "method"]) for s in sel.settings}
    names = groups(sel.data)
    figures, notes = _heatmap_figures(sel, options, figdir)
    role = roles(sel.data.columns)
    near = role.clearance
    clearance = {g: {s: group_rows(sel.data[sel.data["setting"] == s], g)[near].to_numpy(np.float64)
                     for s in sel.settings} for g in names}
    figures.append(save_figure(plot_ecdf(clearance, labels, methods, near, "m"), f"ecdf_{near}",
                               "Empirical CDF of the minimum clearance per setting (left of 0: collision)"
                               if not role.swarm else "Empirical CDF of the closest approach between two UAVs "
                               "per swarm episode and setting (left of 0: two UAVs collide)", figdir, options.svg))
    metric = options.profile_metric or role.profile
    values = sel.data[metric].to_numpy(np.float64)
    taus = _profile_taus(values)
    curves = {}
    for g in names:
        curves[g] = {}
        for s in sel.settings:
            v = group_rows(sel.data[sel.data["setting"] == s], g)[metric].to_numpy(np.float64)
            v = v[~np.isnan(v)]
            if v.size == 0:
                continue
            frac = stats.performance_profile(v, taus)
            lo, hi = stats.wilson_interval(np.round(frac * v.size), v.size, options.confidence)
            curves[g][s] = (frac, lo, hi)
    bands = len(sel.settings) <= 6
    figures.append(save_figure(plot_performance_profile(taus, curves, labels, methods, metric, bands),
                               f"profile_{metric}", f"Performance profile: fraction of episodes with {metric} > τ, "
                               f"{metric} being {find_metric(metric).doc}; at τ → 0 it is the rate of episodes "
                               f"with {metric} > 0, beyond it how many keep a higher value"
                               + (" (bands: pointwise Wilson intervals)" if bands else ""), figdir, options.svg))
    return figures, notes


@plain_text
def table_figures(sel: Selection, summary: pd.DataFrame, comparisons: pd.DataFrame, options: Any,
                  figdir: pathlib.Path) -> list[FigureFile]:
    """The figures drawn from the report's tables (rates, continuous metrics, paired differences),
    written to ``figdir``."""
    labels = {s: sel.labels[s] for s in sel.settings}
    names = groups(sel.data)
    rates, continuous = report_metrics(sel.data.columns)
    units = {m: find_metric(m).unit for m in continuous}
    figures = [save_figure(plot_rates(summary, labels, rates, options.confidence), "rates",
                           f"{', '.join(rates).capitalize()} rates with {100 * options.confidence:g} % Wilson "
                           "intervals", figdir, options.svg),
               save_figure(plot_continuous(summary, labels, continuous, units, options.confidence), "continuous",
                           "Interquartile means of the continuous metrics with stratified bootstrap intervals "
                           "(metrics meaningful only on successes: successful episodes)", figdir, options.svg)]
    if len(comparisons):
        group = headline(names)
        pooled = comparisons[comparisons["family"] == group]
        bases = pd.unique(pooled["baseline_label"])
        baseline = bases[0] if len(bases) == 1 else f"{options.baseline}, each setting's own"
        figures.append(save_figure(plot_differences(pooled, labels, rates + continuous, options.alpha, baseline),
                                   "differences", f"Paired differences to the baseline {baseline} ({group}): rates "
                                   "as the difference in proportions in percentage points (Newcombe interval), "
                                   "continuous metrics as the Hodges-Lehmann shift in their units (signed-rank "
                                   "interval); colour = the verdict of the key findings, grey band = relevance "
                                   "margin", figdir, options.svg))
    return figures
