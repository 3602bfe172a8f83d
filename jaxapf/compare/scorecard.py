"""``jaxapf scorecard``: a frozen benchmark, the zoo scored once and shipped, and a new planner ranked against
every member in minutes, paired field by field, without rerunning the zoo.

A **scorecard** is a compare spec (docs/compare.md) frozen under a version, ``scorecards/<version>/scorecard.toml``
beside this module, cited by its digest (the sha256 of its canonical JSON, :func:`~.select.spec_digest`): the
families and their kinds, the fields per family, the vehicle and episode length (``[sim]``), the selection
seeds, the selection budget per method and the held-out test's seed, one from which no committed study draws
fields of the card's families. Its
``methods`` are the zoo.

**Scoring the zoo** (:func:`score_zoo`, ``jaxapf scorecard --rescore``): every member's gains selected under the
budget for each seed (:func:`~.select.select`), every selection flown on the held-out fields, and stored beside
the spec: ``episodes.parquet`` (one verified sweep part: the columns the scorecard reads), ``selection.csv``,
``identity.json`` (the engine that made them), the leaderboard (``leaderboard.md``, ``.csv``, ``.html``) and
its numbers by name (``facts.json``, :func:`facts`).

**Scoring a method** (:func:`score_method`, ``jaxapf [--plugin FILE] scorecard --method NAME``): the same
selection and test for that method alone, paired with the stored episodes on the same fields and selection
seeds. Each member is compared with it on success and collision over the whole card (the primary Holm family:
families and seeds pooled; per family, and the clearance, exploratory); the leaderboard gains its row and,
beside each member, the difference with the interval that decided the verdict, and the minimum detectable
difference.

**Drift** (:func:`check_drift`): where the engine identity differs from the stored one, a sample of stored
episodes is flown again; the method is paired with the stored zoo only if the sample agrees within the
rounding contract (:data:`AGREE`), else one line says what changed and how to score the zoo again.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import sys
from typing import Any, Sequence

import numpy as np
import pandas as pd

from .. import stats
from ..validation import ConfigError, first_line
from .protocol import read_selections, selection_table, test_sweep_spec
from .select import select, spec_digest
from .spec import CompareSpec, parse_compare_spec

__all__ = ["SCORECARDS", "Scorecard", "load_scorecard", "identity", "stored_identity", "stored_episodes",
           "stored_selections", "score_zoo", "store_leaderboard", "score_method", "claim", "check_drift", "leaderboard",
           "facts", "selection_ties", "identical_members", "AGREE", "DriftError"]

#: The versioned scorecards shipped with jaxapf.
SCORECARDS = pathlib.Path(__file__).parent / "scorecards"
#: The columns the scorecard reads of every episode (beside the keys that pair them).
READ = ("success", "collision", "stalled", "min_clearance")
#: The rounding contract of a re-flown sample: outcomes equal, the clearance within this many metres (float32
#: summation order on another machine moves the last bits of a trajectory, never an outcome far from its edge).
AGREE = 1e-3
#: Stored episodes re-flown per family and member when the engine differs.
SAMPLE_FIELDS = 8


class DriftError(ConfigError):
    """The engine differs from the stored results' and a re-flown sample does not agree with them."""


@dataclasses.dataclass(frozen=True)
class Scorecard:
    """A frozen benchmark: its ``version``, the spec's TOML ``data`` and ``text``, the parsed ``spec`` (the zoo
    as its methods) and the ``folder`` its stored results live in."""

    version: str
    data: dict
    text: str
    spec: CompareSpec
    folder: pathlib.Path

    @property
    def digest(self) -> str:
        """What a paper cites: the sha256 of the spec's canonical JSON."""
        return spec_digest(self.spec)

    @property
    def option(self) -> str:
        """How the command line names this card: ``--card VERSION`` if shipped, else ``--card FOLDER``."""
        shipped = self.folder.resolve() == (SCORECARDS / self.version).resolve()
        return f"--card {self.version}" if shipped else f"--card {self.folder}"

    @property
    def again(self) -> str:
        """What to do where the stored zoo cannot be used: the command that scores it again."""
        return f"score the zoo again (jaxapf scorecard {self.option} --rescore)"

    def stored(self, name: str) -> pathlib.Path:
        """The stored zoo's file ``name`` beside the card, refused in one line where it is missing."""
        path = self.folder / name
        if not path.is_file():
            raise ConfigError(f"scorecard {self.version}: no {name} beside the card ({self.folder}): its zoo is not "
                              f"stored; {self.again}")
        return path

    def for_method(self, method: str) -> CompareSpec:
        """The scorecard's protocol with ``method`` beside the zoo: the same selection (families, seeds, budget,
        candidates, the zoo's default search) and test, the gains it reads searched (the card's frozen
        ``selection.gains`` and any tunable gain of its own beyond them, each drawn from its own stream). So a
        method draws the zoo's values of every gain it shares with it, and a member scored again selects what it
        selected."""
        data = json.loads(json.dumps(self.data))
        if method not in data["methods"]:
            data["methods"] = [*data["methods"], method]
        frozen = data["selection"].get("gains")
        if frozen is None:
            return parse_compare_spec(data, base=self.folder)
        every = {k: v for k, v in data["selection"].items() if k != "gains"}
        own = parse_compare_spec(data | {"selection": every}, base=self.folder).method_gains(method)
        added = tuple(g for g in own if g not in frozen)
        data["selection"]["gains"] = [*frozen, *added]
        spec = parse_compare_spec(data, base=self.folder)
        return dataclasses.replace(spec, selection=dataclasses.replace(spec.selection, added=added))


def load_scorecard(version: str = "v1", folder: str | pathlib.Path | None = None) -> Scorecard:
    """The scorecard ``version`` shipped with jaxapf, or the one in ``folder`` (a ``scorecard.toml``)."""
    from ..validation import read_toml_file

    where = pathlib.Path(folder) if folder is not None else SCORECARDS / version
    path = where / "scorecard.toml"
    if not path.is_file():
        shipped = ", ".join(sorted(p.parent.name for p in SCORECARDS.glob("*/scorecard.toml")))
        raise ConfigError(f"--card {version}: no scorecard at {path}; shipped: {shipped or 'none'}")
    data, text = read_toml_file(path)
    return Scorecard(version if folder is None else where.name, data, text, parse_compare_spec(data, base=where),
                     where)


def identity() -> dict[str, str]:
    """The engine that flies the episodes: jaxapf's version and the digest of its source, JAX's and jaxlib's
    versions, the backend and its device, the host processor and the float type."""
    import jax

    from ..io.versions import processor, source_digest, versions

    v = versions()
    return {"jaxapf": str(v.get("jaxapf")), "source": source_digest(), "jax": jax.__version__,
            "jaxlib": str(v.get("jaxlib")), "backend": jax.default_backend(), "device": str(v.get("device")),
            "processor": processor(), "dtype": "float64" if jax.config.jax_enable_x64 else "float32"}


def stored_identity(card: Scorecard) -> dict[str, str]:
    """The engine that made the stored zoo (``identity.json``), refused in one line where it is missing or
    damaged, or where the zoo was scored under another digest than the card's (its protocol changed since)."""
    path = card.stored("identity.json")
    kept = _read_record(path, f"scorecard {card.version}: ", card.again)
    if kept.get("digest") != card.digest:
        raise ConfigError(f"scorecard {card.version}: the stored zoo was scored under digest "
                          f"{str(kept.get('digest'))[:12]}…, the card's is {card.digest[:12]}… (its protocol "
                          f"changed since); {card.again}")
    return kept


def stored_episodes(card: Scorecard) -> pd.DataFrame:
    """The zoo's stored episodes, verified (a part edited by hand is refused in one line: its content hash)."""
    from ..sweep import read_sweep

    path = card.stored("episodes.parquet")
    try:
        df, _ = read_sweep(path)
    except ConfigError as err:
        raise ConfigError(f"scorecard {card.version}: the stored episodes are refused: {err}") from None
    return df


def _fly(spec: CompareSpec, methods: Sequence[str], out: pathlib.Path, quiet: bool
         ) -> tuple[pd.DataFrame, dict, list]:
    """Every method's selection for each seed (kept in ``out/selection``) and its held-out test episodes (the
    sweep ``out/test.parquet``, tagged with the member's name and the selection) with the sweep's metadata."""
    from ..sweep import read_sweep, run_sweep

    selections = [select(spec, m, seed, out / "selection", quiet=quiet) for seed in spec.selection.seeds
                  for m in methods]
    test = test_sweep_spec(spec, selections, members=True)
    run_sweep(test, out / "test.parquet", quiet=quiet)
    return (*read_sweep(out / "test.parquet"), selections)


def score_zoo(card: Scorecard, out: str | pathlib.Path, *, quiet: bool = False) -> pd.DataFrame:
    """Score every member of the zoo (module docstring) in ``out`` (resumable) and store the results beside the
    scorecard's spec. Returns the leaderboard."""
    import shutil

    from ..io.lock import write_atomic, writing
    from ..sweep.output import write_rows
    from ..text import csv_text

    out = pathlib.Path(out)
    with writing(out, "finished selections and test parts are kept"):
        claim(out)
        df, meta, selections = _fly(card.spec, card.spec.methods, out, quiet)
        columns = [c for c in df.columns if c in ("setting", "member", "selection", "method", "filter", "family",
                                                   "kind", "field", "seed", *READ)]
        write_rows(out, "episodes.parquet", df[columns], meta, list(READ))
    shutil.copy(out / "episodes.parquet", card.folder / "episodes.parquet")  # a verified part, copied whole
    write_atomic(card.folder / "selection.csv",
                 lambda fh: fh.write(csv_text(selection_table(card.spec, selections)).encode()))
    record = json.dumps(identity() | {"digest": card.digest}, indent=1) + "\n"
    write_atomic(card.folder / "identity.json", lambda fh: fh.write(record.encode()))
    return store_leaderboard(card).table


def store_leaderboard(card: Scorecard) -> Board:
    """The stored zoo's leaderboard, computed from its episodes and ``selection.csv``, written beside the card
    (``leaderboard.md``, ``.html``, ``.csv``) with its numbers by name (``facts.json``)."""
    from ..io.lock import write_atomic

    spent = stored_selections(card)
    board = leaderboard(stored_episodes(card), None, spent=spent)
    write_leaderboard(card, board, None, card.folder)
    found = json.dumps(facts(card, board, spent), indent=1, sort_keys=True, allow_nan=False) + "\n"
    write_atomic(card.folder / "facts.json", lambda fh: fh.write(found.encode()))
    return board


def _read_record(path: pathlib.Path, who: str, advice: str) -> dict[str, Any]:
    """An identity record (a JSON object), or :class:`ConfigError` in one line saying it is damaged and ``advice``."""
    from ..io.names import read_own

    try:
        kept = json.loads(read_own(path).decode("utf-8"))
        if not isinstance(kept, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError, RecursionError) as err:
        raise ConfigError(f"{who}{path} is damaged ({first_line(err)}); {advice}") from None
    return kept


def stored_selections(card: Scorecard) -> list[Any]:
    """The zoo's selections (``selection.csv`` beside the card), refused in one line where it is missing or
    unreadable."""
    stored = card.stored("selection.csv")
    try:
        return read_selections(card.spec, stored)
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ConfigError(f"scorecard {card.version}: {stored} cannot be read ({type(err).__name__}: "
                          f"{first_line(err)}); {card.again}") from None


def check_drift(card: Scorecard, *, quiet: bool = True, zoo: pd.DataFrame | None = None,
                selections: Sequence[Any] | None = None, engine: dict[str, Any] | None = None) -> str:
    """``"same engine"`` where this engine's identity is the stored results' (:func:`stored_identity`); else a
    sample of the stored episodes (:data:`SAMPLE_FIELDS` fields of every family, the first member, its first
    seed's selection) flown again, in a temporary folder, and compared: every outcome equal, every clearance
    within :data:`AGREE`. What was found, or :class:`DriftError` in one line. ``zoo``, ``selections``, ``engine``:
    the stored episodes and selections and this engine's :func:`identity` where the caller has them already."""
    import tempfile

    from ..sweep import read_sweep, run_sweep

    kept = stored_identity(card)
    here = {k: v for k, v in (engine or identity()).items() if k != "plugins"}  # the zoo flew no plugin
    changed = {k: (kept.get(k), v) for k, v in here.items() if kept.get(k) != v}
    if not changed:
        return "same engine"
    zoo = stored_episodes(card) if zoo is None else zoo
    member, seed = card.spec.methods[0], card.spec.selection.seeds[0]
    selections = stored_selections(card) if selections is None else selections
    chosen = [s for s in selections if s.method == member and s.seed == seed]
    if not chosen:
        raise ConfigError(f"scorecard {card.version}: its selection.csv holds no selection of {member}, seed {seed}; "
                          + card.again)
    sample = dataclasses.replace(card.spec, methods=(member,), baseline=member,
                                 test=dataclasses.replace(card.spec.test, fields=SAMPLE_FIELDS))
    with tempfile.TemporaryDirectory() as tmp:  # never a sample another engine flew
        run_sweep(test_sweep_spec(sample, chosen[:1], members=True), pathlib.Path(tmp) / "drift.parquet",
                  quiet=quiet)
        again = read_sweep(pathlib.Path(tmp) / "drift.parquet")[0]
    key = ["family", "field"]
    before = zoo[(zoo["member"] == member) & (zoo["selection"] == f"seed{seed}")].set_index(key)
    now = again.set_index(key)
    both = before.loc[now.index]
    outcomes = sum(int((both[c].to_numpy(bool) != now[c].to_numpy(bool)).sum())
                   for c in ("success", "collision", "stalled") if c in both.columns and c in now.columns)
    a, b = both["min_clearance"].to_numpy(np.float64), now["min_clearance"].to_numpy(np.float64)
    finite = np.isfinite(a) & np.isfinite(b)
    alike = all((f(a) == f(b)).all() for f in (np.isnan, np.isposinf, np.isneginf))  # undefined where it was
    gap = float(np.max(np.abs(a - b)[finite], initial=0.0)) if alike else math.inf
    what = ", ".join(f"{k} {_short(x)} -> {_short(y)}" for k, (x, y) in changed.items())
    if outcomes or gap > AGREE:
        raise DriftError(f"scorecard {card.version}: the engine changed ({what}) and {len(now)} re-flown stored "
                         f"episodes disagree ({outcomes} outcomes, clearance by up to {gap:.3g} m): score the zoo "
                         f"again with `jaxapf scorecard {card.option} --rescore`")
    return f"engine changed ({what}); {len(now)} re-flown stored episodes agree (clearance within {gap:.2g} m)"


def _short(value: Any) -> str:
    """An identity's value as a line shows it: a digest by its first 12 characters."""
    text = str(value)
    return text[:12] + "…" if len(text) == 64 and all(c in "0123456789abcdef" for c in text) else text


def selection_ties(selections: Sequence[Any]) -> list[tuple[int, str, str]]:
    """``(seed, member, member)`` for every two members whose selections in one seed the search could not order:
    the same candidate chosen (the zoo's shared draws) at the same success and the same surrogate loss, the two
    keys it ranks by (:mod:`jaxapf.compare.select`). The card's budget separates the zoo where there is none
    apart from members that fly identical episodes (:func:`identical_members`; docs/scorecard.md)."""
    ties = []
    for i, a in enumerate(selections):
        for b in selections[i + 1:]:
            if (a.seed == b.seed and a.chosen == b.chosen and float(a.selection_success) == float(b.selection_success)
                    and float(a.selection_loss) == float(b.selection_loss)):
                ties.append((int(a.seed), a.method, b.method))
    return ties


def identical_members(episodes: pd.DataFrame) -> list[tuple[str, str]]:
    """Every two members (column ``member``) whose episodes agree in every column the card reads on every
    selection seed, family and field: one planner on the card's fields (``velocity_obstacle_unilateral`` is
    ``velocity_obstacle`` where no other UAV flies), which no selection budget can separate."""
    key = ["selection", "family", "field"]
    cols = [c for c in READ if c in episodes.columns]
    frames = {m: g.set_index(key).sort_index()[cols] for m, g in episodes.groupby("member", sort=False)}
    names = list(frames)
    return [(a, b) for i, a in enumerate(names) for b in names[i + 1:]
            if frames[a].index.equals(frames[b].index) and frames[a].equals(frames[b])]


def _finite(v: Any) -> float | None:
    """A number for JSON: ``None`` where it is undefined (no finite clearance, one seed's interval)."""
    return float(v) if math.isfinite(float(v)) else None


def facts(card: Scorecard, board: Board, spent: Sequence[Any] = ()) -> dict[str, Any]:
    """The zoo's leaderboard as named facts (``facts.json`` beside the card, which the README binds): per member
    its rank, success, collision and median clearance with their intervals over the seeds, test episodes,
    selection episodes and seconds, and per-family success and collision; the identical members, the selection
    ties and the hours every selection (``spent``) took together; and the card's protocol in numbers (what a page
    describing the zoo quotes)."""
    table = board.table.set_index("method")
    numbers = ("success", "success_lo", "success_hi", "collision", "collision_lo", "collision_hi",
               "clearance_median", "clearance_median_lo", "clearance_median_hi", "selection_episodes",
               "selection_seconds")
    spec = card.spec
    protocol = {"seeds": len(spec.selection.seeds), "budget": spec.selection.budget,
                "candidates": spec.selection.candidates, "families": len(spec.test.families),
                "test_fields": spec.test.fields, "test_seed": spec.test.seed}
    return {"version": card.version, "digest": card.digest, "members": len(table), "protocol": protocol,
            "rank": {m: int(v) for m, v in table["rank"].items()},
            "episodes": {m: int(v) for m, v in table["episodes"].items()},
            **{c: {m: _finite(v) for m, v in table[c].items()} for c in numbers},
            **{key: {f: {m: _finite(v) for m, v in per[f].items()} for f in per.columns}
               for key, per in (("family_success", board.families.set_index("method")),
                                ("family_collision", board.collisions.set_index("method")))},
            "identical": [f"{a} and {b}" for a, b in board.identical],
            "selection_ties": [f"seed {s}: {a} and {b}" for s, a, b in board.ties],
            "selection_hours": sum(float(x.seconds) for x in spent) / 3600.0}


@dataclasses.dataclass
class Board:
    """A leaderboard: ``table`` (one row per member, best success first), ``families`` and ``collisions`` (success
    and collision per family), ``comparisons`` (the new method against each member; empty without one),
    ``identical`` (members, the new method included, that fly identical episodes: :func:`identical_members`),
    ``ties`` (the selections' :func:`selection_ties` but those of identical members)."""

    table: pd.DataFrame
    families: pd.DataFrame
    collisions: pd.DataFrame
    comparisons: pd.DataFrame
    identical: list[tuple[str, str]]
    ties: list[tuple[int, str, str]]


def _pooled_rows(df: pd.DataFrame) -> pd.DataFrame:
    """Episodes keyed for pairing with the selection seeds pooled: a field of one seed's test is ``seedN/field``."""
    out = df.copy()
    out["field"] = out["selection"].astype(str) + "/" + out["field"].astype(str)
    return out


def leaderboard(zoo: pd.DataFrame, new: pd.DataFrame | None, name: str | None = None, resamples: int = 2000,
                spent: Sequence[Any] = ()) -> Board:
    """The leaderboard of the stored ``zoo`` and, if given, the ``new`` method's episodes (its rows ``name``):
    per member the pooled success and collision (mean over the selection seeds with its t interval over them,
    :func:`~jaxapf.stats.seed_interval`; members of equal success share a rank), the median clearance (each
    seed's median of the finite clearances, their mean with its t interval), and what its selections (``spent``,
    each :class:`~jaxapf.compare.select.Selection` with ``method`` the member's name) realised: episodes and
    seconds, mean over the seeds, and which of them tie (:func:`selection_ties`); per family the success and the
    collisions; and the new method against every member (:func:`_versus`)."""
    frames = [zoo] + ([new.assign(member=name)] if new is not None else [])
    data = pd.concat(frames, ignore_index=True)
    rows, fam, col = [], [], []
    for member, g in data.groupby("member", sort=False):
        per_seed = g.groupby("selection")[["success", "collision"]].mean()
        s_mean, s_lo, s_hi = stats.seed_interval(per_seed["success"].to_numpy())
        c_mean, c_lo, c_hi = stats.seed_interval(per_seed["collision"].to_numpy())
        k_mean, k_lo, k_hi = stats.seed_interval(g.groupby("selection")["min_clearance"].agg(_finite_median))
        rows.append({"method": member, "episodes": len(g), "success": s_mean, "success_lo": s_lo, "success_hi": s_hi,
                     "collision": c_mean, "collision_lo": c_lo, "collision_hi": c_hi, "clearance_median": k_mean,
                     "clearance_median_lo": k_lo, "clearance_median_hi": k_hi})
        fam.append({"method": member, **g.groupby("family")["success"].mean().to_dict()})
        col.append({"method": member, **g.groupby("family")["collision"].mean().to_dict()})
    table = pd.DataFrame(rows)
    cost = pd.DataFrame([{"method": x.method, "selection_episodes": float(x.episodes),
                          "selection_seconds": float(x.seconds)} for x in spent],
                        columns=["method", "selection_episodes", "selection_seconds"]).astype(
        {"selection_episodes": float, "selection_seconds": float})
    table = table.merge(cost.groupby("method", as_index=False).mean(), on="method", how="left")
    table = table.sort_values(["success", "method"], ascending=[False, True], kind="stable")
    table.insert(0, "rank", table["success"].rank(method="min", ascending=False).astype(int))  # equal success, one rank
    order = table["method"]
    families = pd.DataFrame(fam).set_index("method").loc[order].reset_index()
    collisions = pd.DataFrame(col).set_index("method").loc[order].reset_index()
    comparisons = _versus(zoo, new, name, resamples) if new is not None else pd.DataFrame()
    identical = identical_members(data)
    alike = {frozenset(pair) for pair in identical}
    ties = [t for t in selection_ties(spent) if frozenset(t[1:]) not in alike]
    return Board(table.reset_index(drop=True), families, collisions, comparisons, identical, ties)


def _finite_median(values: pd.Series) -> float:
    """The median of the finite values (a clearance is infinite where no obstacle was in range); NaN if none."""
    x = values.to_numpy(np.float64)
    x = x[np.isfinite(x)]
    return float(np.median(x)) if x.size else math.nan


def _versus(zoo: pd.DataFrame, new: pd.DataFrame, name: str, resamples: int) -> pd.DataFrame:
    """The new method against every member, paired on (selection seed, family, field), seeds pooled
    (:func:`jaxapf.report.tables.compare`). The question is the leaderboard's, about the whole card: its primary
    Holm family is success and collision against every member with the families pooled; per family, and the
    stalls and clearance, exploratory."""
    from ..report import ReportOptions
    from ..report.tables import compare

    keep = [c for c in ("family", "kind", "field", "seed", *READ) if c in zoo.columns and c in new.columns]
    members = list(dict.fromkeys(zoo["member"]))
    parts, pairs, labels = [], {}, {}
    for i, m in enumerate(members):
        parts.append(_pooled_rows(zoo[zoo["member"] == m])[keep].assign(setting=2 * i))
        parts.append(_pooled_rows(new)[keep].assign(setting=2 * i + 1))
        pairs[2 * i + 1], labels[2 * i], labels[2 * i + 1] = 2 * i, m, name
    data = pd.concat(parts, ignore_index=True)
    options = ReportOptions(resamples=resamples, gallery=0, heatmap=None, primary_pooled=True)
    comp = compare(data, pairs, labels, options)
    return comp.rename(columns={"baseline_label": "member"})


def _num(v: float, scale: float = 100.0, digits: int = 1, sign: str = "") -> str:
    """A number as the pages print it (a rate in percent by default); ``–`` where it is undefined."""
    return "–" if not math.isfinite(float(v)) else f"{scale * float(v):{sign},.{digits}f}"


def _cell(r: Any, scale: float = 100.0, digits: int = 1) -> str:
    """``+1.2 [-0.4, +2.8] at 99.6 %, inconclusive``: a comparison's difference with its deciding interval."""
    level = stats.format_level(r["confidence"])
    delta = _num(r["delta"], scale, digits, "+")
    if not (math.isfinite(float(r["delta_lo"])) and math.isfinite(float(r["delta_hi"]))):
        return f"{delta} [no {level} CI], {r['verdict']}"
    return (f"{delta} [{_num(r['delta_lo'], scale, digits, '+')}, {_num(r['delta_hi'], scale, digits, '+')}] at "
            f"{level}, {r['verdict']}")


def board_frames(board: Board, name: str | None) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """The leaderboard as the pages print it, and its per-family success and collision tables (%)."""
    from ..report.tables import headline

    shown = []
    comp = board.comparisons
    pooled = headline(list(dict.fromkeys(comp["family"]))) if len(comp) else None
    for r in board.table.itertuples():
        row = {"rank": r.rank, "method": r.method + (" (new)" if r.method == name else ""),
               "success % [seeds' t interval]": f"{_num(r.success)} [{_num(r.success_lo)}, {_num(r.success_hi)}]",
               "collision % [seeds' t interval]":
                   f"{_num(r.collision)} [{_num(r.collision_lo)}, {_num(r.collision_hi)}]",
               "median clearance m [seeds' t interval]":
                   f"{_num(r.clearance_median, 1, 3)} [{_num(r.clearance_median_lo, 1, 3)}, "
                   f"{_num(r.clearance_median_hi, 1, 3)}]",
               "test episodes": f"{r.episodes:,}",
               "selection episodes, s": "–" if not math.isfinite(r.selection_episodes)
               else f"{r.selection_episodes:,.0f}, {r.selection_seconds:,.0f}"}
        if name is not None:
            mine = (comp[(comp["member"] == r.method) & (comp["family"] == pooled)].set_index("metric")
                    if r.method != name else None)
            for metric in ("success", "collision"):
                row[f"{name} − it: Δ {metric} pp"] = _cell(mine.loc[metric]) if mine is not None else "–"
            row[f"{name} − it: clearance shift m (exploratory)"] = (
                _cell(mine.loc["min_clearance"], 1.0, 3) if mine is not None and "min_clearance" in mine.index else "–")
            row["MDE success pp"] = _num(mine.loc["success", "mde"]) if mine is not None else "–"
        shown.append(row)
    per_family = []
    for frame in (board.families, board.collisions):
        frame = frame.copy()
        for c in frame.columns[1:]:
            frame[c] = frame[c].map(_num)
        per_family.append(frame)
    return pd.DataFrame(shown), *per_family


def write_leaderboard(card: Scorecard, board: Board, name: str | None, out: pathlib.Path) -> list[pathlib.Path]:
    """``leaderboard.md``, ``.html`` and ``.csv`` (and, with a new method, ``comparisons.csv``) in ``out``."""
    from ..io.lock import write_atomic
    from ..report.document import Document, render_html, render_markdown
    from ..text import csv_text

    shown, families, collisions = board_frames(board, name)
    doc = Document()
    doc.h(1, f"jaxapf scorecard {card.version}" + (f": {name} against the zoo" if name else ""))
    spec = card.spec
    doc.p(f"Scorecard {card.version}, digest {card.digest}: {len(spec.methods)} methods, each selected by a "
          f"{spec.selection.search} search of {spec.selection.budget:,} episodes per selection seed "
          f"({', '.join(map(str, spec.selection.seeds))}) on {', '.join(spec.selection.families)}, then flown on "
          f"{spec.test.fields} held-out fields of each of {', '.join(spec.test.families)} (seed {spec.test.seed}).")
    if name is not None:
        doc.p(f"{name} against each member, paired on the same fields and selection seeds (seeds pooled): the "
              f"difference in percentage points with the interval that decided its verdict; {stats.VERDICT_RULE}. "
              "MDE: the smallest success difference the pairs detect with power 0.8 at that level.")
    if board.identical:
        doc.p("Identical episodes on every test field (one planner on this card's fields): "
              + "; ".join(f"{a} and {b}" for a, b in board.identical) + ".")
    doc.p("Selection ties (two members of one seed that the search could not order: the same chosen candidate "
          "at the same selection success and surrogate loss; identical members aside): "
          + ("none." if not board.ties else "; ".join(f"seed {s}: {a} and {b}" for s, a, b in board.ties) + "."))
    doc.h(2, "Leaderboard")
    doc.table(shown)
    doc.h(2, "Success per family (%)")
    doc.table(families)
    doc.h(2, "Collision per family (%)")
    doc.table(collisions)
    paths = [out / "leaderboard.md", out / "leaderboard.html", out / "leaderboard.csv"]
    write_atomic(paths[0], lambda fh: fh.write(render_markdown(doc).encode()))
    write_atomic(paths[1], lambda fh: fh.write(render_html(doc, f"jaxapf scorecard {card.version}").encode()))
    per_family = board.families.merge(board.collisions, on="method", suffixes=(" success", " collision"))
    write_atomic(paths[2], lambda fh: fh.write(csv_text(board.table.merge(per_family, on="method")).encode()))
    if name is not None:
        paths.append(out / "comparisons.csv")
        write_atomic(paths[-1], lambda fh: fh.write(csv_text(board.comparisons).encode()))
    return paths


def score_method(card: Scorecard, method: str, out: str | pathlib.Path, *, name: str | None = None,
                 quiet: bool = False, resamples: int = 2000) -> Board:
    """Score ``method`` (a compare method, ``PLANNER[+FILTER]``) on the scorecard (module docstring) in ``out``
    (resumable), its rows labelled ``name`` (default the method); writes the leaderboard there."""
    from ..io.lock import writing
    from ..report import ReportOptions

    out = pathlib.Path(out)
    name = name or method
    spec = card.for_method(method)  # an unknown method or a bad --resamples, before anything flies
    ReportOptions(resamples=resamples)
    zoo = stored_episodes(card)
    if name in set(zoo["member"]):
        raise ConfigError(f"--name {name}: a zoo member of scorecard {card.version} has that name; name the row "
                          "otherwise (--name)")
    with writing(out, "finished selections and test parts are kept"):
        engine = claim(out)
        stored = stored_selections(card)
        drift = check_drift(card, zoo=zoo, selections=stored, engine=engine)
        if not quiet:
            print(f"scorecard {card.version}: {drift}", file=sys.stderr)
        new, _, chosen = _fly(spec, [method], out, quiet)
        new = new[new["member"] == method]
        spent = [*stored, *(dataclasses.replace(x, method=name) for x in chosen)]
        board = leaderboard(zoo, new, name, resamples, spent)
        write_leaderboard(card, board, name, out)
    return board


def claim(out: pathlib.Path) -> dict[str, Any]:
    """The engine and plugins that fly into ``out`` (``out/identity.json``: :func:`identity` and each plugin's
    sha256): recorded by the first run; a run with another engine, or with a recorded plugin edited or missing, is
    refused in one line, so that no selection or test part of two engines, or of two versions of a plugin, is ever
    mixed (a plugin loaded beside them is no change)."""
    from ..io.lock import write_atomic
    from ..spec.plugins import plugin_digests

    here = identity() | {"plugins": plugin_digests()}
    path = out / "identity.json"
    if not path.is_file():
        write_atomic(path, lambda fh: fh.write((json.dumps(here, indent=1) + "\n").encode()))
        return here
    kept = _read_record(path, "", f"remove {out} to fly again")
    plugins = kept.get("plugins") if isinstance(kept.get("plugins"), dict) else {}
    changed = [k for k in here if k != "plugins" and kept.get(k) != here[k]]
    changed += [f"plugin {pathlib.Path(n).name}" for n in sorted(plugins) if plugins[n] != here["plugins"].get(n)]
    if changed:
        raise ConfigError(f"{out} holds what another engine or plugin flew ({', '.join(changed)} changed): score "
                          f"into a new --out, or remove {out} to fly again")
    return here
