"""Running a sweep: JAX set-up, the devices, the loop that writes parts as chunks finish."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import pathlib
import re
import sys
import time
from typing import Any, Callable, Iterator

import numpy as np

from ..io.lock import OutputLock, check_writable
from ..text import format_seconds
from ..validation import ConfigError, Interrupted, first_line
from .audit import resume
from .cluster import RayCluster, RaySession
from .execute import ChunkFailed, Finished, local_results
from .output import part_files, write_part
from .plan import Chunk, Plan, chunk_cost, describe_plan, plan_sweep
from .schema import part_table, schema
from .spec import SweepSpec

__all__ = ["parse_size", "SweepResult", "check_options", "dry_run", "run_sweep"]


#: Largest ``--memory-budget`` [bytes]: 1 TiB, past any one device's memory.
MAX_BUDGET = 1024**4


def parse_size(text: str) -> int:
    """Bytes from ``"512M"``, ``"2G"``, ``"64MiB"``, ``"1e9"`` (K, M, G, T are powers of 1024)."""
    match = re.fullmatch(r"\s*(\d+(?:\.\d*)?(?:e\d+)?)\s*(?:([KMGT])(?:i?B)?|B)?\s*", str(text), re.IGNORECASE)
    if match is None or float(match[1]) < 1:
        raise ConfigError(f"--memory-budget = {text!r} is not a size; write e.g. 256M, 2G or a number of bytes")
    unit = match[2].upper() if match[2] else ""
    size = float(match[1]) * 1024 ** ("_KMGT".index(unit) if unit else 0)
    if not size <= MAX_BUDGET:
        raise ConfigError(f"--memory-budget = {text!r} is more than {MAX_BUDGET // 1024**4} TiB; give the memory "
                          "one chunk may use, e.g. 2G")
    return int(size)


@dataclasses.dataclass(frozen=True)
class SweepResult:
    """What a run did: episodes run now and found done, parts written, wall time."""

    out: pathlib.Path
    episodes: int
    skipped: int
    parts: int
    seconds: float
    duplicates: int = 0  # settings identical to an earlier one in every gain read, not simulated again
    shard: tuple[int, int] | None = None

    def summary(self, name: str) -> str:
        rate = self.episodes / self.seconds if self.seconds > 0 else 0.0
        skipped = f" ({self.skipped:,} already done)" if self.skipped else ""
        same = (f"; {self.duplicates} setting(s) repeat an earlier one in every gain their method reads: "
                "simulated once, rows copied" if self.duplicates else "")
        shard = f" shard {self.shard[0]}/{self.shard[1]}" if self.shard else ""
        return (f"sweep {name}{shard}: {self.episodes:,} episodes{skipped} in {self.seconds:.1f} s, "
                f"{rate:,.1f} episodes/s -> {self.out}{same}")


def check_options(shard: tuple[int, int] | None, devices: int | None, overwrite: bool,
                  ray: RayCluster | None = None) -> None:
    """Refuse, before anything is read or made, the options a run (and its ``--dry-run``) cannot take together."""
    if ray is not None:
        ray.check(shard, devices)
    if shard is not None:
        if overwrite:
            raise ConfigError("--overwrite replaces a whole output; a shard writes only its own parts (remove the "
                              "output, or write the shards elsewhere)")
        if devices not in (None, 1):
            raise ConfigError(f"--devices = {devices}: a shard runs on one device (the shards' chunks must not depend "
                              "on the machine); run more shards instead")


def dry_run(spec: SweepSpec, out: str | os.PathLike, *, overwrite: bool = False, repair: bool = False,
            shard: tuple[int, int] | None = None, **plan: Any) -> str:
    """:func:`describe_plan` of what :func:`run_sweep` would do with ``out`` as it is now
    (refusing, like the run, an output of a different sweep or with parts that cannot be trusted,
    unless ``repair``); with ``shard``, what that shard would run; ``plan``: :func:`plan_sweep` options."""
    check_options(shard, plan.get("devices"), overwrite)
    out = pathlib.Path(out)
    whole = plan_sweep(spec, out=out, **(plan | ({"devices": 1} if shard is not None else {})))
    todo, done = resume(out, whole, shard, overwrite=overwrite, repair=repair, dry=True)
    if shard is None:
        return describe_plan(whole.resumed(done))
    mine = todo + done
    run_s = sum(chunk_cost(whole, c) for c in todo)
    return (describe_plan(whole) + f"\n  shard {shard[0]}/{shard[1]}:        {len(mine)} of {len(whole.chunks)} "
            f"chunks ({whole.episodes_of(mine):,} episodes), {len(todo)} still to run in {out}, up to "
            f"{format_seconds(run_s)} of simulation")


def run_sweep(
    spec: SweepSpec,
    out: str | os.PathLike,
    *,
    memory_budget: int | None = None,
    chunk_fields: int | None = None,
    overwrite: bool = False,
    repair: bool = False,
    quiet: bool = False,
    devices: int | None = None,
    shard: tuple[int, int] | None = None,
    ray: RayCluster | None = None,
    after_part: Callable[[Chunk], None] | None = None,
    policy: str | None = None,
    answers: str | os.PathLike | None = None,
) -> SweepResult:
    """Run (or resume) ``spec`` into the Parquet dataset directory ``out``.

    Finished parts already in ``out`` are read back and checked (:mod:`jaxapf.sweep.audit`) and their
    chunks skipped; the fields they do not cover are cut into chunks of the current size. Parts that
    cannot be trusted are refused, or with ``repair`` removed (damaged, overlapping: recomputed) or
    set aside (foreign). The run holds ``out/.lock`` (one writer per output,
    :class:`jaxapf.io.lock.OutputLock`). ``after_part`` is called after each part is written (tests
    use it to interrupt a run). Ctrl-C raises :class:`~jaxapf.validation.Interrupted` saying what was kept.

    With ``shard = (i, n)`` only shard ``i`` of ``n`` runs (:func:`~jaxapf.sweep.plan.shard_chunks`: the
    chunks of the plan on one device, dealt by cost, the same for every process that reads the
    spec), writing only its own parts: shards run side by side or hours apart, on one output or
    each in its own folder (combined by :func:`~jaxapf.sweep.merge.merge_outputs`), and a shard rerun
    after a crash computes only its missing parts.

    With ``ray`` the chunks run on a Ray cluster's workers (:mod:`jaxapf.sweep.cluster`: one device per
    worker, the plan of the workers' backend) and this process writes the parts as they arrive.

    ``memory_budget`` (default the policy's) and ``policy`` (``cpu`` or ``accelerator``, default the
    backend's): :func:`~jaxapf.sweep.plan.plan_sweep`.
    """
    start = time.perf_counter()
    out = pathlib.Path(out)
    check_options(shard, devices, overwrite, ray)
    with contextlib.ExitStack() as stack:
        session = None if ray is None else stack.enter_context(RaySession(ray))
        result = _run(spec, out, dict(memory_budget=memory_budget, chunk_fields=chunk_fields, policy=policy),
                      overwrite, repair, quiet, devices, shard, session, after_part, answers)
    return dataclasses.replace(result, seconds=time.perf_counter() - start)


def _run(spec: SweepSpec, out: pathlib.Path, options: dict[str, Any], overwrite: bool, repair: bool, quiet: bool,
         devices: int | None, shard: tuple[int, int] | None, session: RaySession | None,
         after_part: Callable[[Chunk], None] | None, answers: str | os.PathLike | None = None) -> SweepResult:
    """:func:`run_sweep` once its Ray session, if any, is open; ``options``: :func:`plan_sweep`'s."""
    if session is not None:  # the workers' backend, free device memory and versions, not this process's
        found = session.probe()
        devices = 1
        options |= dict(backend=found["backend"], versions=found["versions"], free=found.get("free"))
    if shard is not None:
        devices = 1
    plan = dataclasses.replace(plan_sweep(spec, devices=devices, out=out, **options),
                               answers=None if answers is None else str(answers))
    note = (lambda line: None) if quiet else (lambda line: print(f"note: {line}", file=sys.stderr, flush=True))
    check_writable(out)
    with OutputLock(out, shard):
        todo, done = resume(out, plan, shard, overwrite=overwrite, repair=repair)
        padding = plan.padding_note(todo)
        if padding:
            note(padding)
        written = _write_chunks(plan, todo, out, quiet, after_part, shard,
                                local_results if session is None else session.results)
    return SweepResult(out, plan.episodes_of(todo), plan.episodes_of(done), written, 0.0, plan.duplicates, shard)


def _refuse_invalid(plan: Plan, chunk: Chunk, metrics: dict[str, np.ndarray], kept: Callable[[], str]) -> None:
    """:class:`ConfigError` in one line where an episode of ``chunk`` (the first of its variant this run) turned
    non-finite (the ``invalid`` metric): the setting's components named, with the family and the field. Later
    chunks keep such an episode as the outcome it is."""
    invalid = np.asarray(metrics.get("invalid", np.zeros(0, bool)), bool)
    if not invalid.any():
        return
    from ..engine.components import COMPONENTS

    i, j = (int(k) for k in np.argwhere(invalid)[0])
    setting = plan.variants[chunk.variant].settings[i]
    stack = ", ".join(f"{k} = {v!r}" for k, v in setting.static if k in COMPONENTS) or "the defaults"
    raise ConfigError(f"setting {setting.index} ({stack}) flew field {chunk.start + j} of {chunk.family} into a "
                      f"non-finite state (NaN or inf): a component's output is not a number there ({int(invalid.sum())}"
                      f" of {invalid.size} episodes of its first chunk); {kept()}")


def _write_chunks(plan: Plan, chunks: tuple[Chunk, ...], out: pathlib.Path, quiet: bool,
                  after_part: Callable[[Chunk], None] | None, shard: tuple[int, int] | None = None,
                  results: Callable[[Plan, tuple[Chunk, ...]], Iterator[Finished]] = local_results) -> int:
    """Run ``chunks`` of ``plan`` (``results``: on this process's devices, or elsewhere) and write each as a
    part as it finishes; returns the parts written. Ctrl-C and a full disk end it with one line saying
    what was kept."""
    from ..progress import Progress

    out.mkdir(parents=True, exist_ok=True)
    kept_before = len(part_files(out))
    bar = Progress(plan.episodes_of(chunks), plan.spec.name, "ep", quiet=quiet)
    layout = schema(plan)
    written = 0
    finished = results(plan, chunks)

    def kept() -> str:
        return f"{kept_before + written} finished part(s) are kept in {out}"
    checked: set[int] = set()
    try:
        for chunk, arrays, kinds, solvable in finished:
            inverse = np.asarray(plan.variants[chunk.variant].inverse)  # identical settings
            metrics = {m: np.asarray(a)[inverse] for m, a in arrays.items()}
            if chunk.variant not in checked:  # a variant's first chunk: a component that is not a number stops it
                checked.add(chunk.variant)
                _refuse_invalid(plan, chunk, metrics, kept)
            table = part_table(plan, layout, chunk, metrics, np.asarray(kinds), solvable)
            try:
                write_part(out, chunk.name, table, shard)
            except OSError as err:  # a full disk, a quota, a vanished mount: what was kept, how to go on
                raise ConfigError(f"cannot write {out / chunk.name}: {err.strerror or first_line(err)}; {kept()}; "
                                  "rerun the same command to resume once it can be written") from None
            written += 1
            bar.update(plan.episodes_of([chunk]))
            if after_part is not None:
                after_part(chunk)
    except KeyboardInterrupt:
        raise Interrupted(f"interrupted; {kept()} ({written} written now); rerun the same command to resume") from None
    except ChunkFailed as err:  # a chunk that could not run elsewhere: what was kept
        raise ConfigError(f"{err}; {kept()}; rerun the same command to resume") from None
    finally:
        finished.close()
        bar.close()
    return written
