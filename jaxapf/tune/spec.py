"""The ``jaxapf tune`` spec file: TOML, validated into a :class:`TuneSpec`.

Every key is checked before anything is traced; an unknown key or a bad value raises
:class:`~jaxapf.validation.ConfigError` naming it (``train.learning_rate = -1.0 is out of range; ...``).
The keys, their defaults and ranges are listed in ``docs/tune.md``; :data:`SECTIONS` is the
authoritative list.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import itertools
import json
import math
import os
import pathlib
from typing import Any, Mapping, Sequence

import jax.numpy as jnp
import optax

from ..config import MPC_KEYS, SIM_KEYS, MPCConfig, SimConfig
from ..engine import gains_read
from ..gains import GAINS, Gains, check_gain_name, gains_from_mapping
from ..io.plugins import check_plugins, load_plugins
from ..scenarios import FAMILIES, FamilyParams
from ..sweep.spec import check_value, spec_family_params, variant_names
from ..validation import (
    MAX_SEED,
    MAX_SETTINGS,
    ConfigError,
    check_bool,
    check_choice,
    check_int,
    check_names,
    check_range,
    check_table,
    read_toml_file,
)
from .objective import Objective, Reparam

__all__ = [
    "SCHEDULES",
    "TEST_FAMILIES",
    "SECTIONS",
    "TrainSpec",
    "FieldSetSpec",
    "SearchSpec",
    "TuneSpec",
    "load_tune_spec",
    "parse_tune_spec",
    "make_schedule",
    "make_optimizer",
    "check_optimizer",
    "split_count",
    "MAX_HELD_FIELDS",
]

#: Most fields a set (training: steps × fields_per_step; validation; test) may hold: each set is
#: drawn up front, at up to ~0.5 kB a field (2 GB here).
MAX_HELD_FIELDS = 2**22

#: Default test families: every randomized family (the paper's two fixed scenarios need their own t_max).
TEST_FAMILIES: tuple[str, ...] = ("trap", "crossing", "head_on", "overtake", "clutter", "dynamic")
#: Learning-rate schedules: constant, cosine decay to 0 over ``steps``, linear warm-up then cosine.
SCHEDULES: tuple[str, ...] = ("constant", "cosine", "warmup_cosine")

#: Allowed keys of every section (``scenario`` holds one sub-table per family).
SECTIONS: Mapping[str, tuple[str, ...]] = {
    "": ("name", "plugins", "train", "validation", "test", "objective", "init", "tune", "sim", "scenario", "search"),
    "train": ("families", "fields_per_step", "steps", "seed", "optimizer", "learning_rate", "schedule",
              "warmup_steps", "clip", "episode_clip", "patience", "validate_every", "remat"),
    "validation": ("fields", "seed"),
    "test": ("families", "fields", "seed"),
    "objective": tuple(f.name for f in dataclasses.fields(Objective)),
    "tune": ("params", "upper"),
    "sim": SIM_KEYS + MPC_KEYS,
    "search": ("grid", "random_n", "random_range", "random_seed"),
}


def split_count(n: int, parts: int) -> tuple[int, ...]:
    """``n`` items over ``parts`` groups as evenly as possible, the first groups taking the remainder."""
    return tuple(n // parts + (i < n % parts) for i in range(parts))


def make_schedule(name: str, learning_rate: float, steps: int, warmup_steps: int) -> optax.Schedule:
    """``constant``; ``cosine`` decay from ``learning_rate`` to 0 over ``steps``; ``warmup_cosine``:
    linear from 0 over ``warmup_steps``, then cosine decay to 0 at ``steps``."""
    if name == "constant":
        return optax.constant_schedule(learning_rate)
    if name == "cosine":
        return optax.cosine_decay_schedule(learning_rate, max(steps, 1))
    return optax.warmup_cosine_decay_schedule(0.0, learning_rate, warmup_steps, max(steps, warmup_steps + 1))


def make_optimizer(name: str, schedule: optax.Schedule, clip: float) -> optax.GradientTransformation:
    """``clip_by_global_norm(clip)`` followed by the optax optimiser ``name`` on ``schedule``
    (``name`` checked by :func:`check_optimizer`)."""
    return optax.chain(optax.clip_by_global_norm(clip), getattr(optax, name)(learning_rate=schedule))


def check_optimizer(name: str) -> str:
    """``name`` if it is an optax function taking ``learning_rate`` whose
    ``update(grads, state, params)`` needs nothing else (so not ``lbfgs``), tried on a
    one-parameter problem; :class:`ConfigError` naming ``train.optimizer`` otherwise."""
    factory = getattr(optax, name, None) if isinstance(name, str) else None
    hint = "an optax optimiser taking learning_rate, e.g. adam, adamw, sgd, rmsprop, lion, adabelief"
    if factory is None or name.startswith("_") or not callable(factory):
        raise ConfigError(f"train.optimizer = {name!r} is not {hint}")
    try:
        if "learning_rate" not in inspect.signature(factory).parameters:
            raise TypeError
        opt = make_optimizer(name, 0.1, 1.0)
        probe = {"x": jnp.zeros(())}
        opt.update(probe, opt.init(probe), probe)
    except (TypeError, ValueError):
        raise ConfigError(f"train.optimizer = {name!r} is not {hint}") from None
    return name


# --------------------------------------------------------------------------------------------
# sections
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class TrainSpec:
    """``[train]``: training fields, optimiser and stopping (ranges in docs/tune.md)."""

    families: tuple[str, ...] = ("crossing", "trap")
    fields_per_step: int = 16
    steps: int = 200
    seed: int = 0
    optimizer: str = "adam"
    learning_rate: float = 0.05
    schedule: str = "cosine"
    warmup_steps: int = 0
    clip: float = 1.0
    episode_clip: float = 1.0
    patience: int = 5
    validate_every: int = 10
    remat: bool = True


@dataclasses.dataclass(frozen=True)
class FieldSetSpec:
    """``[validation]`` / ``[test]``: a fixed set of fields. ``fields`` is the total over the training
    families for validation, and per family for the test."""

    families: tuple[str, ...]
    fields: int
    seed: int


@dataclasses.dataclass(frozen=True)
class SearchSpec:
    """``[search]``: the searches tuning is compared with under the same budget: a grid (product of
    per-gain value lists) and a random search (``random_n`` settings, each tuned gain log-uniform in
    ``[x0/random_range, x0·random_range]`` around its start value ``x0``, or uniform over its tuning
    range when that is bounded, e.g. ``k`` in ``[0, 1]``)."""

    grid: tuple[tuple[str, tuple[float, ...]], ...] = (("gamma", (0.5, 1.0, 2.0, 4.0)), ("k", (0.0, 0.5, 1.0)))
    random_n: int = 32
    random_range: float = 4.0
    random_seed: int = 0

    def grid_settings(self, base: Gains) -> list[Gains]:
        """Every grid point (product in the order of the spec), on top of ``base``."""
        names = [n for n, _ in self.grid]
        return [gains_from_mapping(dict(zip(names, values)), "search.grid", base)
                for values in itertools.product(*(v for _, v in self.grid))]


@dataclasses.dataclass(frozen=True)
class TuneSpec:
    """A validated tune spec (frozen and hashable: the compiled training step takes it as a static
    argument). ``scenario`` holds ``(family, parameters)`` for every family used (defaults plus the
    ``[scenario.params.FAMILY]`` overrides), shared by training, validation and test."""

    name: str
    plugins: tuple[str, ...]
    train: TrainSpec
    validation: FieldSetSpec
    test: FieldSetSpec
    objective: Objective
    init: Gains
    reparam: Reparam
    sim: SimConfig
    mpc: MPCConfig
    scenario: tuple[tuple[str, FamilyParams], ...]
    search: SearchSpec

    def family(self, name: str) -> FamilyParams:
        """The scenario parameters of family ``name``."""
        return dict(self.scenario)[name]

    def as_dict(self) -> dict[str, Any]:
        """The resolved spec (every default filled in) as plain JSON types."""
        def plain(x: Any) -> Any:
            if isinstance(x, Gains):
                return x.floats()
            if dataclasses.is_dataclass(x):
                return {f.name: plain(getattr(x, f.name)) for f in dataclasses.fields(x)}
            if isinstance(x, (list, tuple)):
                return [plain(v) for v in x]
            if isinstance(x, float) and not math.isfinite(x):
                return str(x)
            return x

        out = plain(self)
        out["search"]["grid"] = {n: list(v) for n, v in self.search.grid}
        out["reparam"]["upper"] = dict(self.reparam.upper)
        out["scenario"] = {f: plain(p) | {"family": p.family} for f, p in self.scenario}
        return out

    def digest(self) -> str:
        """sha256 of the canonical JSON of :meth:`as_dict` (a checkpoint belongs to one spec)."""
        return hashlib.sha256(json.dumps(self.as_dict(), sort_keys=True).encode()).hexdigest()

    def schedule(self) -> optax.Schedule:
        """The learning rate as a function of the step."""
        t = self.train
        return make_schedule(t.schedule, t.learning_rate, t.steps, t.warmup_steps)

    def optimizer(self) -> optax.GradientTransformation:
        """Gradient clipping then the optimiser of ``[train]`` on :meth:`schedule`."""
        return make_optimizer(self.train.optimizer, self.schedule(), self.train.clip)


# --------------------------------------------------------------------------------------------
# parsing
# --------------------------------------------------------------------------------------------


def _table(data: Any, where: str) -> dict[str, Any]:
    return check_table(where, data, SECTIONS[where])


def _float(where: str, value: Any, lo: float | None = None, *, lo_open: bool = False) -> float:
    if isinstance(value, bool):
        raise ConfigError(f"{where} = {value!r} must be a number")
    return float(check_range(where, value, lo, lo_open=lo_open))


def _episode_clip(value: Any) -> float:
    """``train.episode_clip``: a number > 0 or ``inf`` (no per-episode clipping)."""
    if isinstance(value, float) and value == math.inf:
        return value
    return _float("train.episode_clip", value, 0.0, lo_open=True)


def _families(where: str, value: Any, choices: tuple[str, ...]) -> tuple[str, ...]:
    return check_names(where, value, choices, what="family or variant")


def _train(data: dict[str, Any], choices: tuple[str, ...]) -> TrainSpec:
    d = _table(data, "train")
    default = TrainSpec()
    get = lambda key: d.get(key, getattr(default, key))  # noqa: E731
    spec = TrainSpec(
        families=_families("train.families", get("families"), choices),
        fields_per_step=check_int("train.fields_per_step", get("fields_per_step"), 1, MAX_HELD_FIELDS),
        steps=check_int("train.steps", get("steps"), 1, MAX_HELD_FIELDS),
        seed=check_int("train.seed", get("seed"), 0, MAX_SEED),
        optimizer=check_optimizer(get("optimizer")),
        learning_rate=_float("train.learning_rate", get("learning_rate"), 0.0, lo_open=True),
        schedule=check_choice("train.schedule", get("schedule"), SCHEDULES),
        warmup_steps=check_int("train.warmup_steps", get("warmup_steps"), 0),
        clip=_float("train.clip", get("clip"), 0.0, lo_open=True),
        episode_clip=_episode_clip(get("episode_clip")),
        patience=check_int("train.patience", get("patience"), 1),
        validate_every=check_int("train.validate_every", get("validate_every"), 1),
        remat=check_bool("train.remat", get("remat")),
    )
    if spec.fields_per_step < len(spec.families):
        raise ConfigError(f"train.fields_per_step = {spec.fields_per_step} must be at least the number of "
                          f"train.families ({len(spec.families)}): every family is in every step")
    if spec.steps * spec.fields_per_step > MAX_HELD_FIELDS:
        raise ConfigError(f"train.steps × train.fields_per_step = {spec.steps * spec.fields_per_step:,} training "
                          f"fields; at most {MAX_HELD_FIELDS:,} are allowed (they are drawn up front): fewer "
                          "steps or fields per step")
    if spec.schedule == "warmup_cosine" and not 0 < spec.warmup_steps < max(spec.steps, 1):
        raise ConfigError(f"train.warmup_steps = {spec.warmup_steps} must lie in 1..steps-1 for warmup_cosine")
    return spec


def _field_set(data: dict[str, Any], where: str, families: tuple[str, ...] | None, default_fields: int,
               default_seed: int, choices: tuple[str, ...] = ()) -> FieldSetSpec:
    d = _table(data, where)
    fams = families if families is not None else _families(f"{where}.families", d.get("families", list(TEST_FAMILIES)),
                                                           choices)
    fields = check_int(f"{where}.fields", d.get("fields", default_fields), 1, MAX_HELD_FIELDS)
    if families is not None and fields < len(families):
        raise ConfigError(f"{where}.fields = {fields} must be at least the number of train.families ({len(families)})")
    return FieldSetSpec(fams, fields, check_int(f"{where}.seed", d.get("seed", default_seed), 0, MAX_SEED))


def _gains(table: Mapping[str, Any], where: str, base: Gains | None = None) -> Gains:
    """Gains from ``{name: number}`` on top of ``base``; errors name ``where.name``."""
    for name in table:
        check_gain_name(where, name)
    values = {k: _float(f"{where}.{k}", v) for k, v in table.items()}
    return gains_from_mapping(values, where, base)


def read_gains(sim: SimConfig) -> tuple[str, ...]:
    """The tunable gains the planner, filter and plant of ``sim`` read, in declaration order: what
    ``jaxapf tune`` learns unless ``[tune] params`` says otherwise."""
    read = gains_read(sim)
    return tuple(n for n, g in GAINS.items() if n in read and g.tunable)


def _tune(data: dict[str, Any], init: Gains, sim: SimConfig) -> Reparam:
    d = _table(data, "tune")
    params = d.get("params", list(read_gains(sim)))
    if not isinstance(params, list) or not all(isinstance(p, str) for p in params):
        raise ConfigError(f"tune.params = {params!r} must be a list of gain names")
    upper = check_table("tune.upper", d.get("upper", {}))
    for name, value in upper.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"tune.upper.{name} = {value!r} must be a number or inf")
    reparam = Reparam(tuple(params), init, tuple((k, float(v)) for k, v in upper.items()))
    reparam.theta(init)  # the start must be reachable
    return reparam


def _sim(data: dict[str, Any]) -> tuple[SimConfig, MPCConfig]:
    d = _table(data, "sim")
    for key, value in d.items():
        check_value(f"sim.{key}", key, value)
    return (SimConfig.from_flat({k: v for k, v in d.items() if k in SIM_KEYS}),
            MPCConfig(**{k: v for k, v in d.items() if k in MPC_KEYS}))


def _scenario(data: dict[str, Any], families: set[str]) -> tuple[tuple[str, FamilyParams], ...]:
    """``[scenario.params.FAMILY]`` tables, as in a sweep spec (docs/sweep.md)."""
    if not isinstance(data, dict):
        raise ConfigError("scenario must be a table holding [scenario.params.FAMILY] tables")
    extra = sorted(set(data) - {"params"})
    if extra:
        raise ConfigError(f"scenario.{extra[0]} is not allowed; family parameters go in "
                          f"[scenario.params.{extra[0]}], as in a sweep spec")
    params = data.get("params", {})
    if not isinstance(params, dict):
        raise ConfigError("scenario.params must be a table of [scenario.params.FAMILY] tables")
    for name in params:
        check_choice("scenario.params", name, FAMILIES.names() + variant_names(params))
    return tuple((f, spec_family_params(f, params.get(f, {}))) for f in sorted(families | set(params)))


def _search(data: dict[str, Any], reparam: Reparam) -> SearchSpec:
    d = _table(data, "search")
    default = SearchSpec()
    grid_raw = d.get("grid", {n: list(v) for n, v in default.grid})
    if not isinstance(grid_raw, dict) or not grid_raw:
        raise ConfigError("search.grid must be a non-empty table {gain = [values, ...]}")
    grid = []
    for name, values in grid_raw.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f"search.grid.{name} = {values!r} must be a non-empty list of numbers")
        if len(values) > MAX_SETTINGS:
            raise ConfigError(f"search.grid.{name} has {len(values):,} values; at most {MAX_SETTINGS:,} are allowed")
        grid.append((name, tuple(_gains({name: v}, "search.grid", reparam.base)[name] for v in values)))
    count = math.prod(len(v) for _, v in grid)
    if count > MAX_SETTINGS:
        raise ConfigError(f"search.grid expands to {count:,} settings; at most {MAX_SETTINGS:,} are allowed")
    return SearchSpec(
        grid=tuple(grid),
        random_n=check_int("search.random_n", d.get("random_n", default.random_n), 1, MAX_SETTINGS),
        random_range=_float("search.random_range", d.get("random_range", default.random_range), 1.0),
        random_seed=check_int("search.random_seed", d.get("random_seed", default.random_seed), 0, MAX_SEED),
    )


def parse_tune_spec(data: Mapping[str, Any], *, base: str | os.PathLike | None = None,
                    plugin_paths: Sequence[str] | None = None) -> TuneSpec:
    """A :class:`TuneSpec` from a parsed TOML mapping (see docs/tune.md for every key); ``base``:
    the folder relative ``.py`` plugin paths are read from (default the current directory), or
    ``plugin_paths``: what each plugin imports."""
    data = _table(dict(data), "")
    plugins = check_plugins("plugins", data.get("plugins", []))
    load_plugins(plugins, base=base, paths=plugin_paths)
    name = data.get("name", "tune")
    if not isinstance(name, str) or not name:
        raise ConfigError(f"name = {name!r} must be a non-empty string")
    scenario = data.get("scenario", {})
    choices = FAMILIES.names() + variant_names(scenario.get("params", {}) if isinstance(scenario, dict) else {})
    train = _train(data.get("train", {}), choices)
    validation = _field_set(data.get("validation", {}), "validation", train.families, 64, train.seed + 1)
    test = _field_set(data.get("test", {}), "test", None, 256, train.seed + 2, choices)
    seeds = {"train.seed": train.seed, "validation.seed": validation.seed, "test.seed": test.seed}
    if len(set(seeds.values())) != 3:
        raise ConfigError(f"train.seed, validation.seed and test.seed must differ (got {seeds}): "
                          "validation and test fields are never trained on")
    objective_kw = _table(data.get("objective", {}), "objective")
    objective = Objective(**{k: _float(f"objective.{k}", v) for k, v in objective_kw.items()})
    init = _gains(check_table("init", data.get("init", {})), "init")
    sim, mpc = _sim(data.get("sim", {}))
    reparam = _tune(data.get("tune", {}), init, sim)
    return TuneSpec(
        name=name, plugins=plugins, train=train, validation=validation, test=test, objective=objective, init=init,
        reparam=reparam, sim=sim, mpc=mpc,
        scenario=_scenario(scenario, set(train.families) | set(test.families)),
        search=_search(data.get("search", {}), reparam),
    )


def load_tune_spec(path: str | os.PathLike) -> tuple[TuneSpec, str]:
    """The validated spec of the TOML file at ``path`` and the file's text."""
    data, text = read_toml_file(path)
    return parse_tune_spec(data, base=pathlib.Path(path).parent), text
