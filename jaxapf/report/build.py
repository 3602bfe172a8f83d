"""``jaxapf report``: statistics, figures and tables from the episodes of a sweep.

``jaxapf report runs/NAME.parquet --out reports/NAME/`` answers "which method and gains are safer
and converge more, by how much, and how sure are we?" from the Parquet rows written by
``jaxapf sweep`` (format: ``docs/sweep-format.md``). Every number is computed from the rows;
the definitions of the statistics are in :mod:`jaxapf.stats` and ``docs/report.md``.

Outputs (in ``--out``): ``report.html`` (self-contained, figures embedded as base64 PNG),
``report.md`` (figures as relative files), ``summary.csv`` (per setting × family),
``comparisons.csv`` (paired tests against the baseline), ``table.tex`` (booktabs) and
``figures/*.png`` (and ``*.svg`` with ``svg``).

Bad input raises :class:`~jaxapf.report.load.ReportError` (a
:class:`~jaxapf.validation.ConfigError`) with one line.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
import pathlib
from typing import Any, Mapping

import pandas as pd

from .. import stats
from ..io.lock import write_atomic
from ..io.names import subfolder
from ..metrics import all_metrics, find_metric, is_metric
from ..text import csv_text
from ..validation import MAX_SEED
from .document import VERDICT_MARKS, Document, render_html, render_markdown
from .figures import DEFAULT_HEATMAP, check_heatmap, table_figures
from .latex import latex_tables
from .load import ReportError, load_sweep, report_metrics, roles
from .select import format_value, select
from .tables import (
    ALL,
    BOTTOM_LINE_RULE,
    bottom_line,
    compare,
    comparison_table,
    continuous_table,
    findings,
    groups,
    headline,
    margins,
    primary_metrics,
    rates_table,
    summarize,
    swept_name,
    verdict_matrix,
)
from .worker import RowWorker

__all__ = ["ReportOptions", "ReportResult", "build_report"]


#: Most bootstrap resamples (``--resamples``): each interval draws this many; past it a report takes hours
#: and its intervals move less than their last printed digit.
MAX_RESAMPLES = 100_000
#: Most failed episodes re-simulated for the gallery (``--gallery``).
MAX_GALLERY = 100


@dataclasses.dataclass(frozen=True)
class ReportOptions:
    """Settings of one report (the CLI flags).

    Attributes:
      baseline: ``COLUMN=VALUE[,COLUMN=VALUE...]`` selecting the baseline setting(s)
        (default ``method=basic``; ``setting=3`` picks one setting).
      where: ``COLUMN=VALUE[,VALUE...]`` row filters; values of one filter are OR-ed, filters AND-ed.
      heatmap: the two gain columns of the heatmaps, or None to skip them.
      gallery: number of worst episodes to re-simulate and draw (0: none).
      resamples: bootstrap resamples of every interval.
      confidence: level of every interval; tests are significant at ``1 - confidence`` after Holm.
      seed: seed of every bootstrap generator.
      profile_metric: the metric of the performance profile (higher is better; default ``spl``, of a swarm
        sweep ``at_goal``: :data:`~jaxapf.report.load.Roles`).
      margins: ``(metric, margin)`` overrides of the registry's relevance margins (``--margin``).
      efficiency: ``both-success`` (default): metrics meaningful only on successful episodes are
        compared on the pairs where both settings succeed; ``all-pairs``: on every pair.
      pair_on: with several baseline settings, the setting columns on which a setting and its
        baseline must agree (``--pair-on``; e.g. ``selection`` in ``jaxapf compare``'s test); empty:
        every swept column except those the baseline filter fixes or the baseline method ignores.
      svg: also write every figure as SVG (``--svg``; a second draw of each figure).
      animate: also animate each gallery episode (``--animate``): ``gallery_N.gif`` shown in the page,
        ``gallery_N.mp4`` beside it (:mod:`jaxapf.simulate.animate`).
      primary: the metrics of the primary Holm family (``--primary``; empty: success and collision, of a swarm
        sweep ``swarm_success`` and ``agent_collision``), compared per family and pooled; every other
        comparison is exploratory, corrected within its metric (:func:`~jaxapf.report.tables.holm_family`).
      primary_pooled: the primary family holds the pooled comparisons alone (families pooled; a one-family
        report's family), the per-family ones exploratory: the question is about the whole benchmark
        (``jaxapf scorecard``'s leaderboard).
    """

    baseline: str = "method=basic"
    where: tuple[str, ...] = ()
    heatmap: tuple[str, str] | None = DEFAULT_HEATMAP
    gallery: int = 3
    resamples: int = stats.DEFAULT_RESAMPLES
    confidence: float = 0.95
    seed: int = 0
    profile_metric: str | None = None
    margins: tuple[tuple[str, float], ...] = ()
    efficiency: str = "both-success"
    pair_on: tuple[str, ...] = ()
    svg: bool = False
    animate: bool = False
    primary: tuple[str, ...] = ()
    primary_pooled: bool = False

    def __post_init__(self) -> None:
        for name in self.primary:
            if not is_metric(name):
                raise ReportError(f"--primary {name}: {name!r} is not a metric; choose one of "
                                  f"{', '.join(name for name, _ in all_metrics())}")
        if self.efficiency not in ("both-success", "all-pairs"):
            raise ReportError(f"--efficiency = {self.efficiency!r} is not allowed; "
                              "choose one of both-success, all-pairs")
        for name, margin in self.margins:
            if not is_metric(name):
                raise ReportError(f"--margin {name}=...: {name!r} is not a metric; choose one of "
                                  f"{', '.join(name for name, _ in all_metrics())}")
            if isinstance(margin, bool) or not isinstance(margin, (int, float)) or not 0 < margin < math.inf:
                raise ReportError(f"--margin {name}={margin!r} must be a finite number > 0")
            if find_metric(name).kind == "rate" and not margin < 1:
                raise ReportError(f"--margin {name}={margin!r}: a rate's margin is a proportion below 1 "
                                  "(0.02 = 2 percentage points)")
        if (isinstance(self.resamples, bool) or not isinstance(self.resamples, int)
                or not 100 <= self.resamples <= MAX_RESAMPLES):
            raise ReportError(f"--resamples = {self.resamples!r} must be an integer from 100 to {MAX_RESAMPLES:,}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed <= MAX_SEED:
            raise ReportError(f"--seed = {self.seed!r} must be an integer from 0 to {MAX_SEED}")
        if not (isinstance(self.confidence, (int, float)) and 0.5 <= self.confidence < 1.0):
            raise ReportError(f"--confidence = {self.confidence!r} must lie in [0.5, 1)")
        if isinstance(self.gallery, bool) or not isinstance(self.gallery, int) or not 0 <= self.gallery <= MAX_GALLERY:
            raise ReportError(f"--gallery = {self.gallery!r} must be an integer from 0 to {MAX_GALLERY}")
        if self.heatmap is not None and (len(self.heatmap) != 2 or self.heatmap[0] == self.heatmap[1]):
            raise ReportError(f"--heatmap = {','.join(self.heatmap)!r} must name two different columns, e.g. gamma,k")

    @property
    def alpha(self) -> float:
        return 1.0 - self.confidence

def invalid_note(data: Any, labels: Mapping[int, str]) -> str:
    """The episodes whose state turned non-finite (metric ``invalid``), per setting and family: an outcome of
    their own, counted in no rate (neither success, collision nor stall)."""
    bad = data[data["invalid"].astype(bool)].groupby(["setting", "family"]).size()
    said = "; ".join(f"{labels.get(int(s), s)} on {f}: {n}" for (s, f), n in bad.items())
    return (f"{int(bad.sum())} episode(s) turned non-finite (NaN or inf; the invalid outcome, in no rate: neither "
            f"success, collision nor stall): {said}")


def _spec_name(meta: Mapping, path: pathlib.Path) -> str:
    spec = meta.get("spec") if isinstance(meta.get("spec"), Mapping) else {}
    for key in ("name", "title"):
        if isinstance(spec.get(key), str) and spec[key]:
            return spec[key]
        if isinstance(spec.get("sweep"), Mapping) and isinstance(spec["sweep"].get(key), str):
            return spec["sweep"][key]
    name = path.name
    return name[: -len(".parquet")] if name.endswith(".parquet") else path.stem


@dataclasses.dataclass
class ReportResult:
    """What :func:`build_report` wrote."""

    out: pathlib.Path
    paths: list[pathlib.Path]
    summary: pd.DataFrame
    comparisons: pd.DataFrame
    notes: list[str]
    incomplete: str | None = None  # what is missing, when the sweep is incomplete


# long: the report's sections in the order the page shows them, each a few lines over the shared tables
def build_report(path: str | pathlib.Path, out: str | pathlib.Path,
                 options: ReportOptions = ReportOptions(), pool: Any = None) -> ReportResult:
    """Read the sweep at ``path``, compute every statistic and write the report into ``out``. ``pool``:
    the second process, started early (:func:`jaxapf.report.worker.spawn`); else one is started here."""
    path = pathlib.Path(path)
    out = pathlib.Path(out)
    if options.animate:
        from ..simulate.animate import ffmpeg

        ffmpeg()  # a missing video extra is said before any work, not after the gallery
    df, meta = load_sweep(path)
    profile = options.profile_metric or roles(df.columns).profile
    if profile not in df.columns or not is_metric(profile):
        raise ReportError(f"--profile-metric {profile!r} is not a metric column of {path}")
    sel = select(df, options)
    check_heatmap(sel, options)
    rates, continuous = report_metrics(sel.data.columns)
    out.mkdir(parents=True, exist_ok=True)
    figdir = subfolder(out / "figures")
    # the figures drawn from the rows alone and the gallery are made in a second process meanwhile
    with RowWorker(sel, meta, options, figdir, pool) as worker:
        summary = summarize(sel.data, sel.settings, sel.table, sel.labels, options)
        comparisons = compare(sel.data, sel.pairs, sel.labels, options)
        figures = table_figures(sel, summary, comparisons, options, figdir)
        row_figs, shown, worker_notes = worker.result()
    figures += row_figs
    notes = sel.notes + worker_notes
    if meta.get("stray"):
        notes.append(f"{path} holds {len(meta['stray'])} file(s) that are not parts of the sweep, never read as rows: "
                     + ", ".join(meta["stray"][:5]) + (" …" if len(meta["stray"]) > 5 else ""))
    if "invalid" in sel.data.columns and sel.data["invalid"].astype(bool).any():
        notes.insert(0, invalid_note(sel.data, sel.labels))
    incomplete = None
    if meta.get("complete") is False and meta.get("rows_expected"):
        incomplete = (f"the sweep is incomplete: {len(df)} of {meta['rows_expected']} episodes are present "
                      "(an interrupted run?); only rows present in both settings are paired")
        notes.insert(0, incomplete)

    spec_name = _spec_name(meta, path)
    names = groups(sel.data)
    pooled = headline(names)
    sizes = sel.data.groupby("family")["field"].nunique()
    if ALL in names and sizes.nunique() > 1:
        notes.insert(int(incomplete is not None),
                     f"families of unequal sizes: the pooled '{ALL}' rows weight each family by its episodes ("
                     + ", ".join(f"{f} {n} fields" for f, n in sizes.items()) + "); read the per-family rows first")
    versions = meta.get("versions") if isinstance(meta.get("versions"), Mapping) else {}
    n_primary = int((comparisons["holm_family"] == "primary").sum()) if len(comparisons) else 0

    doc = Document()
    title = f"jaxapf report — {spec_name}" + (" (INCOMPLETE SWEEP)" if incomplete else "")
    doc.h(1, title)
    if incomplete:
        doc.p(f"**{incomplete[0].upper() + incomplete[1:]}.**")
    # the conclusion, the verdicts and the figure that carries them come first, on the reader's first screen
    families = [g for g in names if g != pooled and "/" not in g]
    doc.h(2, "Bottom line")
    for paragraph in bottom_line(comparisons, pooled, families, rates):
        doc.p(paragraph)
    if len(comparisons):
        doc.p(BOTTOM_LINE_RULE)
        doc.h(2, "Verdict matrix")
        doc.p("Every setting against its baseline, per family and pooled, per metric: "
              + ", ".join(f"{VERDICT_MARKS[v]} {v}" for v in stats.VERDICTS)
              + " (the rule: How this report was made; each kind of a family: the comparison tables). "
              "Click a column's header in the other tables to sort them.")
        doc.matrix(verdict_matrix(comparisons, rates + continuous, families + [pooled] * (pooled not in families)))
    doc.h(2, "Contents")
    doc.contents()
    doc.h(2, "Key findings")
    doc.items(findings(summary, comparisons, pooled, options) or ["nothing to summarise"])
    key = next((f for f in figures if f.name == ("differences" if len(comparisons) else "rates")), None)
    if key is not None:
        doc.figure(key)
    doc.h(2, "How this report was made")
    doc.items([
        f"sweep: {path} ({len(df)} episodes in the file; {len(sel.data)} reported)",
        f"spec: {spec_name}, spec_hash {meta.get('spec_hash', '–')}, format {meta.get('format')}, "
        f"dtype {meta.get('dtype', '–')}, PRNG {json.dumps(meta.get('prng', {}))}",
        f"settings reported: {len(sel.settings)}; families: {', '.join(g for g in names if g != ALL)}; "
        f"fields per family: " + ", ".join(f"{f}: {n}" for f, n in
                                          sel.data.groupby("family")["field"].nunique().items()),
        f"filters: {' '.join('--where ' + w for w in options.where) or 'none'}; baseline: {options.baseline} "
        f"(setting(s) {', '.join('#' + str(b) for b in sel.baseline_ids)})",
        f"statistics: {100 * options.confidence:g} % intervals; rates: Wilson score intervals; medians and IQMs "
        f"(25 % trimmed means): percentile bootstrap, {options.resamples} resamples, seed {options.seed}, "
        f"stratified by family and kind for pooled groups; paired differences: for rates the difference in "
        f"proportions with Tango's score interval and the asymptotic McNemar (score) test, for continuous metrics "
        f"the Hodges-Lehmann shift with its Walsh-average interval and signed-rank test; Holm within declared "
        f"families: primary ({', '.join(primary_metrics(options, sel.data.columns))} of each setting against its "
        f"baseline, per family and pooled: {n_primary} tests), exploratory (each other metric, and each kind of a "
        f"family, within its metric); each interval beside a verdict is at the level Holm allows its comparison "
        f"(*: Holm-adjusted p <= {options.alpha:.3g}; the unadjusted {100 * options.confidence:g} % intervals are "
        f"in comparisons.csv as delta_lo_95, delta_hi_95)",
        "groups: each family, each kind of a family with several kinds "
        f"({', '.join(g for g in names if '/' in g) or 'none'}), and '{ALL}' pooling the families; a pooled row "
        "says what it pools",
        "metrics meaningful only on successful episodes ("
        + ", ".join(m for m in continuous if find_metric(m).on_success) + "): summarised over successful episodes "
        + ("and compared on the pairs where both settings succeed (n given)" if options.efficiency == "both-success"
           else "and compared on all pairs (--efficiency all-pairs)")
        + "; other non-finite values (e.g. min_clearance = +inf in a field without obstacles) are left out",
        "relevance margins: " + ", ".join(f"{m} {v:g}" for m, v in margins(options).items()
                                          if v is not None and m in rates + continuous)
        + " (rates as proportions); " + stats.VERDICT_RULE,
        "generated " + datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
    ])
    doc.h(2, "Versions (from the sweep's metadata)")
    doc.table(pd.DataFrame({"package": list(versions), "version": [str(v) for v in versions.values()]})
              if versions else pd.DataFrame({"package": ["–"], "version": ["not recorded"]}))

    doc.h(2, "Settings")
    cols = [c for c in sel.swept]
    st = sel.table.loc[sel.settings, cols].reset_index() if cols else pd.DataFrame({"setting": sel.settings})
    st = st.rename(columns={c: swept_name(c) for c in cols})  # a tag named like the report's own columns
    st.insert(1, "label", [sel.labels[s] for s in sel.settings])
    st.insert(2, "role", ["baseline" if s in sel.baseline_ids else (f"vs #{sel.pairs[s]}" if s in sel.pairs else "")
                          for s in sel.settings])
    doc.table(st.map(format_value))

    doc.h(2, "Rates")
    doc.p(f"Rate in % with the {100 * options.confidence:g} % Wilson score interval, per setting and group"
          + (f"; '{ALL}' pools the families (episode-weighted"
             + (", and the families differ in size: " + ", ".join(f"{f} {n}" for f, n in sizes.items())
                + " fields" if sizes.nunique() > 1 else "") + ")." if ALL in names else ".")
          + (" 'among solvable' counts only the fields where a collision-free path exists "
             "(jaxapf.scenarios.solvable, the solvability oracle)." if "n_solvable" in summary.columns else ""))
    if {"success", "stalled"} <= set(rates):  # a single UAV's rates (a swarm's deadlock ends no episode)
        both = int((sel.data["success"].astype(bool) & sel.data["stalled"].astype(bool)).sum())
        doc.p("The rates are not exclusive and need not sum to 100 %: an episode that stalls and then escapes to "
              f"the goal counts as both stalled and successful ({both} episode{'s' if both != 1 else ''} here).")
    doc.table(rates_table(summary, rates))
    doc.h(2, "Continuous metrics")
    doc.p("Median and interquartile mean (IQM, mean of the middle 50 %) with percentile bootstrap intervals "
          f"({options.resamples} resamples, stratified for pooled groups); n = episodes with a finite value "
          "(successful episodes for a metric meaningful only there).")
    for m in continuous:
        metric = find_metric(m)
        unit = f" [{metric.unit}]" if metric.unit else ""
        doc.h(3, f"{m}{unit}: {metric.doc}" + (" (successful episodes only)" if metric.on_success else ""))
        doc.table(continuous_table(summary, m))

    doc.h(2, f"Paired comparisons with the baseline ({options.baseline})")
    if len(comparisons):
        doc.p("Rows with equal (family, kind, field, seed) are the same obstacle field (common random numbers) and "
              "are paired. "
              "Δ pp = setting − baseline difference in proportions (percentage points) with Tango's score "
              "interval; HL shift = the Hodges-Lehmann estimate of the paired differences (setting − baseline) with "
              "its Walsh-average interval. Each interval is at the level Holm allows its comparison within its Holm "
              f"family (primary: {', '.join(primary_metrics(options, sel.data.columns))} per family and pooled, "
              f"{n_primary} tests; exploratory: each other metric and each kind of a family), and the verdict is "
              "read from it: equivalent inside ±margin, else better or worse when it excludes 0 on that side, else "
              "inconclusive. margin: the difference below which it does not matter; p Holm and p equiv. Holm: the "
              "interval's own difference and equivalence tests, Holm-adjusted within the family; MDE: the smallest "
              "difference this many pairs detects with power 0.8 at the row's level. PoI = P(setting better than "
              "baseline on the same field) + ½ P(tie): > 0.5 favours the setting. Better means higher "
              f"for {', '.join(m for m in rates + continuous if find_metric(m).higher_is_better)}, lower for "
              f"{', '.join(m for m in rates + continuous if not find_metric(m).higher_is_better)}; "
              f"* = Holm-adjusted p <= {options.alpha:.3g}.")
        for m in rates + continuous:
            doc.h(3, f"{m}: {find_metric(m).doc}" + (" (higher is better)" if find_metric(m).higher_is_better
                                                      else " (lower is better)"))
            doc.table(comparison_table(comparisons, m))
    else:
        doc.p("No setting to compare: every reported setting is a baseline setting.")

    doc.h(2, "Figures")
    for fig in figures:
        if fig is not key:
            doc.figure(fig)
    doc.h(2, "Worst episodes (re-simulated from their seeds)")
    if shown:
        doc.p("Failed episodes re-simulated with jaxapf.sweep.row_config and jaxapf.simulate.simulate_runs: "
              "collisions (deepest first), stalls and other failures (farthest from the goal first), in turn, "
              "distinct fields first. Red X: first collision.")
        for fig in shown:
            doc.figure(fig)
    else:
        doc.p("No gallery (see notes).")
    doc.h(2, "Notes")
    doc.items(notes or ["none"])

    paths = []
    summary_path, comp_path, tex_path, md_path, html_path = (
        out / n for n in ("summary.csv", "comparisons.csv", "table.tex", "report.md", "report.html"))
    for path, text in ((summary_path, csv_text(summary)), (comp_path, csv_text(comparisons)),
                       (tex_path, latex_tables(summary, comparisons, sel, pooled, options, spec_name, rates)),
                       (md_path, render_markdown(doc)), (html_path, render_html(doc, title))):
        write_atomic(path, text, durable=False)
    paths += [html_path, md_path, summary_path, comp_path, tex_path]
    paths += [figdir / f"{f.name}.{ext}" for f in figures + shown
              for ext in ((f.format, "svg")[: 1 + f.svg] + ("mp4",) * (f.format == "gif"))]
    return ReportResult(out, paths, summary, comparisons, notes, incomplete)
