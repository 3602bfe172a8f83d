"""One obstacle field with a start and a goal: what every episode is flown in."""

from __future__ import annotations

import dataclasses
import zlib

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..validation import ConfigError
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

    def take(self, i: int | slice | Array) -> "Scenario":
        """Field ``i`` of a batch (leading axis on every leaf) as one :class:`Scenario`, for
        :func:`~jaxapf.engine.rollout`; a slice or an index array gives a smaller batch. The same as
        ``jax.tree_util.tree_map(lambda x: x[i], batch)``; ``make_scenarios(seed, params, [i])`` is
        the same field again (bit-identical, as a batch of one)."""
        if jnp.ndim(self.start) != 2:
            raise ConfigError(f"Scenario.take: this is one field (start has shape {jnp.shape(self.start)}), "
                              "not a batch; take() picks fields out of a batch from make_scenarios")
        n = jnp.shape(self.start)[0]
        if isinstance(i, (int, np.integer)) and not isinstance(i, bool) and not -n <= i < n:
            raise ConfigError(f"Scenario.take: field {i} is out of range for a batch of {n} fields")
        return jax.tree_util.tree_map(lambda x: x[i], self)


def episode_key(scenario: Scenario, purpose: str, step: Array | int = 0) -> Array:
    """The PRNG key of ``purpose`` (a name per consumer: ``"sensing"``, ``"wind"``, ...) at control
    step ``step`` (an integer, negative allowed) of an episode in ``scenario``:
    ``fold_in(fold_in(field key, crc32(purpose)), step)``. Distinct names give independent streams."""
    data = jax.random.key_data(jax.random.key(0)) if scenario.key is None else scenario.key
    key = jax.random.fold_in(jax.random.wrap_key_data(data), zlib.crc32(purpose.encode()))
    return jax.random.fold_in(key, jax.lax.bitcast_convert_type(jnp.asarray(step, jnp.int32), jnp.uint32))
