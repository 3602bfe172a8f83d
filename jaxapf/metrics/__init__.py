"""Metrics: one number per episode each, in a registry every tool reads (SPEC 6).

:mod:`.base` holds the registry (:data:`METRICS`, :class:`Metric`), :mod:`.context` the quantities
metrics share (:class:`EpisodeContext`), :mod:`.episode` the built-in metrics, :mod:`.swarm` the
metrics of a swarm episode (:data:`SWARM_METRICS`). Tools that read rows of either kind look a
metric up with :func:`find_metric`.
"""

from .base import DTYPES, KINDS, METRICS, Metric, compute_metrics, metric_names, register_entry_metrics, register_metric
from .context import EpisodeContext, clearance_history, episode_end, interval_clearance, time_to_collision
from .episode import episode_metrics
from .swarm import SWARM_METRICS


def find_metric(name: str, where: str | None = None) -> Metric:
    """The metric ``name`` of :data:`METRICS` (one UAV) or :data:`SWARM_METRICS` (a swarm); the two share
    no name (:func:`register_metric` refuses one); :class:`ConfigError` naming ``where`` otherwise."""
    return SWARM_METRICS.get(name) if name in SWARM_METRICS else METRICS.get(name, where)


def is_metric(name: object) -> bool:
    """Whether ``name`` is a single-UAV or a swarm metric (a metric column of a sweep's rows)."""
    return name in METRICS or name in SWARM_METRICS


def all_metrics() -> tuple[tuple[str, Metric], ...]:
    """Every metric of both registries, single-UAV first, each as ``(name, metric)``."""
    return METRICS.items() + SWARM_METRICS.items()

__all__ = ["Metric", "METRICS", "SWARM_METRICS", "find_metric", "is_metric", "all_metrics", "KINDS", "DTYPES",
           "register_metric", "register_entry_metrics", "metric_names", "compute_metrics", "EpisodeContext",
           "episode_metrics", "episode_end", "clearance_history", "interval_clearance", "time_to_collision"]
