"""Shared machinery of the studies in ``analysis/``: run a sweep spec of ``sweeps/`` (resuming
whatever is already on disk), write its report, and phrase findings with the report's own numbers.

Every study script is ``sweep -> report -> README.md``: the sweep goes to ``runs/`` (git-ignored,
resumable), the report and the conclusion to ``analysis/results/<study>/`` (committed). The
sentences of a conclusion are built here from ``summary`` and ``comparisons`` of
:func:`jaxapf.report.build_report`, never typed by hand, so rerunning a study rewrites them.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import math
import os
import pathlib
import shutil
import sys
from typing import Any, Callable, Mapping

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
RESULTS = ROOT / "analysis" / "results"
#: The report's rate chart, as most studies caption it in their README.
RATES_FIGURE = ("report/figures/rates.png", "Success, collision and stall rates with Wilson intervals")


def positive(text: str) -> int:
    """An argparse type: a whole number >= 1 (``--fields``, ``--resamples``)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be at least 1")
    return value


def parser(doc: str) -> argparse.ArgumentParser:
    """The command line every study shares."""
    p = argparse.ArgumentParser(description=doc.splitlines()[0], epilog="\n".join(doc.splitlines()[1:]),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--fields", type=positive, help="fields per family instead of the spec's (smaller: faster, "
                                               "wider intervals); the sweep then goes to runs/NAME-fN.parquet")
    p.add_argument("--resamples", type=positive, default=2000, help="bootstrap resamples of the report (default 2000)")
    p.add_argument("--out", type=pathlib.Path, help="results folder (default analysis/results/<study>)")
    p.add_argument("--facts-only", action="store_true",
                   help="rewrite facts.json from the committed results (the report's tables and the study's own), "
                        "simulating nothing")
    p.add_argument("--from-episodes", action="store_true",
                   help="rebuild the reports, the findings and facts.json from the committed episodes "
                        "(episodes.parquet in the results folder), simulating nothing")
    p.add_argument("--kept-selections", action="store_true",
                   help="a compare study: fly its test at the selections of its committed selection.csv "
                        "instead of selecting again")
    return p


def entry(main: Callable[[], int | None]) -> None:
    """Run a study's ``main`` as the CLI runs a command: a bad spec, a held lock or an interruption is
    one line on stderr (what was kept: every finished part under ``runs/``), never a traceback."""
    from jaxapf.validation import ConfigError, Interrupted

    name = pathlib.Path(sys.argv[0]).name
    try:
        sys.exit(main())
    except ConfigError as err:
        print(f"{name}: error: {err}", file=sys.stderr)
        sys.exit(2)
    except (Interrupted, KeyboardInterrupt):
        print(f"{name}: interrupted; finished parts under runs/ are kept, and a rerun resumes them", file=sys.stderr)
        sys.exit(130)


def setup_jax() -> None:
    """One JAX device per usable core and the persistent compilation cache, as ``jaxapf sweep`` does.
    Must run before anything touches JAX's backend."""
    from jaxapf.engine import configure_jax, default_cache_dir

    configure_jax(cache_dir=default_cache_dir(), cpu_devices=len(os.sched_getaffinity(0)))


def begin(doc: str, name: str, flags: dict[str, str] | None = None) -> tuple[argparse.Namespace, pathlib.Path]:
    """What every study does first: parse the shared flags (and a study's own switches, ``flags``: name ->
    help), set up JAX, and make the results folder (``--out``, default ``analysis/results/<name>``); returns
    the flags and the folder."""
    p = parser(doc)
    for flag, text in (flags or {}).items():
        p.add_argument(flag, action="store_true", help=text)
    args = p.parse_args()
    setup_jax()
    out = args.out or RESULTS / name
    out.mkdir(parents=True, exist_ok=True)
    return args, out


def keep_episodes(parquet: pathlib.Path, out: pathlib.Path) -> pathlib.Path:
    """``out/episodes.parquet``: the sweep's episodes with only the columns its report reads (the settings'
    columns, the field keys, ``solvable`` and the report's metrics), as one verified sweep part that
    ``jaxapf report`` reads: a later change to the statistics re-derives the study from it
    (``--from-episodes``) without a rerun."""
    from jaxapf.report.load import report_metrics
    from jaxapf.sweep import read_sweep
    from jaxapf.sweep.output import write_rows

    df, meta = read_sweep(parquet)
    rates, continuous = report_metrics(meta["metrics"])
    metrics = [m for m in meta["metrics"] if m in (*rates, *continuous, "invalid")]
    columns = [c for c in df.columns if c not in meta["metrics"] or c in metrics]
    return write_rows(out, "episodes.parquet", df[columns], meta, metrics)


def keep_rows(df, out: pathlib.Path, columns: tuple[str, ...]) -> pathlib.Path:
    """``out/episodes.parquet``: a study's own per-episode rows (one it flies without a sweep) with only the
    ``columns`` its pages and facts read (Parquet's dictionary encoding stores the repeated text once), which
    ``--from-episodes`` reads back (:func:`kept`) instead of flying them again."""
    path = out / "episodes.parquet"
    df[list(columns)].to_parquet(path, index=False, compression="zstd")
    return path


def kept_rows(out: pathlib.Path):
    """The rows :func:`keep_rows` kept in ``out``, read through jaxapf's checked opener (a regular file, no link,
    never blocking, at most 256 MiB); one line where the study kept none."""
    import pandas as pd

    from jaxapf.io.names import open_read

    with open_read(kept(out), 1 << 28) as fh:
        return pd.read_parquet(fh)


def kept_table(out: pathlib.Path, name: str, flag: str):
    """The committed CSV table ``out/name`` that ``flag`` reads, through jaxapf's checked opener (a regular file,
    no link, never blocking, at most 16 MiB); one line where it is missing."""
    import pandas as pd

    from jaxapf.io.names import open_read

    with open_read(kept(out, name, flag), 1 << 24) as fh:
        return pd.read_csv(fh)


def kept(out: pathlib.Path, name: str = "episodes.parquet", flag: str = "--from-episodes") -> pathlib.Path:
    """``out/name``, which ``flag`` reads; one line where the study kept none."""
    from jaxapf.validation import ConfigError

    path = out / name
    if not path.exists():
        raise ConfigError(f"{flag}: {path} does not exist; run the study once without it")
    return path


def sweep_source(args: argparse.Namespace, out: pathlib.Path, name: str) -> pathlib.Path:
    """The episodes a study reports: ``sweeps/<name>.toml`` run now (:func:`run_spec`) and kept in
    ``out/episodes.parquet`` (:func:`keep_episodes`), or with ``--from-episodes`` the committed ones."""
    if args.from_episodes:
        return kept(out)
    parquet = run_spec(name, args.fields)
    keep_episodes(parquet, out)
    return parquet


def run_spec(name: str, fields: int | None = None) -> pathlib.Path:
    """Run ``sweeps/<name>.toml`` (optionally with another field count) into ``runs/``; finished
    chunks already there are kept, so a rerun only computes what is missing. Returns the dataset."""
    from jaxapf.sweep import load_spec, run_sweep

    spec = load_spec(ROOT / "sweeps" / f"{name}.toml")
    suffix = ""
    if fields is not None:
        spec = dataclasses.replace(spec, fields=fields)
        suffix = f"-f{fields}"
    out = ROOT / "runs" / f"{spec.name}{suffix}.parquet"
    result = run_sweep(spec, out, quiet=not sys.stderr.isatty())
    print(result.summary(spec.name))
    return out


def report(parquet: pathlib.Path, out: pathlib.Path, *, resamples: int, folder: str = "report", **options: Any):
    """:func:`jaxapf.report.build_report` into ``out/<folder>``, keeping what a reader of the repository
    needs (``report.md`` with its PNG figures, ``summary.csv``, ``comparisons.csv``, ``table.tex``);
    the self-contained HTML is dropped here (``jaxapf report`` writes it)."""
    from jaxapf.report import ReportOptions, build_report

    target = out / folder
    if target.exists():
        shutil.rmtree(target)
    result = build_report(parquet, target, ReportOptions(resamples=resamples, **options))
    (target / "report.html").unlink(missing_ok=True)
    return result


def run_comparison(args: argparse.Namespace, spec_file: str, selections: pathlib.Path):
    """``jaxapf compare sweeps/<spec_file>`` with the study's ``--fields`` and ``--resamples``, into
    ``runs/compare-NAME[-fN]`` (resuming what is finished; with ``--kept-selections`` the test flown at the
    selections of the committed table ``selections``). Returns ``(spec, runs folder)``."""
    from jaxapf.compare import load_compare_spec, run_compare_spec

    spec, text = load_compare_spec(ROOT / "sweeps" / spec_file)
    suffix = ""
    if args.fields:
        spec = dataclasses.replace(spec, test=dataclasses.replace(spec.test, fields=args.fields))
        suffix = f"-f{args.fields}"
    runs = ROOT / "runs" / f"compare-{spec.name}{suffix}"
    if args.kept_selections:
        from jaxapf.compare.protocol import read_selections
        from jaxapf.compare.select import restore

        restore(spec, read_selections(spec, kept(selections.parent, selections.name, "--kept-selections")),
                runs / "selection")
    run_compare_spec(spec, text, runs, quiet=True, resamples=args.resamples)
    return spec, runs


def rebuild_comparison(args: argparse.Namespace, out: pathlib.Path, spec_file: str):
    """``--from-episodes`` of a compare study: its report again from the committed ``out/episodes.parquet`` and
    ``compare.md`` from it and the committed selections, simulating nothing. Returns the spec."""
    from jaxapf.compare import load_compare_spec
    from jaxapf.compare.protocol import baseline_filter, compare_markdown, read_selections

    spec = load_compare_spec(ROOT / "sweeps" / spec_file)[0]
    result = report(kept(out), out, resamples=args.resamples, baseline=baseline_filter(spec),
                    pair_on=("selection",), heatmap=None, gallery=0)
    markdown = compare_markdown(spec, read_selections(spec, out / "selection.csv"), result.summary,
                                result.comparisons)
    (out / "compare.md").write_text(markdown)
    return spec


def run_compare_study(args: argparse.Namespace, out: pathlib.Path, spec_file: str):
    """What a ``jaxapf compare`` study does after :func:`begin`: :func:`run_comparison`, then its test's episodes
    kept (:func:`keep_episodes`), its report (without its HTML), ``compare.md`` and ``selection.csv`` copied into
    the results folder ``out``. Returns ``(spec, runs folder)``."""
    spec, runs = run_comparison(args, spec_file, out / "selection.csv")
    keep_episodes(runs / "test.parquet", out)
    target = out / "report"
    if target.exists():
        shutil.rmtree(target)
    shutil.copytree(runs / "report", target)
    (target / "report.html").unlink(missing_ok=True)
    shutil.copy(runs / "compare.md", out / "compare.md")
    shutil.copy(runs / "selection.csv", out / "selection.csv")
    return spec, runs


def run_study(doc: str, *, name: str, spec: str, title: str, findings: Callable[["Numbers"], str],
              figures: Callable[[pathlib.Path], list[tuple[str, str]]] | list[tuple[str, str]],
              before: Callable[[pathlib.Path], list[str]] | None = None,
              facts: Callable[["Numbers", pathlib.Path], dict] | None = None, **report_options: Any) -> None:
    """What every study's ``main`` is: parse the shared flags, run ``sweeps/<spec>.toml``, write its
    report with ``report_options``, and ``README.md`` with ``before(out)``'s sections (work that does
    not come from the sweep, e.g. single runs), then ``findings(Numbers)`` and the figures; then
    ``facts.json``, ``facts(Numbers, out)`` of the report as written (with ``--facts-only`` only that, from
    the committed report)."""
    args, out = begin(doc, name)
    if not args.facts_only:
        sections = before(out) if before is not None else []
        parquet = sweep_source(args, out, spec)
        result = report(parquet, out, resamples=args.resamples, **report_options)
        sections.append(findings(Numbers(result)))
        write_readme(out, title, command_line(name, args), parquet, sections,
                     figures(out) if callable(figures) else figures)
        print(f"wrote {out}/README.md")
    if facts is not None:
        write_facts(out, facts(Numbers(committed_report(out)), out))


# --------------------------------------------------------------------------------------------
# numbers of the report, as text
# --------------------------------------------------------------------------------------------


def _select(frame, where: Mapping[str, Any]):
    mask = None
    for column, value in where.items():
        m = frame[column].astype(str) == str(value)
        mask = m if mask is None else mask & m
    rows = frame[mask]
    if len(rows) != 1:
        raise LookupError(f"{len(rows)} rows match {dict(where)}")
    return rows.iloc[0]


@dataclasses.dataclass(frozen=True)
class Delta:
    """One paired comparison of the report: setting minus baseline, with its estimate, interval,
    test and verdict (better, worse, equivalent within the metric's margin, or inconclusive)."""

    metric: str
    delta: float
    lo: float
    hi: float
    p_holm: float
    verdict: str
    higher_is_better: bool
    value: float
    baseline_value: float
    n_pairs: int
    conditioning: str = "all pairs"

    @property
    def better(self) -> bool:
        """Relevantly better than the baseline (the report's verdict)."""
        return self.verdict == "better"

    @property
    def worse(self) -> bool:
        """Relevantly worse than the baseline (the report's verdict)."""
        return self.verdict == "worse"

    @property
    def equivalent(self) -> bool:
        """Shown to lie within the metric's relevance margin."""
        return self.verdict == "equivalent"

    def text(self) -> str:
        """``+5.9 pp [+4.8, +6.9] (worse, Holm p < 0.001)``: rates in percentage points (Newcombe
        interval), continuous metrics as the Hodges-Lehmann shift (signed-rank interval)."""
        scale, unit = (100.0, " pp") if self.metric in RATE_METRICS else (1.0, "")
        p = "< 0.001" if self.p_holm < 0.001 else f"= {self.p_holm:.3f}"
        if not np.isfinite(self.delta):
            return f"– ({self.verdict})"
        return (f"{scale * self.delta:+.3g}{unit} [{scale * self.lo:+.3g}, {scale * self.hi:+.3g}] "
                f"({self.verdict}, Holm p {p})")


RATE_METRICS = ("success", "collision", "stalled")


class Numbers:
    """Lookups in a report's ``summary`` (per setting × family) and ``comparisons`` tables.

    Settings are named by their column values, e.g. ``{"method": "direction_velocity"}``.
    """

    def __init__(self, result) -> None:
        self.summary = result.summary
        self.comparisons = result.comparisons

    def families(self) -> list[str]:
        """Families of the report, without the pooled ``all`` row."""
        return [f for f in dict.fromkeys(self.summary["family"]) if f != "all"]

    def row(self, setting: Mapping[str, Any], family: str):
        return _select(self.summary, {**setting, "family": family})

    def rate(self, setting: Mapping[str, Any], family: str, metric: str) -> str:
        """``30.7 % [26.8, 34.8]`` (Wilson)."""
        r = self.row(setting, family)
        return f"{100 * r[f'{metric}_rate']:.1f} % [{100 * r[f'{metric}_lo']:.1f}, {100 * r[f'{metric}_hi']:.1f}]"

    def rate_value(self, setting: Mapping[str, Any], family: str, metric: str) -> float:
        return float(self.row(setting, family)[f"{metric}_rate"])

    def iqm(self, setting: Mapping[str, Any], family: str, metric: str) -> str:
        """``0.917 [0.896, 0.948]`` (IQM, bootstrap)."""
        r = self.row(setting, family)
        if not np.isfinite(r[f"{metric}_iqm"]):
            return "– (no episodes)"
        return f"{r[f'{metric}_iqm']:.3g} [{r[f'{metric}_iqm_lo']:.3g}, {r[f'{metric}_iqm_hi']:.3g}]"

    def delta(self, setting: Mapping[str, Any], family: str, metric: str) -> Delta:
        sid = int(_select(self.summary, {**setting, "family": family})["setting"])
        c = self.comparisons
        rows = c[(c["setting"] == sid) & (c["family"] == family) & (c["metric"] == metric)]
        if len(rows) != 1:
            raise LookupError(f"no comparison of {dict(setting)} on {family}, {metric}")
        r = rows.iloc[0]
        return Delta(metric, float(r["delta"]), float(r["delta_lo"]), float(r["delta_hi"]), float(r["p_holm"]),
                     str(r["verdict"]), bool(r["higher_is_better"]), float(r["value"]),
                     float(r["baseline_value"]), int(r["n_pairs"]), str(r["conditioning"]))


RATE_COLUMNS = ("success", "collision", "stalled")


def rates(episodes) -> dict[str, float]:
    """The success, collision and stall rates of ``episodes`` (rows of outcomes), each with its 95 %
    Wilson interval (``success_lo``, ``success_hi``, ...)."""
    from jaxapf.stats import rate_row

    row = {}
    for rate in RATE_COLUMNS:
        r = rate_row(episodes[rate].to_numpy())
        row |= {rate: r.rate, f"{rate}_lo": r.lo, f"{rate}_hi": r.hi}
    return row


def paired_success(now, then) -> dict[str, float]:
    """The change in success of ``now`` against ``then`` on the same fields (bool arrays, paired) and the counts
    the verdict reads (``b``: pairs only ``now`` succeeds in, ``c``: only ``then``, ``n_pairs``), for
    :func:`mark_verdicts`."""
    from jaxapf.stats import RatePairs

    r = RatePairs.of(now, then)
    return {"success_change": r.estimate, "b": r.b, "c": r.c, "n_pairs": r.n}


def unanimous(verdicts) -> str:
    """The one verdict all of ``verdicts`` (e.g. the three selection seeds') give, or ``mixed``."""
    marks = set(verdicts)
    return marks.pop() if len(marks) == 1 else "mixed"


#: A verdict of the other side against the question's: the same evidence, the question's side's word.
MIRROR = {"better": "worse", "worse": "better", "equivalent": "equivalent", "inconclusive": "inconclusive"}


def answer_fact(verdicts: Mapping[str, str], mirror: bool = False) -> dict:
    """A yes/no question's answer fact: its deciding verdicts (named, e.g. ``direction seed1``) and the word
    :func:`jaxapf.stats.answer` derives from them (tests/bindings.py checks both where a page binds the word).
    ``mirror``: the verdicts are of the other side against the question's."""
    from jaxapf.stats import answer

    named = {k: MIRROR[v] if mirror else v for k, v in verdicts.items()}
    return {"word": answer(list(named.values())), "verdicts": named}


def recover_counts(change: float, n: int, p: float, p_equivalent: float, margin: float) -> tuple[int, int]:
    """The discordant counts ``(b, c)`` behind a row committed before the tables kept them: the one pair with
    ``(b - c)/n = change`` whose exact McNemar p and Tango TOST p (the tests of that time) are the row's ``p``
    and ``p_equivalent`` to ten digits; LookupError where none or several are."""
    from scipy.stats import binomtest, norm

    from jaxapf.stats import _tango_z  # the statistic of the tests the row holds

    d = round(change * n)
    found = []
    for total in range(abs(d), n + 1, 2):
        b, c = (total + d) // 2, (total - d) // 2
        exact = 1.0 if total == 0 else min(1.0, float(binomtest(b, total, 0.5).pvalue))
        # the TOST p of that time: the larger one-sided p of Tango's score tests at ±margin (uncapped)
        tost = max(norm.cdf(_tango_z(b, c, n, margin)), norm.cdf(_tango_z(c, b, n, margin)))
        if math.isclose(exact, p, rel_tol=1e-10, abs_tol=1e-300) and (
                math.isnan(p_equivalent) or math.isclose(tost, p_equivalent, rel_tol=1e-8, abs_tol=1e-300)):
            found.append((b, c))
    if len(found) != 1:
        raise LookupError(f"{len(found)} count pairs give change {change!r}, p {p!r}, p_equivalent {p_equivalent!r} "
                          f"over {n} pairs")
    return found[0]


def rederive(table, margin, family=None, higher_is_better=True, change: str = "change", n: str = "n"):
    """A committed table of paired rates (``change``, ``p``, ``p_equivalent`` per row, ``n`` pairs; rows without
    ``p`` untested) with its verdicts derived again by today's :func:`mark_verdicts`, from the counts it holds
    (``b``, ``c``, ``n_pairs``) or, for a table committed before it held them, from :func:`recover_counts`."""
    import pandas as pd

    table = pd.DataFrame(table).reset_index(drop=True)
    if "b" not in table.columns:
        tested = table["p"].notna()
        margins = np.broadcast_to(np.asarray(margin, dtype=np.float64), (len(table),))
        counts = [recover_counts(float(r[change]), int(r[n]), float(r["p"]), float(r["p_equivalent"]), float(m))
                  if t else (np.nan, np.nan) for (_, r), t, m in zip(table.iterrows(), tested, margins)]
        table["b"], table["c"] = [b for b, _ in counts], [c for _, c in counts]
        table["n_pairs"] = np.where(tested, table[n], np.nan)
    return mark_verdicts(table, margin, family, higher_is_better)


def mark_verdicts(rows, margin, family=None, higher_is_better=True):
    """The rows (dicts or a table; those with a paired comparison carry :func:`paired_success`'s ``b``, ``c``,
    ``n_pairs``) as a table with the verdict of :func:`jaxapf.stats.decide`: Holm within each ``family`` (one per
    row, or one for the study), each row's interval ``change_lo``, ``change_hi`` at the level that decided it
    (``confidence``), its tests ``p``, ``p_equivalent`` and their Holm-adjusted ``p_holm``,
    ``p_equivalent_holm``. ``margin``, ``family`` and ``higher_is_better`` may be columns (sequences)."""
    import pandas as pd

    from jaxapf.stats import RatePairs, decide

    table = pd.DataFrame(rows).reset_index(drop=True)
    tested = table["b"].notna().to_numpy() if "b" in table.columns else np.zeros(len(table), bool)
    pick = lambda v: np.broadcast_to(np.asarray(v, dtype=object), (len(table),))[tested]  # noqa: E731
    part = table[tested]
    found = [RatePairs(int(r.b), int(r.c), int(r.n_pairs)) for r in part.itertuples()]
    d = decide(found, pick(margin).astype(np.float64), pick(higher_is_better).astype(bool),
               None if family is None else pick(family), 0.05)
    for column, values in (("change_lo", d.lo), ("change_hi", d.hi), ("confidence", d.confidence), ("p", d.p),
                           ("p_equivalent", d.p_equivalence), ("p_holm", d.p_holm),
                           ("p_equivalent_holm", d.p_equivalence_holm), ("verdict", d.verdict)):
        table.loc[tested, column] = values
    return table


def write_results(out: pathlib.Path, lines: list[str], facts: dict) -> dict:
    """A study's conclusion page (``README.md``, the ``lines``) and its numbers (:func:`write_facts`) in
    ``out``; returns the facts."""
    (out / "README.md").write_text("\n".join(lines) + "\n")
    write_facts(out, facts)
    return facts


def committed_report(out: pathlib.Path, folder: str = "report") -> Any:
    """The report a study committed (``out/<folder>/summary.csv`` and ``comparisons.csv``), as
    :class:`Numbers` reads it: what ``--facts-only`` works from."""
    import types

    import pandas as pd

    folder = out / folder
    return types.SimpleNamespace(summary=pd.read_csv(folder / "summary.csv"),
                                 comparisons=pd.read_csv(folder / "comparisons.csv"))


def write_facts(out: pathlib.Path, facts: Mapping[str, Any]) -> pathlib.Path:
    """``out/facts.json``: the named values a study's findings state, for the docs to bind their numbers
    to (tests/bindings.py); written with every run of the study, and by ``--facts-only`` from its
    committed results."""
    import json

    path = out / "facts.json"
    path.write_text(json.dumps(facts, indent=1, sort_keys=True, default=float) + "\n")
    return path


def command_line(name: str, args: argparse.Namespace, flags: Mapping[str, str] | None = None) -> str:
    """The command that made a study's page: the script with the shared flags that change what it flies or
    reads (``--fields``, ``--from-episodes``, ``--kept-selections``) and the study's own switches set."""
    shared = {"--from-episodes": args.from_episodes, "--kept-selections": getattr(args, "kept_selections", False)}
    own = {flag: getattr(args, flag[2:].replace("-", "_")) for flag in flags or {}}
    return (f"python analysis/{name}.py" + (f" --fields {args.fields}" if args.fields else "")
            + "".join(f" {flag}" for flag, on in (shared | own).items() if on))


def write_readme(out: pathlib.Path, title: str, command: str, parquet: pathlib.Path, sections: list[str],
                 figures: list[tuple[str, str]]) -> pathlib.Path:
    """``out/README.md``: the question's title, how it was produced, the findings and the figures
    (paths relative to ``out``)."""
    import jax

    from jaxapf.io.versions import versions

    v = versions()
    kept = parquet if parquet.resolve().parent == out.resolve() else (
        out / "episodes.parquet" if (out / "episodes.parquet").exists() else None)
    lines = [f"# {title}", "",
             f"Produced by `{command}` on {datetime.date.today().isoformat()} "
             f"(jaxapf {v.get('jaxapf')}, jax {jax.__version__}, {jax.devices()[0].platform} × {jax.device_count()}); "
             + (f"episodes: [`{kept.name}`]({kept.name}) (the columns the study reads, committed; "
                "`--from-episodes` rebuilds this page from them without simulating). "
                if kept is not None else
                f"episodes: `{parquet.relative_to(ROOT)}` (git-ignored, rebuilt by the command). ")
             +
             "Every number below is read from the report in `report/` (`summary.csv`, `comparisons.csv`); "
             "the full tables and their definitions are in [`report/report.md`](report/report.md).", ""]
    for section in sections:
        lines += [section.rstrip(), ""]
    if figures:
        lines += ["## Figures", ""]
        for path, caption in figures:
            lines += [f"![{caption}]({path})", "", f"*{caption}*", ""]
    path = out / "README.md"
    path.write_text("\n".join(lines))
    return path
