"""``jaxapf report``: statistics, figures and tables from the episodes of a sweep.

``jaxapf report runs/NAME.parquet --out reports/NAME/`` answers "which method and gains are safer
and converge more, by how much, and how sure are we?" from the Parquet rows written by
``jaxapf sweep`` (format: ``docs/sweep-format.md``). Every number is computed here from the rows;
the definitions of the statistics are in :mod:`jaxapf.stats` and ``docs/report.md``.

Outputs (in ``--out``): ``report.html`` (self-contained, figures embedded as base64 PNG),
``report.md`` (figures as relative files), ``summary.csv`` (per setting × family),
``comparisons.csv`` (paired tests against the baseline), ``table.tex`` (booktabs) and
``figures/*.png|svg``.

Bad input raises :class:`ReportError` (a :class:`~jaxapf.config.ConfigError`) with one line.
"""

from __future__ import annotations

import base64
import dataclasses
import datetime
import html
import io
import json
import math
import pathlib
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np
import pandas as pd

from . import stats
from .config import ConfigError
from .metrics import METRICS

__all__ = [
    "ReportError",
    "ReportOptions",
    "RATES",
    "CONTINUOUS",
    "HIGHER_IS_BETTER",
    "load_sweep",
    "validate_sweep",
    "parse_filters",
    "setting_table",
    "summarize",
    "compare",
    "build_report",
]

RATES: tuple[str, ...] = ("success", "collision", "stalled")
CONTINUOUS: tuple[str, ...] = ("min_clearance", "time_to_goal", "path_ratio", "control_effort", "jerk_rms")
HIGHER_IS_BETTER: dict[str, bool] = {
    "success": True, "collision": False, "stalled": False, "min_clearance": True, "time_to_goal": False,
    "path_ratio": False, "control_effort": False, "jerk_rms": False, "score": True,
}
UNITS: dict[str, str] = {"min_clearance": "m", "time_to_goal": "s", "path_ratio": "", "control_effort": "m²/s³",
                         "jerk_rms": "m/s³", "final_distance": "m", "min_ttc": "s", "time_near": "s",
                         "path_length": "m", "max_velocity_excess": "m/s", "score": ""}
#: Columns of a sweep that every report needs.
REQUIRED: tuple[str, ...] = ("setting", "method", "family", "field") + RATES + CONTINUOUS
#: Columns that identify an episode within a setting (the pairing key, with ``seed`` if present).
ROW_COLUMNS: tuple[str, ...] = ("family", "field", "seed")
#: Columns a method does not read: settings differing only there behave identically.
IGNORED_BY_METHOD: dict[str, tuple[str, ...]] = {"basic": ("gamma", "k", "convention"), "direction": ("k",)}
ALL = "all"
_SYMBOL = {"gamma": "γ", "eta": "η"}
_TEX_SYMBOL = {"gamma": r"$\gamma$", "eta": r"$\eta$", "k": "$k$"}
_METRIC_SET = frozenset(METRICS)


class ReportError(ConfigError):
    """The report cannot be made from this input (bad file, missing column, empty filter, ...)."""


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
      profile_metric: the metric of the performance profile (higher is better).
    """

    baseline: str = "method=basic"
    where: tuple[str, ...] = ()
    heatmap: tuple[str, str] | None = ("gamma", "k")
    gallery: int = 3
    resamples: int = stats.DEFAULT_RESAMPLES
    confidence: float = 0.95
    seed: int = 0
    profile_metric: str = "score"

    def __post_init__(self) -> None:
        if isinstance(self.resamples, bool) or not isinstance(self.resamples, int) or self.resamples < 100:
            raise ReportError(f"--resamples = {self.resamples!r} must be an integer >= 100")
        if not (isinstance(self.confidence, (int, float)) and 0.5 <= self.confidence < 1.0):
            raise ReportError(f"--confidence = {self.confidence!r} must lie in [0.5, 1)")
        if isinstance(self.gallery, bool) or not isinstance(self.gallery, int) or self.gallery < 0:
            raise ReportError(f"--gallery = {self.gallery!r} must be an integer >= 0")
        if self.heatmap is not None and (len(self.heatmap) != 2 or self.heatmap[0] == self.heatmap[1]):
            raise ReportError(f"--heatmap = {','.join(self.heatmap)!r} must name two different columns, e.g. gamma,k")

    @property
    def alpha(self) -> float:
        return 1.0 - self.confidence


# --------------------------------------------------------------------------------------------
# loading and validation
# --------------------------------------------------------------------------------------------


def _part_files(path: pathlib.Path) -> list[pathlib.Path]:
    if path.is_dir():
        return sorted(p for p in path.rglob("*.parquet")
                      if p.is_file() and not any(part.startswith((".", "_")) for part in p.relative_to(path).parts))
    return [path]


def _read_parquet(path: pathlib.Path) -> tuple[pd.DataFrame, dict | None]:
    """Rows and decoded ``jaxapf`` metadata of a Parquet file or dataset directory."""
    import pyarrow.parquet as pq

    files = _part_files(path)
    if not files:
        raise ReportError(f"{path} is not the output of jaxapf sweep: the directory holds no Parquet part file")
    schema = pq.read_schema(files[0])
    raw = (schema.metadata or {}).get(b"jaxapf")
    meta = json.loads(raw) if raw is not None else None
    frames = [pq.read_table(f).to_pandas() for f in files]
    return (pd.concat(frames, ignore_index=True) if len(frames) > 1 else frames[0]), meta


def load_sweep(path: str | pathlib.Path) -> tuple[pd.DataFrame, dict]:
    """The rows and metadata of a sweep (``jaxapf.sweep.read_sweep`` when available), validated.

    Raises :class:`ReportError` with one line for anything that is not a sweep's output.
    """
    import pyarrow as pa

    path = pathlib.Path(path)
    if not path.exists():
        raise ReportError(f"{path}: no such file or directory")
    try:
        try:
            from .sweep import read_sweep
        except ImportError:
            read_sweep = None
        if read_sweep is not None:
            df, meta = read_sweep(path)
        else:
            df, meta = _read_parquet(path)
    except ReportError:
        raise
    except ConfigError as err:
        raise ReportError(str(err)) from None
    except (OSError, ValueError, TypeError, KeyError, pa.ArrowException) as err:
        first = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise ReportError(f"{path} is not a readable sweep output (Parquet): {first}") from None
    validate_sweep(df, meta, path)
    return df, meta


def validate_sweep(df: pd.DataFrame, meta: Any, path: str | pathlib.Path = "input") -> None:
    """Check that ``(df, meta)`` looks like ``jaxapf sweep`` output; :class:`ReportError` if not."""
    if not isinstance(meta, Mapping) or not str(meta.get("format", "")).startswith("jaxapf.sweep/"):
        raise ReportError(f"{path} is not the output of jaxapf sweep (no 'jaxapf' sweep metadata "
                          "with format 'jaxapf.sweep/1' in the Parquet schema)")
    missing = [c for c in REQUIRED if c not in df.columns]
    if missing:
        raise ReportError(f"{path} lacks the column(s) {', '.join(missing)} that a jaxapf sweep writes")
    if len(df) == 0:
        raise ReportError(f"{path} holds no episodes (0 rows)")
    for c in RATES:
        if not (pd.api.types.is_bool_dtype(df[c]) or set(pd.unique(df[c])) <= {0, 1}):
            raise ReportError(f"{path}: column {c} must be boolean (0/1)")
    for c in CONTINUOUS:
        if not pd.api.types.is_numeric_dtype(df[c]):
            raise ReportError(f"{path}: column {c} must be numeric, not {df[c].dtype}")
    key = ["setting"] + [c for c in ROW_COLUMNS if c in df.columns]
    dup = df.duplicated(key)
    if dup.any():
        first = df.loc[dup, key].iloc[0].to_dict()
        raise ReportError(f"{path}: {int(dup.sum())} duplicate episode row(s), e.g. {first}; "
                          "every (setting, family, field) must appear once")


# --------------------------------------------------------------------------------------------
# settings, filters, baseline
# --------------------------------------------------------------------------------------------


def setting_table(df: pd.DataFrame) -> pd.DataFrame:
    """One row per setting (index ``setting``) with every column constant within a setting
    (method, convention, gains, simulation settings); metrics and row columns excluded."""
    cols = [c for c in df.columns if c not in _METRIC_SET and c not in ROW_COLUMNS and c != "setting"]
    grouped = df.groupby("setting", sort=True)
    constant = [c for c in cols if bool((grouped[c].nunique(dropna=False) <= 1).all())]
    return grouped[constant].first()


def swept_columns(table: pd.DataFrame) -> list[str]:
    """Setting columns with more than one value."""
    return [c for c in table.columns if table[c].nunique(dropna=False) > 1]


def _fmt_value(v: Any) -> str:
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v)).lower()
    if isinstance(v, (float, np.floating)):
        return f"{float(v):g}"
    return str(v)


def setting_labels(table: pd.DataFrame, swept: Sequence[str]) -> dict[int, str]:
    """``#3 direction_velocity γ=1 k=0.5``: index, method and the swept columns the method reads."""
    labels = {}
    for s, row in table.iterrows():
        method = str(row.get("method", ""))
        ignored = IGNORED_BY_METHOD.get(method, ())
        parts = [f"#{s}", method]
        parts += [f"{_SYMBOL.get(c, c)}={_fmt_value(row[c])}" for c in swept
                  if c not in ("method",) and c not in ignored]
        labels[int(s)] = " ".join(p for p in parts if p)
    return labels


def parse_filters(texts: Iterable[str], option: str) -> list[tuple[str, list[str]]]:
    """``["family=trap,clutter", "method=basic"]`` -> ``[("family", ["trap", "clutter"]), ...]``."""
    out = []
    for text in texts:
        key, sep, value = str(text).partition("=")
        key = key.strip()
        values = [v.strip() for v in value.split(",") if v.strip()]
        if not sep or not key or not values:
            raise ReportError(f"{option} {text!r} must look like COLUMN=VALUE (e.g. family=trap)")
        out.append((key, values))
    return out


def _parse_baseline(text: str) -> list[tuple[str, list[str]]]:
    parts = [p for p in str(text).split(",") if p.strip()]
    if not parts:
        raise ReportError("--baseline must look like COLUMN=VALUE[,COLUMN=VALUE] (e.g. method=basic or setting=3)")
    return parse_filters(parts, "--baseline")


def _mask(column: pd.Series, values: Sequence[str], what: str) -> np.ndarray:
    """Rows of ``column`` equal to any of ``values`` (numbers compared as numbers)."""
    if pd.api.types.is_bool_dtype(column):
        truth = {"true": True, "1": True, "yes": True, "false": False, "0": False, "no": False}
        wanted = []
        for v in values:
            if v.lower() not in truth:
                raise ReportError(f"{what}: {column.name} is true/false, not {v!r}")
            wanted.append(truth[v.lower()])
        return column.isin(wanted).to_numpy()
    if pd.api.types.is_numeric_dtype(column):
        numbers = []
        for v in values:
            try:
                numbers.append(float(v))
            except ValueError:
                raise ReportError(f"{what}: {column.name} is numeric, {v!r} is not a number") from None
        col = column.to_numpy(dtype=np.float64)
        return np.any([np.isclose(col, x, rtol=1e-9, atol=1e-12) for x in numbers], axis=0)
    return column.astype(str).isin(values).to_numpy()


def _choices(column: pd.Series, limit: int = 12) -> str:
    vals = sorted({_fmt_value(v) for v in pd.unique(column)}, key=lambda x: (len(x), x))
    return ", ".join(vals[:limit]) + (", ..." if len(vals) > limit else "")


@dataclasses.dataclass
class _Selection:
    data: pd.DataFrame  # rows of the reported settings (row filters applied)
    table: pd.DataFrame  # setting table of the whole sweep
    swept: list[str]
    labels: dict[int, str]
    settings: list[int]  # reported settings, ascending
    pairs: dict[int, int]  # setting -> its baseline setting
    baseline_ids: list[int]
    notes: list[str]


def _select(df: pd.DataFrame, options: ReportOptions) -> _Selection:
    table = setting_table(df)
    swept = swept_columns(table)
    labels = setting_labels(table, swept)
    notes: list[str] = []
    setting_cols = set(table.columns) | {"setting"}
    # row filters: family, field, seed, and columns that vary within a setting (e.g. t_max when it
    # defaults to each family's own)
    row_cols = [c for c in df.columns if c not in setting_cols and c not in _METRIC_SET]

    # --where: row filters (family, field, seed) on the rows, setting filters on the settings
    rows = np.ones(len(df), dtype=bool)
    chosen = np.ones(len(table), dtype=bool)
    for key, values in parse_filters(options.where, "--where"):
        what = f"--where {key}={','.join(values)}"
        if key in _METRIC_SET:
            raise ReportError(f"{what}: {key} is a metric; filter on settings or family/field/seed only")
        if key in row_cols:
            m = _mask(df[key], values, what)
            if not m.any():
                raise ReportError(f"{what} selects no rows ({key} has: {_choices(df[key])})")
            rows &= m
        elif key in setting_cols:
            col = pd.Series(table.index, name="setting") if key == "setting" else table[key]
            m = _mask(col, values, what)
            if not m.any():
                raise ReportError(f"{what} selects no rows ({key} has: {_choices(col)})")
            chosen &= m
        else:
            raise ReportError(f"{what}: no column {key!r}; filter on one of "
                              f"{', '.join(['setting', *table.columns, *row_cols])}")
    selected = [int(s) for s in table.index[chosen]]
    rows_df = df[rows]
    present = set(int(s) for s in pd.unique(rows_df["setting"]))
    selected = [s for s in selected if s in present]
    if not selected:
        raise ReportError(f"the filters {' '.join('--where ' + w for w in options.where)} together select no rows")

    # --baseline: among the settings that have rows after the row filters
    base_filters = _parse_baseline(options.baseline)
    avail = table.loc[sorted(present)]
    is_base = np.ones(len(avail), dtype=bool)
    for key, values in base_filters:
        what = f"--baseline {options.baseline}"
        if key == "setting":
            col = pd.Series(avail.index, name="setting")
        elif key in avail.columns:
            col = avail[key]
        else:
            raise ReportError(f"{what}: no setting column {key!r}; use one of {', '.join(['setting', *table.columns])}")
        is_base &= _mask(col, values, what)
    baseline_ids = [int(s) for s in avail.index[is_base]]
    if not baseline_ids:
        key = base_filters[0][0]
        col = pd.Series(avail.index) if key == "setting" else avail[key]
        raise ReportError(f"baseline {options.baseline} is not in the data ({key} has: {_choices(col)})")

    fixed = {k for k, _ in base_filters}
    pairs: dict[int, int] = {}
    for s in selected:
        if s in baseline_ids:
            continue
        if len(baseline_ids) == 1:
            pairs[s] = baseline_ids[0]
            continue
        matches = []
        for b in baseline_ids:
            ignored = IGNORED_BY_METHOD.get(str(table.at[b, "method"]), ())
            cols = [c for c in swept if c not in fixed and c not in ignored]
            if all(_same(table.at[s, c], table.at[b, c]) for c in cols):
                matches.append(b)
        if matches:
            pairs[s] = min(matches)
        else:
            notes.append(f"{labels[s]}: no baseline setting matches it on the swept columns, so it is "
                         "not compared")
    if len(baseline_ids) > 1:
        ignored_text = "; ".join(f"{m} ignores {', '.join(c)}" for m, c in IGNORED_BY_METHOD.items())
        notes.append(f"{len(baseline_ids)} settings match the baseline {options.baseline} "
                     f"({', '.join('#' + str(b) for b in baseline_ids)}): each setting is paired with the "
                     "lowest-numbered one that equals it on every swept column except those the baseline "
                     f"filter fixes and those the baseline method ignores "
                     f"({ignored_text})")
    used = sorted(set(pairs.values()))
    extra = [b for b in used if b not in selected]
    if extra:
        notes.append(f"baseline setting(s) {', '.join('#' + str(b) for b in extra)} are reported although the "
                     "--where filters exclude them, because they are compared against")
    settings = sorted(set(selected) | set(used))
    data = rows_df[rows_df["setting"].isin(settings)].copy()
    for c in RATES:
        data[c] = data[c].astype(bool)
    return _Selection(data, table, swept, labels, settings, pairs, baseline_ids, notes)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, (int, float, np.integer, np.floating)) and isinstance(b, (int, float, np.integer, np.floating)):
        return bool(np.isclose(float(a), float(b), rtol=1e-9, atol=1e-12) or (math.isnan(a) and math.isnan(b)))
    return a == b


# --------------------------------------------------------------------------------------------
# statistics tables
# --------------------------------------------------------------------------------------------


def _groups(data: pd.DataFrame) -> list[str]:
    families = sorted(str(f) for f in pd.unique(data["family"]))
    return families + ([ALL] if len(families) > 1 else [])


def _group_rows(frame: pd.DataFrame, group: str) -> pd.DataFrame:
    return frame if group == ALL else frame[frame["family"] == group]


def _strata(frame: pd.DataFrame, group: str) -> np.ndarray | None:
    return frame["family"].to_numpy() if group == ALL else None


def summarize(data: pd.DataFrame, settings: Sequence[int], table: pd.DataFrame, labels: Mapping[int, str],
              options: ReportOptions) -> pd.DataFrame:
    """One row per (setting, family group) — each family and, with several, ``all`` pooled.

    Columns: ``setting, label``, the setting columns, ``family, n``; per rate ``r``: ``r_k`` (count),
    ``r_rate``, ``r_lo``, ``r_hi`` (Wilson); per continuous metric ``m``: ``m_n`` (finite values;
    ``time_to_goal``: successful episodes), ``m_median``, ``m_median_lo``, ``m_median_hi``,
    ``m_iqm``, ``m_iqm_lo``, ``m_iqm_hi`` (percentile bootstrap, stratified by family for ``all``).
    """
    records = []
    boot = dict(n_resamples=options.resamples, confidence=options.confidence, seed=options.seed)
    for s in settings:
        rows_s = data[data["setting"] == s]
        for group in _groups(data):
            sub = _group_rows(rows_s, group)
            n = len(sub)
            if n == 0:
                continue
            rec: dict[str, Any] = {"setting": int(s), "label": labels[s]}
            rec.update({c: table.at[s, c] for c in table.columns})
            rec.update(family=group, n=n)
            for r in RATES:
                k = int(sub[r].sum())
                lo, hi = stats.wilson_interval(k, n, options.confidence)
                rec.update({f"{r}_k": k, f"{r}_rate": k / n, f"{r}_lo": float(lo), f"{r}_hi": float(hi)})
            strata = _strata(sub, group)
            for m in CONTINUOUS:
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
            options: ReportOptions) -> pd.DataFrame:
    """Paired comparisons of every setting with its baseline, per family group and metric.

    Rows are paired on (family, field, seed). Rates: exact McNemar test, difference in rates (mean
    paired difference). Continuous metrics, on the pairs where both values are finite
    (``time_to_goal``: both successful): Wilcoxon signed-rank test, difference of IQMs. Both with
    paired bootstrap CIs, and the paired probability of improvement with its bootstrap CI.
    ``p_holm``: Holm-adjusted over every p-value of the table; ``significant``: ``p_holm <= alpha``.
    """
    key = [c for c in ROW_COLUMNS if c in data.columns]
    boot = dict(n_resamples=options.resamples, confidence=options.confidence, seed=options.seed)
    records = []
    for s, b in pairs.items():
        merged = pd.merge(data[data["setting"] == s], data[data["setting"] == b], on=key, suffixes=("_x", "_y"))
        for group in _groups(data):
            sub = _group_rows(merged, group)
            if len(sub) == 0:
                continue
            strata = _strata(sub, group)
            for metric in RATES + CONTINUOUS:
                hib = HIGHER_IS_BETTER[metric]
                x = sub[f"{metric}_x"].to_numpy(dtype=np.float64)
                y = sub[f"{metric}_y"].to_numpy(dtype=np.float64)
                rec: dict[str, Any] = {"setting": int(s), "label": labels[s], "baseline": int(b),
                                       "baseline_label": labels[b], "family": group, "metric": metric,
                                       "higher_is_better": hib}
                if metric in RATES:
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


# --------------------------------------------------------------------------------------------
# formatting helpers
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# document model: blocks rendered to Markdown and HTML
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass
class _Figure:
    name: str
    caption: str
    png: bytes


@dataclasses.dataclass
class _Doc:
    blocks: list[tuple[str, Any]] = dataclasses.field(default_factory=list)

    def h(self, level: int, text: str) -> None:
        self.blocks.append(("h", (level, text)))

    def p(self, text: str) -> None:
        self.blocks.append(("p", text))

    def items(self, items: Sequence[str]) -> None:
        if items:
            self.blocks.append(("ul", list(items)))

    def table(self, frame: pd.DataFrame) -> None:
        self.blocks.append(("table", frame))

    def figure(self, fig: _Figure) -> None:
        self.blocks.append(("figure", fig))


def _md_cell(v: Any) -> str:
    return str(v).replace("|", "\\|").replace("\n", " ")


def _render_md(doc: _Doc) -> str:
    out = []
    for kind, value in doc.blocks:
        if kind == "h":
            out.append(f"{'#' * value[0]} {value[1]}\n")
        elif kind == "p":
            out.append(f"{value}\n")
        elif kind == "ul":
            out.append("\n".join(f"- {_md_cell(i)}" for i in value) + "\n")
        elif kind == "table":
            cols = list(value.columns)
            lines = ["| " + " | ".join(_md_cell(c) for c in cols) + " |", "|" + "---|" * len(cols)]
            lines += ["| " + " | ".join(_md_cell(v) for v in row) + " |" for row in value.itertuples(index=False)]
            out.append("\n".join(lines) + "\n")
        elif kind == "figure":
            out.append(f"![{value.caption}](figures/{value.name}.png)\n\n*{value.caption}* "
                       f"(vector: `figures/{value.name}.svg`)\n")
    return "\n".join(out)


_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:2em auto;max-width:1250px;padding:0 1em;
color:#222;line-height:1.4}
h1{border-bottom:2px solid #444}h2{border-bottom:1px solid #bbb;margin-top:2em}
table{border-collapse:collapse;font-size:0.82em;margin:0.8em 0;display:block;overflow-x:auto}
th,td{border:1px solid #ccc;padding:3px 7px;text-align:right;white-space:nowrap}
th{background:#f0f0f0}td:first-child,th:first-child{text-align:left}
tr:nth-child(even){background:#fafafa}
figure{margin:1.2em 0}figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{font-size:0.9em;color:#444}code{background:#f4f4f4;padding:0 3px}
"""


def _render_html(doc: _Doc, title: str) -> str:
    esc = html.escape
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           f"<title>{esc(title)}</title>", f"<style>{_CSS}</style></head><body>"]
    for kind, value in doc.blocks:
        if kind == "h":
            out.append(f"<h{value[0]}>{esc(value[1])}</h{value[0]}>")
        elif kind == "p":
            out.append(f"<p>{esc(value)}</p>")
        elif kind == "ul":
            out.append("<ul>" + "".join(f"<li>{esc(str(i))}</li>" for i in value) + "</ul>")
        elif kind == "table":
            head = "".join(f"<th>{esc(str(c))}</th>" for c in value.columns)
            body = "".join("<tr>" + "".join(f"<td>{esc(str(v))}</td>" for v in row) + "</tr>"
                           for row in value.itertuples(index=False))
            out.append(f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>")
        elif kind == "figure":
            data = base64.b64encode(value.png).decode("ascii")
            out.append(f'<figure><img alt="{esc(value.caption)}" src="data:image/png;base64,{data}">'
                       f"<figcaption>{esc(value.caption)}</figcaption></figure>")
    out.append("</body></html>")
    return "\n".join(out)


# --------------------------------------------------------------------------------------------
# LaTeX
# --------------------------------------------------------------------------------------------

_TEX_ESCAPE = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
               "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}


def _tex(text: Any) -> str:
    return "".join(_TEX_ESCAPE.get(ch, ch) for ch in str(text))


def _tex_label(s: int, table: pd.DataFrame, swept: Sequence[str]) -> str:
    method = str(table.at[s, "method"]) if "method" in table.columns else ""
    ignored = IGNORED_BY_METHOD.get(method, ())
    parts = [_tex(f"#{s}"), _tex(method)]
    parts += [f"{_TEX_SYMBOL.get(c, _tex(c))}={_tex(_fmt_value(table.at[s, c]))}" for c in swept
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


def _latex(summary: pd.DataFrame, comparisons: pd.DataFrame, sel: _Selection, group: str,
           options: ReportOptions, spec_name: str) -> str:
    conf = f"{100 * options.confidence:g}"
    lines = [
        f"% jaxapf report table: {_tex(spec_name)} (needs \\usepackage{{booktabs}}); generated from the sweep, "
        "do not edit by hand",
        r"\begin{table}[t]", r"\centering", r"\small",
        rf"\caption{{Outcomes per setting ({_tex(group)}; $n$ episodes). Rates in \% with {conf}\,\% Wilson "
        rf"intervals; min.\ clearance: IQM [m] and time to goal: median [s] (successful episodes) with "
        rf"{conf}\,\% stratified bootstrap intervals ({options.resamples} resamples).}}",
        r"\label{tab:jaxapf-outcomes}",
        r"\begin{tabular}{lrllll}", r"\toprule",
        r"Setting & $n$ & Success [\%] & Collision [\%] & Stall [\%] & Clearance [m] \\ \midrule",
    ]
    sub = summary[summary["family"] == group]
    for _, r in sub.iterrows():
        cells = [_tex_label(int(r["setting"]), sel.table, sel.swept), str(int(r["n"]))]
        cells += [_tex_ci(r[f"{m}_rate"], r[f"{m}_lo"], r[f"{m}_hi"], _tex_pct) for m in RATES]
        cells.append(_tex_ci(r["min_clearance_iqm"], r["min_clearance_iqm_lo"], r["min_clearance_iqm_hi"], _tex_num))
        lines.append(" & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    # time to goal as an extra table keeps the first one narrow enough for one column
    lines += [
        r"\begin{table}[t]", r"\centering", r"\small",
        rf"\caption{{Time to goal [s] over successful episodes: median with {conf}\,\% stratified bootstrap "
        rf"interval and the number of successful episodes ({_tex(group)}).}}",
        r"\label{tab:jaxapf-time}", r"\begin{tabular}{lrl}", r"\toprule",
        r"Setting & $n_{\mathrm{success}}$ & Time to goal [s] \\ \midrule",
    ]
    for _, r in sub.iterrows():
        lines.append(" & ".join([_tex_label(int(r["setting"]), sel.table, sel.swept), str(int(r["time_to_goal_n"])),
                                 _tex_ci(r["time_to_goal_median"], r["time_to_goal_median_lo"],
                                         r["time_to_goal_median_hi"], _tex_num)]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    if len(comparisons):
        comp = comparisons[comparisons["family"] == group]
        lines += [
            r"\begin{table}[t]", r"\centering", r"\small",
            rf"\caption{{Paired comparison with the baseline ({_tex(options.baseline)}; {_tex(group)}): "
            rf"difference in rate (percentage points, paired bootstrap {conf}\,\% interval), paired probability "
            rf"of improvement (PoI) and Holm-adjusted exact McNemar $p$ over {int(comparisons['p'].notna().sum())} "
            rf"tests.}}",
            r"\label{tab:jaxapf-paired}", r"\begin{tabular}{llllll}", r"\toprule",
            r"Setting & Baseline & $\Delta$ success [pp] & $\Delta$ collision [pp] & PoI success & $p_{\mathrm{Holm}}$ "
            r"(succ./coll.) \\ \midrule",
        ]
        for s in sorted(set(comp["setting"])):
            cs = comp[comp["setting"] == s].set_index("metric")
            if "success" not in cs.index:
                continue
            succ, coll = cs.loc["success"], cs.loc["collision"]
            lines.append(" & ".join([
                _tex_label(int(s), sel.table, sel.swept), _tex(f"#{int(succ['baseline'])}"),
                _tex_ci(succ["delta"], succ["delta_lo"], succ["delta_hi"], _tex_signed_pct),
                _tex_ci(coll["delta"], coll["delta_lo"], coll["delta_hi"], _tex_signed_pct),
                _tex_num(succ["poi"]), f"{_tex_p(succ['p_holm'])} / {_tex_p(coll['p_holm'])}"]) + r" \\")
        lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------


def _save(fig, name: str, caption: str, figdir: pathlib.Path) -> _Figure:
    import matplotlib

    figdir.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    png = buf.getvalue()
    (figdir / f"{name}.png").write_bytes(png)
    with matplotlib.rc_context({"svg.hashsalt": "jaxapf-report"}):
        fig.savefig(figdir / f"{name}.svg", format="svg", metadata={"Date": None})
    fig.clear()
    return _Figure(name, caption, png)


def _heatmap_figures(sel: _Selection, options: ReportOptions, figdir: pathlib.Path) -> tuple[list[_Figure], list[str]]:
    from .report_figures import plot_heatmaps

    if options.heatmap is None:
        return [], ["heatmaps skipped (--heatmap none)"]
    x, y = options.heatmap
    for c in (x, y):
        if c not in sel.table.columns:
            raise ReportError(f"--heatmap {x},{y}: no setting column {c!r}; use two of "
                              f"{', '.join(sel.swept) or 'the swept gains (none here)'}")
    table = sel.table.loc[sel.settings]
    swept_here = [c for c in swept_columns(table)]
    if x not in swept_here or y not in swept_here:
        return [], [f"heatmaps skipped: fewer than 2 swept gains among {x}, {y} "
                    f"(swept here: {', '.join(swept_here) or 'none'})"]
    figures, notes = [], []
    for method in sorted(pd.unique(table["method"])):
        ignored = IGNORED_BY_METHOD.get(method, ())
        if x in ignored or y in ignored:
            continue
        mt = table[table["method"] == method]
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
        for rate in ("success", "collision"):
            cells = []
            for combo in keys:
                ids = list(combos[combo])
                combo = combo if isinstance(combo, tuple) else (combo,)
                panel = " ".join(f"{_SYMBOL.get(c, c)}={_fmt_value(v)}" for c, v in zip(others, combo)) or method
                rows = sel.data[sel.data["setting"].isin(ids)].merge(
                    mt.loc[ids, [x, y]], left_on="setting", right_index=True, suffixes=("", "_setting"))
                xc, yc = (f"{x}_setting" if f"{x}_setting" in rows.columns else x,
                          f"{y}_setting" if f"{y}_setting" in rows.columns else y)
                for group in _groups(sel.data):
                    g = _group_rows(rows, group)
                    for (xv, yv), cell in g.groupby([xc, yc]):
                        cells.append({"row": group, "panel": panel, x: xv, y: yv,
                                      f"{rate} rate": float(cell[rate].mean()), "n": len(cell)})
            if not cells:
                continue
            fig = plot_heatmaps(pd.DataFrame(cells), x, y, f"{rate} rate",
                                f"{rate} rate [%] of {method} over {x} × {y}")
            figures.append(_save(fig, f"heatmap_{rate}_{method}", f"{rate.capitalize()} rate of {method} "
                                 f"over {x} × {y}, per family", figdir))
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


def _figures(sel: _Selection, summary: pd.DataFrame, comparisons: pd.DataFrame, options: ReportOptions,
             figdir: pathlib.Path) -> tuple[list[_Figure], list[str]]:
    from . import report_figures as rf

    labels = {s: sel.labels[s] for s in sel.settings}
    methods = {s: str(sel.table.at[s, "method"]) for s in sel.settings}
    groups = _groups(sel.data)
    figures, notes = _heatmap_figures(sel, options, figdir)

    clearance = {g: {s: _group_rows(sel.data[sel.data["setting"] == s], g)["min_clearance"].to_numpy(np.float64)
                     for s in sel.settings} for g in groups}
    figures.append(_save(rf.plot_ecdf(clearance, labels, methods, "min_clearance", "m"), "ecdf_min_clearance",
                         "Empirical CDF of the minimum clearance per setting (left of 0: collision)", figdir))
    figures.append(_save(rf.plot_rates(summary, labels, RATES, options.confidence), "rates",
                         f"Success, collision and stall rates with {100 * options.confidence:g} % Wilson intervals",
                         figdir))
    figures.append(_save(rf.plot_continuous(summary, labels, CONTINUOUS, UNITS, options.confidence), "continuous",
                         "Interquartile means of the continuous metrics with stratified bootstrap intervals "
                         "(time_to_goal: successful episodes)", figdir))
    if len(comparisons):
        pooled = comparisons[comparisons["family"] == groups[-1]]
        figures.append(_save(rf.plot_differences(pooled, labels, RATES + CONTINUOUS, options.alpha),
                             "differences", f"Paired differences to the baseline ({groups[-1]}): rates in "
                             "fraction, continuous metrics as difference of IQMs; filled = Holm-significant", figdir))
    metric = options.profile_metric
    values = sel.data[metric].to_numpy(np.float64)
    taus = _profile_taus(values)
    curves = {}
    for g in groups:
        curves[g] = {}
        for s in sel.settings:
            v = _group_rows(sel.data[sel.data["setting"] == s], g)[metric].to_numpy(np.float64)
            v = v[~np.isnan(v)]
            if v.size == 0:
                continue
            frac = stats.performance_profile(v, taus)
            lo, hi = stats.wilson_interval(np.round(frac * v.size), v.size, options.confidence)
            curves[g][s] = (frac, lo, hi)
    bands = len(sel.settings) <= 6
    figures.append(_save(rf.plot_performance_profile(taus, curves, labels, methods, metric, bands),
                         f"profile_{metric}", f"Performance profile: fraction of episodes with {metric} > τ"
                         + (" (bands: pointwise Wilson intervals)" if bands else ""), figdir))
    return figures, notes


# --------------------------------------------------------------------------------------------
# gallery of the worst episodes
# --------------------------------------------------------------------------------------------


def _worst(data: pd.DataFrame, count: int) -> list[tuple[str, pd.Series]]:
    """Up to ``count`` failed episodes: collisions (deepest first), stalls and other failures
    (farthest from the goal first), taken in turn, distinct fields before repeats."""
    fails = data[~data["success"]]
    order = ["setting", "family", "field"]
    cats = [
        ("collision", fails[fails["collision"]].sort_values(["min_clearance"] + order, kind="stable")),
        ("stall", fails[~fails["collision"] & fails["stalled"]].sort_values(
            ["final_distance"] + order, ascending=[False, True, True, True], kind="stable")
         if "final_distance" in fails.columns else fails[~fails["collision"] & fails["stalled"]]),
        ("not reached", fails[~fails["collision"] & ~fails["stalled"]].sort_values(
            ["final_distance"] + order, ascending=[False, True, True, True], kind="stable")
         if "final_distance" in fails.columns else fails[~fails["collision"] & ~fails["stalled"]]),
    ]
    queues = [(name, [r for _, r in frame.iterrows()]) for name, frame in cats]
    picked: list[tuple[str, pd.Series]] = []
    seen_fields: set = set()
    taken: set = set()
    for distinct in (True, False):
        progress = True
        while len(picked) < count and progress:
            progress = False
            for name, rows in queues:
                for r in rows:
                    ident = (int(r["setting"]), str(r["family"]), int(r["field"]))
                    if ident in taken or (distinct and (ident[1], ident[2]) in seen_fields):
                        continue
                    picked.append((name, r))
                    taken.add(ident)
                    seen_fields.add((ident[1], ident[2]))
                    progress = True
                    break
                if len(picked) >= count:
                    break
    return picked


def _get(cfg: Any, *names: str) -> Any:
    for n in names:
        if isinstance(cfg, Mapping) and n in cfg:
            return cfg[n]
        if not isinstance(cfg, Mapping) and hasattr(cfg, n):
            return getattr(cfg, n)
    return None


def _simulate_inputs(cfg: Any, row: pd.Series) -> dict[str, Any]:
    """Arguments of :func:`jaxapf.simulate.simulate_runs` from an ``episode_config`` result."""
    params = _get(cfg, "params", "family_params", "scenario_params", "scenario")
    if isinstance(_get(cfg, "overrides", "scenario_overrides"), Mapping):
        overrides = dict(_get(cfg, "overrides", "scenario_overrides"))
    elif params is not None and dataclasses.is_dataclass(params):
        overrides = {f.name: getattr(params, f.name) for f in dataclasses.fields(params) if f.init}
    elif isinstance(params, Mapping):
        overrides = {k: v for k, v in params.items() if k != "family"}
    else:
        overrides = {}
    sim = _get(cfg, "sim")
    return dict(
        family=str(_get(cfg, "family") or (getattr(params, "family", None)) or row["family"]),
        seed=int(_v(_get(cfg, "seed"), row.get("seed", 0))),
        field_index=int(_v(_get(cfg, "field", "field_index"), row["field"])),
        methods=[str(getattr(sim, "method", row["method"]))],
        gains=_get(cfg, "gains"), sim=sim, mpc=_get(cfg, "mpc"), scenario_overrides=overrides,
    )


def _v(value: Any, default: Any) -> Any:
    return default if value is None else value


def _gallery(sel: _Selection, meta: Mapping, options: ReportOptions,
             figdir: pathlib.Path) -> tuple[list[_Figure], list[str]]:
    if options.gallery == 0:
        return [], ["gallery skipped (--gallery 0)"]
    picks = _worst(sel.data, options.gallery)
    if not picks:
        return [], ["gallery: no failed episode among the reported settings"]
    try:
        from .sweep import episode_config
    except ImportError:
        return [], ["gallery skipped: jaxapf.sweep.episode_config is not available"]
    from .plotting import plot_trajectories
    from .simulate import simulate_runs

    if str(meta.get("dtype", "float32")) == "float64":
        import jax

        jax.config.update("jax_enable_x64", True)
    figures, notes = [], []
    for i, (kind, row) in enumerate(picks, 1):
        what = f"{sel.labels[int(row['setting'])]}, {row['family']} field {int(row['field'])}"
        try:
            cfg = episode_config(meta, row.to_dict())
            args = _simulate_inputs(cfg, row)
            field, runs, _ = simulate_runs(**args)
        except (ConfigError, KeyError, ValueError, TypeError, AttributeError, RuntimeError) as err:
            first = (str(err).strip().splitlines() or [type(err).__name__])[0]
            notes.append(f"gallery: could not re-simulate {what}: {first}")
            continue
        run = runs[0]
        recorded = {m: bool(row[m]) for m in RATES}
        resim = {m: bool(run.metrics.get(m, math.nan)) for m in RATES}
        check = "re-simulation matches the recorded outcome" if recorded == resim else (
            "re-simulation differs from the recorded row: recorded "
            + ", ".join(f"{m}={recorded[m]}" for m in RATES) + "; re-simulated "
            + ", ".join(f"{m}={resim[m]}" for m in RATES))
        fig = plot_trajectories(runs, field)
        fig.suptitle(f"Worst episode #{i} ({kind}): {what}", fontsize=10)
        caption = (f"{kind}: {what} (seed {args['seed']}); recorded min clearance "
                   f"{_num(row['min_clearance'])} m, final distance {_num(row.get('final_distance', math.nan))} m; "
                   f"re-simulated min clearance {_num(run.metrics.get('min_clearance', math.nan))} m; {check}")
        figures.append(_save(fig, f"gallery_{i}", caption, figdir))
    return figures, notes


# --------------------------------------------------------------------------------------------
# the report
# --------------------------------------------------------------------------------------------


def _spec_name(meta: Mapping, path: pathlib.Path) -> str:
    spec = meta.get("spec") if isinstance(meta.get("spec"), Mapping) else {}
    for key in ("name", "title"):
        if isinstance(spec.get(key), str) and spec[key]:
            return spec[key]
        if isinstance(spec.get("sweep"), Mapping) and isinstance(spec["sweep"].get(key), str):
            return spec["sweep"][key]
    name = path.name
    return name[: -len(".parquet")] if name.endswith(".parquet") else path.stem


def _rates_table(summary: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for _, r in summary.iterrows():
        rows.append({"setting": r["label"], "family": r["family"], "n": int(r["n"]),
                     **{f"{m} % [CI]": _with_ci(r[f"{m}_rate"], r[f"{m}_lo"], r[f"{m}_hi"], _pct) for m in RATES}})
    return pd.DataFrame(rows)


def _continuous_table(summary: pd.DataFrame, metric: str) -> pd.DataFrame:
    rows = []
    for _, r in summary.iterrows():
        rows.append({"setting": r["label"], "family": r["family"], "n": int(r[f"{metric}_n"]),
                     "median [CI]": _with_ci(r[f"{metric}_median"], r[f"{metric}_median_lo"], r[f"{metric}_median_hi"]),
                     "IQM [CI]": _with_ci(r[f"{metric}_iqm"], r[f"{metric}_iqm_lo"], r[f"{metric}_iqm_hi"])})
    return pd.DataFrame(rows)


def _comparison_table(comp: pd.DataFrame, metric: str) -> pd.DataFrame:
    rows = []
    rate = metric in RATES
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


def _findings(summary: pd.DataFrame, comparisons: pd.DataFrame, group: str, options: ReportOptions) -> list[str]:
    """Headline sentences for the pooled group, every number taken from the two tables."""
    sub = summary[summary["family"] == group]
    out = []
    picks = (("success", "rate", True, "Highest success rate"), ("collision", "rate", False, "Lowest collision rate"),
             ("stalled", "rate", False, "Lowest stall rate"),
             ("min_clearance", "iqm", True, "Largest IQM of the minimum clearance"))
    for metric, kind, high, text in picks:
        col = f"{metric}_{kind}"
        values = sub[col].to_numpy(dtype=np.float64)
        if not np.any(np.isfinite(values)):
            continue
        best = np.nanmax(values) if high else np.nanmin(values)
        rows = sub[np.isclose(values, best, rtol=0, atol=1e-12)]
        r = rows.iloc[0]
        if kind == "rate":
            value = f"{_pct(r[col])} % [{_pct(r[f'{metric}_lo'])}, {_pct(r[f'{metric}_hi'])}]"
        else:
            value = _with_ci(r[col], r[f"{col}_lo"], r[f"{col}_hi"]) + f" {UNITS.get(metric, '')}".rstrip()
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
                rate = r["metric"] in RATES
                delta = _with_ci(r["delta"], r["delta_lo"], r["delta_hi"],
                                 (lambda v: _signed(v, 100.0, 3)) if rate else _signed)
                better = "better" if (r["delta"] > 0) == bool(r["higher_is_better"]) else "worse"
                out.append(f"  {r['label']} vs #{int(r['baseline'])}: {r['metric']} "
                           f"{'Δ ' + delta + ' pp' if rate else 'Δ IQM ' + delta} ({better}), "
                           f"PoI {float(r['poi']):.2f}, p Holm {_p(r['p_holm'])}")
    return out


@dataclasses.dataclass
class ReportResult:
    """What :func:`build_report` wrote."""

    out: pathlib.Path
    paths: list[pathlib.Path]
    summary: pd.DataFrame
    comparisons: pd.DataFrame
    notes: list[str]


def build_report(path: str | pathlib.Path, out: str | pathlib.Path,
                 options: ReportOptions = ReportOptions()) -> ReportResult:
    """Read the sweep at ``path``, compute every statistic and write the report into ``out``."""
    path = pathlib.Path(path)
    out = pathlib.Path(out)
    df, meta = load_sweep(path)
    if options.profile_metric not in df.columns or options.profile_metric not in _METRIC_SET:
        raise ReportError(f"--profile-metric {options.profile_metric!r} is not a metric column of {path}")
    sel = _select(df, options)
    summary = summarize(sel.data, sel.settings, sel.table, sel.labels, options)
    comparisons = compare(sel.data, sel.pairs, sel.labels, options)
    out.mkdir(parents=True, exist_ok=True)
    figdir = out / "figures"
    figures, fig_notes = _figures(sel, summary, comparisons, options, figdir)
    gallery, gallery_notes = _gallery(sel, meta, options, figdir)
    notes = sel.notes + fig_notes + gallery_notes
    if meta.get("complete") is False and meta.get("rows_expected"):
        notes.insert(0, f"the sweep is incomplete: {len(df)} of {meta['rows_expected']} episodes are present "
                        "(an interrupted run?); only rows present in both settings are paired")

    spec_name = _spec_name(meta, path)
    groups = _groups(sel.data)
    pooled = groups[-1]
    versions = meta.get("versions") if isinstance(meta.get("versions"), Mapping) else {}
    n_tests = int(comparisons["p"].notna().sum()) if len(comparisons) else 0

    doc = _Doc()
    title = f"jaxapf report — {spec_name}"
    doc.h(1, title)
    doc.items([
        f"sweep: {path} ({len(df)} episodes in the file; {len(sel.data)} reported)",
        f"spec: {spec_name}, spec_hash {meta.get('spec_hash', '–')}, format {meta.get('format')}, "
        f"dtype {meta.get('dtype', '–')}, PRNG {json.dumps(meta.get('prng', {}))}",
        f"settings reported: {len(sel.settings)}; families: {', '.join(g for g in groups if g != ALL)}; "
        f"fields per family: " + ", ".join(f"{f}: {n}" for f, n in
                                          sel.data.groupby("family")["field"].nunique().items()),
        f"filters: {' '.join('--where ' + w for w in options.where) or 'none'}; baseline: {options.baseline} "
        f"(setting(s) {', '.join('#' + str(b) for b in sel.baseline_ids)})",
        f"statistics: {100 * options.confidence:g} % intervals; rates: Wilson score intervals; medians and IQMs "
        f"(25 % trimmed means): percentile bootstrap, {options.resamples} resamples, seed {options.seed}, "
        f"stratified by family for '{ALL}'; paired differences: paired bootstrap over fields (same resamples); "
        f"tests: exact McNemar (rates), Wilcoxon signed-rank (continuous), two-sided; Holm correction over all "
        f"{n_tests} tests of the comparison tables, significant (*) when the Holm-adjusted p <= {options.alpha:.3g}",
        "time_to_goal is NaN for an episode that does not succeed: its statistics use the successful episodes "
        "only (n given), its paired comparisons the pairs where both succeed; other non-finite values "
        "(e.g. min_clearance = +inf in a field without obstacles) are left out the same way",
        "generated " + datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
    ])
    doc.h(2, "Key findings")
    doc.items(_findings(summary, comparisons, pooled, options) or ["nothing to summarise"])
    doc.h(2, "Versions (from the sweep's metadata)")
    doc.table(pd.DataFrame({"package": list(versions), "version": [str(v) for v in versions.values()]})
              if versions else pd.DataFrame({"package": ["–"], "version": ["not recorded"]}))

    doc.h(2, "Settings")
    cols = [c for c in sel.swept]
    st = sel.table.loc[sel.settings, cols].reset_index() if cols else pd.DataFrame({"setting": sel.settings})
    st.insert(1, "label", [sel.labels[s] for s in sel.settings])
    st.insert(2, "role", ["baseline" if s in sel.baseline_ids else (f"vs #{sel.pairs[s]}" if s in sel.pairs else "")
                          for s in sel.settings])
    doc.table(st.map(_fmt_value) if hasattr(st, "map") else st.applymap(_fmt_value))

    doc.h(2, "Rates")
    doc.p(f"Rate in % with the {100 * options.confidence:g} % Wilson score interval, per setting and family"
          + (f"; '{ALL}' pools the families (episode-weighted)." if ALL in groups else "."))
    doc.table(_rates_table(summary))
    doc.h(2, "Continuous metrics")
    doc.p("Median and interquartile mean (IQM, mean of the middle 50 %) with percentile bootstrap intervals "
          f"({options.resamples} resamples, stratified by family for '{ALL}'); n = episodes with a finite value.")
    for m in CONTINUOUS:
        unit = f" [{UNITS[m]}]" if UNITS.get(m) else ""
        doc.h(3, f"{m}{unit}" + (" — successful episodes only" if m == "time_to_goal" else ""))
        doc.table(_continuous_table(summary, m))

    doc.h(2, f"Paired comparisons with the baseline ({options.baseline})")
    if len(comparisons):
        doc.p("Rows with equal (family, field) are the same obstacle field (common random numbers) and are paired. "
              "Δ = setting − baseline (rates in percentage points; continuous metrics: difference of IQMs over the "
              "pairs) with a paired bootstrap interval. PoI = P(setting better than baseline on the same field) "
              "+ ½ P(tie), over the pairs: > 0.5 favours the setting. Better means higher for success and "
              "min_clearance, lower for collision, stalled, time_to_goal, path_ratio, control_effort, jerk_rms. "
              f"p: exact McNemar (rates) or Wilcoxon signed-rank (continuous); p Holm: Holm-adjusted over all "
              f"{n_tests} tests; * = significant at {options.alpha:.3g}.")
        for m in RATES + CONTINUOUS:
            doc.h(3, m + (" (lower is better)" if not HIGHER_IS_BETTER[m] else " (higher is better)"))
            doc.table(_comparison_table(comparisons, m))
    else:
        doc.p("No setting to compare: every reported setting is a baseline setting.")

    doc.h(2, "Figures")
    for fig in figures:
        doc.figure(fig)
    doc.h(2, "Worst episodes (re-simulated from their seeds)")
    if gallery:
        doc.p("Failed episodes re-simulated with jaxapf.sweep.episode_config and jaxapf.simulate.simulate_runs: "
              "collisions (deepest first), stalls and other failures (farthest from the goal first), in turn, "
              "distinct fields first. Red X: first collision.")
        for fig in gallery:
            doc.figure(fig)
    else:
        doc.p("No gallery (see notes).")
    doc.h(2, "Notes")
    doc.items(notes or ["none"])

    paths = []
    summary_path = out / "summary.csv"
    summary.to_csv(summary_path, index=False)
    comp_path = out / "comparisons.csv"
    comparisons.to_csv(comp_path, index=False)
    tex_path = out / "table.tex"
    tex_path.write_text(_latex(summary, comparisons, sel, pooled, options, spec_name), encoding="utf-8")
    md_path = out / "report.md"
    md_path.write_text(_render_md(doc), encoding="utf-8")
    html_path = out / "report.html"
    html_path.write_text(_render_html(doc, title), encoding="utf-8")
    paths += [html_path, md_path, summary_path, comp_path, tex_path]
    paths += [figdir / f"{f.name}.{ext}" for f in figures + gallery for ext in ("png", "svg")]
    return ReportResult(out, paths, summary, comparisons, notes)
