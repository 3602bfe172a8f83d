"""The ``jaxapf tune`` spec file: TOML, validated into a :class:`TuneSpec`.

Every key is checked before anything is traced; an unknown key or a bad value raises
:class:`~jaxapf.validation.ConfigError` naming it (``train.learning_rate = -1.0 is out of range; ...``).
The keys, their defaults and ranges are listed in ``docs/tune.md``; the schema
(:mod:`jaxapf.spec.schema`) is :func:`_schema`, with the defaults of :class:`TrainSpec`, :class:`SearchSpec` and
:class:`~jaxapf.tune.objective.Objective`.
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

from ..config import MPC_KEYS, SIM_KEYS, MPCConfig, PlannerConfig, SimConfig, VehicleConfig
from ..control import scales_set
from ..engine import gains_read
from ..gains import GAINS, Gains, check_gain_name, gains_from_mapping
from ..scenarios import FAMILIES, FamilyParams
from ..spec.plugins import check_plugins, load_plugins
from ..spec.scenario import spec_family_params, variant_names
from ..spec.schema import OMIT, REQUIRED, SEED, Key, Table, boolean, choice, integer, names, number, value_grid
from ..spec.settings import setting_values, sim_configs
from ..validation import MAX_SETTINGS, ConfigError, check_choice, check_table, read_toml_file
from .estimators import ESTIMATORS
from .objective import Objective, Reparam

__all__ = [
    "SCHEDULES",
    "TUNERS",
    "TEST_FAMILIES",
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
#: The black-box tuners ``[search] tuners`` may name (:mod:`jaxapf.tune.searches`).
TUNERS: tuple[str, ...] = ("grid", "random", "cmaes", "sep_cmaes", "tpe")
#: Learning-rate schedules: constant, cosine decay to 0 over ``steps``, linear warm-up then cosine.
SCHEDULES: tuple[str, ...] = ("constant", "cosine", "warmup_cosine")

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
    """``[train]``: training fields, optimiser, stopping and the gradient estimator (``estimator``,
    with ``samples`` antithetic pairs of perturbations of size ``sigma`` in θ:
    :mod:`jaxapf.tune.estimators`; ranges in docs/tune.md)."""

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
    estimator: str = "pathwise"
    samples: int = 4
    sigma: float = 0.1


@dataclasses.dataclass(frozen=True)
class FieldSetSpec:
    """``[validation]`` / ``[test]``: a fixed set of fields. ``fields`` is the total over the training
    families for validation, and per family for the test."""

    families: tuple[str, ...]
    fields: int
    seed: int


@dataclasses.dataclass(frozen=True)
class SearchSpec:
    """``[search]``: the black-box tuners (``tuners``, of :data:`TUNERS`) flown beside the gradient one
    under the same budget: a grid (product of per-gain value lists), a random search (``random_n``
    settings, each tuned gain log-uniform in ``[x0/random_range, x0·random_range]`` around its start
    value ``x0``, or uniform over its tuning range when that is bounded, e.g. ``k`` in ``[0, 1]``),
    CMA-ES (``popsize`` candidates a generation, 0: the library's ``4 + 3 ln n``; step ``cmaes_sigma``
    in θ) and TPE (``tpe_batch`` trials at a time over the random search's ranges), the last two on
    ``fields_per_setting`` fresh training fields per candidate (0: ``train.fields_per_step``)."""

    grid: tuple[tuple[str, tuple[float, ...]], ...] = (("gamma", (0.5, 1.0, 2.0, 4.0)), ("k", (0.0, 0.5, 1.0)))
    random_n: int = 32
    random_range: float = 4.0
    random_seed: int = 0
    tuners: tuple[str, ...] = ("grid", "random")
    fields_per_setting: int = 0
    popsize: int = 0
    cmaes_sigma: float = 1.0
    tpe_batch: int = 8

    def grid_settings(self, base: Gains) -> list[Gains]:
        """Every grid point (product in the order of the spec), on top of ``base``."""
        names = [n for n, _ in self.grid]
        return [gains_from_mapping(dict(zip(names, values)), "search.grid", base)
                for values in itertools.product(*(v for _, v in self.grid))]


def _drop_newer_gains(tree: Any) -> None:
    """Remove the gains declared after the tune digest was fixed (the MPPI, keep-out MPC and learned-weight
    planners') at their defaults from every gains table in ``tree`` (in place)."""
    from ..planners.keepout_mpc import KMPC_GAINS
    from ..planners.learned import OMEGA_PARAMS
    from ..planners.mppi import MPPI_GAINS

    newer = (*MPPI_GAINS, *KMPC_GAINS, OMEGA_PARAMS)
    if isinstance(tree, dict):
        if all(g.name in tree for g in newer):
            for g in newer:
                value = tuple(tree[g.name]) if isinstance(tree[g.name], list) else tree[g.name]
                if value == g.default:
                    del tree[g.name]
        for value in tree.values():
            _drop_newer_gains(value)
    elif isinstance(tree, list):
        for value in tree:
            _drop_newer_gains(value)


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
        # settings newer than the digests: at their defaults, the digest every spec had before (its checkpoints resume)
        if not self.sim.world.max_neighbours:
            del out["sim"]["world"]["max_neighbours"]
        if not self.sim.planner.projection_rows:
            del out["sim"]["planner"]["projection_rows"]
        if self.sim.planner.tracking == "mpc":
            del out["sim"]["planner"]["tracking"]
        if self.sim.planner.mppi_samples == PlannerConfig().mppi_samples:
            del out["sim"]["planner"]["mppi_samples"]
        if self.sim.vehicle.airframe == VehicleConfig().airframe:
            del out["sim"]["vehicle"]["airframe"]
        _drop_newer_gains(out)
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


def _keys(cls: type, readers: Mapping[str, Any]) -> Table:
    """The table of a section whose keys are the fields of ``cls`` (a dataclass of defaults), each read
    by its reader in ``readers``; a field without a default is required."""
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    return Table({k: Key(read, defaults.get(k, REQUIRED)) for k, read in readers.items()})


def _gains(where: str, table: Any, base: Gains | None = None) -> Gains:
    """Gains from ``{name: number}`` on top of ``base``; errors name ``where.name``."""
    table = check_table(where, table)
    for name in table:
        check_gain_name(where, name)
    return gains_from_mapping({k: number()(f"{where}.{k}", v) for k, v in table.items()}, where, base)


def read_gains(sim: SimConfig) -> tuple[str, ...]:
    """The tunable gains the components of ``sim`` read (the MPC's weight scales only where
    ``mpc_weights = "gains"``), in declaration order: what ``jaxapf tune`` learns unless ``[tune]
    params`` says otherwise."""
    read = gains_read(sim)
    return tuple(n for n, g in GAINS.items() if n in read and g.tunable)


def _gain_names(where: str, value: Any) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(p, str) for p in value):
        raise ConfigError(f"{where} = {value!r} must be a list of gain names")
    return tuple(value)


def _uppers(where: str, value: Any) -> tuple[tuple[str, float], ...]:
    table = check_table(where, value)
    for name, v in table.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(f"{where}.{name} = {v!r} must be a number or inf")
    return tuple((k, float(v)) for k, v in table.items())


def _schema(choices: tuple[str, ...]) -> Table:
    """The tune spec's schema, given the families and variants it may name (docs/tune.md)."""
    families = names(choices, "family or variant")
    train = _keys(TrainSpec, {
        "families": families, "fields_per_step": integer(1, MAX_HELD_FIELDS), "steps": integer(1, MAX_HELD_FIELDS),
        "seed": SEED, "optimizer": lambda where, value: check_optimizer(value),
        "learning_rate": number(0.0, lo_open=True), "schedule": choice(SCHEDULES), "warmup_steps": integer(0),
        "clip": number(0.0, lo_open=True), "episode_clip": number(0.0, lo_open=True, inf=True),
        "patience": integer(1), "validate_every": integer(1),
        "remat": boolean, "estimator": choice(ESTIMATORS), "samples": integer(1, 4096),
        "sigma": number(0.0, lo_open=True)})
    fields = integer(1, MAX_HELD_FIELDS)
    return Table({
        "name": Key(_text, "tune"), "plugins": Key(check_plugins, []), "train": Key(train, {}),
        "validation": Key(Table({"fields": Key(fields, 64), "seed": Key(SEED, OMIT)}), {}),
        "test": Key(Table({"families": Key(families, TEST_FAMILIES), "fields": Key(fields, 256),
                           "seed": Key(SEED, OMIT)}), {}),
        "objective": Key(_keys(Objective, {f.name: number() for f in dataclasses.fields(Objective)}), {}),
        "init": Key(_gains, {}),
        "tune": Key(Table({"params": Key(_gain_names, OMIT), "upper": Key(_uppers, {})}), {}),
        "sim": Key(setting_values(SIM_KEYS + MPC_KEYS), {}),
        "scenario": Key(_scenario, {}),
        "search": Key(Table({"grid": Key(value_grid(lambda where, gain, value: number()(where, value),
                                                    check_key=check_gain_name, empty=_EMPTY_GRID),
                                         {n: list(v) for n, v in SearchSpec.grid}),
                             "random_n": Key(integer(1, MAX_SETTINGS), SearchSpec.random_n),
                             "random_range": Key(number(1.0), SearchSpec.random_range),
                             "random_seed": Key(SEED, SearchSpec.random_seed),
                             "tuners": Key(_tuners, list(SearchSpec.tuners)),
                             "fields_per_setting": Key(integer(0, MAX_HELD_FIELDS), SearchSpec.fields_per_setting),
                             "popsize": Key(integer(0, MAX_SETTINGS), SearchSpec.popsize),
                             "cmaes_sigma": Key(number(0.0, lo_open=True), SearchSpec.cmaes_sigma),
                             "tpe_batch": Key(integer(1, MAX_SETTINGS), SearchSpec.tpe_batch)}), {}),
    })


#: The library each black-box tuner needs beyond the core install (the ``tune`` extra).
TUNER_PACKAGES: dict[str, str] = {"cmaes": "cmaes", "sep_cmaes": "cmaes", "tpe": "optuna"}


def _tuners(where: str, value: Any) -> tuple[str, ...]:
    """Distinct names of :data:`TUNERS` whose library is installed."""
    import importlib.util

    chosen = names(TUNERS, "tuner")(where, value)
    for i, name in enumerate(chosen):
        package = TUNER_PACKAGES.get(name)
        if package and importlib.util.find_spec(package) is None:
            raise ConfigError(f"{where}[{i}] = {name!r} needs the {package} package: pip install 'jaxapf[tune]'")
    return tuple(chosen)


_EMPTY_GRID = "search.grid must be a non-empty table {gain = [values, ...]}"


def _text(where: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{where} = {value!r} must be a non-empty string")
    return value


def _scenario(where: str, data: Any) -> tuple[tuple[str, dict], ...]:
    """``[scenario.params.FAMILY]`` tables, as in a sweep spec (docs/sweep.md); resolved once the
    families the spec uses are known."""
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
    return tuple(params.items())


def parse_tune_spec(data: Mapping[str, Any], *, base: str | os.PathLike | None = None,
                    plugin_paths: Sequence[str] | None = None, start: bool = True) -> TuneSpec:
    """A :class:`TuneSpec` from a parsed TOML mapping (see docs/tune.md for every key); ``base``:
    the folder relative ``.py`` plugin paths are read from (default the current directory), or
    ``plugin_paths``: what each plugin imports. ``start``: a search will start from ``init`` (the
    gradient tuner, CMA-ES), so its θ must exist; a compare selection that only scores given settings
    (random, grid) passes False, as a default on a closed bound (``cbf_brake`` = 0.5) has none."""
    data = check_table("", dict(data))
    plugins = check_plugins("plugins", data.get("plugins", []))
    load_plugins(plugins, base=base, paths=plugin_paths)
    scenario = data.get("scenario", {})
    choices = FAMILIES.names() + variant_names(scenario.get("params", {}) if isinstance(scenario, dict) else {})
    d = _schema(choices)("", data)
    train = TrainSpec(**d["train"])
    if train.fields_per_step < len(train.families):
        raise ConfigError(f"train.fields_per_step = {train.fields_per_step} must be at least the number of "
                          f"train.families ({len(train.families)}): every family is in every step")
    if train.steps * train.fields_per_step > MAX_HELD_FIELDS:
        raise ConfigError(f"train.steps × train.fields_per_step = {train.steps * train.fields_per_step:,} training "
                          f"fields; at most {MAX_HELD_FIELDS:,} are allowed (they are drawn up front): fewer "
                          "steps or fields per step")
    if train.estimator == "blend" and train.samples < 2:
        raise ConfigError(f"train.samples = {train.samples} must be at least 2 for train.estimator = 'blend' "
                          "(its mix weighs the variances of the pairs)")
    if train.schedule == "warmup_cosine" and not 0 < train.warmup_steps < max(train.steps, 1):
        raise ConfigError(f"train.warmup_steps = {train.warmup_steps} must lie in 1..steps-1 for warmup_cosine")
    validation = FieldSetSpec(train.families, d["validation"]["fields"], d["validation"].get("seed", train.seed + 1))
    if validation.fields < len(train.families):
        raise ConfigError(f"validation.fields = {validation.fields} must be at least the number of train.families "
                          f"({len(train.families)})")
    test = FieldSetSpec(d["test"]["families"], d["test"]["fields"], d["test"].get("seed", train.seed + 2))
    seeds = {"train.seed": train.seed, "validation.seed": validation.seed, "test.seed": test.seed}
    if len(set(seeds.values())) != 3:
        raise ConfigError(f"train.seed, validation.seed and test.seed must differ (got {seeds}): "
                          "validation and test fields are never trained on")
    init = d["init"]
    scaled = scales_set(init.floats(), varied=d["tune"].get("params", ())) + scales_set(dict(d["search"]["grid"]))
    sim, mpc = sim_configs(d["sim"], scaled)
    reparam = Reparam(d["tune"].get("params", read_gains(sim)), init, d["tune"]["upper"])
    if start:
        reparam.theta(init)  # the start must be reachable
    arrays = [n for n in reparam.names if GAINS.get(n).shape]
    ranged = [t for t in d["search"].get("tuners", SearchSpec.tuners) if t in ("random", "tpe")]
    if arrays and ranged:
        raise ConfigError(f"search.tuners: {ranged[0]} draws each tuned gain from a range, but {arrays[0]} holds "
                          f"{GAINS.get(arrays[0]).shape[0]:,} numbers; use cmaes or sep_cmaes (and grid) for it")
    grid = tuple((name, tuple(gains_from_mapping({name: v}, "search.grid", reparam.base)[name] for v in values))
                 for name, values in d["search"]["grid"])
    params = dict(d["scenario"])
    used = set(train.families) | set(test.families) | set(params)
    return TuneSpec(
        name=d["name"], plugins=plugins, train=train, validation=validation, test=test,
        objective=Objective(**d["objective"]), init=init, reparam=reparam, sim=sim, mpc=mpc,
        scenario=tuple((f, spec_family_params(f, params.get(f, {}))) for f in sorted(used)),
        search=SearchSpec(**(d["search"] | {"grid": grid})),
    )


def load_tune_spec(path: str | os.PathLike) -> tuple[TuneSpec, str]:
    """The validated spec of the TOML file at ``path`` and the file's text."""
    data, text = read_toml_file(path)
    return parse_tune_spec(data, base=pathlib.Path(path).parent), text
