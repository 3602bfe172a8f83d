"""Batches of episodes: every (gain setting, field) pair of a grid in one compiled call (:func:`evaluate`),
streamed (:mod:`jaxapf.engine.stream`) or in fixed-length vmapped batches, the vmap widths and the
XLA options every compiled closed loop uses.

The nesting follows gymnax: one episode is a ``lax.scan`` over time (:func:`~jaxapf.engine.loop.rollout`);
a batch of fields is a ``vmap`` over scenarios; a population of gain settings is a ``vmap`` over
:class:`~jaxapf.gains.Gains`. Static configuration is compiled in; gains are traced, so a whole gain
grid over many fields is one compiled call.
"""

from __future__ import annotations

import functools
from functools import partial
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..config import MPCConfig, SimConfig
from ..datatypes import Scenario
from ..gains import Gains, setting_count, setting_shape
from ..metrics import METRICS
from .components import gains_read
from .loop import rollout_metrics
from .stream import stream_metrics, stream_slots

__all__ = ["evaluate", "evaluate_program", "episode_index", "default_width", "CPU_WIDTH", "ACCELERATOR_WIDTH",
           "XLA_OPTIONS", "MAX_PROGRAMS", "program", "settings_read", "fixed_batches"]


#: Episodes vmapped together (the vmap width) on CPU: wide enough that every step's kernels run
#: over long contiguous rows (``jaxapf bench engine --width`` measures other widths).
CPU_WIDTH = 1024
#: Episodes vmapped together on accelerators, where wide batches pay.
ACCELERATOR_WIDTH = 4096


#: XLA options of every compiled closed loop on CPU (:func:`program` gives them to the CPU compiler
#: only: a GPU's compiler refuses options it does not know):
#:
#: * ``xla_cpu_experimental_ynn_fusion_type = ""``: jaxlib 0.10 hands reductions and small matrix
#:   products on CPU to YNNPACK kernels, which run the APF's sums over obstacles and xyz slower
#:   than XLA's own fused loops; the empty list switches YNNPACK fusions off.
#: * ``xla_cpu_use_fusion_emitters = False``: XLA's classic loop emitter instead of the newer
#:   fusion emitters. On a lone elementwise kernel the fusion emitters are the faster ones
#:   (``benchmarks/kernels.py``), but the closed loop's kernels are large fusions of the APF's
#:   forward and backward pass over ``(fields, obstacles)``, which the fusion emitters compile
#:   into slower code (``benchmarks/xla_options.py`` times one lowering both ways; the figures are
#:   in docs/performance.md).
#: * ``xla_cpu_copy_insertion_use_region_analysis = True``: XLA's copy insertion analyses the
#:   loops' regions, so FISTA's ``lax.scan`` keeps one copy of its carry per iteration instead of
#:   three: the same arithmetic, faster (docs/performance.md).
XLA_OPTIONS = {
    "xla_cpu_experimental_ynn_fusion_type": "",
    "xla_cpu_use_fusion_emitters": False,
    "xla_cpu_copy_insertion_use_region_analysis": True,
}


#: Closed-loop programs one process keeps compiled, over every :func:`program`; a call that would pass it
#: empties their caches first (a program called again compiles again, from the persistent compilation cache
#: where it is on). On CPU a program holds about 480 memory maps (three per kernel) and Linux allows a process
#: 65,530 (``vm.max_map_count``): a long study compiling over a hundred programs died in LLVM ("Cannot allocate
#: memory") before this bound.
MAX_PROGRAMS = 64
_JITTED: list = []  # every program's jitted functions, whose compiled programs MAX_PROGRAMS bounds


def program(fun: Callable | None = None, *, static_argnames: str | Sequence[str] = ()) -> Callable:
    """``jax.jit`` of a closed-loop program, compiled with :data:`XLA_OPTIONS` when JAX's default backend is
    the CPU and without them elsewhere (decided at each call; ``.lower`` follows), at most
    :data:`MAX_PROGRAMS` of them kept compiled. ``.compiled()``: how many programs its calls have compiled."""
    if fun is None:
        return partial(program, static_argnames=static_argnames)
    on_cpu = jax.jit(fun, static_argnames=static_argnames, compiler_options=XLA_OPTIONS)
    elsewhere = jax.jit(fun, static_argnames=static_argnames)
    _JITTED.extend((on_cpu, elsewhere))
    pick = lambda: on_cpu if jax.default_backend() == "cpu" else elsewhere  # noqa: E731
    compiled = [0]

    @functools.wraps(fun)
    def call(*args: Any, **kwargs: Any) -> Any:
        jitted = pick()
        if sum(j._cache_size() for j in _JITTED) >= MAX_PROGRAMS:
            for j in _JITTED:
                j.clear_cache()
        before = jitted._cache_size()
        out = jitted(*args, **kwargs)
        compiled[0] += jitted._cache_size() - before
        return out
    call.lower = lambda *args, **kwargs: pick().lower(*args, **kwargs)
    call.compiled = lambda: compiled[0]
    return call


def settings_read(gains: Gains, sim: SimConfig) -> tuple[int, Gains]:
    """``(G, gains)``: the G settings of a batch of ``gains`` (the leading axis of its array leaves, 1 if
    none has one), only the gains ``sim``'s components read, each leaf with the leading axis G."""
    n_gains = max((setting_shape(k, x)[0] for k, x in gains.items() if setting_shape(k, x)), default=1)
    read = gains.only(gains_read(sim))
    return n_gains, Gains.unchecked({k: x if setting_shape(k, x) else jnp.full((n_gains,) + jnp.shape(x), x)
                                     for k, x in read.items()})


def default_width(episodes: int | None = None, backend: str | None = None, widest: int | None = None) -> int:
    """The vmap width for ``backend`` (default: this process's default backend), or ``widest`` (a sweep
    policy's, :class:`~jaxapf.engine.policy.Policy`); for a batch of fewer ``episodes``, the smallest power
    of two that holds them (so a small batch is not padded to a wide batch)."""
    width = widest or (CPU_WIDTH if (backend or jax.default_backend()) == "cpu" else ACCELERATOR_WIDTH)
    return width if episodes is None else min(width, 1 << (max(episodes, 1) - 1).bit_length())


def episode_index(total: int, width: int) -> np.ndarray:
    """Episodes ``0 … total-1`` of a (setting, field) grid (episode ``e = g·F + f``: setting
    ``e // F``, field ``e % F``), padded with episode 0 to a whole number of ``width``-wide batches;
    callers drop the padding."""
    index = np.zeros(-(-total // width) * width, np.int64)
    index[:total] = np.arange(total)
    return index


@program(static_argnames=("sim", "mpc", "width", "metrics", "streaming", "refill"))
def evaluate_program(scenarios: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig, width: int,
                     metrics: tuple[str, ...], streaming: bool = True, refill: bool = True) -> dict[str, Array]:
    """The compiled program behind :func:`evaluate`, every static argument explicit (for
    ``evaluate_program.lower(...)``); ``refill``: the streaming engine's slots
    (:func:`~jaxapf.engine.stream.stream_slots`, a :class:`~jaxapf.engine.policy.Policy`'s)."""
    # both engines fly the gains the setting's components declare, nothing else (also when called directly)
    n_gains, gains = settings_read(gains, sim)
    if streaming:
        slots = stream_slots(n_gains * scenarios.start.shape[0], width, refill)
        return stream_metrics(scenarios, gains, sim, mpc, slots, metrics)
    return fixed_batches(lambda s, g: rollout_metrics(s, g, sim, mpc, metrics), scenarios, gains, n_gains, width)


def fixed_batches(episode: Callable[[Any, Gains], dict[str, Array]], fields: Any, gains: Gains, n_gains: int,
                  width: int) -> dict[str, Array]:
    """The fixed-length engine: ``episode(field, setting)`` (a dict of metrics) of every (setting, field)
    pair of a grid, the G·F episodes ``e = g·F + f`` padded to whole batches of ``width`` and run as a
    ``lax.map`` over vmapped batches; arrays (G, F, ...). ``fields``: F on the leading axis of every
    leaf; ``gains``: G on every leaf (:func:`settings_read`)."""
    n_fields = jax.tree_util.tree_leaves(fields)[0].shape[0]
    total = n_gains * n_fields
    width = min(width, total)
    index = episode_index(total, width)
    padded = index.shape[0]
    flat = (
        jax.tree_util.tree_map(lambda x: x[index % n_fields], fields),
        jax.tree_util.tree_map(lambda x: jnp.asarray(x)[index // n_fields], gains),
    )
    batches = jax.tree_util.tree_map(lambda x: x.reshape((padded // width, width) + x.shape[1:]), flat)
    values = jax.lax.map(lambda c: jax.vmap(episode)(*c), batches)
    return jax.tree_util.tree_map(lambda m: m.reshape((padded,) + m.shape[2:])[:total].reshape(
        (n_gains, n_fields) + m.shape[2:]), values)


def evaluate(scenarios: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig, width: int | None = None,
             metrics: Sequence[str] | None = None, *, streaming: bool = True) -> dict[str, Array]:
    """Metrics of every (gain setting, field) pair: arrays of shape (G, F), in one compiled call.

    The G·F episodes ``e = g·F + f`` form one queue. By default they are streamed
    (:mod:`jaxapf.engine.stream`): a few hundred slots fly them side by side and each slot takes the next
    episode when its own ends, so no step is simulated after an episode is over. With
    ``streaming=False`` (the fixed-length engine) the queue is padded to a multiple of ``width``
    and run as a ``lax.map`` over batches of ``width`` vmapped episodes of ``T`` steps each. Both
    give the same numbers, and neither depends on G, F or the batch an episode ran in.

    Args:
      scenarios: a batch of F fields (leading axis F on every leaf).
      gains: a batch of G gain settings (leading axis G on every array leaf; a scalar leaf, e.g. a
        gain left at its default, is shared by all G settings): ``Gains(gamma=[...], k=[...])`` or
        :meth:`~jaxapf.gains.Gains.paired` pairs the lists, :meth:`~jaxapf.gains.Gains.grid` takes
        every combination. Lists of different lengths raise :class:`~jaxapf.validation.ConfigError`.
      width: the vmap width (static; ``None``: :func:`default_width`); the streaming engine flies
        at most this many episodes side by side.
      metrics: the metrics to compute (default: every registered one, :data:`~jaxapf.metrics.METRICS`).
      streaming: stop each episode when it ends (default) instead of flying all ``T`` steps.
    """
    count = setting_count(gains, "evaluate: gains")  # one line for lists of different lengths, which would not pair
    names = METRICS.names() if metrics is None else tuple(metrics)
    # only the gains the setting's components read enter the program (it would fly no others); if none
    # of them varies, the G settings fly the same episodes, so one is flown and its rows stand for all G
    # (a list of a gain no component reads still counts its settings)
    read = gains.only(gains_read(sim))
    out = evaluate_program(scenarios, read, sim, mpc, default_width() if width is None else width, names, streaming)
    if count > 1 and not any(setting_shape(k, x) for k, x in read.items()):
        out = {m: jnp.broadcast_to(v, (count,) + v.shape[1:]) for m, v in out.items()}
    return out
