"""``jaxapf compare SPEC.toml --out DIR``: the tuned comparison protocol, in one command.

1. **Selection** (:mod:`jaxapf.compare.select`): for every method and every selection seed, the
   gains are chosen on training fields of that seed under the same episode budget.
2. **Test**: every method at its defaults and at each seed's selected gains flies the same held-out
   fields (``[test]``: its own seed, possibly other families) -- a sweep with one ``[[setting]]``
   per (method, selection), tagged ``selection`` = ``default`` or ``seed<s>``, written to
   ``DIR/test.parquet`` in the sweep format (``jaxapf report`` reads it).
3. **Report**: ``jaxapf report`` of the test with the baseline method as baseline, each setting
   paired with the baseline of the same ``selection`` (``--pair-on selection``), into
   ``DIR/report/``; and ``DIR/compare.md``: budgets and selected gains per method and seed, test
   rates per seed with their spread, and the verdicts against the baseline seed by seed.

``DIR`` also holds ``selection/`` (one JSON file per method and seed; a rerun reuses those of the
same spec, and a gradient search resumes from its checkpoint), ``selection.csv`` and
``summary.json``. Rerunning the command resumes whatever is missing; the command holds
``DIR/.lock`` while it runs (one writer per folder, :mod:`jaxapf.io.lock`).

**Shards** (``--shard I/N``, e.g. the tasks of a job array): shard ``I`` runs every ``N``-th selection
(seed-major, methods in the spec's order, from the ``I``-th) and, once every selection is in
``DIR`` whoever ran it, shard ``I`` of the test sweep (:func:`jaxapf.sweep.run_sweep`'s shards). A
shard whose selections are done but others' are not says so and ends; run the array again once
they are (docs/compare.md). The report is written by the command without ``--shard``, which then
finds everything done and runs nothing else.
"""

from __future__ import annotations

import json
import math
import pathlib
import sys
from typing import Any, Sequence

import numpy as np
import pandas as pd

from .. import stats
from ..gains import GAINS
from ..io.lock import writing
from ..io.versions import versions
from ..text import csv_text
from ..validation import ConfigError
from .select import Selection, saved_selection, select, spec_digest
from .spec import CompareSpec, load_compare_spec

__all__ = ["run_compare", "run_compare_spec", "test_sweep_spec", "selection_table", "read_selections",
           "baseline_filter", "rows_of",
           "DEFAULT"]

#: The ``selection`` tag of a method at its default gains.
DEFAULT = "default"
#: Metrics whose verdicts ``compare.md`` lists seed by seed.
_VERDICT_METRICS = ("success", "collision", "stalled", "min_clearance", "time_to_goal", "path_ratio")


def _say(quiet: bool, message: str) -> None:
    if not quiet:
        print(message, file=sys.stderr, flush=True)


def _tag(seed: int) -> str:
    return f"seed{seed}"


def test_sweep_spec(spec: CompareSpec, selections: Sequence[Selection], members: bool = False):
    """The held-out test as a sweep spec: one ``[[setting]]`` per (selection, method), defaults first;
    ``members`` (a scorecard's test, :mod:`jaxapf.compare.scorecard`): the selections alone, each tagged with
    its method's name (``member``) as well. The selections flown are those given, in the spec's seed order."""
    from ..sweep.spec import parse_spec

    settings = [] if members else [{**spec.settings(m), "tags": {"selection": DEFAULT}} for m in spec.methods]
    by = {(s.method, s.seed): s for s in selections}
    for seed in spec.selection.seeds:
        for m in spec.methods:
            if (m, seed) not in by:
                continue
            chosen = by[(m, seed)].gains
            searched = spec.method_gains(m)
            settings.append({**spec.settings(m), **{g: chosen[g] for g in searched if g in chosen},
                             "tags": ({"member": m} if members else {}) | {"selection": _tag(seed)}})
    data = {
        "name": f"{spec.name}-test",
        "plugins": list(spec.plugins),
        "scenario": {"families": list(spec.test.families), "fields": spec.test.fields, "seed": spec.test.seed,
                     "params": {f: dict(p) for f, p in spec.params.items() if f in spec.test.families}},
        "sim": {k: list(v) if isinstance(v, tuple) else v for k, v in spec.sim.items()},
        "setting": settings,
        **({"gains": dict(spec.gains)} if spec.gains else {}),
    }
    return parse_spec(data, plugin_paths=spec.plugin_paths or None)


def run_compare(spec_path: str | pathlib.Path, out: str | pathlib.Path | None = None, *, quiet: bool = False,
                resamples: int = 2000, gallery: int = 0, shard: tuple[int, int] | None = None,
                answers: str | pathlib.Path | None = None) -> dict[str, Any]:
    """Run the protocol on the spec file at ``spec_path`` (module docstring); ``out`` defaults to
    ``runs/compare-NAME``; ``answers``: the folder of the oracle's kept answers for the test sweep
    (:func:`~jaxapf.sweep.run_sweep`). Returns the summary written to ``summary.json`` (with ``shard``: what
    the shard did)."""
    spec, text = load_compare_spec(spec_path)
    return run_compare_spec(spec, text, out if out is not None else pathlib.Path("runs") / f"compare-{spec.name}",
                            quiet=quiet, resamples=resamples, gallery=gallery, shard=shard, answers=answers)


def run_compare_spec(spec: CompareSpec, text: str, out: str | pathlib.Path, *, quiet: bool = False,
                     resamples: int = 2000, gallery: int = 0, shard: tuple[int, int] | None = None,
                     answers: str | pathlib.Path | None = None) -> dict[str, Any]:
    """:func:`run_compare` on a validated spec; ``text`` is recorded as the spec file."""
    out = pathlib.Path(out)
    with writing(out, "finished selections and test parts are kept", shard):
        return _run(spec, text, out, quiet=quiet, resamples=resamples, gallery=gallery, shard=shard, answers=answers)


def _run(spec: CompareSpec, text: str, out: pathlib.Path, *, quiet: bool, resamples: int, gallery: int,
         shard: tuple[int, int] | None, answers: str | pathlib.Path | None = None) -> dict[str, Any]:
    """The body of :func:`run_compare_spec`, under the lock."""
    from ..io.lock import write_atomic
    from ..io.names import check_kind, read_own
    from ..report import ReportOptions, build_report
    from ..sweep import run_sweep

    digest = spec_digest(spec)
    stamp = out / "spec_digest"
    if check_kind(stamp) and read_own(stamp).decode("utf-8", "replace").strip() != digest:
        raise ConfigError(f"{out} holds a comparison of another spec; use another --out or delete it")
    if not stamp.exists():  # shards of one spec would write the same; written once
        write_atomic(stamp, lambda fh: fh.write((digest + "\n").encode()))

    jobs = [(seed, method) for seed in spec.selection.seeds for method in spec.methods]
    mine = set(jobs if shard is None else jobs[shard[0]::shard[1]])
    selections, missing = [], 0
    for seed, method in jobs:
        if (seed, method) in mine:
            s = select(spec, method, seed, out / "selection", quiet=quiet)
            _say(quiet, f"selection {method} seed {seed}: {s.chosen} of {s.candidates} ({s.search}), "
                        f"{s.episodes} episodes in {s.seconds:.1f} s, training success "
                        + (f"{s.selection_success:.3f}" if math.isfinite(s.selection_success) else "not measured"))
        else:
            s = saved_selection(spec, method, seed, out / "selection")
        selections.append(s)
        missing += s is None
    if missing:  # only a shard gets here: the test needs every selection
        done = f"its {len(mine)} selection(s) are done"
        _say(quiet, f"compare {spec.name} shard {shard[0]}/{shard[1]}: {done}; {missing} selection(s) of other "
                    f"shards are not yet in {out}, so the test waits: run the shards again once they are")
        return {"name": spec.name, "shard": list(shard), "selections_done": len(jobs) - missing,
                "selections_missing": missing}
    if shard is not None:
        test = test_sweep_spec(spec, selections)
        result = run_sweep(test, out / "test.parquet", quiet=quiet, shard=shard, answers=answers)
        _say(quiet, result.summary(test.name) + "; `jaxapf compare` without --shard writes the report once every "
                    "shard's test parts are there")
        return {"name": spec.name, "shard": list(shard), "selections_done": len(jobs), "selections_missing": 0,
                "test": {"episodes": result.episodes + result.skipped, "seconds": result.seconds}}
    write_atomic(out / "selection.csv", csv_text(selection_table(spec, selections)))

    test = test_sweep_spec(spec, selections)
    result = run_sweep(test, out / "test.parquet", quiet=quiet, answers=answers)
    _say(quiet, result.summary(test.name))
    report = build_report(out / "test.parquet", out / "report",
                          ReportOptions(baseline=baseline_filter(spec), pair_on=("selection",), heatmap=None,
                                        gallery=gallery, resamples=resamples))
    markdown = compare_markdown(spec, selections, report.summary, report.comparisons)
    write_atomic(out / "compare.md", markdown)
    summary = {"name": spec.name, "spec_file": text, "spec_digest": digest, "versions": versions(),
               "selections": [s.to_json() for s in selections],
               "test": {"episodes": result.episodes + result.skipped, "seconds": result.seconds}}
    write_atomic(out / "summary.json", json.dumps(summary, indent=2, default=_plain) + "\n")
    _say(quiet, f"wrote {out}/: compare.md, selection.csv, summary.json, test.parquet, report/")
    return summary


def selection_table(spec: CompareSpec, selections: Sequence[Selection]) -> pd.DataFrame:
    """``selection.csv``: each selection's budget, outcome and the scalar gains it chose (an array-valued gain's
    numbers are in ``selection/<method>-seed<s>.json``)."""
    return pd.DataFrame([{k: v for k, v in s.to_json().items() if k != "gains"}
                         | {g: s.gains[g] for g in spec.method_gains(s.method) if not GAINS.get(g).shape}
                         for s in selections])


def read_selections(spec: CompareSpec, path: str | pathlib.Path) -> list[Selection]:
    """The selections of a ``selection.csv`` (:func:`selection_table`), each with the scalar gains it chose (an
    array-valued gain's numbers are not in the table)."""
    import dataclasses

    from ..io.names import open_read

    with open_read(path, 1 << 24) as fh:
        table = pd.read_csv(fh)
    fields = [f.name for f in dataclasses.fields(Selection) if f.name != "gains"]
    return [Selection(**{k: r[k] for k in fields}, gains={g: float(r[g]) for g in spec.method_gains(r["method"])
                                                          if g in r and pd.notna(r[g])})
            for _, r in table.iterrows()]


def _plain(x: Any) -> Any:
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    raise TypeError(type(x).__name__)


# --------------------------------------------------------------------------------------------
# compare.md
# --------------------------------------------------------------------------------------------


def _md(frame: pd.DataFrame) -> list[str]:
    cols = [str(c) for c in frame.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in frame.itertuples(index=False)]
    return lines + [""]


def _pct(x: float) -> str:
    return "–" if not math.isfinite(float(x)) else f"{100 * float(x):.1f}"


def baseline_filter(spec: CompareSpec) -> str:
    """The report's ``--baseline`` for the spec's baseline method (``method=basic[,filter=...]``)."""
    return ",".join(f"{k}={v}" for k, v in spec.settings(spec.baseline).items())


def rows_of(summary: pd.DataFrame, spec: CompareSpec, method: str) -> pd.DataFrame:
    """The rows of a report table that belong to the compared ``method`` (planner and filter)."""
    mask = np.ones(len(summary), bool)
    for column, value in spec.settings(method).items():
        mask &= (summary[column] == value).to_numpy()
    return summary[mask]


def _setting_of(summary: pd.DataFrame, spec: CompareSpec, method: str, selection: str) -> int:
    rows = rows_of(summary, spec, method)
    return int(rows.loc[rows["selection"] == selection, "setting"].iloc[0])


def compare_markdown(spec: CompareSpec, selections: Sequence[Selection], summary: pd.DataFrame,
                     comparisons: pd.DataFrame) -> str:
    """``compare.md``: what the held-out test says first, then budgets, selected gains, test rates per seed
    with their spread, and the verdicts against the baseline seed by seed (every number from the
    selections and the report)."""
    sel = spec.selection
    tags = [_tag(s) for s in sel.seeds]
    lines = [f"# jaxapf compare — {spec.name}", "",
             f"- methods: {', '.join(spec.methods)}; baseline: {spec.baseline}",
             f"- selection: {_searches(spec)} on {', '.join(sel.families)}; budget {sel.budget:,} episode "
             f"rollouts per method and seed; seeds {', '.join(map(str, sel.seeds))}; searched gains "
             f"{', '.join(sel.gains)} (each method those it reads)",
             f"- test: {spec.test.fields} held-out fields per family of seed {spec.test.seed} on "
             f"{', '.join(spec.test.families)}; every method at its defaults and at each seed's selection",
             "- statistics and definitions: [report/report.md](report/report.md) (each setting is paired with "
             f"{spec.baseline} of the same selection)", ""]
    verdicts, findings = _verdict_tables(spec, summary, comparisons, tags)
    lines += _conclusions(spec, findings, tags) + _selection_tables(spec, selections) + _test_rates(spec, summary,
                                                                                                    tags)
    return "\n".join(lines + verdicts)


def _selection_tables(spec: CompareSpec, selections: Sequence[Selection]) -> list[str]:
    """compare.md's budget and outcome of every selection, and the gains each chose."""
    lines = ["## Selection: budget and outcome per method and seed", ""]
    rows = [{"method": s.method, "seed": s.seed, "search": s.search, "candidates": s.candidates,
             "fields per candidate": s.fields_per_candidate, "episodes": f"{s.episodes:,} of {s.budget:,}",
             "seconds": f"{s.seconds:.1f}", "training success %": _pct(s.selection_success), "chosen": s.chosen}
            for s in selections]
    lines += _md(pd.DataFrame(rows))
    lines += ["## Selected gains", ""]
    gains = [g for g in spec.selection.gains if any(g in spec.method_gains(m) for m in spec.methods)]
    rows = [{"method": s.method, "seed": s.seed, **{g: _gain_text(s, g) if g in spec.method_gains(s.method) else "–"
                                                    for g in gains}} for s in selections]
    return lines + _md(pd.DataFrame(rows))


def _gain_text(s: Selection, gain: str) -> str:
    """A selected gain in compare.md: the number, or where an array-valued gain's numbers are."""
    if GAINS.get(gain).shape:
        return f"{len(s.gains[gain]):,} numbers (selection/{s.method}-seed{s.seed}.json)"
    return f"{s.gains[gain]:.3g}"


def _searches(spec: CompareSpec) -> str:
    """How the methods' gains were selected, in words: ``random search`` or ``random search (gradient for X)``."""
    sel = spec.selection
    other = [f"{how} for {m}" for m, how in sel.searches if how != sel.search]
    return f"{sel.search} search" + (f" ({'; '.join(other)})" if other else "")


def _test_rates(spec: CompareSpec, summary: pd.DataFrame, tags: list[str]) -> list[str]:
    """compare.md's held-out rates per selection and their spread over the seeds."""
    lines = ["## Held-out test: rates per selection, and their spread over seeds", "",
             "Rates in %; *spread* is the mean over the selection seeds [lowest, highest].", ""]
    for metric in ("success", "collision", "stalled"):
        rows = []
        for group in dict.fromkeys(summary["family"]):
            for m in spec.methods:
                sub = rows_of(summary[summary["family"] == group], spec, m).set_index("selection")
                values = [float(sub.at[t, f"{metric}_rate"]) for t in tags]
                rows.append({"group": group, "method": m, DEFAULT: _pct(sub.at[DEFAULT, f"{metric}_rate"]),
                             **{t: _pct(v) for t, v in zip(tags, values)},
                             "spread": f"{_pct(np.mean(values))} [{_pct(min(values))}, {_pct(max(values))}]"})
        lines += [f"### {metric}", ""] + _md(pd.DataFrame(rows))
    return lines


def _verdict_tables(spec: CompareSpec, summary: pd.DataFrame, comparisons: pd.DataFrame, tags: list[str]
                    ) -> tuple[list[str], list[tuple[str, str, pd.Series]]]:
    """compare.md's paired differences to the baseline seed by seed, and the pooled verdict counts of each
    method on success and collision (``findings``)."""
    lines = ["## Against the baseline, seed by seed", "",
             f"Each cell: the paired difference to {spec.baseline} of the same selection with the interval that "
             "decided its verdict and that interval's level (rates in percentage points; Tango score / "
             f"Hodges-Lehmann), then the verdict: {stats.VERDICT_RULE}.", ""]
    findings = []
    for m in spec.methods:
        if m == spec.baseline:
            continue
        rows = []
        for group in dict.fromkeys(summary["family"]):
            for metric in _VERDICT_METRICS:
                cells, verdicts, deltas = {}, [], []
                for t in (DEFAULT, *tags):
                    sid = _setting_of(summary, spec, m, t)
                    r = comparisons[(comparisons["setting"] == sid) & (comparisons["family"] == group)
                                    & (comparisons["metric"] == metric)]
                    if not len(r):
                        cells[t] = "–"
                        continue
                    r = r.iloc[0]
                    scale = 100.0 if metric in ("success", "collision", "stalled") else 1.0
                    lo, hi = scale * r["delta_lo"], scale * r["delta_hi"]
                    level = stats.format_level(r["confidence"])
                    cells[t] = (f"– {r['verdict']}" if not math.isfinite(r["delta"]) else
                                f"{scale * r['delta']:+.3g} [no {level} CI from {int(r['n_pairs'])} pairs] "
                                f"{r['verdict']}" if not (math.isfinite(lo) and math.isfinite(hi)) else
                                f"{scale * r['delta']:+.3g} [{lo:+.3g}, {hi:+.3g}] at {level} {r['verdict']}")
                    if t != DEFAULT:
                        verdicts.append(str(r["verdict"]))
                        deltas.append(scale * float(r["delta"]))
                counts = pd.Series(verdicts).value_counts()
                agreement = ", ".join(f"{v} {c}/{len(tags)}" for v, c in counts.items())
                rows.append({"group": group, "metric": metric, **cells, "tuned seeds": agreement})
                if group == "all" and metric in ("success", "collision") and len(verdicts) == len(tags):
                    findings.append((m, metric, counts, stats.seed_interval(deltas)))
        lines += [f"### {m} vs {spec.baseline}", ""] + _md(pd.DataFrame(rows))
    return lines, findings


def _conclusions(spec: CompareSpec, findings: list[tuple[str, str, pd.Series, tuple]], tags: list[str]) -> list[str]:
    """compare.md's closing list: what every selection seed agrees on, and where they do not, each with the mean
    difference over the seeds and its t interval (the seeds as a sample of selections)."""
    lines = ["## What the test says (pooled over the test families)", "",
             "Per method and rate: the selection seeds' verdicts against the baseline (the answer follows them), "
             "then the mean paired difference over the seeds in percentage points with its 95 % t interval over "
             "the seeds.", ""]
    for m, metric, counts, (mean, lo, hi) in findings:
        top, n = counts.index[0], int(counts.iloc[0])
        tally = ", ".join(f"{v} {c}" for v, c in counts.items())
        over = (f"; mean over the seeds {mean:+.3g} [{lo:+.3g}, {hi:+.3g}] pp" if math.isfinite(lo) else
                f"; mean over the seeds {mean:+.3g} pp")
        if n == len(tags):
            lines.append(f"- {m} vs {spec.baseline}, {metric}: **{top}** for every selection seed ({n}/{len(tags)})"
                         f"{over}.")
        elif "better" in counts.index and "worse" in counts.index:
            lines.append(f"- {m} vs {spec.baseline}, {metric}: the selection seeds contradict each other ({tally})"
                         f"{over}: no conclusion survives the selection's randomness.")
        else:
            lines.append(f"- {m} vs {spec.baseline}, {metric}: {top} for {n} of {len(tags)} selection seeds ({tally})"
                         f"{over}: not robust to the selection's randomness.")
    return lines + [""]
