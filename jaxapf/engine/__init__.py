"""The engine: the closed loop of one episode (:mod:`~jaxapf.engine.loop`), batches of episodes in
one compiled call, streamed or fixed-length (:mod:`~jaxapf.engine.batch`, :mod:`~jaxapf.engine.stream`),
split over devices (:mod:`~jaxapf.engine.devices`), how a sweep fills a backend (:mod:`~jaxapf.engine.policy`),
the table of the components a setting names (:mod:`~jaxapf.engine.components`), and the process's JAX settings
(:mod:`~jaxapf.engine.runtime`)."""

from .batch import (
                    ACCELERATOR_WIDTH,
                    CPU_WIDTH,
                    XLA_OPTIONS,
                    default_width,
                    episode_index,
                    evaluate,
                    evaluate_program,
                    program,
)
from .components import COMPONENTS, components_read_gains, gains_read
from .devices import DeviceBatch
from .loop import rollout, rollout_metrics
from .runtime import configure_jax, default_cache_dir

__all__ = ["rollout", "rollout_metrics", "gains_read", "evaluate", "evaluate_program", "episode_index",
           "default_width", "CPU_WIDTH", "ACCELERATOR_WIDTH", "XLA_OPTIONS", "COMPONENTS", "components_read_gains",
           "DeviceBatch", "program", "configure_jax", "default_cache_dir"]
