"""Running a sweep's chunks on a Ray cluster: ``jaxapf sweep SPEC --ray [ADDRESS]``.

This process (Ray's driver) plans the sweep, holds the output's lock and is its one writer. Each slot
of the cluster (a node's share of ``--ray-cpus`` CPUs and ``--ray-gpus`` GPUs) holds one
:class:`ChunkWorker`, a Ray actor with one JAX device that keeps its device and its compiled programs
for every chunk it runs and returns each chunk's metrics; the driver writes the part as it arrives.
Chunks go to whichever worker is up and free (two in flight per worker), and workers are added as
the cluster grows. When a worker's process or node dies its chunks go back to the queue (each at most
``retries`` times) and Ray restarts the worker; a part once written is never recomputed, and a rerun
of the command resumes like any sweep. The chunks are those of the one-device plan for the workers'
backend, so the rows equal a one-process run's on one device of that kind, bit for bit.
docs/sweep.md ("A Ray cluster") says how to start a cluster.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Iterator

from ..validation import ConfigError, check_int, check_range, first_line
from .plan import Chunk, Plan

__all__ = ["RayCluster", "RaySession", "ChunkWorker"]

#: Chunks in flight per worker, and how often the driver rereads the cluster's size for new workers.
IN_FLIGHT_PER_SLOT = 2
RESIZE_EVERY_S = 5.0


@dataclasses.dataclass(frozen=True)
class RayCluster:
    """Where and how the chunks run.

    Attributes:
      address: a Ray cluster's address (``HOST:PORT``, ``auto`` for the one started on this machine
        with ``ray start --head``, ``ray://…`` for Ray Client); ``None``: ``RAY_ADDRESS`` if set, else
        a Ray instance started here for this run and stopped after it.
      cpus, gpus: Ray resources of one worker (a GPU worker: ``gpus = 1``; on CPU nodes, cores per
        worker: XLA spreads one device's kernels over the cores it may use).
      retries: how often a chunk whose worker or node died is run again before the run stops.
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

def _configure(settings: dict[str, Any]) -> None:
    """The driver's JAX settings and plugins, in a worker. A worker that asks for no GPU keeps JAX on the
    CPU (Ray shows such a process every GPU of its node)."""
    import jax

    from ..engine.runtime import configure_jax
    from ..spec.plugins import load_plugin

    if settings["cpu_only"]:
        try:
            jax.config.update("jax_platforms", "cpu")
        except RuntimeError:  # JAX already started in this process
            pass
    try:
        configure_jax(cache_dir=settings["cache_dir"], cpu_devices=1)
    except OSError:  # the driver's cache folder cannot be made on this node: compile without it
        configure_jax(cpu_devices=1)
    jax.config.update("jax_enable_x64", settings["x64"])
    for name, path in settings["plugins"]:
        load_plugin(name, "plugin", path)


class ChunkWorker:
    """One slot's worker for one run (a Ray actor: it holds its CPUs and GPU for its life, so JAX keeps
    its device, and the runner, with its compiled programs, serves every chunk it is given)."""

    def __init__(self, settings: dict[str, Any]):
        self.runner, self.plan, self.error = None, None, None
        try:
            _configure(settings)
        except Exception as err:  # noqa: BLE001 - raised by probe and run, where the driver reads it in one line
            self.error = err

    def probe(self) -> dict[str, Any]:
        """The JAX backend this worker runs on, its device's free memory (``None`` on CPU) and the versions its
        parts record."""
        import jax

        from ..engine.policy import free_memory
        from ..io.versions import versions

        if self.error is not None:
            raise self.error
        return {"backend": jax.default_backend(), "free": free_memory(), "versions": versions()}

    def run(self, boxed_plan: list, chunk: Chunk, backend: str) -> tuple:
        """One chunk on this worker's device: ``(chunk, metrics, kinds, solvable)`` as NumPy arrays.
        ``boxed_plan``: ``[ObjectRef of the plan]`` (boxed, so Ray does not fetch it for every call; a
        worker fetches it once). A worker whose JAX backend is not the plan's ``backend`` refuses (e.g.
        a node where JAX finds no GPU): its rows would not be the plan's."""
        import jax
        import numpy as np

        from .execute import ChunkRunner

        if self.error is not None:
            raise self.error
        if jax.default_backend() != backend:
            raise ConfigError(f"a worker runs JAX on {jax.default_backend()}, the plan on {backend}: every worker "
                              "must have the same kind of device")
        if self.plan != boxed_plan[0].hex():  # a new plan: its own runner
            if self.runner is not None:
                self.runner.close()
            self.runner, self.plan = ChunkRunner(_ray().get(boxed_plan[0])), boxed_plan[0].hex()
        metrics, kinds, solvable = self.runner.dispatch(chunk)
        return chunk, {m: np.asarray(a) for m, a in metrics.items()}, np.asarray(kinds), solvable


# -- on the driver -------------------------------------------------------------------------------

class RaySession:
    """A connection to a Ray cluster for one run (a context manager: a Ray instance it started is
    stopped on exit)."""

    def __init__(self, cluster: RayCluster):
        import jax

        from ..spec.plugins import LOADED

        self.cluster = cluster
        ray = self.ray = _ray()
        self.started = False
        self.settings = {"x64": bool(jax.config.jax_enable_x64), "cache_dir": jax.config.jax_compilation_cache_dir,
                         "plugins": list(LOADED), "cpu_only": cluster.gpus == 0}
        self.workers: list[Any] = []  # every worker started
        self.starting: dict[Any, Any] = {}  # those not known to be up: {ref of their probe: worker}
        try:  # checked before anything starts
            # Ray restarts a dead worker; its chunks fail at once and go back to the queue (results)
            self._worker = ray.remote(num_cpus=cluster.cpus, num_gpus=cluster.gpus, max_restarts=-1,
                                      max_task_retries=0)(ChunkWorker)
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
        for worker in self.workers:  # their CPUs and GPUs go back to the cluster
            try:
                self.ray.kill(worker)
            except Exception:  # noqa: BLE001 - the cluster is gone already: nothing to give back
                pass
        if self.started:
            self.ray.shutdown()

    def probe(self) -> dict[str, Any]:
        """The workers' JAX backend and versions (the first worker up reports them); refused in one line
        when no node could ever hold a worker (Ray would wait for ever)."""
        ray = self.ray
        if self._slots() == 0:
            raise ConfigError(f"--ray: no node of the cluster has {self.cluster.cpus:g} CPU(s) and "
                              f"{self.cluster.gpus:g} GPU(s) for one worker; give --ray-cpus and --ray-gpus that a "
                              "node has")
        self._grow()
        (ref,), _ = ray.wait(list(self.starting), num_returns=1)
        try:
            found = ray.get(ref)
        except ray.exceptions.RayError as err:
            raise ConfigError(f"--ray: a worker could not start JAX ({_reason(err)})") from None
        self.first = self.starting.pop(ref)
        self.backend = found["backend"]
        return found

    def _slots(self) -> int:
        """Workers the cluster's live nodes can hold at once, node by node."""
        need = {"CPU": self.cluster.cpus, "GPU": self.cluster.gpus}
        return sum(int(min(r.get(k, 0.0) / v for k, v in need.items() if v > 0))
                   for r in (n.get("Resources", {}) for n in self.ray.nodes() if n.get("Alive")))

    def _grow(self) -> None:
        """Start a worker for every slot of the cluster that has none; each is asked to report once up."""
        for _ in range(self._slots() - len(self.workers)):
            worker = self._worker.remote(self.settings)
            self.workers.append(worker)
            self.starting[worker.probe.remote()] = worker

    def results(self, plan: Plan, chunks: tuple[Chunk, ...]) -> Iterator[tuple]:
        """Run ``chunks`` on the workers, yielding each as it finishes (any order). A worker gets chunks
        once it is up, :data:`IN_FLIGHT_PER_SLOT` at a time; workers are added as the cluster grows. When a
        worker dies its chunks go back to the queue (each at most ``retries`` times) and it gets chunks
        again once Ray has restarted it. A chunk's own exception, or a chunk dead ``retries + 1``
        times, raises :class:`~jaxapf.sweep.execute.ChunkFailed`."""
        from ..spec.plugins import plugin_failure
        from .execute import ChunkFailed

        ray = self.ray
        if not self.workers:
            self.probe()
        boxed = [ray.put(dataclasses.replace(plan, chunks=(), done=()))]  # shapes, variants, spec
        queue, running, deaths = list(reversed(chunks)), {}, {}
        free = [self.first] * IN_FLIGHT_PER_SLOT
        resized = time.monotonic()
        while queue or running:
            while queue and free:
                worker, chunk = free.pop(), queue.pop()
                running[worker.run.remote(boxed, chunk, self.backend)] = (worker, chunk)
            waiting = list(running) + (list(self.starting) if queue else [])
            if not waiting:
                raise ChunkFailed(f"no Ray worker is up to run chunk {queue[-1].name}")
            ready, _ = ray.wait(waiting, num_returns=1, timeout=RESIZE_EVERY_S)
            if time.monotonic() - resized > RESIZE_EVERY_S:
                self._grow()
                resized = time.monotonic()
            if not ready:
                continue
            ref = ready[0]
            if ref in self.starting:  # a worker is up; one that could not start, or on another backend, gets none
                worker = self.starting.pop(ref)
                try:
                    if ray.get(ref)["backend"] == self.backend:
                        free += [worker] * IN_FLIGHT_PER_SLOT
                except ray.exceptions.RayError:
                    pass
                continue
            worker, chunk = running.pop(ref)
            try:
                finished = ray.get(ref)
            except ray.exceptions.RayActorError as err:  # the worker died: the chunk again, elsewhere or later
                deaths[chunk] = deaths.get(chunk, 0) + 1
                if deaths[chunk] > self.cluster.retries:
                    raise ChunkFailed(f"chunk {chunk.name} failed on the Ray cluster: its worker died "
                                      f"{deaths[chunk]} time(s) ({_reason(err)})") from None
                queue.append(chunk)
                free = [w for w in free if w is not worker]
                if worker not in self.starting.values():
                    self.starting[worker.probe.remote()] = worker  # chunks again once Ray has restarted it
                continue
            except ray.exceptions.RayError as err:  # the chunk's own error; a plugin's says where it failed
                said = plugin_failure(err)
                raise ChunkFailed(f"chunk {chunk.name} failed on the Ray cluster"
                                  + (f": {said}" if said else f" ({_reason(err)})")) from None
            free.append(worker)
            yield finished


#: How long :func:`_check_reachable` waits for a connection and for a Ray head's first answer [s].
PROBE_TIMEOUT_S = 10.0
#: The HTTP/2 connection preface and an empty SETTINGS frame: what a gRPC client sends first.
_H2_HELLO = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"


def _check_reachable(address: str | None) -> None:
    """Refuse in one line a ``HOST:PORT`` nothing answers at, or that does not answer as a Ray cluster
    does: a Ray head's address is its GCS, a gRPC server, which answers a client's HTTP/2 preface with a
    SETTINGS frame at once (Ray itself retries for minutes, and hung on a port that answered TCP but
    was not Ray). Skipped with TLS (``RAY_USE_TLS``), where the preface is encrypted. A gRPC server that is
    not Ray's passes this probe; Ray then retries, and Ctrl-C stops it."""
    import os
    import socket

    timeout_s = PROBE_TIMEOUT_S
    host, sep, port = (address or "").rpartition(":")
    if not sep or "://" in address or not port.isdigit():
        return  # auto, ray://, or Ray's own error
    try:
        conn = socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout_s)
    except OSError as err:
        raise ConfigError(f"--ray {address}: nothing answers there ({err.strerror or first_line(err)}); start a "
                          "cluster with `ray start --head` and give the address it prints") from None
    if os.environ.get("RAY_USE_TLS", "0").lower() in ("1", "true"):
        conn.close()
        return
    head, why = b"", "it closed the connection"
    try:
        conn.sendall(_H2_HELLO)
        while len(head) < 9:
            more = conn.recv(9 - len(head))
            if not more:
                break
            head += more
    except TimeoutError:
        why = f"no answer within {timeout_s:g} s"
    except OSError as err:
        why = f"{err.strerror or first_line(err)}"
    finally:
        conn.close()
    if len(head) >= 9 and head[3] != 0x04 or 0 < len(head) < 9:
        why = "it answered, but not in gRPC (HTTP/2)"
    if len(head) < 9 or head[3] != 0x04:  # the server's first frame must be SETTINGS (type 4)
        raise ConfigError(f"--ray {address}: something answers there, but not as a Ray cluster does ({why}); give "
                          "the address `ray start --head` prints (its GCS port, 6379 by default)")


def _reason(err: Exception) -> str:
    """The first line of a Ray error that says what happened (a task's own exception, or a dead worker)."""
    cause = getattr(err, "cause", None)
    return first_line(cause) if cause is not None else first_line(err)
