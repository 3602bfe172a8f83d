"""Running a sweep's chunks as Ray tasks: ``jaxapf sweep SPEC --ray [ADDRESS]``.

This process (Ray's driver) plans the sweep, holds the output's lock and is its one writer; each
chunk runs as one Ray task on a worker with one JAX device and returns its metrics, and the driver
writes the part as it arrives. Ray balances the load (a task goes to whichever worker is free) and
reruns the task of a worker process or node that died (``retries``); a part once written is never
recomputed, and a rerun of the command resumes like any sweep. The chunks are those of the
one-device plan for the workers' backend, so the rows equal a one-process run's on one device of
that kind, bit for bit. docs/sweep.md ("On a Ray cluster") says how to start a cluster.
"""

from __future__ import annotations

import dataclasses
import time
import uuid
from typing import Any, Iterator

from ..validation import ConfigError, check_int, check_range, first_line
from .plan import Chunk, Plan

__all__ = ["RayCluster", "RaySession"]

#: How often the driver rereads the cluster's size to keep this many tasks per slot in flight.
IN_FLIGHT_PER_SLOT = 2
RESIZE_EVERY_S = 5.0


@dataclasses.dataclass(frozen=True)
class RayCluster:
    """Where and how the chunks run.

    Attributes:
      address: a Ray cluster's address (``HOST:PORT``, ``auto`` for the one started on this machine
        with ``ray start --head``, ``ray://…`` for Ray Client); ``None``: ``RAY_ADDRESS`` if set, else
        a Ray instance started here for this run and stopped after it.
      cpus, gpus: Ray resources of one chunk's task (a GPU worker: ``gpus = 1``; on CPU nodes, cores
        per task: XLA spreads one device's kernels over the cores it may use).
      retries: how often a task whose worker or node died is run again before the run stops.
    """

    address: str | None = None
    cpus: float = 1.0
    gpus: float = 0.0
    retries: int = 3

    def __post_init__(self):
        check_range("--ray-cpus", self.cpus, 0.0)
        check_range("--ray-gpus", self.gpus, 0.0)
        check_int("retries", self.retries, 0)
        if self.cpus == 0 and self.gpus == 0:
            raise ConfigError("--ray-cpus and --ray-gpus are both 0: a task needs some resource")

    def check(self, shard: tuple[int, int] | None, devices: int | None) -> None:
        """Refuse the options a Ray run cannot take (a run and its ``--dry-run`` alike)."""
        if shard is not None:
            raise ConfigError("--ray and --shard: Ray deals the chunks itself; give one of them")
        if devices not in (None, 1):
            raise ConfigError(f"--devices = {devices}: with --ray each task runs on one device; ask Ray for more "
                              "workers instead")


def _ray():
    try:
        import ray
    except ImportError:
        raise ConfigError("--ray needs Ray: pip install 'jaxapf[ray]'") from None
    return ray


# -- on the workers ------------------------------------------------------------------------------

#: The worker's runner of the current run: {run token: :class:`jaxapf.sweep.execute.ChunkRunner`}.
_RUNNER: dict[str, Any] = {}


def _configure(settings: dict[str, Any]) -> None:
    """The driver's JAX settings and plugins, in a worker (cheap to repeat). A task that asks for no GPU
    keeps JAX on the CPU (Ray shows such a task every GPU of its node)."""
    import jax

    from ..io.plugins import load_plugin
    from .execute import configure_jax

    if settings["cpu_only"]:
        try:
            jax.config.update("jax_platforms", "cpu")
        except RuntimeError:  # JAX already started in this worker
            pass
    try:
        configure_jax(cache_dir=settings["cache_dir"], cpu_devices=1)
    except OSError:  # the driver's cache folder cannot be made on this node: compile without it
        configure_jax(cpu_devices=1)
    jax.config.update("jax_enable_x64", settings["x64"])  # both ways: a worker may serve runs of either
    for name, path in settings["plugins"]:
        load_plugin(name, "plugin", path)


def _probe(settings: dict[str, Any]) -> dict[str, Any]:
    """The JAX backend a chunk's task runs on, and the versions its parts record."""
    import jax

    from ..io.versions import versions

    _configure(settings)
    return {"backend": jax.default_backend(), "versions": versions()}


def _run_chunk(settings: dict[str, Any], token: str, boxed_plan: list, chunk: Chunk) -> tuple:
    """One chunk on this worker's device: ``(chunk, metrics, kinds, solvable)`` as NumPy arrays. The
    runner (compiled programs, gains on the device, oracle answers) is kept for the run's next chunks.
    A worker whose backend is not the plan's refuses (its rows would not be the plan's)."""
    import jax
    import numpy as np

    from .execute import ChunkRunner

    _configure(settings)
    if jax.default_backend() != settings["backend"]:
        raise ConfigError(f"a worker runs JAX on {jax.default_backend()}, the plan on {settings['backend']}: give "
                          "--ray-gpus so that every task lands on the same kind of device")
    if token not in _RUNNER:  # a new run: the last one's device buffers go
        for runner in _RUNNER.values():
            runner.close()
        _RUNNER.clear()
        _RUNNER[token] = ChunkRunner(_ray().get(boxed_plan[0]))
    metrics, kinds, solvable = _RUNNER[token].dispatch(chunk)
    return chunk, {m: np.asarray(a) for m, a in metrics.items()}, np.asarray(kinds), solvable


# -- on the driver -------------------------------------------------------------------------------

class RaySession:
    """A connection to a Ray cluster for one run (a context manager: a Ray instance it started is
    stopped on exit)."""

    def __init__(self, cluster: RayCluster):
        import jax

        from ..io.plugins import LOADED

        self.cluster = cluster
        ray = self.ray = _ray()
        self.started = False
        self.settings = {"x64": bool(jax.config.jax_enable_x64), "cache_dir": jax.config.jax_compilation_cache_dir,
                         "plugins": list(LOADED), "cpu_only": cluster.gpus == 0}
        options = {"num_cpus": cluster.cpus, "num_gpus": cluster.gpus, "max_retries": cluster.retries}
        try:  # checked before anything starts
            self._probe = ray.remote(**options)(_probe)
            self._chunk = ray.remote(**options)(_run_chunk)
        except ValueError as err:
            raise ConfigError(f"--ray-cpus/--ray-gpus: {first_line(err)}") from None
        if ray.is_initialized():  # this process is a driver already (a notebook, a test)
            here = ray.get_runtime_context().gcs_address
            if cluster.address not in (None, "auto", here):
                _check_reachable(cluster.address)
                raise ConfigError(f"--ray {cluster.address}: this process is connected to the Ray cluster at {here}")
            return
        self._connect()

    def _connect(self) -> None:
        import logging
        import os
        import signal

        ray, cluster = self.ray, self.cluster
        local = cluster.address is None and not os.environ.get("RAY_ADDRESS")
        _check_reachable(cluster.address or os.environ.get("RAY_ADDRESS"))
        sigterm = signal.getsignal(signal.SIGTERM)
        try:
            ray.init(address=cluster.address, logging_level=logging.ERROR, log_to_driver=True,
                     **({"include_dashboard": False} if local else {}))
        except KeyboardInterrupt:
            raise
        except Exception as err:  # noqa: BLE001 - Ray raises many kinds here; each is one line for the user
            raise ConfigError(f"--ray {cluster.address or ''}: cannot start or reach a Ray cluster ("
                              f"{first_line(err)})".replace("--ray :", "--ray:")) from None
        finally:  # Ray's own SIGTERM handler exits without a word; the CLI's says what was kept
            if sigterm is not None:
                signal.signal(signal.SIGTERM, sigterm)
        self.started = local

    def __enter__(self) -> "RaySession":
        return self

    def __exit__(self, *exc) -> None:
        if self.started:
            self.ray.shutdown()

    def probe(self) -> dict[str, Any]:
        """The workers' JAX backend and versions (a task with the chunks' resources reports them);
        refused in one line when no node could ever run such a task (Ray would wait for ever)."""
        ray, need = self.ray, {"CPU": self.cluster.cpus, "GPU": self.cluster.gpus}
        nodes = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive")]
        if not any(all(r.get(k, 0.0) >= v for k, v in need.items()) for r in nodes):
            raise ConfigError(f"--ray: no node of the cluster has {need['CPU']:g} CPU(s) and {need['GPU']:g} GPU(s) "
                              "for one task; give --ray-cpus and --ray-gpus that a node has")
        try:
            found = ray.get(self._probe.remote(self.settings))
        except ray.exceptions.RayError as err:
            raise ConfigError(f"--ray: a worker could not start JAX ({_reason(err)})") from None
        self.settings["backend"] = found["backend"]
        return found

    def _slots(self) -> int:
        """Tasks the cluster can run at once with each task's resources (at least one)."""
        total = self.ray.cluster_resources()
        fits = [total.get(k, 0.0) / need for k, need in (("CPU", self.cluster.cpus), ("GPU", self.cluster.gpus))
                if need > 0]
        return max(1, int(min(fits)))

    def results(self, plan: Plan, chunks: tuple[Chunk, ...]) -> Iterator[tuple]:
        """Run ``chunks`` as Ray tasks, yielding each as it finishes (any order). A few tasks per slot
        are in flight, so a worker never waits and a cluster that grows is used. A task that fails for
        good raises :class:`~jaxapf.sweep.execute.ChunkFailed`; on exit the tasks still running are cancelled."""
        from .execute import ChunkFailed

        if "backend" not in self.settings:
            self.probe()
        ray = self.ray
        slim = dataclasses.replace(plan, chunks=(), done=())  # what a worker needs: shapes, variants, spec
        boxed = [ray.put(slim)]  # inside a list, so a worker fetches it only when its runner is new
        token = uuid.uuid4().hex
        queue, running = list(reversed(chunks)), {}
        limit, resized = IN_FLIGHT_PER_SLOT * self._slots(), time.monotonic()
        try:
            while queue or running:
                while queue and len(running) < limit:
                    chunk = queue.pop()
                    running[self._chunk.remote(self.settings, token, boxed, chunk)] = chunk
                ready, _ = ray.wait(list(running), num_returns=1)
                chunk = running.pop(ready[0])
                try:
                    finished = ray.get(ready[0])
                except ray.exceptions.RayError as err:
                    raise ChunkFailed(f"chunk {chunk.name} failed on the Ray cluster ({_reason(err)})") from None
                yield finished
                if time.monotonic() - resized > RESIZE_EVERY_S:
                    limit, resized = IN_FLIGHT_PER_SLOT * self._slots(), time.monotonic()
        finally:
            for ref in running:
                ray.cancel(ref, force=True)


def _check_reachable(address: str | None, timeout_s: float = 10.0) -> None:
    """Refuse in one line a ``HOST:PORT`` nothing answers at (Ray itself retries for minutes)."""
    import socket

    host, sep, port = (address or "").rpartition(":")
    if not sep or "://" in address or not port.isdigit():
        return  # auto, ray://, or Ray's own error
    try:
        socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout_s).close()
    except OSError as err:
        raise ConfigError(f"--ray {address}: nothing answers there ({err.strerror or first_line(err)}); start a "
                          "cluster with `ray start --head` and give the address it prints") from None


def _reason(err: Exception) -> str:
    """The first line of a Ray error that says what happened (a task's own exception, or a dead worker)."""
    cause = getattr(err, "cause", None)
    return first_line(cause) if cause is not None else first_line(err)
