"""The record of one closed-loop episode (batched episodes carry extra leading axes)."""

from __future__ import annotations

import dataclasses

import jax
from jax import Array

__all__ = ["Trajectory"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Trajectory:
    """Samples of one episode of ``T`` control steps.

    Attributes:
      time: (T+1,) sample times ``t_i = i dt`` [s].
      position: (T+1, 3) UAV position at the samples [m].
      velocity: (T+1, 3) UAV velocity at the samples [m/s].
      control: (T, 3) acceleration applied on ``[t_i, t_{i+1})`` [m/s²].
    """

    time: Array
    position: Array
    velocity: Array
    control: Array

    @property
    def steps(self) -> int:
        return self.control.shape[-2]
