"""One obstacle field with a start and a goal: what every episode is flown in."""

from __future__ import annotations

import dataclasses
import zlib

import jax
import jax.numpy as jnp
from jax import Array

from .obstacles import Obstacles

__all__ = ["Scenario", "episode_key"]


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
      key: uint32 (2,) data of the field's PRNG key, ``field_key(seed, i)`` (``make_scenarios``
        sets it): the episode's randomness (sensing noise, wind gusts) is drawn from it folded
        with a purpose and the control step, so it depends on the field only, never on the method
        or the gains (settings stay paired on common random numbers). ``None`` for a hand-made
        field: :func:`episode_key` then uses ``jax.random.key(0)``.
    """

    start: Array
    goal: Array
    obstacles: Obstacles
    kind: Array | None = None
    key: Array | None = None


def episode_key(scenario: Scenario, purpose: str, step: Array | int = 0) -> Array:
    """The PRNG key of ``purpose`` (a name per consumer: ``"sensing"``, ``"wind"``, ...) at control
    step ``step`` (an integer, negative allowed) of an episode in ``scenario``:
    ``fold_in(fold_in(field key, crc32(purpose)), step)``. Distinct names give independent streams."""
    data = jax.random.key_data(jax.random.key(0)) if scenario.key is None else scenario.key
    key = jax.random.fold_in(jax.random.wrap_key_data(data), zlib.crc32(purpose.encode()))
    return jax.random.fold_in(key, jax.lax.bitcast_convert_type(jnp.asarray(step, jnp.int32), jnp.uint32))
