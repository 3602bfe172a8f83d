"""The metric registry: one entry per number an episode yields.

Each :class:`Metric` says how it is computed from an episode (a function of the
:class:`~jaxapf.metrics.context.EpisodeContext`, traced under ``jit``/``vmap``) and what it means:
dtype, unit, whether it is a rate (a boolean outcome) or continuous, whether higher is better,
whether it is meaningful only on successful episodes, and whether the default report shows it.
The sweep's Parquet schema, the report's tables and units, ``jaxapf simulate``'s table and
``jaxapf bench`` all read this registry; there is no second list anywhere.

Register a metric with :func:`register_metric` (``docs/extending.md``); every later program
computes it and every later sweep writes its column.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Sequence

import jax.numpy as jnp
from jax import Array

from ..registry import Registry, loop_rank
from ..validation import ConfigError
from .context import EpisodeContext

__all__ = ["Metric", "METRICS", "KINDS", "DTYPES", "register_metric", "register_entry_metrics", "compute_metrics",
           "metric_names"]

#: What a metric is: a boolean outcome (its mean is a rate), a continuous number, or a count.
KINDS = ("rate", "continuous", "count")
#: Value types: ``bool``, ``int32``, or ``float`` (the trajectory's floating dtype).
DTYPES = ("bool", "int32", "float")


@dataclasses.dataclass(frozen=True)
class Metric:
    """One number per episode.

    Attributes:
      name: column name (letters, digits, ``_``).
      fn: ``fn(ctx) -> scalar`` on the :class:`~jaxapf.metrics.context.EpisodeContext`.
      dtype: ``bool``, ``int32`` or ``float``.
      kind: ``rate`` (``dtype`` bool), ``continuous`` or ``count``.
      unit: unit for tables and axes (``"m"``), ``""`` for none.
      higher_is_better: direction of improvement (``None``: neither, e.g. a diagnostic).
      on_success: meaningful only on successful episodes (NaN or ignored otherwise).
      report: shown in the default tables of ``jaxapf report``.
      margin: the relevance margin of a difference between two settings, in the metric's unit (a
        rate's in proportion: 0.02 = 2 percentage points); a smaller difference does not matter.
        Reports judge equivalence against it and may override it (``--margin NAME=VALUE``).
        ``None``: no verdict of relevance.
      per_step: the value moves in whole control steps (a count of steps, or a time ``dt`` × a count):
        two programs that round a step's comparison apart may differ by one step in it.
      doc: one line of what it measures (its exact definition belongs in ``fn``'s docstring).
      flag: the per-step diagnostic of a component that the metric sums (:meth:`flagged_steps`), or
        ``None``; a swarm's rows sum it too, over every UAV (:func:`jaxapf.metrics.swarm.swarm_metric_names`).
    """

    name: str
    fn: Callable[["EpisodeContext"], Array]
    dtype: str = "float"
    kind: str = "continuous"
    unit: str = ""
    higher_is_better: bool | None = None
    on_success: bool = False
    report: bool = False
    margin: float | None = None
    per_step: bool = False
    doc: str = ""
    flag: str | None = None

    def __post_init__(self) -> None:
        if self.dtype not in DTYPES:
            raise ConfigError(f"metric {self.name!r}: dtype = {self.dtype!r}; choose one of {', '.join(DTYPES)}")
        if self.kind not in KINDS:
            raise ConfigError(f"metric {self.name!r}: kind = {self.kind!r}; choose one of {', '.join(KINDS)}")
        if (self.kind == "rate") != (self.dtype == "bool"):
            raise ConfigError(f"metric {self.name!r}: a rate is exactly a metric of dtype bool")
        if self.margin is not None and not self.margin > 0:
            raise ConfigError(f"metric {self.name!r}: margin = {self.margin!r} must be > 0 or None")

    @classmethod
    def flagged_steps(cls, name: str, flag: str, doc: str, per_step: bool = True) -> "Metric":
        """The sum over the control steps of a component's per-step diagnostic ``flag`` (a count, lower is
        better): the steps at which the CBF filter or the velocity obstacles were infeasible or not certified
        exact, the obstacle-steps the sensor missed (``per_step=False``: not a count of steps). In a swarm's
        rows, summed over the UAVs too, each UAV's steps before its end."""
        return cls(name, lambda ctx: ctx.extra(flag), dtype="int32", kind="count", higher_is_better=False,
                   per_step=per_step, doc=doc, flag=flag)

    def cast(self, value: Array, float_dtype) -> Array:
        """``value`` in the metric's dtype (``float``: ``float_dtype``)."""
        if self.dtype == "bool":
            return value.astype(bool)
        if self.dtype == "int32":
            return value.astype(jnp.int32)
        return jnp.asarray(value).astype(float_dtype)


def _describe(metric: Metric) -> str:
    unit = f" [{metric.unit}]" if metric.unit else ""
    better = {True: ", higher is better", False: ", lower is better", None: ""}[metric.higher_is_better]
    success = ", successful episodes only" if metric.on_success else ""
    margin = "" if metric.margin is None else f", margin {metric.margin:g}" + (
        f" {metric.unit}" if metric.unit and metric.kind != "rate" else "")
    return f"{metric.doc}{unit} ({metric.kind}{better}{success}{margin})"


#: Where each metric is listed: the episode's own metrics first, then those of the closed loop's
#: components by kind (:data:`jaxapf.registry.LOOP`).
_RANK: dict[str, int] = {}

#: Registered metrics, in column order: the episode's own, then the components' by kind, each in
#: registration order (whichever module was imported first).
METRICS: Registry[Metric] = Registry("metric", describe=_describe, rank=_RANK.__getitem__)


#: The names of the swarm metrics (:mod:`jaxapf.metrics.swarm` adds them as it registers them): no
#: single-UAV metric may take one.
SWARM_NAMES: set[str] = set()


def register_metric(metric: Metric, *, replace: bool = False, kind: str | None = None) -> Metric:
    """Register ``metric`` under its name; ``kind``: the kind of component whose metric it is (None: the
    episode's, listed first). A swarm metric's name is refused (:func:`jaxapf.metrics.find_metric`
    finds a metric of either registry by its name)."""
    if metric.name in SWARM_NAMES:
        raise ConfigError(f"metric {metric.name!r} is a swarm metric's name; give the metric a name of its own")
    _RANK[metric.name] = -1 if kind is None else loop_rank(kind)
    return METRICS.register(metric.name, metric, replace=replace)


def register_entry_metrics(entry: Any, registry: Registry) -> None:
    """What a component registry does with a new entry: register the metrics it owns (``entry.metrics``,
    measuring what only it records, e.g. a filter's infeasible steps)."""
    for metric in getattr(entry, "metrics", ()):
        register_metric(metric, kind=registry.what)


def metric_names(*, kind: str | None = None, report: bool | None = None) -> tuple[str, ...]:
    """Registered metric names, optionally only of one ``kind`` or only those (not) in the default report."""
    return tuple(n for n, m in METRICS.items()
                 if (kind is None or m.kind == kind) and (report is None or m.report == report))


def compute_metrics(ctx: "EpisodeContext", names: Sequence[str], float_dtype) -> dict[str, Array]:
    """``{name: value}`` of the metrics ``names`` on one episode's context."""
    return {name: METRICS.get(name).cast(METRICS.get(name).fn(ctx), float_dtype) for name in names}
