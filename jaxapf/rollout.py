r"""The closed loop: APF reference → per-axis MPC → exact plant step, scanned over an episode.

The nesting follows gymnax: one episode is a ``lax.scan`` over time (:func:`rollout`); a batch
of fields is a ``vmap`` over scenarios; a population of gain settings is a ``vmap`` over
:class:`~jaxapf.config.Gains` (:func:`evaluate`). Static configuration (:class:`SimConfig`,
:class:`MPCConfig`) is compiled in; gains are traced, so a whole gain grid over many fields is
one compiled call.

Each control step ``k`` (time ``t_k = k Δt``):

1. :func:`~jaxapf.reference.apf_reference` rolls the saturated APF gradient flow N steps ahead,
   with the obstacles extrapolated at constant velocity;
2. :func:`~jaxapf.mpc.solve_axes` solves the three per-axis condensed box QPs by FISTA, warm
   started from the previous solution shifted by one step;
3. the first acceleration is applied and the plant integrates it exactly
   (:func:`~jaxapf.dynamics.step`).

Episodes run for the fixed ``SimConfig.steps``; termination (goal, collision) is applied by the
metrics' masks, not by the loop, so every episode of a batch has the same shape.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .config import Gains, MPCConfig, SimConfig
from .dynamics import step
from .metrics import episode_metrics
from .mpc import axis_problem, shift_warm_start, solve_axes
from .obstacles import Scenario
from .reference import apf_reference
from .trajectory import Trajectory

__all__ = ["rollout", "rollout_metrics", "evaluate", "episode_index", "default_chunk", "CPU_CHUNK",
           "ACCELERATOR_CHUNK", "XLA_OPTIONS"]


def rollout(scenario: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig, *, remat: bool = False
            ) -> Trajectory:
    """Simulate one episode from rest at ``scenario.start``; returns its :class:`Trajectory`.

    With ``remat`` the control step is wrapped in :func:`jax.checkpoint`: reverse-mode
    differentiation then stores only the scan carry ``(x, warm start)`` of each step and recomputes
    the step's APF reference and FISTA iterations on the way back, so the memory of a gradient
    grows with ``T·(6 + 3N)`` numbers instead of ``T·(residuals of one step)``. The forward values
    are the same either way (``jaxapf tune`` measures the trade-off, see docs/tune.md).
    """
    dtype = scenario.start.dtype
    gains = jax.tree_util.tree_map(lambda g: jnp.asarray(g, dtype), gains)
    prob = axis_problem(mpc, sim.dt, dtype)
    x0 = jnp.concatenate([scenario.start, jnp.zeros(3, dtype)])
    obstacles = scenario.obstacles.columns()  # once per episode, not once per control step

    def control_step(carry, k):
        x, warm = carry
        t = k * sim.dt
        x_ref = apf_reference(x, t, scenario.goal, obstacles, gains, sim, mpc.horizon)
        u = solve_axes(prob, x, x_ref, warm, a_max=sim.a_max, v_max=sim.v_max, iters=mpc.iters)
        a = u[:, 0]
        x_next = step(x, a, sim.dt)
        return (x_next, shift_warm_start(u)), (x_next, a)

    warm0 = jnp.zeros((3, mpc.horizon), dtype)
    ks = jnp.arange(sim.steps, dtype=dtype)
    body = jax.checkpoint(control_step, prevent_cse=False) if remat else control_step
    _, (states, controls) = jax.lax.scan(body, (x0, warm0), ks)
    states = jnp.concatenate([x0[None], states], axis=0)
    return Trajectory(
        time=jnp.arange(sim.steps + 1, dtype=dtype) * sim.dt,
        position=states[:, :3],
        velocity=states[:, 3:],
        control=controls,
    )


def rollout_metrics(scenario: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig) -> dict[str, Array]:
    """Per-episode metrics (SPEC 6) of one episode; the trajectory is not kept."""
    return episode_metrics(rollout(scenario, gains, sim, mpc), scenario, sim)


#: Episodes vmapped together per chunk on CPU: wide enough that every step's kernels run over
#: long contiguous rows (``jaxapf bench --chunk`` measures other widths).
CPU_CHUNK = 1024
#: Episodes per chunk on accelerators, where wide batches pay.
ACCELERATOR_CHUNK = 4096


#: XLA options of every compiled closed loop (CPU only; other backends ignore them):
#:
#: * ``xla_cpu_experimental_ynn_fusion_type = ""``: jaxlib 0.10 hands reductions and small matrix
#:   products on CPU to YNNPACK kernels, which run the APF's sums over obstacles and xyz several
#:   times slower than XLA's own fused loops (``jaxapf bench``: the engine took about twice as long);
#:   the empty list switches YNNPACK fusions off.
#: * ``xla_cpu_use_fusion_emitters = False``: XLA's classic loop emitter instead of the newer
#:   fusion emitters. On a lone elementwise kernel the fusion emitters are the faster ones
#:   (``jaxapf bench --kernels``), but the closed loop's kernels are large fusions of the APF's
#:   forward and backward pass over ``(fields, obstacles)``, which the fusion emitters compile
#:   into slower code: the whole closed loop runs about 1.1-1.2x faster with the classic one
#:   (``jaxapf bench --xla-option xla_cpu_use_fusion_emitters=true`` compiles one lowering both
#:   ways and times them interleaved; README, "Speed").
#: * ``xla_cpu_copy_insertion_use_region_analysis = True``: XLA's copy insertion analyses the
#:   loops' regions, so FISTA's ``lax.scan`` keeps one copy of its carry per iteration instead of
#:   three; the same arithmetic, about 1.07x faster (median of five ``jaxapf bench --xla-option``
#:   runs, README "Speed").
XLA_OPTIONS = {
    "xla_cpu_experimental_ynn_fusion_type": "",
    "xla_cpu_use_fusion_emitters": False,
    "xla_cpu_copy_insertion_use_region_analysis": True,
}


def default_chunk(episodes: int | None = None) -> int:
    """Episodes per vmapped chunk for the default backend; for a batch of fewer ``episodes``, the
    smallest power of two that holds them (so a small batch is not padded to a wide chunk)."""
    width = CPU_CHUNK if jax.default_backend() == "cpu" else ACCELERATOR_CHUNK
    return width if episodes is None else min(width, 1 << (max(episodes, 1) - 1).bit_length())


def episode_index(total: int, chunk: int) -> np.ndarray:
    """Episodes ``0 … total-1`` of a (setting, field) grid (episode ``e = g·F + f``: setting
    ``e // F``, field ``e % F``), padded with episode 0 to a whole number of ``chunk``-wide batches;
    callers drop the padding."""
    index = np.zeros(-(-total // chunk) * chunk, np.int64)
    index[:total] = np.arange(total)
    return index


@partial(jax.jit, static_argnames=("sim", "mpc", "chunk"), compiler_options=XLA_OPTIONS)
def evaluate(
    scenarios: Scenario, gains: Gains, sim: SimConfig, mpc: MPCConfig, chunk: int | None = None
) -> dict[str, Array]:
    """Metrics of every (gain setting, field) pair: arrays of shape (G, F).

    The G·F episodes form one flat batch, padded to a multiple of ``chunk`` and run as a
    ``lax.map`` over chunks of ``chunk`` vmapped episodes (``None``: :func:`default_chunk`). Every
    episode is therefore computed by the same kernels at the same batch width whatever G and F
    are, so an episode's numbers do not depend on the batch it was run in.

    Args:
      scenarios: a batch of F fields (leading axis F on every leaf).
      gains: a batch of G gain settings (leading axis G on every leaf).
      chunk: episodes per vmapped chunk (static).
    """
    n_gains = jax.tree_util.tree_leaves(gains)[0].shape[0]
    n_fields = scenarios.start.shape[0]
    total = n_gains * n_fields
    chunk = min(default_chunk() if chunk is None else chunk, total)
    index = episode_index(total, chunk)
    padded = index.shape[0]
    flat = (
        jax.tree_util.tree_map(lambda x: x[index % n_fields], scenarios),
        jax.tree_util.tree_map(lambda x: jnp.asarray(x)[index // n_fields], gains),
    )
    chunks = jax.tree_util.tree_map(lambda x: x.reshape((padded // chunk, chunk) + x.shape[1:]), flat)
    episodes = jax.vmap(lambda s, g: rollout_metrics(s, g, sim, mpc))
    metrics = jax.lax.map(lambda c: episodes(*c), chunks)
    return jax.tree_util.tree_map(lambda m: m.reshape((padded,) + m.shape[2:])[:total].reshape(
        (n_gains, n_fields) + m.shape[2:]), metrics)
