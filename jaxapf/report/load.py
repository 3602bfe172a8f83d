"""Loading a sweep for a report: its rows, metadata, and which metrics the report shows.

What a metric means (rate or continuous, unit, direction, successful episodes only) comes from the
metric registries (:data:`jaxapf.metrics.METRICS`, :data:`~jaxapf.metrics.SWARM_METRICS` for a swarm
sweep); the default report shows the registered metrics
marked ``report=True`` that the sweep wrote.
"""

from __future__ import annotations

import dataclasses
import pathlib
from typing import Any, Iterable, Mapping

import pandas as pd

from ..metrics import METRICS, all_metrics
from ..validation import ConfigError

__all__ = ["ReportError", "ROW_COLUMNS", "FIELD_COLUMNS", "Roles", "SINGLE_ROLES", "SWARM_ROLES", "roles",
           "report_metrics", "load_sweep", "validate_sweep"]

#: Columns that identify an episode within a setting (the pairing key: those present).
ROW_COLUMNS: tuple[str, ...] = ("family", "kind", "field", "seed")
#: Row columns that describe the episode's field under its setting's vehicle (not a setting column);
#: ``agents``: the UAVs of a swarm field.
FIELD_COLUMNS: tuple[str, ...] = ("solvable", "agents")
#: Columns every report needs besides its metrics.
BASE_COLUMNS: tuple[str, ...] = ("setting", "method", "family", "field")


@dataclasses.dataclass(frozen=True)
class Roles:
    """The metric columns that play each part of a report: the outcome (``success``), the failure
    (``collision``), being stuck (``stalled``), the clearance of the ECDF, the gallery and the LaTeX
    table, the duration of the LaTeX table (``time``), and the default metric of the performance
    profile."""

    success: str
    collision: str
    stalled: str
    clearance: str
    time: str
    profile: str

    @property
    def swarm(self) -> bool:
        return self is SWARM_ROLES


#: A single-UAV sweep's roles.
SINGLE_ROLES = Roles("success", "collision", "stalled", "min_clearance", "time_to_goal", "spl")
#: A swarm sweep's (:data:`~jaxapf.metrics.SWARM_METRICS`): every UAV at its goal, two UAVs colliding,
#: deadlock, the closest approach between UAVs, the makespan, the fraction of UAVs at their goals.
SWARM_ROLES = Roles("swarm_success", "agent_collision", "deadlock", "min_agent_clearance", "makespan", "at_goal")


def roles(columns: Iterable[str]) -> Roles:
    """The roles of a sweep's rows with these ``columns`` (a swarm sweep's if it has ``swarm_success``)."""
    return SWARM_ROLES if "swarm_success" in set(columns) else SINGLE_ROLES


class ReportError(ConfigError):
    """The report cannot be made from this input (bad file, missing column, empty filter, ...)."""


def report_metrics(columns: Iterable[str] | None = None) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``(rates, continuous)``: the registered metrics of the default report (single-UAV, then swarm
    metrics), in registration order, among ``columns`` if given (else the single-UAV ones)."""
    keep = set(METRICS.names()) if columns is None else set(columns)
    pick = lambda kind: tuple(m for m, metric in all_metrics()  # noqa: E731
                              if metric.kind == kind and metric.report and m in keep)
    return pick("rate"), pick("continuous")


def load_sweep(path: str | pathlib.Path) -> tuple[pd.DataFrame, dict]:
    """The rows and metadata of a sweep (:func:`jaxapf.sweep.read_sweep`), validated.

    Raises :class:`ReportError` with one line for anything that is not a sweep's output.
    """
    from ..sweep import read_sweep

    path = pathlib.Path(path)
    try:
        df, meta = read_sweep(path)
    except ConfigError as err:
        raise ReportError(str(err)) from None
    validate_sweep(df, meta, path)
    return df, meta


def validate_sweep(df: pd.DataFrame, meta: Any, path: str | pathlib.Path = "input") -> None:
    """Check that ``(df, meta)`` looks like ``jaxapf sweep`` output; :class:`ReportError` if not.

    The report's metrics the sweep says it wrote (its metadata's ``metrics``; every registered one
    for an output that does not say) must be columns."""
    if not isinstance(meta, Mapping) or not str(meta.get("format", "")).startswith("jaxapf.sweep/"):
        raise ReportError(f"{path} is not the output of jaxapf sweep (no 'jaxapf' sweep metadata "
                          "with a 'jaxapf.sweep/N' format in the Parquet schema)")
    rates, continuous = report_metrics(meta.get("metrics"))
    missing = [c for c in BASE_COLUMNS + rates + continuous if c not in df.columns]
    if missing:
        raise ReportError(f"{path} lacks the column(s) {', '.join(missing)} that a jaxapf sweep writes")
    if len(df) == 0:
        raise ReportError(f"{path} holds no episodes (0 rows)")
    for c in rates:
        if not (pd.api.types.is_bool_dtype(df[c]) or set(pd.unique(df[c])) <= {0, 1}):
            raise ReportError(f"{path}: column {c} must be boolean (0/1)")
    for c in continuous:
        if not pd.api.types.is_numeric_dtype(df[c]):
            raise ReportError(f"{path}: column {c} must be numeric, not {df[c].dtype}")
    key = ["setting"] + [c for c in ROW_COLUMNS if c in df.columns]
    dup = df.duplicated(key)
    if dup.any():
        first = df.loc[dup, key].iloc[0].to_dict()
        raise ReportError(f"{path}: {int(dup.sum())} duplicate episode row(s), e.g. {first}; "
                          "every (setting, family, field) must appear once")
