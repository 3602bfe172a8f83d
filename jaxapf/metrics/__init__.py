"""Metrics: one number per episode each, in a registry every tool reads (SPEC 6)."""

from .base import DTYPES, KINDS, METRICS, Metric, compute_metrics, metric_names, register_metric
from .episode import (EpisodeContext, clearance_history, episode_end, episode_metrics, interval_clearance,
                      time_to_collision)

__all__ = ["Metric", "METRICS", "KINDS", "DTYPES", "register_metric", "metric_names", "compute_metrics",
           "EpisodeContext", "episode_metrics", "episode_end", "clearance_history", "interval_clearance",
           "time_to_collision"]
