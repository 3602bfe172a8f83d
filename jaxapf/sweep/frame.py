"""One call from a notebook to a table: fields × gain settings → the rows a sweep would write.

:func:`evaluate_frame` runs :func:`~jaxapf.engine.evaluate` on fields ``0 … F-1`` of a family and
returns its (G, F) metric arrays as a :class:`pandas.DataFrame` with a sweep's columns
(docs/sweep-format.md): it states the call as a sweep spec (:func:`jaxapf.sweep.parse_spec`, one
``[[setting]]`` table per gain setting) and builds the rows with the sweep's own code
(:func:`jaxapf.sweep.schema.part_table`), so column names, order and dtypes are those of
:func:`jaxapf.sweep.read_sweep`'s rows for the same study, and ``df.attrs["jaxapf"]`` is the
metadata a sweep part carries (``row_config(df.attrs["jaxapf"], row)`` re-simulates a row).
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any, Sequence

import numpy as np

from ..config import MPC_KEYS, SIM_KEYS, MPCConfig, SimConfig
from ..engine import default_width, evaluate
from ..gains import GAINS, Gains, setting_count, setting_shape
from ..metrics import METRICS
from ..scenarios import FamilyParams, family_params, make_scenarios
from ..scenarios import solvable as solvable_fields
from ..validation import BoundWarning, ConfigError, check_int
from .plan import Chunk, plan_sweep
from .schema import part_table, schema
from .spec import SweepSpec, parse_spec

__all__ = ["evaluate_frame"]


def _plain(value: Any) -> Any:
    """A configuration value as a spec writes it: tuples as lists."""
    return list(value) if isinstance(value, tuple) else value


def _changed(config: Any, default: Any, keys: Sequence[str]) -> dict[str, Any]:
    return {k: _plain(config[k]) for k in keys if config[k] != default[k]}


def evaluate_frame(family: str | FamilyParams, gains: Gains | None = None, sim: SimConfig | None = None,
                   mpc: MPCConfig | None = None, *, fields: int, seed: int = 0,
                   metrics: Sequence[str] | None = None, width: int | None = None, streaming: bool = True,
                   solvable: bool = False) -> "pd.DataFrame":  # noqa: F821
    """Every (gain setting, field) episode of ``family`` as a table: one row per episode, with the
    columns of a sweep's rows (:func:`jaxapf.sweep.read_sweep`).

    Args:
      family: a family's name, or its :class:`~jaxapf.scenarios.FamilyParams` (``family_params("trap",
        max_obstacles=8)``) for changed parameters.
      gains: G gain settings (default: one, the declared defaults): ``Gains.grid(gamma=[...], k=[...])``
        for every combination, ``Gains(gamma=[...], k=[...])`` (or ``Gains.paired``) for paired lists.
      sim, mpc: static settings (default: :class:`SimConfig` with the family's ``t_max``, :class:`MPCConfig`).
      fields: the number of fields F; field ``i`` is ``make_scenarios(seed, params, [i])``, the same
        field a sweep with this seed flies.
      metrics, width, streaming: as :func:`~jaxapf.engine.evaluate` (default: every metric).
      solvable: add the ``solvable`` column (:func:`~jaxapf.scenarios.solvable`, a sweep's ``oracle``).

    Returns:
      A DataFrame of G·F rows, settings-major: ``setting`` (0 … G-1, the position in ``gains``),
      ``method``, ``convention``, the gains a sweep gives a column (those the components read and those
      given as lists or changed from their defaults), ``t_max`` and the static settings changed from
      their defaults, ``family``, ``kind``, ``field``, ``seed``, [``solvable``], then the metrics. The
      metric values are ``evaluate``'s arrays: ``df[m].to_numpy().reshape(G, F) == evaluate(...)[m]``.
      ``df.attrs["jaxapf"]`` holds the sweep metadata (docs/sweep-format.md).

    Raises:
      ConfigError: one line, for an unknown family, method or metric, a gain out of range, lists of
        gains of different lengths, or a bad number of fields.
    """
    import jax

    params, gains = _checked(family, gains, sim, mpc)
    fields = check_int("evaluate_frame: fields", fields, 1)
    count = setting_count(gains, "evaluate_frame: gains")
    names = METRICS.names() if metrics is None else tuple(metrics)
    for m in names:
        METRICS.get(m, "evaluate_frame: metrics")
    sim = sim or SimConfig.from_flat(t_max=params.t_max)
    mpc = mpc or MPCConfig()
    spec = _as_spec(params, gains, sim, mpc, fields, seed, solvable, count)
    name = params.family

    scenarios = make_scenarios(seed, params, fields)
    arrays = evaluate(scenarios, gains, sim, mpc, width, names, streaming=streaming)
    plan = plan_sweep(spec, chunk_fields=fields, devices=1, width=width or default_width(), metrics=names)
    host = {m: np.asarray(a).reshape(count, fields) for m, a in jax.device_get(arrays).items()}
    oracle = None
    if solvable:
        oracle = solvable_fields(jax.device_get(scenarios), r_uav=sim.vehicle.r_uav, v_max=sim.vehicle.v_max,
                                 t_max=sim.episode.t_max, r_goal=sim.episode.r_goal)
    rows = part_table(plan, schema(plan), Chunk(0, name, 0, fields), host, np.asarray(scenarios.kind), oracle)
    frame = rows.to_pandas()
    frame.attrs["jaxapf"] = dict(plan.meta)
    return frame


def _checked(family: Any, gains: Any, sim: Any, mpc: Any) -> tuple[FamilyParams, Gains]:
    """:func:`evaluate_frame`'s family, gains and configurations checked: the family's parameters and the gains."""
    if isinstance(family, FamilyParams):
        params = family
    elif isinstance(family, str):
        params = family_params(family)
    else:
        raise ConfigError(f"evaluate_frame: family = {family!r} must be a family's name or its FamilyParams")
    gains = Gains() if gains is None else gains
    if not isinstance(gains, Gains):
        raise ConfigError(f"evaluate_frame: gains must be a Gains (Gains.grid(...), Gains(...)), "
                          f"got {type(gains).__name__}")
    if sim is not None and not isinstance(sim, SimConfig):
        raise ConfigError(f"evaluate_frame: sim must be a SimConfig (SimConfig.from_flat(...)), "
                          f"got {type(sim).__name__}")
    if mpc is not None and not isinstance(mpc, MPCConfig):
        raise ConfigError(f"evaluate_frame: mpc must be an MPCConfig, got {type(mpc).__name__}")
    return params, gains


def _as_spec(params: FamilyParams, gains: Gains, sim: SimConfig, mpc: MPCConfig, fields: int, seed: int,
             solvable: bool, count: int) -> SweepSpec:
    """The call as a sweep spec: its settings, columns and metadata are the sweep's; refused where
    ``sim``/``mpc`` cannot be written as a sweep's settings."""
    name = params.family
    values = {k: np.asarray(v, np.float64) for k, v in gains.items()}
    listed = [k for k, v in values.items() if setting_shape(k, v)]
    arrays = {k: v.tolist() for k, v in values.items()
              if k not in listed and GAINS.get(k).shape and v.tolist() != list(GAINS.get(k).default)}
    defaults = {k: spec.default for k, spec in GAINS.items()}
    overrides = _changed(dataclasses.asdict(params), dataclasses.asdict(family_params(name)),
                         [f.name for f in dataclasses.fields(params)])
    table: dict[str, Any] = {
        "name": "evaluate_frame",
        "scenario": {"families": [name], "fields": fields, "seed": seed, "oracle": bool(solvable),
                     "params": {name: overrides} if overrides else {}},
        "sim": {**_changed(sim.flat(), SimConfig().flat(), SIM_KEYS), "t_max": sim.episode.t_max,
                **_changed(dataclasses.asdict(mpc), dataclasses.asdict(MPCConfig()), MPC_KEYS)},
        "gains": {k: float(v) for k, v in values.items() if not v.ndim and float(v) != defaults[k]} | arrays,
    }
    if listed:
        table["setting"] = [{k: values[k][g].tolist() for k in listed} for g in range(count)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BoundWarning)  # Gains(...) warned already, where the user wrote it
        spec = parse_spec(table)
    if spec.configs(spec.settings()[0].static, name) != (sim, mpc):  # a setting the spec cannot state
        raise ConfigError("evaluate_frame: this sim/mpc cannot be written as a sweep's settings; use evaluate()")
    return spec
