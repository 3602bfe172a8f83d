"""Running a sweep: JAX set-up, the devices, the loop that writes parts as chunks finish."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import pathlib
import re
import sys
import time
from typing import Any, Callable, Iterator, Mapping

import numpy as np

from ..io.lock import OutputLock, check_writable
from ..text import format_seconds
from ..validation import ConfigError, Interrupted, first_line
from .audit import audit_output, check_folder, prepare_output, repair_parts
from .cluster import RayCluster, RaySession
from .division import Division, agree_division
from .execute import ChunkFailed, Finished, local_results
from .output import part_files, part_record, write_part
from .plan import DEFAULT_MEMORY_BUDGET, Chunk, Plan, chunk_cost, describe_plan, plan_sweep, shard_chunks
from .schema import part_table, schema, sweep_meta
from .spec import SweepSpec

__all__ = ["parse_size", "SweepResult", "check_options", "dry_run", "run_sweep"]


def parse_size(text: str) -> int:
    """Bytes from ``"512M"``, ``"2G"``, ``"64MiB"``, ``"1e9"`` (K, M, G, T are powers of 1024)."""
    match = re.fullmatch(r"\s*(\d+(?:\.\d*)?(?:e\d+)?)\s*(?:([KMGT])(?:i?B)?|B)?\s*", str(text), re.IGNORECASE)
    if match is None or float(match[1]) < 1:
        raise ConfigError(f"--memory-budget = {text!r} is not a size; write e.g. 256M, 2G or a number of bytes")
    unit = match[2].upper() if match[2] else ""
    return int(float(match[1]) * 1024 ** ("_KMGT".index(unit) if unit else 0))


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
    if shard is not None:  # the shard run's own checks, changing nothing
        whole = plan_sweep(spec, **(plan | {"devices": 1}))
        mine = shard_chunks(whole, *shard)
        meta = sweep_meta(spec, whole, out)
        todo, _, _ = _shard_audit(spec, pathlib.Path(out), meta, whole, mine, shard, repair)
        agree_division(pathlib.Path(out), _division(whole, meta, shard, plan), shard, dry=True)
        run_s = sum(chunk_cost(whole, c) for c in todo)
        return (describe_plan(whole) + f"\n  shard {shard[0]}/{shard[1]}:        {len(mine)} of {len(whole.chunks)} "
                f"chunks ({whole.episodes_of(mine):,} episodes), {len(todo)} still to run in {out}, up to "
                f"{format_seconds(run_s)} of simulation")
    done = prepare_output(pathlib.Path(out), sweep_meta(spec, plan_sweep(spec, **plan), out), spec,
                          overwrite=overwrite, clean=False, repair=repair)
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
    shard: tuple[int, int] | None = None,
    ray: RayCluster | None = None,
    after_part: Callable[[Chunk], None] | None = None,
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
    """
    start = time.perf_counter()
    out = pathlib.Path(out)
    check_options(shard, devices, overwrite, ray)
    with contextlib.ExitStack() as stack:
        session = None if ray is None else stack.enter_context(RaySession(ray))
        result = _run(spec, out, memory_budget, chunk_fields, overwrite, repair, quiet, devices, shard, session,
                      after_part)
    return dataclasses.replace(result, seconds=time.perf_counter() - start)


def _run(spec: SweepSpec, out: pathlib.Path, memory_budget: int, chunk_fields: int | None, overwrite: bool,
         repair: bool, quiet: bool, devices: int | None, shard: tuple[int, int] | None, session: RaySession | None,
         after_part: Callable[[Chunk], None] | None) -> SweepResult:
    """:func:`run_sweep` once its Ray session, if any, is open."""
    backend = versions = None
    if session is not None:  # the workers' backend and versions, not this process's
        found = session.probe()
        devices, backend, versions = 1, found["backend"], found["versions"]
    if shard is not None:
        devices = 1
    probe = plan_sweep(spec, memory_budget=memory_budget, chunk_fields=chunk_fields, devices=devices, backend=backend)
    meta = sweep_meta(spec, probe, out, versions)
    note = (lambda line: None) if quiet else (lambda line: print(f"note: {line}", file=sys.stderr, flush=True))
    check_writable(out)
    with OutputLock(out, shard):
        if shard is None:
            done = prepare_output(out, meta, spec, overwrite=overwrite, clean=True, repair=repair)
            plan = probe.resumed(done)
            todo = plan.chunks
        else:
            plan, mine = probe, shard_chunks(probe, *shard)
            todo, found, problems = _shard_audit(spec, out, meta, plan, mine, shard, repair)
            agree_division(out, _division(plan, meta, shard, {"memory_budget": memory_budget,
                                                              "chunk_fields": chunk_fields}), shard)
            _clean_shard(out, found, problems, mine)
        padding = plan.padding_note()
        if padding:
            note(padding)
        written = _write_chunks(plan, todo, out, meta, quiet, after_part, shard,
                                local_results if session is None else session.results)
    scope = plan.episodes if shard is None else plan.episodes_of(mine)  # this run's part
    return SweepResult(out, plan.episodes_of(todo), scope - plan.episodes_of(todo), written, 0.0, plan.duplicates,
                       shard)


def _division(plan: Plan, meta: Mapping[str, Any], shard: tuple[int, int], options: Mapping[str, Any]) -> Division:
    """This shard's :class:`~jaxapf.sweep.division.Division` of ``plan`` (``options``: what cut it)."""
    return Division.of(plan, meta, shard[1], options.get("chunk_fields"),
                       options.get("memory_budget", DEFAULT_MEMORY_BUDGET))


def _shard_audit(spec: SweepSpec, out: pathlib.Path, meta: Mapping[str, Any], plan: Plan, mine: tuple[Chunk, ...],
                 shard: tuple[int, int], repair: bool) -> tuple[tuple[Chunk, ...], Any, dict[str, str]]:
    """The chunks of shard ``shard`` (``mine``, of ``plan``) still to run in ``out`` (those no sound part
    holds), the audit of ``out`` and the shard's own parts that cannot be trusted; reads, changes
    nothing. Refused: a folder of another sweep (the vmap width, hence the kind of device, is part of a
    sweep's identity), parts chunked otherwise than this plan, or written by a division into another
    number of shards, and, without ``repair``, damaged, foreign or overlapping parts of this shard; any
    other part is another shard's business (`jaxapf sweep verify` reports it)."""
    names = {c.name for c in mine}
    if not out.exists():
        return mine, None, {}
    check_folder(out)
    if not part_files(out):
        return mine, None, {}
    found = audit_output(out, meta, spec)
    other = sorted(found.other_sweep)
    if other:
        raise ConfigError(f"--out {out} holds parts {found.foreign[other[0]]} (e.g. {other[0]}); "
                          "every shard must run the same spec, float type and kind of device")
    planned = set(plan.chunks)
    otherwise = [c.name for c in found.sound if c not in planned]
    if otherwise:
        raise ConfigError(f"--out {out} holds parts chunked otherwise than this plan (e.g. {otherwise[0]}): shards "
                          "chunk on one device; give every shard the same --chunk-fields and --memory-budget, and "
                          "write a sweep run otherwise elsewhere")
    divisions = {tuple(r["shard"]) for c in found.sound if "shard" in (r := part_record(out / c.name))}
    if any(n != shard[1] for _, n in divisions):
        counts = sorted({n for _, n in divisions})
        raise ConfigError(f"--out {out} is being written as {', '.join(map(str, counts))} shard(s), not "
                          f"{shard[1]}: every shard of one output must give the same N in --shard I/N")
    problems = {n: why for n, why in found.problems.items() if n in names}
    if problems and not repair:
        listed = "; ".join(f"{n}: {problems[n]}" for n in sorted(problems)[:3])
        raise ConfigError(f"--out {out}: {len(problems)} part(s) of shard {shard[0]}/{shard[1]} cannot be trusted: "
                          f"{listed}. Rerun the same command with --repair to recompute them")
    sound = {c.name for c in found.sound} - set(problems)
    return tuple(c for c in mine if c.name not in sound), found, problems


def _clean_shard(out: pathlib.Path, found: Any, problems: Mapping[str, str], mine: tuple[Chunk, ...]) -> None:
    """What ``--repair`` does to the shard's own ``problems`` (of the audit ``found``), and the temporary
    parts a dead run of this shard left (the shard lock is ours; others' are theirs)."""
    if found is None:
        return
    names = {c.name for c in mine}
    repair_parts(out, found, problems)
    for tmp in out.iterdir():
        if tmp.name.startswith(".part-") and tmp.name.split(".tmp-")[0][1:] in names:
            tmp.unlink(missing_ok=True)


def _write_chunks(plan: Plan, chunks: tuple[Chunk, ...], out: pathlib.Path, meta: Mapping[str, Any], quiet: bool,
                  after_part: Callable[[Chunk], None] | None, shard: tuple[int, int] | None = None,
                  results: Callable[[Plan, tuple[Chunk, ...]], Iterator[Finished]] = local_results) -> int:
    """Run ``chunks`` of ``plan`` (``results``: on this process's devices, or elsewhere) and write each as a
    part as it finishes; returns the parts written. Ctrl-C and a full disk end it with one line saying
    what was kept."""
    out.mkdir(parents=True, exist_ok=True)
    layout = schema(plan, meta)
    kept_before = len(part_files(out))
    from ..progress import Progress

    bar = Progress(plan.episodes_of(chunks), plan.spec.name, "ep", quiet=quiet)
    written = 0
    finished = results(plan, chunks)

    def kept() -> str:
        return f"{kept_before + written} finished part(s) are kept in {out}"
    try:
        for chunk, arrays, kinds, solvable in finished:
            inverse = np.asarray(plan.variants[chunk.variant].inverse)  # identical settings
            metrics = {m: np.asarray(a)[inverse] for m, a in arrays.items()}
            try:
                write_part(out, chunk.name, part_table(plan, layout, chunk, metrics, np.asarray(kinds), solvable),
                           shard)
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
