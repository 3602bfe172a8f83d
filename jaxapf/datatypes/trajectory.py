"""The record of one closed-loop episode (batched episodes carry extra leading axes)."""

from __future__ import annotations

import dataclasses
from typing import Mapping

import jax
from jax import Array

__all__ = ["Trajectory"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Trajectory:
    """Samples of one episode of ``T`` control steps.

    Attributes:
      time: (T+1,) sample times ``t_i = i dt`` [s].
      position: (T+1, 3) UAV position at the samples [m] (the plant's truth).
      velocity: (T+1, 3) UAV velocity at the samples [m/s].
      control: (T, 3) acceleration command applied to the plant on ``[t_i, t_{i+1})`` [m/s²]
        (after the safety filter).
      extras: per-step diagnostics of the episode's components, each (T, ...) (e.g. a safety
        filter's infeasible steps); empty for the paper's stack. Metrics may read them.
    """

    time: Array
    position: Array
    velocity: Array
    control: Array
    extras: Mapping[str, Array] = dataclasses.field(default_factory=dict)

    @property
    def steps(self) -> int:
        return self.control.shape[-2]
