"""Settings, filters and the pairing of every setting with its baseline."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Iterable, Sequence

import numpy as np
import pandas as pd

from ..config import PlannerConfig, SimConfig
from ..engine.components import COMPONENTS
from ..gains import GAINS
from ..metrics import is_metric
from ..planners import PLANNERS
from .load import FIELD_COLUMNS, ROW_COLUMNS, ReportError, report_metrics

__all__ = ["Selection", "select", "setting_table", "swept_columns", "setting_labels", "parse_filters",
           "ignored_columns", "format_value", "symbol"]

#: Planner settings a planner may or may not read (``Planner.reads``).
_PLANNER_OPTIONS = tuple(f.name for f in dataclasses.fields(PlannerConfig) if f.name not in ("method", "filter"))


def symbol(column: str) -> str:
    """A gain's short label (``γ`` for ``gamma``), else the column's name."""
    return GAINS.get(column).label if column in GAINS else column


def ignored_columns(row: Any) -> tuple[str, ...]:
    """Setting columns the components of a setting do not read (``row``: its method, filter, plant,
    sensor and disturbance, absent ones at their defaults): settings that differ only there fly the same episodes.
    Nothing is ignored for a planner that is not registered in this process."""
    defaults = SimConfig().flat()
    name = lambda key: str(row.get(key, defaults[key]) if hasattr(row, "get") else defaults[key])  # noqa: E731
    if name("method") not in PLANNERS:
        return ()
    planner = PLANNERS.get(name("method"))
    read = {g.name for key, registry in COMPONENTS.items() if name(key) in registry
            for g in registry.get(name(key)).gains}
    return tuple(g for g in GAINS.names() if g not in read) + tuple(o for o in _PLANNER_OPTIONS
                                                                        if o not in planner.reads)


def setting_table(df: pd.DataFrame) -> pd.DataFrame:
    """One row per setting (index ``setting``) with every column constant within a setting
    (method, convention, gains, simulation settings); metrics and row columns excluded."""
    cols = [c for c in df.columns if not is_metric(c) and c not in ROW_COLUMNS + FIELD_COLUMNS and c != "setting"]
    grouped = df.groupby("setting", sort=True)
    constant = [c for c in cols if bool((grouped[c].nunique(dropna=False) <= 1).all())]
    return grouped[constant].first()


def swept_columns(table: pd.DataFrame) -> list[str]:
    """Setting columns with more than one value."""
    return [c for c in table.columns if table[c].nunique(dropna=False) > 1]


def format_value(v: Any) -> str:
    """A setting's value as a label shows it (``true``, ``0.5``, ``basic``)."""
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v)).lower()
    if isinstance(v, (float, np.floating)):
        return f"{float(v):g}"
    return str(v)


def setting_labels(table: pd.DataFrame, swept: Sequence[str]) -> dict[int, str]:
    """``#3 direction_velocity γ=1 k=0.5``: index, method and the swept columns the method reads; where a
    ``selection`` column names the settings (``jaxapf compare``'s test: ``#3 direction_velocity seed2``), the
    name instead of the gains it selected (the report's settings table lists those)."""
    labels = {}
    named = "selection" in swept
    for s, row in table.iterrows():
        method = str(row.get("method", ""))
        ignored = ignored_columns(row)
        parts = [f"#{s}", method]
        if named:
            parts.append(format_value(row["selection"]))
        else:
            parts += [f"{symbol(c)}={format_value(row[c])}" for c in swept if c != "method" and c not in ignored]
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
    vals = sorted({format_value(v) for v in pd.unique(column)}, key=lambda x: (len(x), x))
    return ", ".join(vals[:limit]) + (", ..." if len(vals) > limit else "")


@dataclasses.dataclass
class Selection:
    """What a report is about: rows, settings, labels and the baseline pairing."""

    data: pd.DataFrame  # rows of the reported settings (row filters applied)
    table: pd.DataFrame  # setting table of the whole sweep
    swept: list[str]
    labels: dict[int, str]
    settings: list[int]  # reported settings, ascending
    pairs: dict[int, int]  # setting -> its baseline setting
    baseline_ids: list[int]
    notes: list[str]


def select(df: pd.DataFrame, options: Any) -> Selection:
    """The rows, settings and baseline pairs of a report with ``options``
    (:class:`~jaxapf.report.build.ReportOptions`)."""
    table = setting_table(df)
    swept = swept_columns(table)
    labels = setting_labels(table, swept)
    notes: list[str] = []
    setting_cols = set(table.columns) | {"setting"}
    # row filters: family, field, seed, and columns that vary within a setting (e.g. t_max when it
    # defaults to each family's own)
    row_cols = [c for c in df.columns if c not in setting_cols and not is_metric(c)]

    rows, chosen = _where(df, table, row_cols, setting_cols, options.where)
    selected = [int(s) for s in table.index[chosen]]
    rows_df = df[rows]
    present = set(int(s) for s in pd.unique(rows_df["setting"]))
    selected = [s for s in selected if s in present]
    if not selected:
        raise ReportError(f"the filters {' '.join('--where ' + w for w in options.where)} together select no rows")

    base_filters = _parse_baseline(options.baseline)
    baseline_ids = _baseline(table, present, base_filters, options.baseline)
    fixed = {k for k, _ in base_filters}
    for c in options.pair_on:
        if c not in table.columns:
            raise ReportError(f"--pair-on {c}: no setting column {c!r}; use one of {', '.join(table.columns)}")
    pairs: dict[int, int] = {}
    for s in selected:
        if s in baseline_ids:
            continue
        if len(baseline_ids) == 1:
            pairs[s] = baseline_ids[0]
            continue
        matches = []
        for b in baseline_ids:
            ignored = ignored_columns(table.loc[b])
            cols = list(options.pair_on) or [c for c in swept if c not in fixed and c not in ignored]
            if all(_same(table.at[s, c], table.at[b, c]) for c in cols):
                matches.append(b)
        if matches:
            pairs[s] = min(matches)
        else:
            on = ", ".join(options.pair_on) if options.pair_on else "the swept columns"
            notes.append(f"{labels[s]}: no baseline setting matches it on {on}, so it is not compared")
    if len(baseline_ids) > 1 and options.pair_on:
        notes.append(f"{len(baseline_ids)} settings match the baseline {options.baseline} "
                     f"({', '.join('#' + str(b) for b in baseline_ids)}): each setting is paired with the "
                     f"lowest-numbered one that equals it on {', '.join(options.pair_on)} (--pair-on)")
    elif len(baseline_ids) > 1:
        ignores = {str(table.at[b, "method"]): [c for c in ignored_columns(table.loc[b]) if c in swept]
                   for b in baseline_ids}
        ignored_text = "; ".join(f"{m} ignores {', '.join(c)}" for m, c in ignores.items() if c) or "none ignore any"
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
    for c in report_metrics(data.columns)[0]:
        data[c] = data[c].astype(bool)
    return Selection(data, table, swept, labels, settings, pairs, baseline_ids, notes)


def _baseline(table: pd.DataFrame, present: set[int], base_filters: list[tuple[str, list[str]]],
              baseline: str) -> list[int]:
    """``--baseline``: the settings it names among those with rows after the row filters."""
    avail = table.loc[sorted(present)]
    is_base = np.ones(len(avail), dtype=bool)
    for key, values in base_filters:
        what = f"--baseline {baseline}"
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
        raise ReportError(f"baseline {baseline} is not in the data ({key} has: {_choices(col)})")
    return baseline_ids


def _where(df: pd.DataFrame, table: pd.DataFrame, row_cols: list[str], setting_cols: set[str],
           where: Any) -> tuple[np.ndarray, np.ndarray]:
    """``--where``: the rows its row filters (family, field, seed) keep and the settings its setting filters
    keep, as masks; a filter on a metric, on no column, or keeping nothing refused in one line."""
    rows = np.ones(len(df), dtype=bool)
    chosen = np.ones(len(table), dtype=bool)
    for key, values in parse_filters(where, "--where"):
        what = f"--where {key}={','.join(values)}"
        if is_metric(key):
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
    return rows, chosen


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, (int, float, np.integer, np.floating)) and isinstance(b, (int, float, np.integer, np.floating)):
        return bool(np.isclose(float(a), float(b), rtol=1e-9, atol=1e-12) or (math.isnan(a) and math.isnan(b)))
    return a == b


