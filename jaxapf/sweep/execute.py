"""Where a sweep's chunks run: a runner of chunks on this process's devices, and what every place that
runs chunks yields (:func:`local_results` here; a Ray cluster's workers in :mod:`jaxapf.sweep.cluster`)."""

from __future__ import annotations

from typing import Any, Iterator, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from ..engine.devices import DeviceBatch
from ..gains import Gains
from .plan import Chunk, Plan, Variant

__all__ = ["ChunkRunner", "ChunkFailed", "Finished", "local_results"]


class ChunkRunner:
    """Runs the chunks of a plan on this process's devices (:class:`~jaxapf.engine.devices.DeviceBatch`),
    keeping the gains it put on them and the oracle's answers for the plan's next chunks."""

    def __init__(self, plan: Plan):
        self.batch = DeviceBatch(jax.local_devices()[: plan.devices])
        self.plan = plan
        self._gains: dict[int, list[Gains]] = {}
        self._oracle: dict[tuple, np.ndarray] = {}

    def close(self) -> None:
        self.batch.close()

    def _variant_gains(self, variant: Variant) -> list[Gains]:
        if variant.index not in self._gains:
            self._gains[variant.index] = self.batch.put_gains(self.plan.gains(variant))
        return self._gains[variant.index]

    def dispatch(self, chunk: Chunk) -> tuple[dict[str, jax.Array], jax.Array, np.ndarray | None]:
        """Start the chunk (asynchronously); returns global (G, padded) metric arrays, the fields'
        kinds and, with the spec's ``oracle``, whether each real field is solvable (computed on the
        host while the devices run)."""
        from ..engine import evaluate_program
        from ..engine.swarm import evaluate_swarms
        from ..scenarios import make_scenarios
        from ..scenarios.swarms import make_swarms

        plan = self.plan
        block = plan.blocks[(chunk.variant, chunk.family)]
        indices = np.full(block.padded, chunk.start, np.int64)
        indices[: chunk.stop - chunk.start] = np.arange(chunk.start, chunk.stop)
        make, program = (make_swarms, evaluate_swarms) if plan.spec.swarm else (make_scenarios, evaluate_program)
        fields = make(plan.spec.seed, plan.spec.family_params(chunk.family), jnp.asarray(indices))
        gains = self._variant_gains(plan.variants[chunk.variant])
        metrics = self.batch.evaluate(plan.flown(fields), gains, block.flown, block.mpc, block.width, plan.metrics,
                                      program, refill=plan.policy.refill)
        return metrics, fields.kind, self._solvable(chunk, fields, block.sim) if plan.spec.oracle else None

    def _solvable(self, chunk: Chunk, fields: Any, sim: Any) -> np.ndarray:
        """:func:`~jaxapf.scenarios.solvable` of the chunk's real fields, once per field and vehicle
        (variants that differ only in method or gains share the answer; with the plan's ``answers`` folder,
        runs that fly the same fields too: :mod:`jaxapf.scenarios.answers`); of a swarm field, whether every
        UAV passes it alone (:func:`~jaxapf.scenarios.swarms.agents_solvable`)."""
        from ..scenarios import solvable
        from ..scenarios.answers import remembered
        from ..scenarios.swarms import agents_solvable

        oracle = (lambda real, **v: agents_solvable(real, **v).all(axis=-1)) if self.plan.spec.swarm else solvable
        vehicle = dict(r_uav=sim.vehicle.r_uav, v_max=sim.vehicle.v_max, t_max=sim.episode.t_max,
                       r_goal=sim.episode.r_goal)
        key = (chunk.family, chunk.start, chunk.stop, *vehicle.values())
        if key not in self._oracle:
            n = chunk.stop - chunk.start
            real = jax.tree_util.tree_map(lambda a: np.asarray(a)[:n], fields)
            arrays = {name: leaf for name, leaf in ((jax.tree_util.keystr(path), leaf) for path, leaf in
                                                    jax.tree_util.tree_flatten_with_path(real)[0])
                      if name not in (".kind", ".key")}  # the geometry, not the field's name
            question = vehicle | {"swarm": self.plan.spec.swarm}
            self._oracle[key] = remembered(self.plan.answers, arrays, question, (n,), lambda: oracle(real, **vehicle))
        return self._oracle[key]


class ChunkFailed(Exception):
    """A chunk could not be run (e.g. on a Ray worker, for good); the message says which and why."""


#: What a chunk's run yields: the chunk, its (G, padded) metric arrays, the fields' kinds and, with the
#: spec's ``oracle``, whether each real field is solvable.
Finished = tuple[Chunk, Mapping[str, Any], Any, "np.ndarray | None"]


#: How often the main thread looks whether a chunk it waits for has compiled or finished [s]: between
#: looks Python runs its signal handlers, so Ctrl-C and SIGTERM stop a run within this, not after the chunk.
WAIT_POLL_S = 0.05


def _interruptible(future: Any) -> Any:
    """``future``'s result, waited for in short steps (a wait inside XLA would hold off Ctrl-C)."""
    import concurrent.futures

    while True:
        try:
            return future.result(timeout=WAIT_POLL_S)
        except concurrent.futures.TimeoutError:
            continue


def _until_ready(arrays: Any) -> None:
    """Return once every JAX array of ``arrays`` is computed, looking every :data:`WAIT_POLL_S`."""
    import time

    pending = [a for a in jax.tree_util.tree_leaves(arrays) if isinstance(a, jax.Array)]
    while not all(a.is_ready() for a in pending):
        time.sleep(WAIT_POLL_S)


def local_results(plan: Plan, chunks: tuple[Chunk, ...]) -> Iterator[Finished]:
    """Run ``chunks`` on this process's devices, yielding each as it finishes; the next chunk is
    dispatched before the previous one is yielded, so it runs while that one is written. Dispatching
    (which compiles a program the first time) runs on a helper thread and every wait is in short steps,
    so a signal stops the run at once, not after the chunk (:data:`WAIT_POLL_S`)."""
    import concurrent.futures

    runner = ChunkRunner(plan)
    helper = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="jaxapf-dispatch")
    try:
        pending = None
        for chunk in (*chunks, None):
            running = None if chunk is None else (chunk, *_interruptible(helper.submit(runner.dispatch, chunk)))
            if pending is not None:
                _until_ready(pending[1])
                yield pending
            pending = running
    finally:
        helper.shutdown(wait=False, cancel_futures=True)  # a compilation under way is left to the process's end
        runner.close()
