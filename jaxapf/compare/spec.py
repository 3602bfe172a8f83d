"""The ``jaxapf compare`` spec: TOML, validated into a :class:`CompareSpec` before anything runs.

A comparison names the methods, how each gets its gains (``[selection]``: a search on training
fields under the same episode budget for every method, repeated for several selection seeds) and
the held-out test (``[test]``: fields and families never used in selection). ``docs/compare.md``
lists every key; an unknown key or a bad value raises :class:`~jaxapf.validation.ConfigError`
naming it.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
from typing import Any, Mapping

from ..config import STATIC_KEYS
from ..control import scales_set
from ..gains import GAINS, GainSpec
from ..planners import PLANNERS
from ..spec.plugins import check_plugins, load_plugins
from ..spec.scenario import spec_family_params, variant_names
from ..spec.schema import OMIT, REQUIRED, SEED, Key, Table, choice, given, integer, number, spec_name, value_grid
from ..spec.settings import RandomRange, check_value, parse_range, setting_values, traced_weights
from ..tune.spec import MAX_HELD_FIELDS
from ..validation import (
    MAX_FIELDS,
    MAX_SETTINGS,
    ConfigError,
    check_choice,
    check_names,
    check_table,
    did_you_mean,
    read_toml_file,
)

__all__ = ["SEARCHES", "MIN_SEEDS", "GRADIENT_KEYS", "CMAES_KEYS", "SelectionSpec", "TestSpec", "CompareSpec",
           "default_range", "parse_compare_spec", "load_compare_spec"]

#: How a method's gains are selected on the training fields.
SEARCHES: tuple[str, ...] = ("random", "grid", "gradient", "cmaes", "sep_cmaes")
#: ``[selection.cmaes]`` keys: CMA-ES's step in θ, its candidates a generation (0: the library's
#: ``4 + 3 ln n``) and the training fields each candidate flies (0: the gradient search's fields per step).
CMAES_KEYS: tuple[str, ...] = ("sigma", "popsize", "fields_per_candidate")
#: Fewest independent selections per method: one selection is an anecdote.
MIN_SEEDS = 3
#: ``[selection.gradient]`` keys: those of a tune spec's ``[train]`` that a comparison may set
#: (families, seed and steps come from ``[selection]`` and its budget), and ``validation_fields``.
GRADIENT_KEYS: tuple[str, ...] = ("fields_per_step", "optimizer", "learning_rate", "schedule", "warmup_steps",
                                  "clip", "episode_clip", "patience", "validate_every", "remat",
                                  "validation_fields")


def default_range(spec: GainSpec) -> RandomRange:
    """The random search's range of a gain the spec leaves open: uniform over a bounded tuning range
    (``k``: [0, 1], ``cbf_brake``: [0.05, 0.5]), else log-uniform within a factor 4 of the declared default."""
    if spec.tuning_high is not None:
        return RandomRange(spec.low, spec.tuning_high)
    return RandomRange(spec.default / 4.0, spec.default * 4.0, log=True)


@dataclasses.dataclass(frozen=True)
class SelectionSpec:
    """How every method's gains are selected (``[selection]``).

    Attributes:
      families: training families or variants (their fields come from each selection seed).
      seeds: independent selection seeds (>= :data:`MIN_SEEDS`): training fields, random draws.
      budget: episode rollouts per method and seed, the same for every method.
      search: ``random``, ``grid``, ``gradient``, ``cmaes`` or ``sep_cmaes`` (:data:`SEARCHES`), every
        method's unless ``searches`` names its own.
      searches: ``(method, search)`` for the methods searched otherwise (``[selection.searches]``; e.g. a
        learned weight's thousand parameters by ``gradient`` beside the paper's six gains by ``random``).
      candidates: settings of a random search (the method's defaults are the first).
      gains: the gains searched (a method searches those it reads).
      ranges: ``(gain, range)`` of the random search, one per searched gain.
      grid: ``(gain, values)`` of a grid search.
      gradient: ``(key, value)`` training options of a gradient search (:data:`GRADIENT_KEYS`).
      cmaes: ``(key, value)`` options of a CMA-ES search (:data:`CMAES_KEYS`).
      added: gains a scorecard searches for a method beyond its frozen ``gains`` (the last of ``gains``): each
        draws from a stream of its own, so the frozen ones draw what the zoo drew (:mod:`jaxapf.compare.select`).
    """

    families: tuple[str, ...]
    seeds: tuple[int, ...]
    budget: int
    search: str = "random"
    candidates: int = 32
    gains: tuple[str, ...] = ()
    ranges: tuple[tuple[str, RandomRange], ...] = ()
    grid: tuple[tuple[str, tuple[float, ...]], ...] = ()
    gradient: tuple[tuple[str, Any], ...] = ()
    searches: tuple[tuple[str, str], ...] = ()
    cmaes: tuple[tuple[str, Any], ...] = ()
    added: tuple[str, ...] = ()

    def search_of(self, method: str) -> str:
        """How ``method``'s gains are selected."""
        return dict(self.searches).get(method, self.search)


@dataclasses.dataclass(frozen=True)
class TestSpec:
    """The held-out test (``[test]``): ``fields`` per family of seed ``seed`` (no selection seed)."""

    families: tuple[str, ...]
    fields: int
    seed: int


@dataclasses.dataclass(frozen=True)
class CompareSpec:
    """A validated comparison: methods, selection, test, and the shared simulation settings.

    ``sim`` holds fixed static settings (``[sim]``, as in a sweep spec; not ``method``), ``gains``
    fixed gains no selection searches (``[gains]``: the world's, e.g. a wind to select and test in),
    ``params`` the ``[scenario.params.LABEL]`` tables of every family or variant used, ``objective``
    the surrogate loss's weights (``[objective]``: selection ties and the gradient search).
    """

    name: str
    methods: tuple[str, ...]
    baseline: str
    selection: SelectionSpec
    test: TestSpec
    sim: Mapping[str, Any]
    params: Mapping[str, Mapping[str, Any]]
    objective: Mapping[str, float]
    plugins: tuple[str, ...] = ()
    gains: Mapping[str, float] = dataclasses.field(default_factory=dict)
    #: what each plugin imported (a ``.py`` file's absolute path; relative ones from the spec file's folder)
    plugin_paths: tuple[str, ...] = dataclasses.field(default=(), compare=False)

    def settings(self, method: str) -> dict[str, str]:
        """The static settings of the compared ``method`` (``PLANNER`` or ``PLANNER+FILTER``):
        ``method``, and ``filter`` wherever some compared method names one (``none`` for the others,
        so the test sweep has a ``filter`` column to tell them apart)."""
        return _settings(method, self.methods)

    def method_gains(self, method: str) -> tuple[str, ...]:
        """The searched gains ``method`` reads (its planner's, plus the filter's and plant's:
        :func:`jaxapf.engine.gains_read`)."""
        read = _gains_read(self.sim, self.settings(method))
        return tuple(g for g in self.selection.gains if g in read)


def _settings(method: str, methods: tuple[str, ...]) -> dict[str, str]:
    """:meth:`CompareSpec.settings` of ``method`` among the compared ``methods``."""
    planner, _, safety_filter = method.partition("+")
    with_filter = any("+" in m for m in methods)
    return {"method": planner, **({"filter": safety_filter or "none"} if with_filter else {})}


def _gains_read(sim: Mapping[str, Any], settings: Mapping[str, str]) -> set[str]:
    from ..config import SIM_KEYS, SimConfig
    from ..engine import gains_read

    return set(gains_read(SimConfig.from_flat({**{k: v for k, v in sim.items() if k in SIM_KEYS}, **settings})))


def _methods(value: Any, sim: Mapping[str, Any]) -> tuple[str, ...]:
    """``methods``: registered planners, each optionally ``+FILTER`` (a registered safety filter)."""
    from ..control import FILTERS

    if not isinstance(value, list) or not all(isinstance(m, str) for m in value):
        raise ConfigError(f"methods = {value!r} must be a list of planner names (PLANNER or PLANNER+FILTER)")
    filters = tuple(f for f in FILTERS.names() if f != "none")
    for i, m in enumerate(value):
        planner, plus, safety_filter = m.partition("+")
        if planner not in PLANNERS.names():
            raise ConfigError(f"methods[{i}] = {m!r} is not a registered planner"
                              f"{did_you_mean(planner, PLANNERS.names())}; allowed: "
                              f"{', '.join(PLANNERS.names())}, each optionally +FILTER ({', '.join(filters)})")
        if plus:
            if safety_filter not in filters:
                raise ConfigError(f"methods[{i}] = {m!r}: {safety_filter!r} is not a registered safety filter"
                                  f"{did_you_mean(safety_filter, filters)}; "
                                  f"allowed after +: {', '.join(filters)}")
            if "filter" in sim:
                raise ConfigError(f"methods[{i}] = {m!r} names a filter and [sim] sets filter = {sim['filter']!r}; "
                                  "name filters in one place")
    if len(set(value)) != len(value):
        raise ConfigError(f"methods = {value!r} lists a method twice")
    if len(value) < 2:
        raise ConfigError(f"methods = {value!r} must list at least two planners")
    return tuple(value)


def _seeds(where: str, value: Any) -> tuple[int, ...]:
    if not isinstance(value, list):
        raise ConfigError(f"{where} = {value!r} must be a list of at least {MIN_SEEDS} distinct integers")
    seeds = tuple(SEED(f"{where}[{i}]", s) for i, s in enumerate(value))
    if len(set(seeds)) != len(seeds) or len(seeds) < MIN_SEEDS:
        raise ConfigError(f"{where} = {value!r} must list at least {MIN_SEEDS} distinct seeds: "
                          "each is an independent selection, and their spread is part of the result")
    return seeds


def _finite(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where} = {value!r} must be a number")
    return float(value)


def _schema() -> Table:
    """The compare spec's schema (docs/compare.md); the methods, the baseline, the families and gains
    of ``[selection]`` and its grid are read once ``[sim]`` and the methods are known."""
    from ..tune.objective import Objective

    return Table({
        "name": Key(spec_name(), "compare"),
        "plugins": Key(check_plugins, []),
        "methods": Key(given, REQUIRED, 'list the planners to compare, e.g. methods = ["basic", '
                                        '"direction_velocity"]'),
        "baseline": Key(given, OMIT),
        "selection": Key(Table({
            "families": Key(given, REQUIRED), "seeds": Key(_seeds, REQUIRED),
            "budget": Key(integer(1, MAX_HELD_FIELDS), REQUIRED), "search": Key(choice(SEARCHES), "random"),
            "candidates": Key(integer(1, MAX_SETTINGS), OMIT), "gains": Key(given, OMIT),
            "ranges": Key(given, {}), "grid": Key(given, OMIT), "gradient": Key(given, OMIT),
            "searches": Key(check_table, {}), "cmaes": Key(given, OMIT),
        }), REQUIRED, "add [selection] with families, seeds and budget"),
        "test": Key(Table({"families": Key(given, REQUIRED), "fields": Key(integer(1, MAX_FIELDS), REQUIRED),
                           "seed": Key(SEED, OMIT)}), REQUIRED, "add [test] with families and fields"),
        "sim": Key(setting_values(tuple(k for k in STATIC_KEYS if k != "method")), {}),
        "gains": Key(setting_values(GAINS.names()), {}),
        "scenario": Key(Table({"params": Key(check_table, {})}), {}),
        "objective": Key(Table({f.name: Key(_finite) for f in dataclasses.fields(Objective)}), {}),
    })


def _selection(d: Mapping[str, Any], choices: tuple[str, ...], read: Mapping[str, set[str]]) -> SelectionSpec:
    """``[selection]``; ``read``: the gains each compared method reads."""
    families = check_names("selection.families", d["families"], choices, what="family or variant")
    search = d["search"]
    searches = tuple((m, choice(SEARCHES)(f"selection.searches.{m}", v))
                     for m, v in check_table("selection.searches", d["searches"], tuple(read)).items())
    used = {search if m not in dict(searches) else dict(searches)[m] for m in read}
    tunable = tuple(n for n, g in GAINS.items() if g.tunable and n in set().union(*read.values()))
    gains = check_names("selection.gains", d.get("gains", list(tunable)), tunable, what="tunable gain read by "
                        "one of the methods", canonical=True)
    ranged = [g for g in gains if not GAINS.get(g).shape]  # a network's parameters have no range to draw from
    for m, names in read.items():
        arrays = [g for g in gains if g in names and GAINS.get(g).shape]
        how = dict(searches).get(m, search)
        if arrays and how in ("random", "grid"):
            raise ConfigError(f"selection: {m} reads {arrays[0]} ({GAINS.get(arrays[0]).shape[0]:,} numbers), which a "
                              f"{how} search cannot choose; give it selection.searches.{m} = \"gradient\", "
                              "\"cmaes\" or \"sep_cmaes\"")
    ranges_in = check_table("selection.ranges", d["ranges"], ranged)
    ranges = tuple((g, parse_range(f"selection.ranges.{g}", g, ranges_in[g]) if g in ranges_in
                    else default_range(GAINS.get(g))) for g in ranged)
    cmaes = ()
    if "cmaes" in d:
        if not used & {"cmaes", "sep_cmaes"}:
            raise ConfigError("selection.cmaes is for a cmaes or sep_cmaes search (no method's search is one)")
        table = check_table("selection.cmaes", d["cmaes"], CMAES_KEYS)
        cmaes = tuple((k, (number(0.0, lo_open=True) if k == "sigma" else integer(0, MAX_SETTINGS))(
            f"selection.cmaes.{k}", v)) for k, v in table.items())
    grid = ()
    if "grid" in used:
        read_grid = value_grid(lambda where, g, v: check_value(where, g, v), keys=gains,
                               empty="selection.grid is empty; a grid search needs values for at least one gain, "
                                     "e.g. grid = { k_rep = [5.0, 10.0, 20.0] }")
        given = dict(read_grid("selection.grid", d.get("grid", {})))
        grid = tuple((g, given[g]) for g in gains if g in given)
    elif "grid" in d:
        raise ConfigError(f"selection.grid is for search = \"grid\" (this spec's search is {search!r})")
    gradient = ()
    if "gradient" in d:
        if "gradient" not in used:
            raise ConfigError(f"selection.gradient is for search = \"gradient\" (this spec's search is {search!r})")
        gradient = tuple(check_table("selection.gradient", d["gradient"], GRADIENT_KEYS).items())
    if "candidates" in d and "random" not in used:
        raise ConfigError(f"selection.candidates is for search = \"random\" (this spec's search is {search!r})")
    return SelectionSpec(families=families, seeds=d["seeds"], budget=d["budget"], search=search,
                         candidates=d.get("candidates", 32), gains=gains, ranges=ranges, grid=grid, gradient=gradient,
                         searches=searches, cmaes=cmaes)


def parse_compare_spec(data: Mapping[str, Any], *, base: str | os.PathLike | None = None) -> CompareSpec:
    """A :class:`CompareSpec` from a parsed TOML mapping (every key checked; docs/compare.md);
    ``base``: the folder relative ``.py`` plugin paths are read from (default the current directory)."""
    from ..scenarios import FAMILIES
    from ..tune.objective import Objective

    data = check_table("", dict(data))
    plugins = check_plugins("plugins", data.get("plugins", []))
    paths = load_plugins(plugins, base=base)
    d = _schema()("", data)
    # a searched MPC weight scale traces the MPC's weights, as in sweep and tune specs
    named = [g for part in (d["selection"].get(k) for k in ("gains", "ranges", "grid"))
             if isinstance(part, (list, dict)) for g in part if isinstance(g, str)]  # bad ones: refused below
    sim = traced_weights(d["sim"], scales_set({}, varied=named))
    methods = _methods(d["methods"], sim)
    baseline = check_choice("baseline", d.get("baseline", methods[0]), methods)
    tables = d["scenario"]["params"]
    choices = FAMILIES.names() + variant_names(tables)
    read = {m: _gains_read(sim, _settings(m, methods)) for m in methods}
    selection = _selection(d["selection"], choices, read)
    for gain in d["gains"]:
        if gain in selection.gains:
            raise ConfigError(f"gains.{gain} is also searched (selection.gains); fix it in one place")
    test = d["test"]
    families = check_names("test.families", test["families"], choices, what="family or variant")
    seed = test.get("seed", max(selection.seeds) + 1)
    if seed in selection.seeds:
        raise ConfigError(f"test.seed = {seed} is also a selection seed; the test fields must be held out")
    used = set(selection.families) | set(families)
    for label in tables:
        if label not in used:
            raise ConfigError(f"scenario.params.{label} is not one of selection.families or test.families")
    params = {label: dict(check_table(f"scenario.params.{label}", tables.get(label, {}))) for label in sorted(used)}
    for label, table in params.items():
        spec_family_params(label, table)
    Objective(**d["objective"])
    return CompareSpec(name=d["name"], methods=methods, baseline=baseline, selection=selection,
                       test=TestSpec(families=families, fields=test["fields"], seed=seed), sim=sim, params=params,
                       objective=d["objective"], plugins=plugins, gains=d["gains"], plugin_paths=paths)


def load_compare_spec(path: str | os.PathLike) -> tuple[CompareSpec, str]:
    """The validated spec of the TOML file at ``path`` and the file's text."""
    data, text = read_toml_file(path)
    return parse_compare_spec(data, base=pathlib.Path(path).parent), text
