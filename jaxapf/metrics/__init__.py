"""Metrics: one number per episode each, in a registry every tool reads (SPEC 6).

:mod:`.base` holds the registry (:data:`METRICS`, :class:`Metric`), :mod:`.context` the quantities
metrics share (:class:`EpisodeContext`), :mod:`.episode` the built-in metrics.
"""

from .base import DTYPES, KINDS, METRICS, Metric, compute_metrics, metric_names, register_entry_metrics, register_metric
from .context import EpisodeContext, clearance_history, episode_end, interval_clearance, time_to_collision
from .episode import episode_metrics

__all__ = ["Metric", "METRICS", "KINDS", "DTYPES", "register_metric", "register_entry_metrics", "metric_names",
           "compute_metrics", "EpisodeContext", "episode_metrics", "episode_end", "clearance_history",
           "interval_clearance", "time_to_collision"]
