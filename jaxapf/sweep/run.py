"""Running a sweep: JAX set-up, the devices, the loop that writes parts as chunks finish."""

from __future__ import annotations

import dataclasses
import os
import pathlib
import re
import sys
import time
from typing import Any, Callable, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from ..engine.devices import DeviceBatch
from ..gains import Gains
from ..io.lock import OutputLock, check_writable
from ..validation import ConfigError, Interrupted, first_line
from .output import prepare_output, write_part
from .plan import DEFAULT_MEMORY_BUDGET, Chunk, Plan, Variant, describe_plan, plan_sweep
from .schema import part_table, schema, sweep_meta
from .spec import SweepSpec

__all__ = ["configure_jax", "default_cache_dir", "parse_size", "SweepResult", "dry_run", "run_sweep"]


def default_cache_dir() -> pathlib.Path:
    """``$XDG_CACHE_HOME/jaxapf/xla`` (default ``~/.cache/jaxapf/xla``)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "jaxapf" / "xla"


def configure_jax(*, x64: bool = False, cache_dir: str | os.PathLike | None = None,
                  cpu_devices: int | None = None, distributed: bool = False,
                  cluster: Mapping[str, Any] | None = None) -> None:
    """Process-wide JAX settings for a sweep; call before anything runs on a device.

    Args:
      x64: float64 everywhere (``jax_enable_x64``).
      cache_dir: persistent compilation cache (``jax_compilation_cache_dir``); programs that took
        more than 0.1 s to compile are stored there and loaded by later runs. ``None``: no cache.
      cpu_devices: split the host CPU into this many JAX devices (``jax_num_cpu_devices``), one
        per core being the useful setting; ignored when ``XLA_FLAGS`` already forces a count.
      distributed: ``jax.distributed.initialize(**cluster)`` (multi-process runs). Without
        ``cluster`` JAX detects the cluster (Slurm, Open MPI, TPU pods); elsewhere pass
        ``coordinator_address``, ``num_processes`` and ``process_id``.
    """
    if distributed:
        jax.distributed.initialize(**(cluster or {}))
    if x64:
        jax.config.update("jax_enable_x64", True)
    if cache_dir is not None:
        pathlib.Path(cache_dir).mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(cache_dir))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.1)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    if cpu_devices is not None and "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
        try:
            jax.config.update("jax_num_cpu_devices", int(cpu_devices))
        except RuntimeError:  # JAX already ran something in this process: keep its devices
            pass


def parse_size(text: str) -> int:
    """Bytes from ``"512M"``, ``"2G"``, ``"64MiB"``, ``"1e9"`` (K, M, G, T are powers of 1024)."""
    match = re.fullmatch(r"\s*(\d+(?:\.\d*)?(?:e\d+)?)\s*(?:([KMGT])(?:i?B)?|B)?\s*", str(text), re.IGNORECASE)
    if match is None or float(match[1]) < 1:
        raise ConfigError(f"--memory-budget = {text!r} is not a size; write e.g. 256M, 2G or a number of bytes")
    unit = match[2].upper() if match[2] else ""
    return int(float(match[1]) * 1024 ** ("_KMGT".index(unit) if unit else 0))


class _Devices:
    """Runs the chunks of a plan on the local devices (:class:`~jaxapf.engine.devices.DeviceBatch`)."""

    def __init__(self, plan: Plan):
        self.batch = DeviceBatch(jax.local_devices()[: plan.devices])
        self.plan = plan
        self._gains: dict[int, list[Gains]] = {}
        self._oracle: dict[tuple, np.ndarray] = {}

    def close(self) -> None:
        self.batch.close()

    def _variant_gains(self, variant: Variant) -> list[Gains]:
        if variant.index not in self._gains:
            self._gains[variant.index] = self.batch.put_gains(variant.gains(self.plan.dtype))
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
        metrics = self.batch.evaluate(fields, self._variant_gains(plan.variants[chunk.variant]), block.sim,
                                      block.mpc, block.width, plan.metrics, program)
        return metrics, fields.kind, self._solvable(chunk, fields, block.sim) if plan.spec.oracle else None

    def _solvable(self, chunk: Chunk, fields: Any, sim: Any) -> np.ndarray:
        """:func:`~jaxapf.scenarios.solvable` of the chunk's real fields, once per field and vehicle
        (variants that differ only in method or gains share the answer); of a swarm field, whether every
        UAV passes it alone (:func:`~jaxapf.scenarios.swarms.agents_solvable`)."""
        from ..scenarios import solvable
        from ..scenarios.swarms import agents_solvable

        oracle = (lambda real, **v: agents_solvable(real, **v).all(axis=-1)) if self.plan.spec.swarm else solvable
        vehicle = dict(r_uav=sim.vehicle.r_uav, v_max=sim.vehicle.v_max, t_max=sim.episode.t_max,
                       r_goal=sim.episode.r_goal)
        key = (chunk.family, chunk.start, chunk.stop, *vehicle.values())
        if key not in self._oracle:
            n = chunk.stop - chunk.start
            real = jax.tree_util.tree_map(lambda a: np.asarray(a)[:n], fields)
            self._oracle[key] = oracle(real, **vehicle)
        return self._oracle[key]


@dataclasses.dataclass(frozen=True)
class SweepResult:
    """What a run did: episodes run now and found done, parts written, wall time."""

    out: pathlib.Path
    episodes: int
    skipped: int
    parts: int
    seconds: float
    duplicates: int = 0  # settings identical to an earlier one in every gain read, not simulated again

    def summary(self, name: str) -> str:
        rate = self.episodes / self.seconds if self.seconds > 0 else 0.0
        skipped = f" ({self.skipped:,} already done)" if self.skipped else ""
        same = (f"; {self.duplicates} setting(s) repeat an earlier one in every gain their method reads: "
                "simulated once, rows copied" if self.duplicates else "")
        return (f"sweep {name}: {self.episodes:,} episodes{skipped} in {self.seconds:.1f} s, "
                f"{rate:,.1f} episodes/s -> {self.out}{same}")


_CONNECTED = False


def _sync(name: str) -> None:
    """A barrier of all processes (nothing with one). The first one connects the processes' CPU
    collectives (Gloo), which print ``[Gloo] Rank r is connected to n peer ranks ...`` on the C++
    standard output with no setting to turn it off; that line is dropped (file descriptor 1 goes to
    /dev/null during the first barrier, when nothing else writes there)."""
    global _CONNECTED
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        if _CONNECTED:
            multihost_utils.sync_global_devices(name)
            return
        sys.stdout.flush()
        saved = os.dup(1)
        try:
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 1)
            os.close(null)
            multihost_utils.sync_global_devices(name)
            _CONNECTED = True
        finally:
            os.dup2(saved, 1)
            os.close(saved)


def dry_run(spec: SweepSpec, out: str | os.PathLike, *, overwrite: bool = False, repair: bool = False,
            **plan: Any) -> str:
    """:func:`describe_plan` of what :func:`run_sweep` would do with ``out`` as it is now
    (refusing, like the run, an output of a different sweep or with damaged parts, unless
    ``repair``); ``plan``: :func:`plan_sweep` options."""
    done = prepare_output(pathlib.Path(out), sweep_meta(spec, plan_sweep(spec, **plan), out), spec, overwrite=overwrite,
                          clean=False, repair=repair)
    return describe_plan(plan_sweep(spec, done=done, **plan))


def run_sweep(
    spec: SweepSpec,
    out: str | os.PathLike,
    *,
    memory_budget: int = DEFAULT_MEMORY_BUDGET,
    chunk_fields: int | None = None,
    overwrite: bool = False,
    repair: bool = False,
    quiet: bool = False,
    devices: int | None = None,
    after_part: Callable[[Chunk], None] | None = None,
) -> SweepResult:
    """Run (or resume) ``spec`` into the Parquet dataset directory ``out``.

    Finished parts already in ``out`` are verified and kept, and their chunks skipped; the fields
    they do not cover are cut into chunks of the current size. A damaged part is refused, or with
    ``repair`` removed and its chunk recomputed. The run holds ``out/.lock`` (one writer per
    output, :class:`jaxapf.io.lock.OutputLock`). ``after_part`` is called after each part is written
    (tests use it to interrupt a run). Ctrl-C raises :class:`~jaxapf.validation.Interrupted`
    saying what was kept. In a multi-process run (``jax.distributed``), process ``p`` runs chunks
    ``p, p + P, p + 2P, …`` of the plan; process 0 holds the lock.
    """
    start = time.perf_counter()
    out = pathlib.Path(out)
    process, processes = jax.process_index(), jax.process_count()
    probe = plan_sweep(spec, memory_budget=memory_budget, chunk_fields=chunk_fields, devices=devices,
                       processes=processes)
    meta = sweep_meta(spec, probe, out)
    note = (lambda line: None) if quiet else (lambda line: print(f"note: {line}", file=sys.stderr, flush=True))
    lock = OutputLock(out)
    if process == 0:
        check_writable(out)
        lock.acquire()
    try:
        return _run(spec, out, meta, start, memory_budget=memory_budget, chunk_fields=chunk_fields,
                    overwrite=overwrite, repair=repair, quiet=quiet, devices=devices, after_part=after_part,
                    note=note)
    finally:
        lock.release()


def _run(spec: SweepSpec, out: pathlib.Path, meta: Mapping[str, Any], start: float, *,
         memory_budget: int, chunk_fields: int | None, overwrite: bool, repair: bool, quiet: bool,
         devices: int | None, after_part: Callable[[Chunk], None] | None, note: Callable[[str], None]
         ) -> SweepResult:
    """The body of :func:`run_sweep`, under the lock; ``note`` prints one line (unless quiet)."""
    process, processes = jax.process_index(), jax.process_count()
    if process == 0:
        done = prepare_output(out, meta, spec, overwrite=overwrite, clean=True, repair=repair)
    _sync("jaxapf-sweep-prepared")
    if process != 0:
        done = prepare_output(out, meta, spec, overwrite=False, clean=False)
    _sync("jaxapf-sweep-listed")
    plan = plan_sweep(spec, done=done, memory_budget=memory_budget, chunk_fields=chunk_fields, devices=devices,
                      processes=processes)
    mine = plan.chunks[process::processes]
    padding = plan.padding_note() if process == 0 else None
    if padding:
        note(padding)
    out.mkdir(parents=True, exist_ok=True)
    layout = schema(plan, meta)
    total = plan.episodes_of(mine)
    from tqdm import tqdm

    bar = tqdm(total=total, unit="ep", unit_scale=True, desc=spec.name, dynamic_ncols=True,
               disable=quiet or not sys.stderr.isatty())
    runner = _Devices(plan)
    written = 0
    kept = len(done)
    try:
        pending: tuple[Chunk, tuple[dict[str, jax.Array], jax.Array, np.ndarray | None]] | None = None
        for chunk in (*mine, None):
            running = None if chunk is None else (chunk, runner.dispatch(chunk))
            if pending is not None:  # write the previous chunk while this one runs
                done_chunk, (arrays, kinds, solvable) = pending
                inverse = np.asarray(plan.variants[done_chunk.variant].inverse)  # identical settings
                metrics = {m: np.asarray(a)[inverse] for m, a in arrays.items()}
                try:
                    write_part(out, done_chunk.name,
                               part_table(plan, layout, done_chunk, metrics, np.asarray(kinds), solvable))
                except OSError as err:  # a full disk, a quota, a vanished mount: what was kept, how to go on
                    raise ConfigError(f"cannot write {out / done_chunk.name}: {err.strerror or first_line(err)}; "
                                      f"{kept + written} finished part(s) are kept in {out}; rerun the same command "
                                      "to resume once it can be written") from None
                written += 1
                bar.update(plan.episodes_of([done_chunk]))
                if after_part is not None:
                    after_part(done_chunk)
            pending = running
    except KeyboardInterrupt:
        raise Interrupted(f"interrupted; {kept + written} finished part(s) are kept in {out} ({written} written "
                          f"now); rerun the same command to resume") from None
    finally:
        runner.close()
        bar.close()
    return SweepResult(out, total, plan.episodes_of(done), written, time.perf_counter() - start,
                       plan.duplicates)


