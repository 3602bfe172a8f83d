"""Reading a sweep's output back: its rows and metadata, and the configuration of any row."""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
from typing import Any, Mapping

from ..config import MPCConfig, SimConfig
from ..gains import Gains
from ..scenarios import FamilyParams
from ..validation import ConfigError, first_line
from .meta import identity, read_meta, sweep_spec
from .output import read_part
from .plan import Chunk, variants

__all__ = ["read_sweep", "RowConfig", "row_config", "sweep_spec"]


def read_sweep(path: str | os.PathLike) -> tuple["pd.DataFrame", dict[str, Any]]:  # noqa: F821
    """The rows of a sweep output (sorted by setting, family in spec order, field) and its metadata.

    ``path`` is the output directory (its parts are the files named as a sweep names them; a folder
    holding none, every visible ``*.parquet``) or one part file.
    The metadata is the parts' ``jaxapf`` object (docs/sweep-format.md) plus ``parts`` (number of
    part files), ``rows_expected`` (from the spec; None if the spec cannot be expanded),
    ``complete`` (every expected (setting, family, field) exactly once, read from the parts' rows),
    ``stray`` (the folder's visible entries that are not parts: named, never read) and ``location``
    (the output folder, absolute: a ``.py`` plugin is looked for there first,
    :func:`sweep_spec`). Every part is verified (its page CRCs and content hash,
    :func:`~jaxapf.sweep.output.read_part`) and, in a directory, checked against its name and the
    sweep (:mod:`jaxapf.sweep.audit`). Raises :class:`ConfigError` for a path that is not a sweep
    output, a damaged part, parts of different sweeps, or parts whose rows another part holds too or
    that are not those their names say.
    """
    import pyarrow as pa

    from .audit import judge, read_parts, reference_meta

    path = pathlib.Path(path)
    if not path.exists():
        raise ConfigError(f"{path}: no such file or directory")
    files, stray = _files(path)
    named = all(Chunk.from_name(p.name) is not None for p in files)
    if path.is_dir():
        tables, metas, damaged = read_parts(path, files)
        if damaged:
            name = sorted(damaged)[0]
            raise ConfigError(f"{path}: damaged part {name}: {damaged[name]}; rerun the sweep with --repair to "
                              "recompute it")
        if not tables:
            raise ConfigError(f"{path} is not the output of jaxapf sweep: the directory holds no Parquet part file")
        if len({json.dumps(identity(m), sort_keys=True) for m in metas.values()}) > 1:
            raise ConfigError(f"{path} mixes parts of different sweeps or jaxapf versions (their spec_hash, dtype, "
                              "vmap_width, metrics or version differ); `jaxapf sweep verify` lists them")
        meta = reference_meta(path, metas, bound=named)
        parts = len(tables)
    else:
        meta = {**read_meta(path), "location": str(path.parent.resolve())}
        try:
            tables = {path.name: read_part(path)}
        except ConfigError as err:
            raise ConfigError(f"{path}: damaged part {err}; rerun the sweep with --repair to recompute it") from None
        parts = 1
    try:
        spec = sweep_spec(meta)
        expected = len(spec.settings()) * len(spec.families) * spec.fields
    except ConfigError:
        # a folder's parts are judged against their spec, or not read (`jaxapf sweep verify` says the same);
        # a single part file is read as it is (its plugins' components must be registered: say which to name)
        if path.is_dir() and named or meta.get("spec", {}).get("plugins"):
            raise
        spec, expected = None, None
    complete = False
    if path.is_dir() and named and spec is not None:
        found = judge(tables, metas, {}, meta, spec, variants(spec))
        if found.problems:
            name = sorted(found.problems)[0]
            raise ConfigError(f"{path}: part {name} {found.problems[name]} ({len(found.problems)} part(s) cannot be "
                              "trusted; `jaxapf sweep verify` lists them, and rerunning the sweep with --repair "
                              "sets them aside and recomputes their chunks)")
        complete = found.complete
    try:
        df = pa.concat_tables(list(tables.values())).to_pandas()
    except (OSError, pa.ArrowException) as err:
        raise ConfigError(f"{path} is not a readable sweep output (Parquet): {first_line(err)}") from None
    if {"setting", "family", "field"} <= set(df.columns):
        doubled = int(df.duplicated(["setting", "family", "field"]).sum())
        if doubled:  # parts a sweep did not name (stray copies) are not audited, but never read twice
            raise ConfigError(f"{path} holds {doubled} episode row(s) twice; `jaxapf sweep verify` lists the parts")
        families = list(meta.get("spec", {}).get("scenario", {}).get("families", []))
        rank = {f: i for i, f in enumerate(families + sorted(set(df["family"]) - set(families)))}
        df = (df.assign(_rank=df["family"].map(rank)).sort_values(["setting", "_rank", "field"], kind="stable")
              .drop(columns="_rank").reset_index(drop=True))
    if not (path.is_dir() and named and spec is not None):  # complete if the rows are the whole sweep (once)
        complete = expected is not None and len(df) == expected
    return df, {**meta, "parts": parts, "rows_expected": expected, "complete": complete, "stray": stray}


def _files(path: pathlib.Path) -> tuple[list[pathlib.Path], list[str]]:
    """The part files of the output ``path`` and its visible entries that are not parts (named, never read):
    the files named as a sweep names its parts; in a folder holding none (files renamed by hand), every
    Parquet file, unaudited."""
    from .audit import not_parts

    if not path.is_dir():
        return [path], []
    stray = not_parts(path)
    files = [path / n for n in sorted(os.listdir(path)) if Chunk.from_name(n) is not None]
    if not files:
        files = [path / n for n in stray if n.endswith(".parquet") and (path / n).is_file()]
        stray = [n for n in stray if path / n not in files]
    return files, stray


@dataclasses.dataclass(frozen=True)
class RowConfig:
    """Everything needed to re-simulate one row with :func:`jaxapf.simulate.simulate_runs`:
    ``simulate_runs(c.family, c.seed, c.field, [c.sim.planner.method], c.gains, c.sim, c.mpc, c.overrides)``
    (in float64 if ``c.dtype`` is float64: enable ``jax_enable_x64`` first). ``family`` is the
    registered family, ``label`` the row's ``family`` column (a variant's name for a variant)."""

    family: str
    label: str
    params: FamilyParams
    overrides: Mapping[str, Any]
    seed: int
    field: int
    gains: Gains
    sim: SimConfig
    mpc: MPCConfig
    dtype: str


def row_config(meta: Mapping[str, Any], row: Mapping[str, Any]) -> RowConfig:
    """The configuration of one output row (``meta`` from :func:`read_sweep`)."""
    spec = sweep_spec(meta)
    setting = spec.settings()[int(row["setting"])]
    label = str(row["family"])
    sim, mpc = spec.configs(setting.static, label)
    params = spec.family_params(label)
    overrides = {k: v for k, v in spec.params.get(label, {}).items() if k != "family"}
    return RowConfig(family=params.family, label=label, params=params, overrides=overrides, seed=spec.seed,
                     field=int(row["field"]), gains=setting.as_gains(), sim=sim, mpc=mpc,
                     dtype=str(meta["dtype"]))
