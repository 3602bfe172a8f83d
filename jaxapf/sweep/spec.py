"""Sweep specifications: a study stated as a TOML file, validated completely before anything runs.

:func:`load_spec` parses and checks a spec (scenario families and fields, fixed settings, and the
settings to vary: ``[grid]``, ``[random]`` gain samples or ``[[setting]]`` tables) into a
:class:`SweepSpec`, whose :meth:`SweepSpec.settings` expands it, once, into the settings every field is
flown with. Gains are traced (any number share one program); static settings make variants, each with its
own program. The language, the expansion order and the random samples: docs/sweep.md. Every error is a
:class:`~jaxapf.validation.ConfigError` naming the key.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import itertools
import json
import math
import os
import pathlib
import re
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from ..config import STATIC_KEYS, MPCConfig, SimConfig
from ..control import scales_set
from ..engine.components import COMPONENTS
from ..gains import GAINS, Gains, read_gains_file
from ..metrics import METRICS
from ..scenarios import FAMILIES, FamilyParams
from ..scenarios.swarms import SWARM_FAMILIES, SwarmParams
from ..spec.plugins import check_plugins, load_plugins
from ..spec.scenario import spec_family_params, variant_names
from ..spec.schema import OMIT, REQUIRED, SEED, Key, Table, boolean, given, integer, spec_name, value_grid
from ..spec.settings import RandomRange, check_value, parse_range, setting_values, sim_configs
from ..validation import MAX_FIELDS, MAX_SETTINGS, ConfigError, check_int, check_names, check_table, read_toml_file

__all__ = ["Setting", "SweepSpec", "load_spec", "parse_spec", "read_toml"]

_RANDOM_KEYS = ("n", "seed")
_TAG = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
#: Columns of every sweep row that a tag may not shadow.
_RESERVED_COLUMNS = frozenset({"setting", "family", "kind", "agents", "field", "seed", "solvable"})


# --------------------------------------------------------------------------------------------
# the spec
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Setting:
    """One entry of the expanded spec: every setting key the spec fixes or varies.

    Attributes:
      index: position in :meth:`SweepSpec.settings` (the ``setting`` column).
      gains: the full gain setting (defaults of :class:`Gains` for keys the spec does not name; an
        array-valued gain as a tuple).
      static: the static settings the spec names (fixed ``[sim]`` values and static grid axes),
        in :data:`STATIC_KEYS` order; everything else keeps its :class:`SimConfig` /
        :class:`MPCConfig` default, except ``t_max``, whose default is the family's.
    """

    index: int
    gains: Mapping[str, float | tuple[float, ...]]
    static: tuple[tuple[str, Any], ...]
    tags: tuple[tuple[str, Any], ...] = ()

    def as_gains(self) -> Gains:
        """The gains as :class:`Gains` (an array-valued gain, a tuple here so settings compare, as an array)."""
        return Gains.unchecked({k: np.asarray(v, np.float64) if isinstance(v, tuple) else v
                                for k, v in self.gains.items()})


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """A validated sweep specification (see the module docstring and docs/sweep.md).

    Attributes:
      name: the study's name (letters, digits, ``_ . -``).
      plugins: modules registering components the spec uses (imported by :func:`parse_spec`), as
        written (so the hash does not depend on where the spec lies).
      plugin_paths: what each plugin imported: a ``.py`` file's absolute path (a relative one read
        from the spec file's folder), a module's name; not part of the spec's JSON or hash.
      families: scenario families (SPEC 5), in the spec's order.
      fields: randomized fields per family.
      seed: scenario seed; field ``i`` has key ``fold_in(key(seed), i)``.
      params: per-family (or per-variant) parameter overrides (validated by
        :func:`spec_family_params`), normalised; a variant's table names its ``family``.
      oracle: add the ``solvable`` column (:func:`~jaxapf.scenarios.solvable`; ``[scenario] oracle``,
        default true).
      sim: fixed static settings (``[sim]``).
      gains: fixed gains (``[gains]``, then ``--gains FILE`` on top).
      grid: ``(key, values)`` axes in the spec's order.
      random_n: number of random gain samples (0: no ``[random]``).
      random_seed: seed of the gain samples.
      random: ``(gain, range)`` in the spec's order.
      explicit: the ``[[setting]]`` tables: each a tuple of ``(key, value)`` in the spec's order.
      tags: each explicit setting's ``(tag, value)`` pairs (the same tags in every setting).
    """

    name: str
    families: tuple[str, ...]
    fields: int
    seed: int
    params: Mapping[str, Mapping[str, Any]]
    sim: Mapping[str, Any]
    gains: Mapping[str, float]
    grid: tuple[tuple[str, tuple[Any, ...]], ...] = ()
    random_n: int = 0
    random_seed: int = 0
    random: tuple[tuple[str, RandomRange], ...] = ()
    plugins: tuple[str, ...] = ()
    oracle: bool = True
    explicit: tuple[tuple[tuple[str, Any], ...], ...] = ()
    tags: tuple[tuple[tuple[str, Any], ...], ...] = ()
    plugin_paths: tuple[str, ...] = dataclasses.field(default=(), compare=False)

    def _replace_plugins(self, plugins: Sequence[str], paths: Sequence[str] | None) -> "SweepSpec":
        """This spec naming ``plugins`` (imported by whoever registered their components)."""
        return dataclasses.replace(self, plugins=tuple(plugins), plugin_paths=tuple(paths or plugins))

    # ---- canonical form -----------------------------------------------------------------

    def to_json(self) -> dict[str, Any]:
        """The spec as a JSON object (stored in every output part; order-preserving lists for the
        grid and random axes, so the hash sees their order; ``plugins`` only when there are some)."""
        plugins = {"plugins": list(self.plugins)} if self.plugins else {}
        explicit = {"setting": [{**{k: list(v) if isinstance(v, tuple) else v for k, v in entry},
                                 **({"tags": dict(tags)} if tags else {})}
                                for entry, tags in zip(self.explicit, self.tags or [()] * len(self.explicit))]}
        return {
            "name": self.name,
            **plugins,
            "scenario": {"families": list(self.families), "fields": self.fields, "seed": self.seed,
                         "params": {f: dict(p) for f, p in self.params.items()}, "oracle": self.oracle},
            "sim": dict(self.sim),
            "gains": dict(self.gains),
            "grid": [[key, list(values)] for key, values in self.grid],
            "random": None if not self.random_n else {
                "n": self.random_n, "seed": self.random_seed,
                "ranges": [[key, {"range": [r.low, r.high], "log": r.log}] for key, r in self.random],
            },
            **(explicit if self.explicit else {}),
        }

    @property
    def hash(self) -> str:
        """sha256 of the canonical JSON (sorted object keys, no spaces)."""
        text = json.dumps(self.to_json(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()

    @classmethod
    def from_json(cls, data: Mapping[str, Any], plugin_paths: Sequence[str] | None = None, *,
                  import_plugins: bool = True) -> "SweepSpec":
        """Inverse of :meth:`to_json` (re-validates); ``plugin_paths``: what each plugin imports
        (default: relative ``.py`` paths from the current directory); ``import_plugins=False``: import
        none (a dataset's spec, :func:`parse_spec`)."""
        table: dict[str, Any] = {"name": data["name"], "scenario": dict(data["scenario"]), "sim": data["sim"],
                                 "gains": data["gains"]}
        if data.get("plugins"):
            table["plugins"] = list(data["plugins"])
        if data["grid"]:
            table["grid"] = {key: values for key, values in data["grid"]}
        if data["random"]:
            table["random"] = {"n": data["random"]["n"], "seed": data["random"]["seed"],
                               **{key: r for key, r in data["random"]["ranges"]}}
        if data.get("setting"):
            table["setting"] = [dict(entry) for entry in data["setting"]]
        return parse_spec(table, plugin_paths=plugin_paths, import_plugins=import_plugins)

    # ---- expansion ----------------------------------------------------------------------

    def random_samples(self) -> list[dict[str, float]]:
        """The ``n`` random gain samples (one dict per sample; ``[{}]`` without ``[random]``)."""
        if not self.random_n:
            return [{}]
        import jax
        import jax.numpy as jnp

        bits = np.asarray(jax.random.bits(jax.random.key(self.random_seed), (self.random_n, len(self.random)),
                                          jnp.uint32), dtype=np.float64)
        u = (bits + 0.5) / 2.0**32
        columns = {key: r.sample(u[:, i]) for i, (key, r) in enumerate(self.random)}
        return [{key: float(col[j]) for key, col in columns.items()} for j in range(self.random_n)]

    def settings(self) -> list[Setting]:
        """Every setting, in ``setting`` order: the ``[[setting]]`` tables as written, or the grid
        product (last key fastest) crossed with the random samples (innermost)."""
        return list(self._settings)

    @functools.cached_property
    def _settings(self) -> tuple[Setting, ...]:
        """:meth:`settings`, expanded once per spec (a spec is frozen; a 2,000-sample ``[random]`` takes
        tenths of a second to expand, and every part written asks for its gain columns)."""
        if self.explicit:
            points = [(dict(entry), tags) for entry, tags in zip(self.explicit, self.tags or [()] * len(self.explicit))]
        else:
            keys = [key for key, _ in self.grid]
            points = [(dict(zip(keys, point)) | sample, ())
                      for point in itertools.product(*(values for _, values in self.grid))
                      for sample in self.random_samples()]
        out = []
        for varied, tags in points:
            values = {**self.sim, **self.gains, **varied}
            gains = {k: tuple(values.get(k, spec.default)) if spec.shape else float(values.get(k, spec.default))
                     for k, spec in GAINS.items()}
            static = tuple((k, values[k]) for k in STATIC_KEYS if k in values)
            out.append(Setting(index=len(out), gains=gains, static=static, tags=tuple(tags)))
        return tuple(out)

    @property
    def tag_names(self) -> tuple[str, ...]:
        """The ``tags`` of the ``[[setting]]`` tables (each a column), in the order written."""
        return tuple(k for k, _ in self.tags[0]) if self.tags else ()

    @property
    def static_keys(self) -> tuple[str, ...]:
        """Static settings the spec names (``[sim]`` and grid), in :data:`STATIC_KEYS` order."""
        named = set(self.sim) | {key for key, _ in self.grid} | {key for entry in self.explicit for key, _ in entry}
        return tuple(k for k in STATIC_KEYS if k in named)

    def family_params(self, family: str) -> FamilyParams:
        """The validated :class:`~jaxapf.scenarios.FamilyParams` of ``family`` (a family or a variant)
        with the spec's overrides."""
        return spec_family_params(family, self.params.get(family, {}), swarms=True)

    @property
    def swarm(self) -> bool:
        """Whether the spec flies swarm families (every family is one, or none)."""
        return isinstance(self.family_params(self.families[0]), SwarmParams)

    def components(self, key: str) -> tuple[str, ...]:
        """The names the spec's settings give a component key (:data:`COMPONENTS`; its default if unnamed)."""
        default = SimConfig().flat()[key]
        return tuple(dict.fromkeys(dict(s.static).get(key, default) for s in self.settings()))

    def gain_columns(self) -> tuple[str, ...]:
        """The gains that get a column: those the spec's components (planners, filters, plants, sensors,
        disturbances) read, and any the spec names, in declaration order; an array-valued gain gets none (it
        is one value for the whole sweep, in the spec its metadata holds)."""
        return self._gain_columns

    @functools.cached_property
    def _gain_columns(self) -> tuple[str, ...]:
        read = {g.name for key, registry in COMPONENTS.items() for name in self.components(key)
                for g in registry.get(name).gains}
        return tuple(k for k in GAINS.names() if k in read | self.named_gains() and not GAINS.get(k).shape)

    def named_gains(self) -> set[str]:
        """The gains the spec sets (``[gains]``) or varies (grid, random, explicit settings)."""
        return (set(self.gains) | {k for k, _ in self.grid} | {k for k, _ in self.random}
                | {k for entry in self.explicit for k, _ in entry})

    def scaled_weights(self) -> set[str]:
        """The MPC weight scales some setting sets to something other than 1 (sampled ones always)."""
        return (set(scales_set(self.gains, varied=(k for k, _ in self.random))) | set(scales_set(dict(self.grid)))
                | {k for entry in self.explicit for k in scales_set(dict(entry))})

    def configs(self, static: Iterable[tuple[str, Any]], family: str) -> tuple[SimConfig, MPCConfig]:
        """:class:`SimConfig` and :class:`MPCConfig` of one setting's static part on ``family``
        (``t_max``: the spec's if named, else the family's)."""
        values = dict(static)
        values.setdefault("t_max", self.family_params(family).t_max)
        return sim_configs(values, self.scaled_weights())


# --------------------------------------------------------------------------------------------
# parsing
# --------------------------------------------------------------------------------------------


def _scenario(where: str, table: Any) -> tuple[tuple[str, ...], int, int, dict[str, dict[str, Any]], bool]:
    scenario = Table({"families": Key(given, REQUIRED), "fields": Key(integer(1, MAX_FIELDS), REQUIRED),
                      "seed": Key(SEED, 0), "params": Key(check_table, {}),
                      "oracle": Key(boolean, True)})(where, table)
    families, tables = scenario["families"], scenario["params"]
    choices = FAMILIES.names() + SWARM_FAMILIES.names() + variant_names(tables)
    if not isinstance(families, list):
        raise ConfigError(f"scenario.families = {families!r} must be a non-empty list of family names; "
                          f"allowed: {', '.join(choices)}")
    families = check_names("scenario.families", families, choices, what="family or variant")
    params = {}
    for label, overrides in tables.items():
        overrides = check_table(f"scenario.params.{label}", overrides)
        if label not in families:
            raise ConfigError(f"scenario.params.{label} is not one of scenario.families ({', '.join(families)})")
        # normalised in the family's own units (a scale is applied when the fields are made, once; the whole
        # table, the scale too, is checked with every family below)
        resolved = spec_family_params(label, {k: v for k, v in overrides.items() if k != "scale"}, swarms=True)
        params[label] = {k: (list(v) if isinstance(v, tuple) else v) if k not in ("family", "scale") else overrides[k]
                         for k, v in ((k, getattr(resolved, k, None)) for k in overrides)}
    swarm = {f: isinstance(spec_family_params(f, tables.get(f, {}), swarms=True), SwarmParams) for f in families}
    if len(set(swarm.values())) > 1:
        raise ConfigError(f"scenario.families mixes swarm families ({', '.join(f for f in families if swarm[f])}) "
                          f"with single-UAV ones ({', '.join(f for f in families if not swarm[f])}): their rows "
                          "have different metrics; sweep them in two specs")
    return tuple(families), scenario["fields"], scenario["seed"], params, scenario["oracle"]


def _schema() -> Table:
    """The sweep spec's schema (docs/sweep.md; built once the plugins, which may declare gains, are
    loaded); the settings (``[grid]``, ``[random]``, ``[[setting]]``) are read once ``[sim]`` and
    ``[gains]`` are known."""
    return Table({
        "name": Key(spec_name("it names the default output runs/NAME.parquet"), REQUIRED,
                    'give the spec a name = "..." (it names the default output runs/NAME.parquet)'),
        "plugins": Key(check_plugins, []),
        "scenario": Key(_scenario, REQUIRED, "add [scenario] with families and fields"),
        "sim": Key(setting_values(STATIC_KEYS), {}),
        "gains": Key(setting_values(GAINS.names()), {}),
        "grid": Key(given, OMIT), "random": Key(given, OMIT), "setting": Key(given, OMIT),
    })


def _grid(table: Any, fixed: Mapping[str, str]) -> tuple[tuple[str, tuple[Any, ...]], ...]:
    def check_key(where: str, key: str) -> None:
        only_fixed(f"{where}.{key}", key)
        if key in fixed:
            raise ConfigError(f"grid.{key} is also set in [{fixed[key]}]; set it in one place")

    read = value_grid(check_value, keys=GAINS.names() + STATIC_KEYS, check_key=check_key,
                      empty="grid is empty; give at least one key with a list of values, or remove [grid]")
    return read("grid", table)


def only_fixed(where: str, key: str) -> None:
    """Refuses to make an array-valued gain (a network's parameters) a grid or random axis: it has no column
    of its own, so it is set in ``[gains]``, a ``--gains`` file or ``[[setting]]`` tables (each row's
    ``setting`` then names it, and the spec in the metadata holds every value)."""
    if key in GAINS and GAINS.get(key).shape:
        raise ConfigError(f"{where}: {key} holds {GAINS.get(key).shape[0]:,} numbers and cannot be a grid or random "
                          "axis; set it in [gains], a --gains file or [[setting]] tables")


def _explicit(value: Any, fixed: Mapping[str, str]) -> tuple[tuple, tuple]:
    """The ``[[setting]]`` tables: ``(key, value)`` pairs and ``(tag, value)`` pairs of each."""
    if not isinstance(value, list) or not value or not all(isinstance(t, dict) for t in value):
        raise ConfigError("setting must be one or more [[setting]] tables")
    entries, tags = [], []
    for i, table in enumerate(value):
        where = f"setting[{i}]"
        table = check_table(where, table, GAINS.names() + STATIC_KEYS + ("tags",))
        for key in table:
            if key in fixed:
                raise ConfigError(f"{where}.{key} is also set in [{fixed[key]}]; set it in one place")
        entries.append(tuple((k, check_value(f"{where}.{k}", k, v)) for k, v in table.items() if k != "tags"))
        own = check_table(f"{where}.tags", table.get("tags", {}))
        for name, v in own.items():
            if (not _TAG.fullmatch(name) or name in GAINS or name in STATIC_KEYS or name in _RESERVED_COLUMNS
                    or name in METRICS):
                raise ConfigError(f"{where}.tags.{name}: a tag is letters, digits and '_' and not the name of a "
                                  "gain, setting or column")
            if isinstance(v, bool) or not isinstance(v, (str, int)):
                raise ConfigError(f"{where}.tags.{name} = {v!r} must be text or an integer")
        tags.append(tuple(own.items()))
    names = [tuple(k for k, _ in t) for t in tags]
    for i, n in enumerate(names):
        if set(n) != set(names[0]):
            raise ConfigError(f"setting[{i}].tags has {', '.join(n) or 'no tags'}; every setting needs the same "
                              f"tags ({', '.join(names[0]) or 'none'})")
        for name, v in tags[i]:
            first = dict(tags[0])[name]
            if isinstance(v, str) != isinstance(first, str):
                raise ConfigError(f"setting[{i}].tags.{name} = {v!r}: setting[0] gives it as "
                                  f"{'text' if isinstance(first, str) else 'an integer'}; use one type")
    order = names[0]
    return tuple(entries), tuple(tuple((k, dict(t)[k]) for k in order) for t in tags) if order else ()


def _random(table: Any, fixed: Mapping[str, str], grid: Iterable[str]) -> tuple[int, int, tuple]:
    table = check_table("random", table)
    if "n" not in table:
        raise ConfigError("random.n is missing; give the number of samples")
    n = check_int("random.n", table["n"], 1, MAX_SETTINGS)
    seed = SEED("random.seed", table.get("seed", 0))
    grid = set(grid)
    ranges = []
    for key, value in table.items():
        if key in _RANDOM_KEYS:
            continue
        if key not in GAINS:
            raise ConfigError(f"random.{key} is not a gain; only gains can be sampled (allowed: "
                              f"{', '.join(_RANDOM_KEYS + GAINS.names())})")
        only_fixed(f"random.{key}", key)
        if key in fixed or key in grid:
            raise ConfigError(f"random.{key} is also set in [{fixed.get(key, 'grid')}]; set it in one place")
        ranges.append((key, parse_range(f"random.{key}", key, value)))
    if not ranges:
        raise ConfigError(f"random has no gain to sample; add e.g. gamma = [0.0, 3.0] "
                          f"(gains: {', '.join(GAINS.names())})")
    return n, seed, tuple(ranges)


def parse_spec(data: Mapping[str, Any], gains_file: str | os.PathLike | None = None, *,
               base: str | os.PathLike | None = None, plugin_paths: Sequence[str] | None = None,
               import_plugins: bool = True) -> SweepSpec:
    """Validate a spec given as a mapping (parsed TOML) and return it as a :class:`SweepSpec`.

    ``base``: the folder relative ``.py`` plugin paths are read from (the spec file's;
    default the current directory); ``plugin_paths``: what each plugin imports, instead.
    ``import_plugins=False`` (the spec stored in a dataset, which is data): the plugins are not
    imported, their components must be registered already (``--plugin``), and a spec that needs
    what is not says which plugin files to name.

    ``gains_file`` (``--gains FILE``, read by :func:`~jaxapf.gains.read_gains_file`) overrides the
    spec's ``[gains]``: the file's values on top of the spec's, every gain either names then fixed,
    except the gains the grid or ``[random]`` vary. Every check runs here, including the :class:`SimConfig` /
    :class:`MPCConfig` of every variant on every family.
    """
    data = check_table("", dict(data))
    plugins = check_plugins("plugins", data.get("plugins", []))
    if plugin_paths is not None and len(plugin_paths) != len(plugins):
        raise ConfigError(f"plugins: {len(plugin_paths)} paths given for {len(plugins)} plugins")
    if not import_plugins:
        try:
            return parse_spec({k: v for k, v in data.items() if k != "plugins"}, gains_file)._replace_plugins(
                plugins, plugin_paths)
        except ConfigError as err:
            if not plugins:
                raise
            files = ", ".join(plugin_paths or plugins)
            raise ConfigError(f"{err}; the dataset was written with the plugin(s) {files}, which opening a dataset "
                              "never imports: name each one you trust, `jaxapf --plugin FILE COMMAND ...` (in Python "
                              "jaxapf.spec.plugins.load_plugin(FILE)), to read it") from None
    paths = load_plugins(plugins, base=base, paths=plugin_paths)
    d = _schema()("", data)
    name, (families, fields, seed, params, oracle), sim, gains = d["name"], d["scenario"], d["sim"], d["gains"]
    fixed = {**{k: "sim" for k in sim}, **{k: "gains" for k in gains}}
    if "setting" in d and ("grid" in d or "random" in d):
        raise ConfigError("setting: [[setting]] tables list the settings themselves; remove [grid] and [random] "
                          "or the [[setting]] tables")
    explicit, tags = _explicit(d["setting"], fixed) if "setting" in d else ((), ())
    grid = _grid(d["grid"], fixed) if "grid" in d else ()
    random_n, random_seed, ranges = _random(d["random"], fixed, (k for k, _ in grid)) if "random" in d else (0, 0, ())
    if gains_file is not None:
        varied = {k for k, _ in grid} | {k for k, _ in ranges} | {k for entry in explicit for k, _ in entry}
        read = {k: tuple(v) if isinstance(v, list) else v for k, v in read_gains_file(gains_file).items()}
        gains = {k: v for k, v in {**gains, **read}.items() if k not in varied}
    count = math.prod(len(values) for _, values in grid) * max(random_n, 1) if not explicit else len(explicit)
    if count > MAX_SETTINGS:
        raise ConfigError(f"the spec expands to {count:,} settings (grid product x random.n); at most "
                          f"{MAX_SETTINGS:,} are allowed: fewer grid values or samples")
    spec = SweepSpec(name=name, families=families, fields=fields, seed=seed, params=params, sim=sim, gains=gains,
                     grid=grid, random_n=random_n, random_seed=random_seed, random=ranges, plugins=plugins,
                     oracle=oracle, explicit=explicit, tags=tags, plugin_paths=paths)
    for static in {s.static for s in spec.settings()}:
        for family in families:
            sim_config, _ = spec.configs(static, family)
            if spec.swarm:
                from ..engine.swarm import check_neighbours

                check_neighbours(sim_config)
    return spec


def read_toml(path: str | os.PathLike) -> dict[str, Any]:
    """The table of a TOML spec file, unvalidated (:func:`~jaxapf.validation.read_toml_file`)."""
    return read_toml_file(path)[0]


def load_spec(path: str | os.PathLike, gains_file: str | os.PathLike | None = None) -> SweepSpec:
    """Read and validate a TOML spec file (see :func:`parse_spec`; its plugins' relative paths are
    read from the file's folder)."""
    return parse_spec(read_toml(path), gains_file, base=pathlib.Path(path).parent)
