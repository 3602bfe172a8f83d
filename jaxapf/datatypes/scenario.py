"""One obstacle field with a start and a goal: what every episode is flown in."""

from __future__ import annotations

import dataclasses

import jax
from jax import Array

from .obstacles import Obstacles

__all__ = ["Scenario"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Scenario:
    """One obstacle field with a start and a goal (all leaves arrays, batchable).

    Attributes:
      start: (3,) initial position; the UAV starts at rest.
      goal: (3,) goal position.
      obstacles: the padded obstacle set.
      kind: int32 index of the field's kind in its family's ``kinds`` (``make_scenarios`` sets it;
        ``None`` for a hand-made field, which then has no such leaf).
    """

    start: Array
    goal: Array
    obstacles: Obstacles
    kind: Array | None = None
