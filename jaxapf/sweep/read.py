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
from .output import read_part
from .schema import identity, read_meta
from .spec import SweepSpec

__all__ = ["read_sweep", "RowConfig", "row_config", "sweep_spec"]


def read_sweep(path: str | os.PathLike) -> tuple["pd.DataFrame", dict[str, Any]]:  # noqa: F821
    """The rows of a sweep output (sorted by setting, family in spec order, field) and its metadata.

    ``path`` is the output directory (every visible ``*.parquet`` in it is a part) or one part file.
    The metadata is the parts' ``jaxapf`` object (docs/sweep-format.md) plus ``parts`` (number of
    part files), ``rows_expected`` (from the spec; None if the spec cannot be expanded),
    ``complete`` (every (setting, family, field) present) and ``location`` (the output folder,
    absolute: a ``.py`` plugin is looked for there first, :func:`sweep_spec`). Every part is verified (its page CRCs
    and content hash, :func:`~jaxapf.sweep.output.read_part`). Raises :class:`ConfigError` for a
    path that is not a sweep output, a damaged part, or parts of different sweeps.
    """
    import pyarrow as pa

    path = pathlib.Path(path)
    if not path.exists():
        raise ConfigError(f"{path}: no such file or directory")
    parts = sorted(p for p in path.glob("*.parquet") if p.is_file() and not p.name.startswith((".", "_"))) \
        if path.is_dir() else [path]
    if not parts:
        raise ConfigError(f"{path} is not the output of jaxapf sweep: the directory holds no Parquet part file")
    metas, tables = [], []
    for p in parts:  # every part verified before the parts are compared with each other
        metas.append(read_meta(p))
        try:
            tables.append(read_part(p))
        except ConfigError as err:
            raise ConfigError(f"{path}: damaged part {err}; rerun the sweep with --repair to recompute it") from None
    if len({json.dumps(identity(m), sort_keys=True) for m in metas}) > 1:
        raise ConfigError(f"{path} mixes parts of different sweeps (their spec_hash, dtype, vmap_width or metrics "
                          "differ)")
    try:
        df = pa.concat_tables(tables).to_pandas()
    except (OSError, pa.ArrowException) as err:
        raise ConfigError(f"{path} is not a readable sweep output (Parquet): {first_line(err)}") from None
    meta = {**metas[0], "location": str((path if path.is_dir() else path.parent).resolve())}
    if {"setting", "family", "field"} <= set(df.columns):
        families = list(meta.get("spec", {}).get("scenario", {}).get("families", []))
        rank = {f: i for i, f in enumerate(families + sorted(set(df["family"]) - set(families)))}
        df = (df.assign(_rank=df["family"].map(rank)).sort_values(["setting", "_rank", "field"], kind="stable")
              .drop(columns="_rank").reset_index(drop=True))
    try:
        spec = sweep_spec(meta)
        expected = len(spec.settings()) * len(spec.families) * spec.fields
    except (KeyError, TypeError, ConfigError):
        expected = None
    return df, {**meta, "parts": len(parts), "rows_expected": expected, "complete": len(df) == expected}


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


def sweep_spec(meta: Mapping[str, Any]) -> SweepSpec:
    """The spec of a sweep's metadata (``meta`` from :func:`read_sweep`), its plugins imported: a
    ``.py`` plugin from its path relative to the output folder (``location``) if it is there (a
    dataset moved together with its plugin), else from the absolute path recorded by the sweep;
    metadata without ``plugin_files`` (older sweeps) reads relative paths from the current directory."""
    files = meta.get("plugin_files") or []
    names = list(meta["spec"].get("plugins", []))
    if not files or len(files) != len(names):
        return SweepSpec.from_json(meta["spec"])
    location = meta.get("location")
    paths = []
    for name, rec in zip(names, files):
        if not isinstance(rec, Mapping) or "path" not in rec:
            paths.append(name)
            continue
        near = ([str((pathlib.Path(location) / rec["from_output"]).resolve())]
                if location and rec.get("from_output") else [])
        paths.append(next((c for c in near if pathlib.Path(c).is_file()), str(rec["path"])))
    return SweepSpec.from_json(meta["spec"], plugin_paths=paths)


def row_config(meta: Mapping[str, Any], row: Mapping[str, Any]) -> RowConfig:
    """The configuration of one output row (``meta`` from :func:`read_sweep`)."""
    spec = sweep_spec(meta)
    setting = spec.settings()[int(row["setting"])]
    label = str(row["family"])
    sim, mpc = spec.configs(setting.static, label)
    params = spec.family_params(label)
    overrides = {k: v for k, v in spec.params.get(label, {}).items() if k != "family"}
    return RowConfig(family=params.family, label=label, params=params, overrides=overrides, seed=spec.seed,
                     field=int(row["field"]), gains=Gains.unchecked(setting.gains), sim=sim, mpc=mpc,
                     dtype=str(meta["dtype"]))
