r"""Episode streaming: a batch of slots, each taking the next episode of the queue when its own ends.

The fixed-length engine (``evaluate(..., streaming=False)``) flies every episode for the whole ``t_max``;
this engine flies the same episodes with the same control step (:func:`~jaxapf.engine.loop.loop_step`) and
computes the same metrics, but stops each one once it has *certainly* ended
(:func:`~jaxapf.metrics.context.certainly_ended`). ``slots`` episodes fly side by side in segments of
:data:`SEGMENT` steps, record into a ring, hand finished episodes to a store that is measured a batch at a
time, and take the next episodes of the queue; the tail of a long queue runs on narrower vmaps
(:func:`stream_levels`). All of it is one ``lax.while_loop`` in the caller's program. An episode's numbers do
not depend on the queue it ran in, bit for bit; against the fixed engine they agree up to rounding. The
design, the contract it rests on and what it costs: docs/performance.md, "Episode streaming".
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
from jax import Array

from ..config import MPCConfig, SimConfig
from ..datatypes import Scenario
from ..gains import Gains
from ..metrics import episode_metrics
from ..metrics.context import certainly_at_goal, certainly_ended
from .loop import closed_loop, episode_loop, loop_init, loop_step, record_trajectory

__all__ = ["SEGMENT", "NARROWEST", "NARROWING_FROM", "stream_slots", "stream_levels", "stream_metrics", "EpisodeKind",
           "single_uav"]

#: Control steps between two refills of the slots.
SEGMENT = 10
#: The narrowest vmap of the engine: a short queue flies at it. Below it XLA:CPU rounds a few
#: episodes differently (``tests/engine/test_stream.py``).
NARROWEST = 64
#: The fewest slots whose tail moves to narrower vmaps: with fewer, a call saves a fraction of what
#: compiling the narrower widths costs (``benchmarks/stream_levels.py``, docs/performance.md); with more,
#: a call saves more, and a program called for several chunks repays it.
NARROWING_FROM = 256


def stream_slots(episodes: int, width: int, refill: bool = True) -> int:
    """The slot count for a queue of ``episodes``: about a quarter of them (so that each slot flies
    several and slots freed early are refilled), or with ``refill=False`` enough for all of them
    (:class:`~jaxapf.engine.policy.Policy`); a power of two, at least :data:`NARROWEST` and at most ``width``."""
    wanted = max(episodes // 4, 1).bit_length() - 1 if refill else (max(episodes, 1) - 1).bit_length()
    return min(width, max(NARROWEST, 1 << wanted))


def stream_levels(slots: int, narrowing_from: int = NARROWING_FROM) -> tuple[int, ...]:
    """The vmap widths ``slots`` flies its queue at, widest first: ``slots``, then ``slots/2`` and
    ``slots/4`` (never below :data:`NARROWEST`) for the tail from ``narrowing_from`` slots on. The widths
    change no number, only the time (an episode's numbers do not depend on the width it flew at, from
    :data:`NARROWEST` up)."""
    if slots < narrowing_from:
        return (slots,)
    return tuple(sorted({max(slots >> i, min(slots, NARROWEST)) for i in range(3)}, reverse=True))


def _rows(tree: Any, index: Any) -> Any:
    return jax.tree_util.tree_map(lambda x: x[index], tree)


def _put(tree: Any, index: Array, rows: Any) -> Any:
    """``tree[index] = rows`` leaf by leaf; indices out of range are dropped."""
    return jax.tree_util.tree_map(lambda x, r: x.at[index].set(r, mode="drop"), tree, rows)


def _columns(tree: Any, index: Any) -> Any:
    """Episodes ``index`` of time-major arrays (episodes on axis 1)."""
    return jax.tree_util.tree_map(lambda x: x[:, index], tree)


def _write(tree: Any, block: Any, row: Array, column: Array | int) -> Any:
    """``block`` into the time-major ``tree`` at (``row``, ``column``), leaf by leaf."""
    start = (row, column)
    return jax.tree_util.tree_map(lambda x, b: jax.lax.dynamic_update_slice(
        x, b, tuple(jnp.asarray(i, jnp.int32) for i in start + (0,) * (x.ndim - 2))), tree, block)


class EpisodeKind(NamedTuple):
    """What one slot of the streaming engine flies, as three pure functions:

    * ``start(field, gains)``: the slot at the start of an episode on ``field`` with the setting
      ``gains``: a dict holding at least ``k`` (control steps flown, int32), ``ended`` (whether the
      episode has certainly ended) and ``x0`` (its first sample);
    * ``step(slot)``: one control step, ``(slot, record)``;
    * ``measure(x0, records, field)``: the metrics of a finished episode from its first sample and
      its records (``T`` on the leading axis).

    :func:`single_uav` is one UAV among the field's obstacles;
    :func:`~jaxapf.engine.swarm.swarm_episodes` a swarm, which ends when every UAV has ended."""

    start: Callable[[Any, Gains], dict[str, Any]]
    step: Callable[[dict[str, Any]], tuple[dict[str, Any], Any]]
    measure: Callable[[Array, Any, Any], dict[str, Array]]


def single_uav(sim: SimConfig, mpc: MPCConfig, dtype: Any, metrics: Sequence[str]) -> EpisodeKind:
    """One UAV per episode (:class:`~jaxapf.datatypes.Scenario` fields): :func:`~jaxapf.engine.loop.loop_step`
    per control step, ended when :func:`~jaxapf.metrics.context.certainly_ended` fires, measured by
    :func:`~jaxapf.metrics.episode_metrics`."""
    loop = closed_loop(sim, mpc, dtype)
    dt = sim.episode.dt

    def start(scenario: Scenario, g: Gains) -> dict[str, Any]:
        carry = loop_init(loop, scenario, g, sim, mpc)
        own = {} if loop.prob is not None else {"prob": episode_loop(loop, g, sim, mpc, dtype).prob}
        return {**own, "scenario": scenario, "obstacles": scenario.obstacles.columns(), "gains": g, "carry": carry,
                "k": jnp.zeros((), jnp.int32), "ended": certainly_at_goal(scenario.start, scenario, sim),
                "x0": loop.plant.kinematics(carry[0])}

    def step(slot: dict[str, Any]) -> tuple[dict[str, Any], tuple]:
        """One control step of one slot and its record (the plant's ``[p, v]`` after it, the
        applied acceleration, the components' diagnostics)."""
        k = slot["k"]
        p0 = loop.plant.kinematics(slot["carry"][0])[:3]
        flown = loop if loop.prob is not None else loop._replace(prob=slot["prob"])
        carry, record = loop_step(flown, slot["carry"], k.astype(dtype), slot["scenario"], slot["obstacles"],
                                  slot["gains"], sim, mpc)
        ended = slot["ended"] | certainly_ended(p0, record[0][:3], k.astype(dtype) * dt, slot["scenario"], sim)
        return {**slot, "carry": carry, "k": k + 1, "ended": ended}, record

    def measure(x0: Array, record: tuple, field: Scenario) -> dict[str, Array]:
        return episode_metrics(record_trajectory(x0, record, sim), field, sim, metrics)

    return EpisodeKind(start, step, measure)


# long: the streaming program's parts are closures over its shapes (slots, ring, levels), traced as one
def stream_metrics(fields: Any, gains: Gains, sim: SimConfig, mpc: MPCConfig, slots: int,
                   metrics: Sequence[str], kind: Callable[..., EpisodeKind] = single_uav,
                   levels: Sequence[int] | None = None) -> dict[str, Array]:
    """The ``metrics`` of every (setting, field) episode, arrays (G, F), by episode streaming.

    Args:
      fields: F fields (leading axis F): :class:`~jaxapf.datatypes.Scenario` fields, or what ``kind`` flies.
      gains: G settings, every leaf with leading axis G.
      slots: episodes flown side by side (:func:`stream_slots`).
      kind: ``kind(sim, mpc, dtype, metrics)`` is the :class:`EpisodeKind` of the episodes
        (:func:`single_uav`, :func:`~jaxapf.engine.swarm.swarm_episodes`).
      levels: the vmap widths, widest (``slots``) first (default :func:`stream_levels`).
    """
    dtype = fields.start.dtype
    gains = gains.as_arrays(dtype)
    flying = kind(sim, mpc, dtype, metrics)
    n_fields = fields.start.shape[0]
    n_gains = next((leaf.shape[0] for leaf in jax.tree_util.tree_leaves(gains)), 1)  # no gain read: one setting
    total, steps = n_gains * n_fields, sim.episode.steps
    levels = stream_levels(slots) if levels is None else tuple(levels)
    moves = max(slots // 4, 1)  # finished episodes handed to the store per boundary, oldest first
    # the record ring: a finished episode waits at most ceil(slots / moves) boundaries for its move,
    # so its T records are still in the ring (R a whole number of segments)
    ring = SEGMENT * -(-(steps + SEGMENT * (2 + -(-slots // moves))) // SEGMENT)

    def episode(e: Array) -> dict[str, Any]:
        """A slot at the start of episode ``e``: its field, gains, carry and first sample."""
        return flying.start(_rows(fields, e % n_fields), _rows(gains, e // n_fields))

    def step(slot: dict[str, Any], _) -> tuple[dict[str, Any], tuple]:
        return flying.step(slot)

    def segment(width: int):
        """``SEGMENT`` steps of the first ``width`` slots; their records go to the ring."""
        def run(st: dict[str, Any]) -> dict[str, Any]:
            part, records = jax.lax.scan(jax.vmap(step), _rows(st["fly"], slice(0, width)), None, length=SEGMENT)
            fly = jax.tree_util.tree_map(lambda x, p: x.at[:width].set(p), st["fly"], part)
            return {**st, "fly": fly, "ring": _write(st["ring"], records, st["clock"] % ring, 0)}
        return run

    record = jax.eval_shape(lambda: step(episode(jnp.zeros((), jnp.int32)), None))[1]

    def records(length: int, episodes: int) -> tuple:
        """Zeroed time-major records (``length``, ``episodes``, ...) of the steps' outputs."""
        return jax.tree_util.tree_map(lambda r: jnp.zeros((length, episodes) + r.shape, r.dtype), record)

    def measure(start: Array, flown: tuple, ids: Array) -> dict[str, Array]:
        """The metrics of ``slots`` stored episodes: their first samples ``start`` (slots, ...) and
        records ``flown`` (T, slots, ...)."""
        return jax.vmap(flying.measure, in_axes=(0, 1, 0))(start, flown,
                                                            _rows(fields, jnp.clip(ids, 0, total - 1) % n_fields))

    first_sample = jax.eval_shape(lambda: episode(jnp.zeros((), jnp.int32))["x0"])
    out_shape = jax.eval_shape(measure, jnp.zeros((slots,) + first_sample.shape, dtype), records(steps, slots),
                               jnp.zeros((slots,), jnp.int32))
    first = jnp.arange(slots)
    fly = jax.vmap(episode)(jnp.minimum(first, total - 1))
    fly["id"] = jnp.where(first < total, first, -1).astype(jnp.int32)
    fly["born"] = jnp.zeros((slots,), jnp.int32)  # the clock at the episode's first step
    state = {
        "fly": fly,
        "clock": jnp.zeros((), jnp.int32),  # control steps flown by the slots so far
        "ring": records(ring, slots),
        "store": (jnp.zeros((slots + moves,) + first_sample.shape, dtype), records(steps, slots + moves)),
        "store_id": jnp.full((slots + moves,), total, jnp.int32),  # ``total``: no episode (dropped on output)
        "stored": jnp.zeros((), jnp.int32),
        "next": jnp.asarray(min(slots, total), jnp.int32),
        "out": {m: jnp.zeros((total,), r.dtype) for m, r in out_shape.items()},
    }

    def flush(st: dict[str, Any]) -> dict[str, Any]:
        """Metrics of the store's first ``slots`` episodes; the rest move up."""
        (start, flown), ids = st["store"], st["store_id"][:slots]
        values = measure(start[:slots], _columns(flown, slice(0, slots)), ids)
        out = {m: st["out"][m].at[ids].set(values[m], mode="drop") for m in st["out"]}
        rest = (start[slots:], _columns(flown, slice(slots, None)))
        store = (start.at[:moves].set(rest[0]), _write(flown, rest[1], 0, 0))
        store_id = jnp.concatenate([st["store_id"][slots:], jnp.full((slots,), total, jnp.int32)])
        return {**st, "out": out, "store": store, "store_id": store_id, "stored": jnp.maximum(st["stored"] - slots, 0)}

    def level(n: Array) -> Array:
        """Index of the narrowest level that holds ``n`` slots."""
        return jnp.sum(jnp.asarray(levels[1:]) >= n).astype(jnp.int32)

    def span(fly: dict[str, Any]) -> Array:
        """One past the last slot still flying."""
        return jnp.max(jnp.where(fly["id"] >= 0, jnp.arange(slots) + 1, 0))

    def boundary(st: dict[str, Any]) -> dict[str, Any]:
        fly = st["fly"]
        done = (fly["id"] >= 0) & (fly["ended"] | (fly["k"] >= steps))
        # the oldest finished episodes (their records leave the ring first) go to the store
        index = jnp.argsort(jnp.where(done, fly["born"], jnp.iinfo(jnp.int32).max), stable=True)[:moves]
        moved = done[index]
        n_moved = jnp.sum(moved).astype(jnp.int32)
        rows = (fly["born"][index][None, :] + jnp.arange(steps)[:, None]) % ring  # (T, moves)
        flown = jax.tree_util.tree_map(lambda r: r[rows, index[None, :]], st["ring"])
        (start, stored_records), at = st["store"], st["stored"]
        store = (_write(start[None], fly["x0"][index][None], 0, at)[0], _write(stored_records, flown, 0, at))
        store_id = jax.lax.dynamic_update_slice(st["store_id"], jnp.where(moved, fly["id"][index], total), (at,))
        st = {**st, "store": store, "store_id": store_id, "stored": at + n_moved}
        last = (st["next"] >= total) & ~jnp.any((fly["id"] >= 0) & ~done)  # nothing left to fly
        st = jax.lax.cond((st["stored"] >= slots) | (last & (st["stored"] > 0)), flush, lambda s: s, st)
        # the moved slots take the next episodes of the queue
        new = st["next"] + jnp.cumsum(moved) - 1
        fresh = jax.vmap(episode)(jnp.clip(new, 0, total - 1))
        fresh["id"] = jnp.where(new < total, new, -1).astype(jnp.int32)
        fresh["born"] = jnp.broadcast_to(st["clock"], (moves,))
        fly = _put(fly, jnp.where(moved, index, slots), fresh)
        st = {**st, "fly": fly, "next": jnp.minimum(st["next"] + n_moved, total)}
        if len(levels) == 1:  # one width: no slot ever moves to a narrower one
            return st
        # an empty queue: the slots still flying move to the front once a narrower level holds them
        active = fly["id"] >= 0
        shrink = (st["next"] >= total) & (level(jnp.sum(active)) > level(span(fly)))

        def to_front(s: dict[str, Any]) -> dict[str, Any]:
            order = jnp.argsort(~active, stable=True)
            return {**s, "fly": _rows(s["fly"], order), "ring": _columns(s["ring"], order)}
        return jax.lax.cond(shrink, to_front, lambda s: s, st)

    def body(st: dict[str, Any]) -> dict[str, Any]:
        st = jax.lax.switch(level(span(st["fly"])), [segment(w) for w in levels], st)
        return boundary({**st, "clock": st["clock"] + SEGMENT})

    state = jax.lax.while_loop(lambda st: jnp.any(st["fly"]["id"] >= 0) | (st["stored"] > 0), body, state)
    return {m: v.reshape(n_gains, n_fields) for m, v in state["out"].items()}
