"""The batch axis of fields laid out over local devices, each running the single-device engine.

A batch of F fields is placed with a ``jax.make_mesh`` mesh over the devices and
``NamedSharding(mesh, P("batch"))``; each device runs the single-device
:func:`jaxapf.engine.evaluate` program on its block of F / D fields, dispatched from a thread per
device so the devices run concurrently, and the per-device ``(G, F/D)`` metrics are assembled
into global ``(G, F)`` arrays with ``jax.make_array_from_single_device_arrays``. Not
``shard_map``: on XLA:CPU the SPMD-partitioned executable rounds differently from the
single-device one (last-bit differences in a few percent of episodes, docs/sweep.md), and
``jaxapf sweep`` promises the same numbers on any number of devices. Used by ``jaxapf sweep`` and
``jaxapf bench engine --devices``.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Callable, Sequence

import jax
from jax.sharding import NamedSharding, PartitionSpec

from ..config import MPCConfig, SimConfig
from ..datatypes import Scenario
from ..datatypes.swarm import Swarm
from ..gains import Gains
from .batch import evaluate_program

__all__ = ["DeviceBatch"]


class DeviceBatch:
    """Runs :func:`~jaxapf.engine.evaluate` with the fields split over ``devices``.

    The field count must be a multiple of ``len(devices)`` (callers pad). Close it (or use it as a
    context manager) to stop its threads.
    """

    def __init__(self, devices: Sequence[jax.Device]):
        self.devices = list(devices)
        mesh = jax.make_mesh((len(self.devices),), ("batch",), devices=self.devices,
                             axis_types=(jax.sharding.AxisType.Auto,))
        self.fields = NamedSharding(mesh, PartitionSpec("batch"))
        self.sharding = NamedSharding(mesh, PartitionSpec(None, "batch"))
        self.pool = ThreadPoolExecutor(len(self.devices), thread_name_prefix="jaxapf-device")

    def __enter__(self) -> "DeviceBatch":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop the threads; one still running a program (a stopped run) is left to the process's end."""
        self.pool.shutdown(wait=False, cancel_futures=True)

    def put_gains(self, gains: Gains) -> list[Gains]:
        """One copy of a gain batch on every device (reuse it across calls)."""
        return [jax.device_put(gains, d) for d in self.devices]

    def evaluate(self, scenarios: Scenario | Swarm, gains: Sequence[Gains], sim: SimConfig, mpc: MPCConfig,
                 width: int, metrics: tuple[str, ...], program: Callable = evaluate_program,
                 refill: bool = True) -> dict[str, jax.Array]:
        """The ``metrics``, each as a global ``(G, F)`` array sharded over the devices; returns once all
        devices have been dispatched (block on the result to wait for them). ``program``: the compiled
        program each device runs, ``program(fields, gains, sim, mpc, width, metrics)``
        (:func:`~jaxapf.engine.evaluate_program`, or :func:`~jaxapf.engine.swarm.evaluate_swarms` for
        a batch of :class:`~jaxapf.datatypes.swarm.Swarm` fields); ``refill``: its streaming slots
        (:func:`~jaxapf.engine.stream.stream_slots`). A planner that may not run on several
        CPU devices at once (:attr:`~jaxapf.planners.Planner.concurrent_cpu_devices`) has its blocks run
        one after another, each waited for."""

        from .components import component

        placed = jax.device_put(scenarios, self.fields)
        shards = [jax.tree_util.tree_map(lambda x, i=i: _shard(x, i), placed) for i in range(len(self.devices))]
        run = partial(self.pool.submit, program, sim=sim, mpc=mpc, width=width, metrics=metrics, refill=refill)
        if component("method", sim.planner.method).concurrent_cpu_devices or self.devices[0].platform != "cpu":
            futures = [run(s, g) for s, g in zip(shards, gains)]
            outs = [f.result() for f in futures]
        else:  # one block after another (Planner.concurrent_cpu_devices)
            outs = [jax.block_until_ready(run(s, g).result()) for s, g in zip(shards, gains)]
        settings = outs[0][metrics[0]].shape[0]
        fields = scenarios.start.shape[0]
        return {m: jax.make_array_from_single_device_arrays((settings, fields), self.sharding, [o[m] for o in outs])
                for m in metrics}


def _shard(x: jax.Array, i: int) -> jax.Array:
    """The ``i``-th block of ``x``'s leading axis, on its device."""
    return sorted(x.addressable_shards, key=lambda s: s.index[0].start or 0)[i].data
