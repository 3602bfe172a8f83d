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
seeds. Each member is compared with it on success and collision (the primary Holm family, per family and
pooled; the clearance exploratory), seeds pooled; the leaderboard gains its row and, beside each member, the
difference with the interval that decided the verdict, and the minimum detectable difference.

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
from ..validation import ConfigError
from .protocol import read_selections, selection_table, test_sweep_spec
from .select import select, spec_digest
from .spec import CompareSpec, parse_compare_spec

__all__ = ["SCORECARDS", "Scorecard", "load_scorecard", "identity", "stored_episodes", "score_zoo", "score_method",
           "check_drift", "leaderboard", "facts", "selection_ties", "identical_members", "AGREE", "DriftError"]

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

    def for_method(self, method: str) -> CompareSpec:
        """The scorecard's protocol with ``method`` beside the zoo: the same selection (families, seeds, budget,
        candidates, the zoo's default search) and test, the gains it reads searched (the card's frozen
        ``selection.gains`` and any tunable gain of its own beyond them). A method reading no gain beyond them
        draws the zoo's candidates, so a member scored again selects what it selected."""
        data = json.loads(json.dumps(self.data))
        if method not in data["methods"]:
            data["methods"] = [*data["methods"], method]
        frozen = data["selection"].get("gains")
        if frozen is not None:
            every = {k: v for k, v in data["selection"].items() if k != "gains"}
            own = parse_compare_spec(data | {"selection": every}, base=self.folder).method_gains(method)
            data["selection"]["gains"] = [*frozen, *(g for g in own if g not in frozen)]
        return parse_compare_spec(data, base=self.folder)


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
    """The engine that flies the episodes: jaxapf's and JAX's versions, the backend and the float type."""
    import jax

    from ..io.versions import versions

    v = versions()
    return {"jaxapf": str(v.get("jaxapf")), "jax": jax.__version__, "backend": jax.default_backend(),
            "dtype": "float64" if jax.config.jax_enable_x64 else "float32"}


def stored_episodes(card: Scorecard) -> pd.DataFrame:
    """The zoo's stored episodes, verified (a part edited by hand is refused in one line: its content hash)."""
    from ..sweep import read_sweep

    path = card.folder / "episodes.parquet"
    if not path.is_file():
        raise ConfigError(f"scorecard {card.version}: no stored episodes at {path}; score the zoo first "
                          "(jaxapf scorecard --rescore)")
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
        df, meta, selections = _fly(card.spec, card.spec.methods, out, quiet)
        columns = [c for c in df.columns if c in ("setting", "member", "selection", "method", "filter", "family",
                                                   "kind", "field", "seed", *READ)]
        write_rows(out, "episodes.parquet", df[columns], meta, list(READ))
    shutil.copy(out / "episodes.parquet", card.folder / "episodes.parquet")  # a verified part, copied whole
    write_atomic(card.folder / "selection.csv",
                 lambda fh: fh.write(csv_text(selection_table(card.spec, selections)).encode()))
    record = json.dumps(identity() | {"digest": card.digest}, indent=1) + "\n"
    write_atomic(card.folder / "identity.json", lambda fh: fh.write(record.encode()))
    board = leaderboard(stored_episodes(card), None, spent=selections)
    write_leaderboard(card, board, None, card.folder)
    found = json.dumps(facts(card, board), indent=1, sort_keys=True, allow_nan=False) + "\n"
    write_atomic(card.folder / "facts.json", lambda fh: fh.write(found.encode()))
    return board.table


def check_drift(card: Scorecard, out: pathlib.Path, *, quiet: bool = True) -> str:
    """``"same engine"`` where this engine's identity is the stored results'; else a sample of the stored
    episodes (:data:`SAMPLE_FIELDS` fields of every family, the first member, its first seed's selection) flown
    again and compared within :data:`AGREE`: what was found, or :class:`DriftError` in one line."""
    from ..io.names import read_own
    from ..sweep import read_sweep, run_sweep

    path = card.folder / "identity.json"
    if not path.is_file():
        raise ConfigError(f"scorecard {card.version}: no {path.name} beside its stored episodes; score the zoo again "
                          f"(jaxapf scorecard --card {card.version} --rescore)")
    kept = json.loads(read_own(path).decode("utf-8"))
    here = identity()
    changed = {k: (kept.get(k), v) for k, v in here.items() if kept.get(k) != v}
    if not changed:
        return "same engine"
    zoo = stored_episodes(card)
    member, seed = card.spec.methods[0], card.spec.selection.seeds[0]
    chosen = next(s for s in read_selections(card.spec, card.folder / "selection.csv")
                  if s.method == member and s.seed == seed)
    sample = dataclasses.replace(card.spec, methods=(member,), baseline=member,
                                 test=dataclasses.replace(card.spec.test, fields=SAMPLE_FIELDS))
    run_sweep(test_sweep_spec(sample, [chosen], members=True), out / "drift.parquet", quiet=quiet)
    again = read_sweep(out / "drift.parquet")[0]
    key = ["family", "field"]
    before = zoo[(zoo["member"] == member) & (zoo["selection"] == f"seed{seed}")].set_index(key)
    now = again.set_index(key)
    both = before.loc[now.index]
    outcomes = sum(int((both[c].to_numpy(bool) != now[c].to_numpy(bool)).sum()) for c in ("success", "collision"))
    gap = float(np.nanmax(np.abs(np.where(np.isfinite(both["min_clearance"]), both["min_clearance"], 0.0)
                                 - np.where(np.isfinite(now["min_clearance"]), now["min_clearance"], 0.0))))
    what = ", ".join(f"{k} {a} -> {b}" for k, (a, b) in changed.items())
    if outcomes or gap > AGREE:
        raise DriftError(f"scorecard {card.version}: the engine changed ({what}) and {len(now)} re-flown stored "
                         f"episodes disagree ({outcomes} outcomes, clearance by up to {gap:.3g} m): score the zoo "
                         f"again with `jaxapf scorecard --card {card.version} --rescore`")
    return f"engine changed ({what}); {len(now)} re-flown stored episodes agree (clearance within {gap:.2g} m)"


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


def facts(card: Scorecard, board: Board) -> dict[str, Any]:
    """The zoo's leaderboard as named facts (``facts.json`` beside the card, which the README binds): per member
    its rank, success and collision with their intervals over the seeds, median clearance, test episodes,
    selection episodes and seconds and per-family success; the identical members and the selection ties."""
    table, fam = board.table.set_index("method"), board.families.set_index("method")
    numbers = ("success", "success_lo", "success_hi", "collision", "collision_lo", "collision_hi",
               "clearance_median", "selection_episodes", "selection_seconds")
    return {"version": card.version, "digest": card.digest, "members": len(table),
            "rank": {m: int(v) for m, v in table["rank"].items()},
            "episodes": {m: int(v) for m, v in table["episodes"].items()},
            **{c: {m: _finite(v) for m, v in table[c].items()} for c in numbers},
            "family_success": {f: {m: _finite(v) for m, v in fam[f].items()} for f in fam.columns},
            "identical": [f"{a} and {b}" for a, b in board.identical],
            "selection_ties": [f"seed {s}: {a} and {b}" for s, a, b in board.ties]}


@dataclasses.dataclass
class Board:
    """A leaderboard: ``table`` (one row per member, best success first), ``families`` (success per family),
    ``comparisons`` (the new method against each member; empty without one), ``identical`` (members, the new
    method included, that fly identical episodes: :func:`identical_members`), ``ties`` (the selections'
    :func:`selection_ties` but those of identical members)."""

    table: pd.DataFrame
    families: pd.DataFrame
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
    :func:`~jaxapf.stats.seed_interval`), the median clearance, and what its selections (``spent``, each
    :class:`~jaxapf.compare.select.Selection` with ``method`` the member's name) realised: episodes and seconds,
    mean over the seeds, and which of them tie (:func:`selection_ties`); per family the success; and the new method
    against every member (:func:`_versus`)."""
    frames = [zoo] + ([new.assign(member=name)] if new is not None else [])
    data = pd.concat(frames, ignore_index=True)
    rows, fam = [], []
    for member, g in data.groupby("member", sort=False):
        per_seed = g.groupby("selection")[["success", "collision"]].mean()
        s_mean, s_lo, s_hi = stats.seed_interval(per_seed["success"].to_numpy())
        c_mean, c_lo, c_hi = stats.seed_interval(per_seed["collision"].to_numpy())
        clear = g["min_clearance"].to_numpy(np.float64)
        rows.append({"method": member, "episodes": len(g), "success": s_mean, "success_lo": s_lo, "success_hi": s_hi,
                     "collision": c_mean, "collision_lo": c_lo, "collision_hi": c_hi,
                     "clearance_median": float(np.median(clear[np.isfinite(clear)])) if np.isfinite(clear).any()
                     else math.nan})
        fam.append({"method": member, **g.groupby("family")["success"].mean().to_dict()})
    table = pd.DataFrame(rows)
    cost = pd.DataFrame([{"method": x.method, "selection_episodes": float(x.episodes),
                          "selection_seconds": float(x.seconds)} for x in spent],
                        columns=["method", "selection_episodes", "selection_seconds"]).astype(
        {"selection_episodes": float, "selection_seconds": float})
    table = table.merge(cost.groupby("method", as_index=False).mean(), on="method", how="left")
    table = table.sort_values(["success", "method"], ascending=[False, True], kind="stable")
    table.insert(0, "rank", np.arange(1, len(table) + 1))
    families = pd.DataFrame(fam).set_index("method").loc[table["method"]].reset_index()
    comparisons = _versus(zoo, new, name, resamples) if new is not None else pd.DataFrame()
    identical = identical_members(data)
    alike = {frozenset(pair) for pair in identical}
    ties = [t for t in selection_ties(spent) if frozenset(t[1:]) not in alike]
    return Board(table.reset_index(drop=True), families, comparisons, identical, ties)


def _versus(zoo: pd.DataFrame, new: pd.DataFrame, name: str, resamples: int) -> pd.DataFrame:
    """The new method against every member, paired on (selection seed, family, field): success and collision in
    the primary Holm family, per family and pooled; the clearance exploratory (:func:`jaxapf.report.tables.compare`)."""
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
    comp = compare(data, pairs, labels, ReportOptions(resamples=resamples, gallery=0, heatmap=None))
    return comp.rename(columns={"baseline_label": "member"})


def _pct(v: float) -> str:
    return "–" if not math.isfinite(float(v)) else f"{100 * float(v):.1f}"


def _cell(r: Any, scale: float = 100.0) -> str:
    """``+1.2 [-0.4, +2.8] at 99.6 %, inconclusive``: a comparison's difference with its deciding interval."""
    level = stats.format_level(r["confidence"])
    if not (math.isfinite(float(r["delta_lo"])) and math.isfinite(float(r["delta_hi"]))):
        return f"{scale * r['delta']:+.1f} [no {level} CI], {r['verdict']}"
    return (f"{scale * r['delta']:+.1f} [{scale * r['delta_lo']:+.1f}, {scale * r['delta_hi']:+.1f}] at {level}, "
            f"{r['verdict']}")


def board_frames(board: Board, name: str | None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The leaderboard as the pages print it, and its per-family success table."""
    from ..report.tables import headline

    shown = []
    comp = board.comparisons
    pooled = headline(list(dict.fromkeys(comp["family"]))) if len(comp) else None
    for r in board.table.itertuples():
        row = {"rank": r.rank, "method": r.method + (" (new)" if r.method == name else ""),
               "success % [seeds' t interval]": f"{_pct(r.success)} [{_pct(r.success_lo)}, {_pct(r.success_hi)}]",
               "collision % [seeds' t interval]":
                   f"{_pct(r.collision)} [{_pct(r.collision_lo)}, {_pct(r.collision_hi)}]",
               "median clearance m": f"{r.clearance_median:.3f}", "test episodes": f"{r.episodes:,}",
               "selection episodes, s": "–" if not math.isfinite(r.selection_episodes)
               else f"{r.selection_episodes:,.0f}, {r.selection_seconds:,.0f}"}
        if name is not None and r.method != name:
            mine = comp[(comp["member"] == r.method) & (comp["family"] == pooled)].set_index("metric")
            for metric in ("success", "collision"):
                row[f"{name} − it: Δ {metric} pp"] = _cell(mine.loc[metric])
            row["MDE success pp"] = f"{100 * mine.loc['success', 'mde']:.1f}"
        elif name is not None:
            row.update({f"{name} − it: Δ success pp": "–", f"{name} − it: Δ collision pp": "–", "MDE success pp": "–"})
        shown.append(row)
    families = board.families.copy()
    for c in families.columns[1:]:
        families[c] = families[c].map(_pct)
    return pd.DataFrame(shown), families


def write_leaderboard(card: Scorecard, board: Board, name: str | None, out: pathlib.Path) -> list[pathlib.Path]:
    """``leaderboard.md``, ``.html`` and ``.csv`` (and, with a new method, ``comparisons.csv``) in ``out``."""
    from ..io.lock import write_atomic
    from ..report.document import Document, render_html, render_markdown
    from ..text import csv_text

    shown, families = board_frames(board, name)
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
    paths = [out / "leaderboard.md", out / "leaderboard.html", out / "leaderboard.csv"]
    write_atomic(paths[0], lambda fh: fh.write(render_markdown(doc).encode()))
    write_atomic(paths[1], lambda fh: fh.write(render_html(doc, f"jaxapf scorecard {card.version}").encode()))
    write_atomic(paths[2], lambda fh: fh.write(csv_text(board.table.merge(board.families, on="method")).encode()))
    if name is not None:
        paths.append(out / "comparisons.csv")
        write_atomic(paths[-1], lambda fh: fh.write(csv_text(board.comparisons).encode()))
    return paths


def score_method(card: Scorecard, method: str, out: str | pathlib.Path, *, name: str | None = None,
                 quiet: bool = False, resamples: int = 2000) -> Board:
    """Score ``method`` (a compare method, ``PLANNER[+FILTER]``) on the scorecard (module docstring) in ``out``
    (resumable), its rows labelled ``name`` (default the method); writes the leaderboard there."""
    out = pathlib.Path(out)
    name = name or method
    zoo = stored_episodes(card)
    if name in set(zoo["member"]):
        raise ConfigError(f"--name {name}: a zoo member of scorecard {card.version} has that name; name the row "
                          "otherwise (--name)")
    from ..io.lock import writing

    with writing(out, "finished selections and test parts are kept"):
        drift = check_drift(card, out)
        if not quiet:
            print(f"scorecard {card.version}: {drift}", file=sys.stderr)
        new, _, chosen = _fly(card.for_method(method), [method], out, quiet)
        new = new[new["member"] == method]
        stored = card.folder / "selection.csv"
        spent = [*(read_selections(card.spec, stored) if stored.is_file() else ()),
                 *(dataclasses.replace(x, method=name) for x in chosen)]
        board = leaderboard(zoo, new, name, resamples, spent)
        write_leaderboard(card, board, name, out)
    return board
