"""What a sweep's output holds, read from its parts' contents, not their names.

Every part is read back (:func:`~jaxapf.sweep.output.read_part`: page CRCs and content hash) and
checked against the sweep it should belong to:

- **damaged**: unreadable, truncated or changed after it was written;
- **foreign**: of another sweep (spec, dtype, vmap width, metrics or format differ), outside this
  sweep's plan (a variant, family or fields the spec does not have), or holding rows other than
  those its name says (a part copied over another's name);
- **overlapping**: holding episodes another sound part holds too (two runs that chunked the same
  fields differently): of such parts the widest are kept, and each part overlapping a kept one is
  overlapping;
- **sound**: everything else; what the sound parts do not cover is **missing**.

Resume (:func:`resume`, judging against the run's plan) trusts only sound parts and never extends
the plan with a foreign one; ``--repair`` removes damaged and overlapping parts (their chunks are
recomputed) and moves foreign ones to ``OUT/.set-aside/``; ``jaxapf sweep verify`` prints the audit
and says by its exit status whether the dataset is complete and sound.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
from typing import Any, Mapping, Sequence

import numpy as np

from ..io.lock import LOCK_NAME
from ..io.names import check_kind, kind, remove_leftover, subfolder
from ..validation import ConfigError
from .division import Division, agree_division, forget_division, is_division_file
from .meta import META_KEY, identity, needed, parse_meta, read_meta, stored_spec_bound, sweep_spec
from .output import _PROBE, _TMP, PartUnreadable, audited_hash, part_files, part_record, read_part
from .plan import Chunk, Plan, Variant, gaps, shard_chunks, variants
from .spec import SweepSpec

__all__ = ["Audit", "audit_output", "audit_folder", "read_parts", "reference_meta", "judge", "describe_audit",
           "SET_ASIDE", "resume", "prepare_output", "check_folder", "clear_temporaries", "repair_parts", "not_parts"]

#: What a part whose stored spec fails :func:`~jaxapf.sweep.meta.stored_spec_bound` is said to be.
_EDITED_SPEC = "its stored spec is not the one its spec_hash names (edited after it was written)"
#: Where ``--repair`` moves foreign parts (hidden: Parquet readers skip it).
SET_ASIDE = ".set-aside"


@dataclasses.dataclass(frozen=True)
class Audit:
    """The parts of an output by what they hold (module docstring); ``missing``: the (variant, family,
    start, stop) field ranges no sound part covers; ``rows``: rows in sound parts; ``expected``: rows of
    the whole sweep; ``other_sweep``: the foreign parts that belong to another sweep altogether; ``hashes``: each
    sound part's content hash, as the audit read and verified it."""

    sound: tuple[Chunk, ...]
    damaged: Mapping[str, str]
    foreign: Mapping[str, str]
    overlapping: Mapping[str, str]
    missing: tuple[tuple[int, str, int, int], ...]
    rows: int
    expected: int
    other_sweep: frozenset[str] = frozenset()
    hashes: Mapping[str, str] = dataclasses.field(default_factory=dict)

    @property
    def problems(self) -> dict[str, str]:
        """Every part that is not sound, with what is wrong with it."""
        return {**self.damaged, **self.foreign, **self.overlapping}

    @property
    def complete(self) -> bool:
        """Sound and complete: every expected episode exactly once, nothing else."""
        return not self.problems and not self.missing and self.rows == self.expected


def _rows_problem(table: Any, chunk: Chunk, settings: list[int], family: str) -> str | None:
    """What is wrong with a part's rows for its name, or None: ``settings`` the setting indices of its
    variant, every one of them for every field ``start … stop-1`` of ``family``."""
    n = chunk.stop - chunk.start
    want = len(settings) * n
    if table.num_rows != want:
        return f"holds {table.num_rows} rows where its name says {want}"
    columns = {c: table.column(c).to_numpy(zero_copy_only=False) for c in ("setting", "family", "field")
               if c in table.column_names}
    if len(columns) < 3:
        return "lacks the setting, family or field column"
    if not np.array_equal(columns["setting"], np.repeat(np.asarray(settings), n)):
        return "holds rows of other settings than its name says"
    if not np.all(columns["family"] == family):
        return f"holds rows of family {sorted(set(columns['family']))[0]!s}, its name says {family}"
    if not np.array_equal(columns["field"], np.tile(np.arange(chunk.start, chunk.stop), len(settings))):
        lo, hi = int(columns["field"].min()), int(columns["field"].max())
        return f"holds fields {lo}-{hi}, its name says {chunk.start}-{chunk.stop - 1}"
    return None


def _layout(spec: SweepSpec, meta: Mapping[str, Any], gain_columns: Any = None) -> list[tuple[str, str]] | None:
    """The columns and types every part of the sweep holds, in order (``gain_columns``: the plan's, if
    planned); None for the legacy format, whose parts lack two of them."""
    from .meta import FORMAT
    from .schema import row_schema

    if meta.get("format") != FORMAT:
        return None
    needed(meta)
    return [(f.name, str(f.type)) for f in row_schema(spec, meta, gain_columns)]


def _columns_problem(schema: Any, layout: list[tuple[str, str]]) -> str | None:
    """What differs between a part's columns and the sweep's ``layout`` (names, order, types), or None."""
    have = [(f.name, str(f.type)) for f in schema]
    if have == layout:
        return None
    if [n for n, _ in have] != [n for n, _ in layout]:
        extra = sorted(set(n for n, _ in have) - set(n for n, _ in layout))
        lacks = sorted(set(n for n, _ in layout) - set(n for n, _ in have))
        what = "; ".join(filter(None, [f"columns {', '.join(extra[:3])} not of this sweep" if extra else "",
                                       f"lacks {', '.join(lacks[:3])}" if lacks else ""])) or "columns in another order"
        return f"holds other columns than the sweep's ({what})"
    (name, typ), want = next(((h, w[1]) for h, w in zip(have, layout) if h != w))
    return f"holds column {name} as {typ}, the sweep's is {want}"


def read_parts(out: pathlib.Path, files: list[pathlib.Path] | None = None
               ) -> tuple[dict[str, Any], dict[str, dict], dict[str, str]]:
    """``(tables, metas, damaged)`` of every part file in ``out`` (or of ``files``): the verified tables
    and their ``jaxapf`` metadata by part name, and what is wrong with each part that does not read back
    intact."""
    damaged, tables, metas = {}, {}, {}
    for p in files if files is not None else part_files(out) if out.is_dir() else []:
        what = kind(os.lstat(p))
        if what != "file":  # read, it would be another file's rows under this name
            damaged[p.name] = f"a {what}, not a part file"
            continue
        try:
            tables[p.name] = read_part(p)  # its metadata from the very bytes read and verified: one read
            metas[p.name] = parse_meta((tables[p.name].schema.metadata or {}).get(META_KEY), p)
        except PartUnreadable:  # cannot be read now (permissions, I/O): not damage, nothing is judged
            raise
        except ConfigError as err:
            damaged[p.name] = str(err).split(": ", 1)[-1]
            tables.pop(p.name, None)
    return tables, metas, damaged


def reference_meta(out: pathlib.Path, metas: Mapping[str, dict], bound: bool = True) -> dict:
    """The metadata of the sweep most of the readable parts belong to (``location``: ``out``), among the parts
    whose stored spec is the one their ``spec_hash`` names; :class:`ConfigError` naming a part if none is.
    ``bound=False`` counts every part (files not named as a sweep names its parts, read as they are)."""
    counts: dict[str, int] = {}
    counted = {name: m for name, m in metas.items() if not bound or stored_spec_bound(m)}
    for m in counted.values():
        key = json.dumps(identity(m), sort_keys=True)
        counts[key] = counts.get(key, 0) + 1
    if not counts and metas:
        first = sorted(metas)[0]
        raise ConfigError(f"{out / first}{f' and {len(metas) - 1} other part(s)' if len(metas) > 1 else ''}: "
                          f"{_EDITED_SPEC}")
    if not counts:
        raise ConfigError(f"{out} is not the output of jaxapf sweep: no readable part file")
    reference = max(counts, key=counts.get)
    meta = next(m for m in counted.values() if json.dumps(identity(m), sort_keys=True) == reference)
    return {**meta, "location": str(out.resolve())}


def judge(tables: Mapping[str, Any], metas: Mapping[str, dict], damaged: Mapping[str, str], meta: Mapping[str, Any],
          spec: SweepSpec, groups: Sequence[Variant], gain_columns: Any = None) -> Audit:
    """The :class:`Audit` of parts read by :func:`read_parts`, against the sweep of ``meta`` and ``spec``
    (its settings grouped into ``groups``, :func:`~jaxapf.sweep.plan.variants`; ``gain_columns``: the
    plan's, if planned); a part's columns must be the sweep's, names, order and types."""
    settings = {v.index: [s.index for s in v.settings] for v in groups}
    want = identity(meta)
    layout = _layout(spec, meta, gain_columns)
    foreign, sound, other_sweep = {}, [], set()
    for name, table in tables.items():
        chunk = Chunk.from_name(name)
        other = identity(metas[name])
        if not stored_spec_bound(metas[name]):
            foreign[name] = _EDITED_SPEC
        elif other != want:
            differ = ", ".join(k for k in want if other[k] != want[k])
            foreign[name] = f"of another sweep ({differ} {'differs' if ',' not in differ else 'differ'})"
            other_sweep.add(name)
        elif layout is not None and (problem := _columns_problem(table.schema, layout)) is not None:
            foreign[name] = problem
        elif chunk.variant not in settings or chunk.family not in spec.families or chunk.stop > spec.fields:
            foreign[name] = (f"outside this sweep's plan (variants 0-{len(groups) - 1}, families "
                             f"{', '.join(spec.families)}, fields 0-{spec.fields - 1})")
        elif (problem := _rows_problem(table, chunk, settings[chunk.variant], chunk.family)) is not None:
            foreign[name] = problem
        else:
            sound.append(chunk)
    overlapping = {}
    by_block: dict[tuple[int, str], list[Chunk]] = {}
    for c in sound:
        by_block.setdefault((c.variant, c.family), []).append(c)
    for block in by_block.values():  # keep the widest part first, then every part that overlaps no kept one
        kept: list[Chunk] = []
        for c in sorted(block, key=lambda c: (c.start - c.stop, c.start)):
            clash = next((k for k in kept if c.start < k.stop and k.start < c.stop), None)
            if clash is None:
                kept.append(c)
            else:
                overlapping[c.name] = (f"shares fields {max(c.start, clash.start)}-{min(c.stop, clash.stop) - 1} "
                                       f"with {clash.name}")
    sound = [c for c in sound if c.name not in overlapping]
    missing = []
    for v in groups:
        for family in spec.families:
            done = [(c.start, c.stop) for c in sound if (c.variant, c.family) == (v.index, family)]
            missing += [(v.index, family, a, b) for a, b in gaps(done, spec.fields)]
    rows = sum(len(settings[c.variant]) * (c.stop - c.start) for c in sound)
    expected = sum(len(s) for s in settings.values()) * len(spec.families) * spec.fields
    return Audit(tuple(sorted(sound, key=lambda c: c.name)), dict(damaged), foreign, overlapping, tuple(missing),
                 rows, expected, frozenset(other_sweep), {c.name: audited_hash(tables[c.name]) for c in sound})


def audit_output(out: pathlib.Path, plan: Plan) -> Audit:
    """The audit of the output ``out`` against the sweep ``plan`` plans (its metadata, spec and variants)."""
    return judge(*read_parts(out), plan.meta, plan.spec, plan.variants, plan.gain_columns)


def audit_folder(out: pathlib.Path, meta: Mapping[str, Any] | None = None) -> tuple[Audit, dict]:
    """The audit of the output ``out`` against the sweep of the metadata ``meta``
    (:func:`~jaxapf.sweep.meta.sweep_meta`), without it that of the sweep most of its readable parts
    belong to (``jaxapf sweep verify``, merge), and the metadata it judged against; every part read once."""
    tables, metas, damaged = read_parts(out)
    meta = dict(meta) if meta is not None else reference_meta(out, metas)
    spec = sweep_spec(meta)
    return judge(tables, metas, damaged, meta, spec, variants(spec)), meta


def not_parts(out: pathlib.Path) -> list[str]:
    """The visible entries of the output ``out`` that are not parts: named by verify and the report,
    never read as rows."""
    return sorted(p.name for p in out.iterdir()
                  if not p.name.startswith((".", "_")) and Chunk.from_name(p.name) is None)


def describe_audit(out: pathlib.Path, found: Audit, meta: Mapping[str, Any], limit: int = 10) -> str:
    """What ``jaxapf sweep verify`` prints: one line saying whether the dataset is complete and sound,
    then each part that cannot be trusted, each missing range (the first ``limit`` of each) and the
    entries that are not parts."""
    head = (f"{out}: {len(found.sound):,} sound part(s), {found.rows:,} of {found.expected:,} episodes "
            f"(spec_hash {str(meta.get('spec_hash'))[:12]}, {meta.get('format')}, {meta.get('dtype')})")
    others = not_parts(out)
    stray = ([f"  not a part (never read as rows): {', '.join(others[:limit])}"
              + (f" … and {len(others) - limit} more" if len(others) > limit else "")] if others else [])
    if found.complete:
        return "\n".join([f"{head}: complete and sound, every episode exactly once"] + stray)
    lines = [f"{head}: NOT complete and sound"] + stray
    for label, parts in (("damaged", found.damaged), ("foreign", found.foreign), ("overlapping", found.overlapping)):
        for name in sorted(parts)[:limit]:
            lines.append(f"  {label}: {name}: {parts[name]}")
        if len(parts) > limit:
            lines.append(f"  … and {len(parts) - limit} more {label} part(s)")
    for variant, family, start, stop in found.missing[:limit]:
        lines.append(f"  missing: variant v{variant:03d}, {family}, fields {start}-{stop - 1}")
    if len(found.missing) > limit:
        lines.append(f"  … and {len(found.missing) - limit} more missing range(s)")
    if found.problems:
        lines.append("  rerunning the sweep with --repair removes the damaged and overlapping parts, sets the foreign "
                     "ones aside and recomputes their chunks")
    elif found.missing:
        lines.append("  rerunning the sweep (or its missing shards) computes the missing ranges")
    return "\n".join(lines)


def prepare_output(out: pathlib.Path, plan: Plan, *, overwrite: bool, clean: bool, repair: bool = False) -> list[Chunk]:
    """Check ``out`` against the sweep ``plan`` plans and return the chunks already finished there.

    Every part is read and checked against its name and this sweep (:func:`~jaxapf.sweep.audit.audit_output`).
    Refuses (:class:`ConfigError`) a path that is a file, a directory holding other files, an output of
    a different sweep (spec hash, dtype, vmap width, metrics, format) unless ``overwrite`` (which
    deletes the parts, and nothing else), and parts that cannot be trusted -- damaged, foreign
    (another sweep's, outside this plan, or holding other rows than their names say) or overlapping
    another -- unless ``repair``, which removes the damaged and overlapping ones (their chunks run
    again) and moves the foreign ones to ``OUT/.set-aside/``. With ``clean`` (the lock's holder only),
    temporary files of a dead writer are removed and repairs are carried out.
    """
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} is a file; a sweep writes a directory of Parquet parts")
    if not out.exists():
        return []
    check_folder(out)
    parts = part_files(out)
    if clean:
        clear_temporaries(out)
    if overwrite:
        if clean:
            for p in parts:
                p.unlink(missing_ok=True)
            forget_division(out)
        return []
    if not parts:
        return []
    found = audit_output(out, plan)
    other = found.other_sweep
    if other and not found.sound and len(other) == len(parts) - len(found.damaged):
        old = identity(read_meta(out / sorted(other)[0]))
        new = identity(plan.meta)
        what = "; ".join(f"{k} {old[k]!s:.12} here, {new[k]!s:.12} now" for k in new if old[k] != new[k])
        raise ConfigError(f"--out {out} holds a different sweep ({what}); rerun with --overwrite to replace it, "
                          "or choose another --out")
    problems = found.problems
    if problems and not repair:
        listed = "; ".join(f"{n}: {problems[n]}" for n in sorted(problems)[:3]) + (
            f"; and {len(problems) - 3} more" if len(problems) > 3 else "")
        if not found.foreign and not found.overlapping:
            raise ConfigError(f"--out {out}: {len(problems)} damaged part(s): {listed}. Rerun the same command with "
                              "--repair to remove exactly those parts and recompute their chunks")
        raise ConfigError(f"--out {out}: {len(problems)} part(s) cannot be trusted: {listed}. Rerun the same command "
                          f"with --repair to remove the damaged and overlapping ones (their chunks are recomputed) "
                          f"and move the foreign ones to {out / SET_ASIDE}")
    if problems and clean:
        repair_parts(out, found, problems)
    return list(found.sound)


def resume(out: pathlib.Path, plan: Plan, shard: tuple[int, int] | None = None, *, overwrite: bool = False,
           repair: bool = False, dry: bool = False) -> tuple[tuple[Chunk, ...], tuple[Chunk, ...]]:
    """``(todo, done)``: the chunks of ``plan`` (with ``shard = (i, n)``, of its shard,
    :func:`~jaxapf.sweep.plan.shard_chunks`) still to run in ``out``, and those sound parts there hold.

    The whole sweep's output is checked by :func:`prepare_output` and its gaps cut at this plan's sizes;
    a shard's by its own rules (:func:`_shard_audit`), and its division must agree with the other
    shards' (:func:`~jaxapf.sweep.division.agree_division`). Unless ``dry`` (``--dry-run``: nothing
    changes), the run holding the output's lock clears what a dead run left and carries out ``repair``.
    """
    if shard is None:
        done = tuple(prepare_output(out, plan, overwrite=overwrite, clean=not dry, repair=repair))
        return plan.chunks_left(done), done
    mine = shard_chunks(plan, *shard)
    todo, found, problems = _shard_audit(out, plan, mine, shard, repair)
    agree_division(out, Division.of(plan, shard[1]), shard, dry=dry)
    if not dry:
        _clean_shard(out, found, problems, mine)
    left = set(todo)
    return todo, tuple(c for c in mine if c not in left)


def _shard_audit(out: pathlib.Path, plan: Plan, mine: tuple[Chunk, ...], shard: tuple[int, int], repair: bool
                 ) -> tuple[tuple[Chunk, ...], Any, dict[str, str]]:
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
    found = audit_output(out, plan=plan)
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
    clear_temporaries(out, names)


def check_folder(out: pathlib.Path) -> None:
    """Refuse a folder holding entries that are neither parts nor what a sweep keeps beside them, or
    any of those names holding something a sweep never makes there (a link, a FIFO, a folder; only
    ``.set-aside`` is a folder): :class:`~jaxapf.io.names.Planted`, naming it."""
    foreign = []
    for p in out.iterdir():
        if p.name == SET_ASIDE:
            check_kind(p, "folder")
        elif (Chunk.from_name(p.name) is not None or _TMP.fullmatch(p.name) or _PROBE.fullmatch(p.name)
              or p.name.startswith(LOCK_NAME) or is_division_file(p.name)):
            check_kind(p)
        else:
            foreign.append(p.name)
    if foreign:
        raise ConfigError(f"--out {out} holds entries that are not sweep parts ({', '.join(sorted(foreign)[:3])}); "
                          "choose another --out")


def clear_temporaries(out: pathlib.Path, names: Any = None) -> None:
    """Remove the temporary parts a dead writer left in ``out`` (of the parts ``names`` only, if given);
    only regular files are removed (:func:`~jaxapf.io.names.remove_leftover`)."""
    for tmp in out.iterdir():
        if _TMP.fullmatch(tmp.name) and (names is None or tmp.name.split(".tmp-")[0][1:] in names):
            remove_leftover(tmp)


def repair_parts(out: pathlib.Path, found: Any, names: Any) -> None:
    """What ``--repair`` does to the parts ``names`` of the audit ``found``: damaged and overlapping ones are
    removed (their chunks run again), foreign ones moved to ``OUT/.set-aside/`` under a name not taken there."""
    for name in names:
        if name in found.foreign:
            aside = subfolder(out / SET_ASIDE)
            target, n = aside / name, 1
            while os.path.lexists(target):  # never over an earlier set-aside part
                target, n = aside / f"{name}.{n}", n + 1
            (out / name).replace(target)
        else:
            (out / name).unlink(missing_ok=True)
