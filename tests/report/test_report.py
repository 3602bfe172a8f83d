"""``jaxapf report`` end to end on small synthetic sweeps (Parquet written here with pyarrow)."""

from __future__ import annotations

import json
import math
import pathlib
import re

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import ROOT
from scipy import stats as sst

from jaxapf import stats
from jaxapf.cli import main
from jaxapf.metrics import METRICS
from jaxapf.report import ReportError, ReportOptions, build_report, load_sweep, report_metrics
from jaxapf.report.document import _SORT
from jaxapf.report.figures import _heatmap_figures
from jaxapf.report.select import select

RATES, CONTINUOUS = report_metrics()

RESAMPLES = 200
META = {"format": "jaxapf.sweep/1", "spec": {"name": "synthetic-test"}, "spec_hash": "f" * 64,
        "versions": {"jaxapf": "0.1.0", "jax": "0.0.test", "numpy": np.__version__},
        "prng": {"impl": "threefry2x32", "field_key": "fold_in(key(seed), field)"}, "dtype": "float32"}


def _settings() -> list[tuple[str, float, float]]:
    """basic × γ × k (basic ignores γ, k: four equivalent baselines) then direction_velocity × γ × k."""
    return [(m, g, k) for m in ("basic", "direction_velocity") for g in (0.5, 1.0) for k in (0.5, 1.0)]


def make_rows(families=("trap", "clutter"), fields: int = 12, seed: int = 7,
              settings: list | None = None) -> pd.DataFrame:
    """Episode rows in the documented column order; the same fields for every setting (CRN)."""
    rng = np.random.default_rng(seed)
    settings = settings or _settings()
    rows = []
    for fam in families:
        for f in range(fields):
            difficulty = rng.uniform()
            noise = rng.normal(size=5)
            for s, (method, gamma, k) in enumerate(settings):
                skill = 0.0 if method == "basic" else 0.25 + 0.1 * gamma - 0.05 * k
                u = difficulty - skill
                success = bool(u < 0.5)
                collision = bool(not success and u > 0.8)
                shift = np.zeros(5) if method == "basic" else np.array([0.3, -1.0, -0.05, -1.0, -0.2])
                e = noise + shift
                rows.append(dict(
                    setting=s, method=method, convention="intent", gamma=gamma, k=k, k_rep=10.0, d_s=4.0,
                    k_att=1.0, eta=0.5, dt=0.1, t_max=60.0, horizon=20, iters=30, family=fam, field=f, seed=0,
                    success=success, collision=collision,
                    min_clearance=(-0.1 - 0.1 * abs(e[0])) if collision else 0.5 + 0.2 * abs(e[0]),
                    time_to_goal=20.0 + 2.0 * e[1] if success else math.nan,
                    path_length=25.0 + abs(e[2]), path_ratio=1.05 + 0.1 * abs(e[2]),
                    stalled=bool(not success and not collision),
                    final_distance=0.4 if success else 3.0 + abs(e[3]),
                    control_effort=5.0 + abs(e[3]), jerk_rms=2.0 + abs(e[4]), max_velocity_excess=0.0,
                    time_near=1.0, min_ttc=3.0, spl=0.9 if success else 0.0, steps=200))
    df = pd.DataFrame(rows)
    df["setting"] = df["setting"].astype("int32")
    df["steps"] = df["steps"].astype("int32")
    return df


def write_sweep(path: pathlib.Path, df: pd.DataFrame, meta: dict | None = META, parts: int = 2) -> pathlib.Path:
    """A Parquet dataset directory of ``parts`` part files with the ``jaxapf`` schema metadata."""
    path.mkdir(parents=True, exist_ok=True)
    for i, idx in enumerate(np.array_split(np.arange(len(df)), parts)):
        table = pa.Table.from_pandas(df.iloc[idx], preserve_index=False)
        if meta is not None:
            table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                                   b"jaxapf": json.dumps(meta).encode()})
        pq.write_table(table, path / f"part-{i:05d}.parquet")
    return path


@pytest.fixture(scope="module")
def sweep(tmp_path_factory) -> tuple[pathlib.Path, pd.DataFrame]:
    df = make_rows()
    return write_sweep(tmp_path_factory.mktemp("runs") / "synthetic.parquet", df), df


@pytest.fixture(scope="module")
def report(sweep, tmp_path_factory) -> pathlib.Path:
    path, _ = sweep
    out = tmp_path_factory.mktemp("reports") / "synthetic"
    rc = main(["report", str(path), "--out", str(out), "--resamples", str(RESAMPLES), "--gallery", "0"])
    assert rc == 0
    return out


# --------------------------------------------------------------------------------------------
# outputs
# --------------------------------------------------------------------------------------------


SORT_SCRIPT = f"<script>{_SORT}</script>"


def test_outputs_exist_and_html_is_self_contained(report):
    for name in ("report.html", "report.md", "summary.csv", "comparisons.csv", "table.tex"):
        assert (report / name).stat().st_size > 0, name
    figures = {p.name for p in (report / "figures").iterdir()}
    for stem in ("ecdf_min_clearance", "rates", "continuous", "differences", "profile_spl",
                 "heatmap_success_direction_velocity", "heatmap_collision_direction_velocity"):
        assert f"{stem}.png" in figures, stem
    assert not any(name.endswith(".svg") for name in figures), "SVGs only with --svg"
    text = (report / "report.html").read_text(encoding="utf-8")
    assert "http://" not in text and "https://" not in text
    assert text.count(SORT_SCRIPT) == 1  # the page's one script: its tables' sorting, no user text in it
    assert not re.search(r"<(script|link|iframe|object|embed)\b", text.replace(SORT_SCRIPT, ""), re.I)
    assert not re.search(r"url\(", text)
    sources = re.findall(r"""src\s*=\s*["']([^"']*)""", text)
    assert sources and all(s.startswith("data:image/png;base64,") for s in sources)
    links = re.findall(r"""href\s*=\s*["']([^"']*)""", text)  # the contents: to headings of the page itself
    assert links and all(h.startswith("#") and f'id="{h[1:]}"' in text for h in links)
    md = (report / "report.md").read_text(encoding="utf-8")
    linked = re.findall(r"\]\((figures/[^)]+)\)", md)
    assert linked and all((report / f).is_file() for f in linked)


def test_the_conclusion_and_its_figure_come_first(report):
    md = (report / "report.md").read_text(encoding="utf-8")
    heads = [line for line in md.splitlines() if line.startswith("## ")]
    assert heads[:5] == ["## Bottom line", "## Verdict matrix", "## Contents", "## Key findings",
                         "## How this report was made"]
    key = md.index("## Key findings")
    assert key < md.index("(figures/differences.png)") < md.index("## How this report was made")
    assert md.count("(figures/differences.png)") == 1


def _png_size(path: pathlib.Path) -> tuple[int, int]:
    from matplotlib.image import imread

    height, width = imread(path).shape[:2]
    return width, height


def test_every_report_figure_fits_a_page(report):
    for png in (report / "figures").glob("*.png"):
        width, height = _png_size(png)
        assert width <= 2400 and width <= 3 * height, (png.name, width, height)


@pytest.mark.parametrize("groups, settings", [(1, 2), pytest.param(9, 12, marks=pytest.mark.slow)])
def test_figures_of_many_groups_and_metrics_are_grids_that_fit_a_page(groups, settings, tmp_path):
    """One family or nine, two settings or twelve, every metric the registry has: each figure at most
    2,400 px wide and at most 3:1 (panels go into rows of three, not one long row)."""
    from jaxapf.report.document import save_figure
    from jaxapf.report.figures import (
        plot_continuous,
        plot_differences,
        plot_ecdf,
        plot_performance_profile,
        plot_rates,
    )

    rng = np.random.default_rng(0)
    names = [f"family{g}" for g in range(groups)]
    labels = {s: f"#{s} direction_velocity γ={s}" for s in range(settings)}
    methods = {s: "direction_velocity" for s in range(settings)}
    rows = []
    for g in names:
        for s in range(settings):
            row = {"family": g, "setting": s}
            for m in RATES + CONTINUOUS:
                for suffix in ("_rate", "_iqm"):
                    v = rng.uniform()
                    row[m + suffix], row[m + suffix.replace("rate", "lo").replace("iqm", "iqm_lo")] = v, v - 0.1
                    row[m + suffix.replace("rate", "hi").replace("iqm", "iqm_hi")] = v + 0.1
                row[f"{m}_lo"], row[f"{m}_hi"] = row[f"{m}_rate"] - 0.1, row[f"{m}_rate"] + 0.1
            rows.append(row)
    summary = pd.DataFrame(rows)
    comparisons = pd.DataFrame([{"setting": s, "metric": m, "delta": 0.01, "delta_lo": -0.02, "delta_hi": 0.04,
                                 "p_holm": 0.5, "higher_is_better": True, "margin": 0.02, "verdict": "inconclusive",
                                 "holm_family": "primary" if m in ("success", "collision") else f"exploratory: {m}",
                                 "test": "score" if m in RATES else "signed rank"}
                                for s in range(settings) for m in RATES + CONTINUOUS])
    values = {g: {s: rng.normal(size=50) for s in range(settings)} for g in names}
    taus = np.linspace(0, 1, 20)
    curves = {g: {s: (np.linspace(1, 0, 20),) * 3 for s in range(settings)} for g in names}
    figures = [plot_ecdf(values, labels, methods, "min_clearance", "m"),
               plot_performance_profile(taus, curves, labels, methods, "spl", True),
               plot_rates(summary, labels, RATES, 0.95),
               plot_continuous(summary, labels, CONTINUOUS, {m: METRICS.get(m).unit for m in CONTINUOUS}, 0.95),
               plot_differences(comparisons, labels, RATES + CONTINUOUS, 0.05, "#0 basic")]
    for i, fig in enumerate(figures):
        save_figure(fig, f"f{i}", "", tmp_path)
        width, height = _png_size(tmp_path / f"f{i}.png")
        assert width <= 2400 and width <= 3 * height, (i, width, height)


def test_header_states_spec_versions_and_statistics(report, sweep):
    _, df = sweep
    md = (report / "report.md").read_text(encoding="utf-8")
    assert "# jaxapf report — synthetic-test" in md
    assert "spec_hash " + "f" * 64 in md
    assert "| jax | 0.0.test |" in md
    assert f"{RESAMPLES} resamples, seed 0" in md
    # 4 settings × 3 groups × 2 primary metrics; the other 7 metrics are exploratory, each its own family
    assert "Holm within declared families: primary (success, collision of each setting against its baseline, " \
           "per family and pooled: 24 tests)" in md
    assert "successful episodes only" in md
    # key findings come from the rows: the settings with the highest pooled success rate
    rate = df.groupby("setting")["success"].agg(["sum", "count"])
    best = rate[rate["sum"] == rate["sum"].max()]
    lo, hi = stats.wilson_interval(int(best["sum"].iloc[0]), int(best["count"].iloc[0]))
    names = ", ".join(f"#{s} direction_velocity γ={g:g} k={k:g}" for s, (_, g, k) in enumerate(_settings())
                      if s in best.index)
    assert (f"- Highest success rate (all): {names}: {100 * best['sum'].iloc[0] / best['count'].iloc[0]:.1f} % "
            f"[{100 * lo:.1f}, {100 * hi:.1f}].") in md


def test_rates_say_why_they_may_sum_past_100_percent(report, sweep):
    _, df = sweep
    md = (report / "report.md").read_text(encoding="utf-8")
    both = int((df["success"] & df["stalled"]).sum())
    assert (f"counts as both stalled and successful ({both} episode{'s' if both != 1 else ''} here)") in md


def test_summary_matches_direct_pandas_computation(report, sweep):
    _, df = sweep
    summary = pd.read_csv(report / "summary.csv")
    assert set(summary["family"]) == {"trap", "clutter", "all"}
    for (setting, family), g in list(df.groupby(["setting", "family"])) + [
            ((s, "all"), g) for s, g in df.groupby("setting")]:
        row = summary[(summary["setting"] == setting) & (summary["family"] == family)]
        assert len(row) == 1
        row = row.iloc[0]
        assert row["n"] == len(g)
        for r in RATES:
            k = int(g[r].sum())
            assert row[f"{r}_k"] == k
            assert row[f"{r}_rate"] == pytest.approx(g[r].mean())
            lo, hi = stats.wilson_interval(k, len(g))
            assert (row[f"{r}_lo"], row[f"{r}_hi"]) == pytest.approx((float(lo), float(hi)))
        on_success = {name for name, m in METRICS.items() if m.on_success}
        for m in CONTINUOUS:
            v = (g[g["success"]] if m in on_success else g)[m].dropna()
            assert row[f"{m}_n"] == len(v)
            assert row[f"{m}_median"] == pytest.approx(v.median())
            assert row[f"{m}_iqm"] == pytest.approx(sst.trim_mean(v, 0.25))
            assert row[f"{m}_median_lo"] <= row[f"{m}_median"] <= row[f"{m}_median_hi"]
        assert row["time_to_goal_n"] == g["success"].sum()


def test_comparisons_pair_fields_and_match_direct_computation(report, sweep):
    _, df = sweep
    comp = pd.read_csv(report / "comparisons.csv")
    # direction_velocity settings 4..7 are each paired with basic #0 (basic ignores γ and k)
    assert sorted(set(comp["setting"])) == [4, 5, 6, 7]
    assert set(comp["baseline"]) == {0}
    # 4 settings × (2 families + all) × 9 metrics = 108 rows; Holm within each declared family
    assert len(comp) == 108
    assert np.all(comp["p_holm"] >= comp["p"] - 1e-12)
    assert (comp["holm_family"] == "primary").sum() == 24
    for _, rows in comp.groupby("holm_family"):
        np.testing.assert_allclose(rows["p_holm"], stats.holm(rows["p"].to_numpy()))
    pairs = df[df.setting == 6].merge(df[df.setting == 0], on=["family", "field", "seed"])
    for metric in ("success", "collision"):
        row = comp[(comp.setting == 6) & (comp.family == "all") & (comp.metric == metric)].iloc[0]
        x, y = pairs[f"{metric}_x"].to_numpy(bool), pairs[f"{metric}_y"].to_numpy(bool)
        b, c = int(np.sum(x & ~y)), int(np.sum(~x & y))
        assert row["discordant"] == f"b={b}, c={c}"
        # McNemar's asymptotic test: (b - c)²/(b + c) on one degree of freedom
        assert row["p"] == pytest.approx(sst.chi2.sf((b - c) ** 2 / (b + c), 1) if b + c else 1.0)
        assert row["delta"] == pytest.approx(x.mean() - y.mean())
        wins = np.sum(x > y) if metric == "success" else np.sum(x < y)
        assert row["poi"] == pytest.approx((wins + 0.5 * np.sum(x == y)) / len(x))
    row = comp[(comp.setting == 6) & (comp.family == "trap") & (comp.metric == "time_to_goal")].iloc[0]
    trap = pairs[(pairs.family == "trap") & pairs.success_x & pairs.success_y]
    assert row["n_pairs"] == len(trap)  # pairs where both succeeded
    assert row["p"] == pytest.approx(stats.ShiftPairs.of(trap.time_to_goal_x, trap.time_to_goal_y).p_difference())


def test_latex_table_is_booktabs_and_escaped(report):
    tex = (report / "table.tex").read_text(encoding="utf-8")
    for cmd in (r"\toprule", r"\midrule", r"\bottomrule", r"\begin{tabular}", r"\caption{"):
        assert cmd in tex
    assert r"direction\_velocity" in tex and r"\#4" in tex
    body = re.sub(r"\$[^$]*\$", "", tex)  # outside math mode no bare _ or %
    assert not re.search(r"(?<!\\)_", body)
    assert not re.search(r"(?<!\\)%", "\n".join(line for line in body.splitlines() if not line.startswith("%")))


# --------------------------------------------------------------------------------------------
# selection rules (no figures: fast)
# --------------------------------------------------------------------------------------------


def test_where_filters_and_baseline_kept(sweep):
    path, _ = sweep
    df, _ = load_sweep(path)
    sel = select(df, ReportOptions(where=("method=direction_velocity", "family=trap")))
    assert sel.settings == [0, 4, 5, 6, 7]  # the baseline stays, reported for the comparison
    assert set(sel.data["family"]) == {"trap"}
    assert any("exclude them" in n for n in sel.notes)
    sel = select(df, ReportOptions(baseline="setting=5", where=("gamma=0.5,1",)))
    assert sel.pairs == {s: 5 for s in range(8) if s != 5}


def test_heatmap_skipped_with_fewer_than_two_swept_gains(sweep, tmp_path):
    path, _ = sweep
    df, _ = load_sweep(path)
    sel = select(df, ReportOptions(where=("gamma=0.5",)))
    figures, notes = _heatmap_figures(sel, ReportOptions(), tmp_path)
    assert figures == [] and "fewer than 2 swept gains" in notes[0]


def test_default_heatmap_of_a_sweep_without_its_gains_is_a_note(sweep, tmp_path):
    """A sweep without a gamma column (e.g. only `basic`, which reads neither gain) gets a note
    from the default --heatmap gamma,k; a column the user names that does not exist is an error."""
    path, _ = sweep
    df, _ = load_sweep(path)
    sel = select(df.drop(columns=["gamma"]), ReportOptions())
    figures, notes = _heatmap_figures(sel, ReportOptions(), tmp_path)
    assert figures == [] and "no gamma column" in notes[0]
    with pytest.raises(ReportError, match="no setting column 'gamma'"):
        _heatmap_figures(sel, ReportOptions(heatmap=("k", "gamma")), tmp_path)


# --------------------------------------------------------------------------------------------
# bad input: one line on stderr, exit status 2
# --------------------------------------------------------------------------------------------


def _bad_inputs(tmp: pathlib.Path, good: pathlib.Path) -> dict[str, tuple[list[str], str]]:
    plain = tmp / "plain.parquet"
    pd.DataFrame({"a": [1, 2]}).to_parquet(plain)
    junk = tmp / "junk.parquet"
    junk.write_text("not parquet")
    missing = write_sweep(tmp / "missing.parquet", make_rows(fields=2).drop(columns=["collision"]))
    empty_dir = tmp / "empty.parquet"
    empty_dir.mkdir()
    return {
        "no such file": ([str(tmp / "nope.parquet")], "no such file"),
        "not a sweep": ([str(plain)], "is not the output of jaxapf sweep"),
        "not parquet": ([str(junk)], "not a readable sweep output"),
        "empty dir": ([str(empty_dir)], "no Parquet part file"),
        "missing column": ([str(missing)], "lacks the column(s) collision"),
        "baseline": ([str(good), "--baseline", "method=direction"], "baseline method=direction is not in the data"),
        "baseline column": ([str(good), "--baseline", "colour=red"], "no setting column 'colour'"),
        "where empty": ([str(good), "--where", "family=forest"], "--where family=forest selects no rows"),
        "where number": ([str(good), "--where", "gamma=7"], "--where gamma=7 selects no rows"),
        "where column": ([str(good), "--where", "colour=red"], "no column 'colour'"),
        "where syntax": ([str(good), "--where", "trap"], "must look like COLUMN=VALUE"),
        "heatmap column": ([str(good), "--heatmap", "gamma,colour"], "no setting column 'colour'"),
        "resamples": ([str(good), "--resamples", "5"], "--resamples"),
    }


def test_bad_input_gives_one_line_and_status_2(sweep, tmp_path, capsys):
    good, _ = sweep
    for name, (args, message) in _bad_inputs(tmp_path, good).items():
        rc = main(["report", "--out", str(tmp_path / "out"), "--gallery", "0", "--resamples", "100", *args])
        err = capsys.readouterr().err
        assert rc == 2, name
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("jaxapf report: error: "), (name, err)
        assert message in lines[0], (name, lines[0])
        assert "Traceback" not in err


def test_report_error_is_a_config_error():
    from jaxapf.validation import ConfigError

    assert issubclass(ReportError, ConfigError)


# --------------------------------------------------------------------------------------------
# gallery: one tiny episode re-simulated
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_gallery_resimulates_a_failed_episode(tmp_path):
    # a spec whose settings match the rows (basic, direction_velocity with the default gains), so
    # the real jaxapf.sweep.row_config rebuilds each row; one tiny episode is re-simulated
    from jaxapf.sweep import parse_spec

    spec = parse_spec({"name": "tiny", "scenario": {"families": ["trap"], "fields": 3, "seed": 0,
                                                    "params": {"trap": {"distance": [4.0, 5.0]}}},
                       "sim": {"t_max": 1.0, "horizon": 3, "iters": 3},
                       "grid": {"method": ["basic", "direction_velocity"]}})
    meta = {**META, "spec": spec.to_json(), "spec_hash": spec.hash}
    df = make_rows(families=("trap",), fields=3, settings=[("basic", 1.0, 0.5), ("direction_velocity", 1.0, 0.5)])
    path = write_sweep(tmp_path / "tiny.parquet", df, meta=meta, parts=1)
    result = build_report(path, tmp_path / "out", ReportOptions(gallery=1, resamples=100, heatmap=None, svg=True))
    assert not any("could not re-simulate" in n for n in result.notes), result.notes
    assert (tmp_path / "out" / "figures" / "gallery_1.png").is_file()
    assert (tmp_path / "out" / "figures" / "gallery_1.svg").is_file()
    md = (tmp_path / "out" / "report.md").read_text(encoding="utf-8")
    fails = df[~df.success]
    collisions = fails[fails.collision].sort_values("min_clearance")
    first_failure = (collisions if len(collisions) else
                     fails[fails.stalled].sort_values("final_distance", ascending=False)).iloc[0]
    assert "figures/gallery_1.png" in md and "re-simulated min clearance" in md
    assert f"{first_failure['family']} field {first_failure['field']}" in md


@pytest.mark.slow
def test_sweep_to_report_end_to_end(tmp_path):
    # a real `jaxapf sweep` on a tiny spec, then `jaxapf report` on its output: the report's counts
    # are the Parquet's, every field is paired, and the gallery's re-simulation reproduces its row
    spec = tmp_path / "e2e.toml"
    spec.write_text('name = "e2e"\n[scenario]\nfamilies = ["trap"]\nfields = 4\nseed = 3\n'
                    '[scenario.params.trap]\ndistance = [4.0, 5.0]\n'
                    '[sim]\nt_max = 3.0\nhorizon = 3\niters = 3\n'
                    '[grid]\nmethod = ["basic", "direction_velocity"]\n')
    runs = tmp_path / "e2e.parquet"
    assert main(["sweep", str(spec), "--out", str(runs), "--no-cache", "--devices", "1", "--quiet"]) == 0
    out = tmp_path / "report"
    assert main(["report", str(runs), "--out", str(out), "--resamples", "100", "--gallery", "1",
                 "--heatmap", "none", "--animate"]) == 0
    rows = pd.concat([pd.read_parquet(p) for p in sorted(runs.glob("part-*.parquet"))])
    summary = pd.read_csv(out / "summary.csv")
    for method, group in rows.groupby("method"):
        got = summary[(summary["method"] == method) & (summary["family"] == "trap")].iloc[0]
        assert got["n"] == len(group) == 4
        for rate in ("success", "collision", "stalled"):
            assert got[f"{rate}_k"] == int(group[rate].sum())
    comparisons = pd.read_csv(out / "comparisons.csv")
    assert set(comparisons["label"]) == {"#1 direction_velocity"}
    whole = comparisons[comparisons["family"].isin(["trap", "all"])]  # not the trap/<kind> groups
    assert (whole.loc[whole["test"] == "mcnemar", "n_pairs"] == 4).all()
    kinds = comparisons[comparisons["family"].str.startswith("trap/")]
    assert set(kinds["family"]) == {f"trap/{k}" for k in rows["kind"].unique()}
    md = (out / "report.md").read_text(encoding="utf-8")
    assert "re-simulation matches the recorded outcome" in md
    page = (out / "report.html").read_text(encoding="utf-8")
    assert page.count("data:image/png;base64,") >= 5
    # the worst episode animated: the GIF in the page, its MP4 beside it
    assert page.count("data:image/gif;base64,") == 1 and (out / "figures" / "gallery_1_animated.mp4").is_file()


def _study():
    import importlib
    import sys

    sys.path.insert(0, str(ROOT / "analysis"))
    return importlib.import_module("study")


def test_study_delta_verdicts_and_text():
    study = _study()
    fewer_collisions = study.Delta("collision", -0.05, -0.08, -0.02, 0.001, "better", False, 0.10, 0.15, 512)
    assert fewer_collisions.better and not fewer_collisions.worse
    assert fewer_collisions.text() == "-5 pp [-8, -2] (better, Holm p = 0.001)"
    less_success = study.Delta("success", -0.05, -0.08, -0.02, 0.0001, "worse", True, 0.4, 0.45, 512)
    assert less_success.worse and less_success.text().endswith("(worse, Holm p < 0.001)")
    same = study.Delta("min_clearance", 0.002, 0.001, 0.003, 0.01, "equivalent", True, 1.0, 0.998, 512)
    assert same.equivalent and not same.better
    assert same.text() == "+0.002 [+0.001, +0.003] (equivalent, Holm p = 0.010)"


def test_study_numbers_read_the_report(report):
    study = _study()
    tables = type("Result", (), {"summary": pd.read_csv(report / "summary.csv"),
                                 "comparisons": pd.read_csv(report / "comparisons.csv")})
    n = study.Numbers(tables)
    assert sorted(n.families()) == ["clutter", "trap"]
    setting = {"method": "direction_velocity", "gamma": 1.0, "k": 0.5}
    row = tables.summary[(tables.summary["method"] == "direction_velocity") & (tables.summary["gamma"] == 1.0)
                         & (tables.summary["k"] == 0.5) & (tables.summary["family"] == "trap")].iloc[0]
    assert n.rate(setting, "trap", "success") == (f"{100 * row['success_rate']:.1f} % [{100 * row['success_lo']:.1f}, "
                                                  f"{100 * row['success_hi']:.1f}]")
    d = n.delta(setting, "trap", "success")
    c = tables.comparisons
    want = c[(c["setting"] == row["setting"]) & (c["family"] == "trap") & (c["metric"] == "success")].iloc[0]
    assert (d.delta, d.p_holm, d.n_pairs, d.verdict) == (want["delta"], want["p_holm"], 12, want["verdict"])
    with pytest.raises(LookupError, match="0 rows match"):
        n.row({"method": "nonexistent"}, "trap")


@pytest.mark.slow
def test_an_incomplete_sweep_says_so_in_the_title_and_first_lines(tmp_path, capsys):
    from jaxapf.sweep import parse_spec, run_sweep

    spec = parse_spec({"name": "cut", "scenario": {"families": ["trap"], "fields": 4, "seed": 3},
                       "sim": {"t_max": 2.0, "horizon": 3, "iters": 3}, "grid": {"k_rep": [5.0, 10.0]}})

    class Stop(Exception):
        pass

    def stop(chunk):
        raise Stop

    runs = tmp_path / "cut.parquet"
    with pytest.raises(Stop):
        run_sweep(spec, runs, chunk_fields=2, quiet=True, after_part=stop)
    out = tmp_path / "report"
    assert main(["report", str(runs), "--out", str(out), "--resamples", "100", "--gallery", "0",
                 "--heatmap", "none", "--baseline", "setting=0"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == ("INCOMPLETE SWEEP: the sweep is incomplete: 4 of 8 episodes are present (an interrupted "
                          "run?); only rows present in both settings are paired")
    md = (out / "report.md").read_text(encoding="utf-8").splitlines()
    assert md[0] == "# jaxapf report — cut (INCOMPLETE SWEEP)"
    first_text = next(line for line in md[1:] if line.strip())
    assert first_text.startswith("**The sweep is incomplete: 4 of 8 episodes are present")


@pytest.mark.slow
def test_pooling_families_of_unequal_sizes_is_said(tmp_path):
    df = pd.concat([make_rows(families=("trap",), fields=12), make_rows(families=("clutter",), fields=6, seed=8)])
    path = write_sweep(tmp_path / "unequal.parquet", df)
    result = build_report(path, tmp_path / "out", ReportOptions(gallery=0, resamples=100, heatmap=None))
    note = ("families of unequal sizes: the pooled 'all' rows weight each family by its episodes (clutter 6 fields, "
            "trap 12 fields); read the per-family rows first")
    assert note in result.notes
    assert "the families differ in size: clutter 6, trap 12 fields" in (tmp_path / "out" / "report.md").read_text(
        encoding="utf-8")
    balanced = build_report(write_sweep(tmp_path / "equal.parquet", make_rows()), tmp_path / "out2",
                            ReportOptions(gallery=0, resamples=100, heatmap=None))
    assert not any("unequal sizes" in n for n in balanced.notes)


def test_swept_tags_named_like_the_reports_columns_and_holding_html_are_shown_as_text(tmp_path):
    """A tag named `role` or `label` (docs/sweep.md's own example) crashed the report ("cannot insert role,
    already exists"); tag text reached report.md raw, so a Markdown viewer ran `<script>` and `<img onerror>`."""
    from markdown_it import MarkdownIt

    df = make_rows(families=("trap",), fields=8)
    evil = {s: f"<script>alert({s})</script>" for s in df["setting"].unique()}
    df["role"] = df["setting"].map(evil)
    df["label"] = df["setting"].map(lambda s: f"<img src=x onerror=alert({s})> [x](javascript:alert({s})) &amp;")
    df["n"] = df["setting"].map(lambda s: f"N{s}")  # a tag named like the summary's count
    out = tmp_path / "out"
    build_report(write_sweep(tmp_path / "tags.parquet", df), out, ReportOptions(gallery=0, resamples=100,
                                                                                 heatmap=None))
    markdown = (out / "report.md").read_text(encoding="utf-8")
    rendered = MarkdownIt("commonmark").render(markdown)  # what a Markdown viewer makes of it
    assert "<script" not in rendered and "<img src=x" not in rendered and 'href="javascript' not in rendered
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in rendered  # shown, as text
    page = (out / "report.html").read_text(encoding="utf-8")
    page = page.replace(SORT_SCRIPT, "")
    assert "<script" not in page and "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    header = next(line for line in markdown.splitlines() if line.startswith("| setting | label | role |"))
    assert "| role (swept) |" in header and "| label (swept) |" in header
    summary = pd.read_csv(out / "summary.csv")  # the report's own label stays the setting's, the tag beside it
    assert summary["label"].str.startswith("#").all() and summary["label (swept)"].str.startswith("<img").all()
    assert (summary["n"] == 8).all() and summary["n (swept)"].str.startswith("N").all()


# --------------------------------------------------------------------------------------------
# the bottom line
# --------------------------------------------------------------------------------------------


def _verdicts(rows):
    """A comparisons frame of hand-made verdicts: (setting, family, metric, verdict), each rate at 50 % against
    the baseline's 40 %, Δ +10 pp [+2, +18] at 97.5 %; stalled exploratory."""
    return pd.DataFrame([{"setting": s, "label": f"#{s} m{s}", "baseline": 0, "baseline_label": "#0 base",
                          "family": f, "metric": m, "verdict": v, "value": 0.5, "baseline_value": 0.4,
                          "delta": 0.1, "delta_lo": 0.02, "delta_hi": 0.18, "confidence": 0.975,
                          "holm_family": "primary" if m in ("success", "collision") else f"exploratory: {m}"}
                         for s, f, m, v in rows])


def test_the_bottom_line_names_each_settings_rates_and_the_families_that_differ():
    from jaxapf.report.tables import bottom_line

    comp = _verdicts([(1, "all", "success", "better"), (1, "all", "collision", "equivalent"),
                      (1, "all", "time_to_goal", "worse"), (2, "all", "success", "inconclusive"),
                      (2, "all", "collision", "inconclusive"), (2, "all", "time_to_goal", "inconclusive"),
                      (1, "trap", "success", "worse"), (1, "trap", "collision", "equivalent"),
                      (2, "trap", "success", "inconclusive"), (1, "clutter", "success", "inconclusive")])
    text = bottom_line(comp, "all", ["trap", "clutter"], ["success", "collision"])
    assert text == [
        "Pooled over the families (against #0 base): #1 m1: success 50.0 vs 40.0 (+10 [+2, +18] at 97.5 %, better), "
        "collision 50.0 vs 40.0 (+10 [+2, +18] at 97.5 %, equivalent); #2 m2: success 50.0 vs 40.0 (+10 [+2, +18] "
        "at 97.5 %, inconclusive), collision 50.0 vs 40.0 (+10 [+2, +18] at 97.5 %, inconclusive).",
        "In trap: #1 m1: success 50.0 vs 40.0 (+10 [+2, +18] at 97.5 %, worse)."]  # clutter: nothing new
    assert bottom_line(comp.iloc[:0], "all", [], []) == ["Nothing to compare: every reported setting is a "
                                                         "baseline setting."]


def test_each_paragraph_of_the_bottom_line_stays_under_sixty_words():
    """Six settings (two of each end are shown) on three families, every rate's verdict moving per family."""
    from test_readme_rules import words

    from jaxapf.report.tables import bottom_line

    verdicts = ["better", "worse", "equivalent"]
    comp = _verdicts([(s, f, m, verdicts[(s + i) % 3]) for s in range(1, 7) for i, f in enumerate(["all", "a", "b"])
                      for m in ("success", "collision", "stalled")])
    text = bottom_line(comp, "all", ["a", "b"], ["success", "collision", "stalled"])
    assert len(text) == 3 and "(2 settings in between)" in text[0]
    assert max(words(t) for t in text) <= 60, [words(t) for t in text]


def test_the_verdict_matrix_marks_every_setting_group_and_metric():
    from jaxapf.report.tables import verdict_matrix

    comp = _verdicts([(1, "trap", "success", "better"), (1, "all", "success", "worse"),
                      (2, "all", "success", "equivalent"), (2, "trap", "collision", "inconclusive")])
    m = verdict_matrix(comp, ["success", "collision"], ["trap", "all"])
    assert list(m.columns) == [("", "setting"), ("trap", "success"), ("trap", "collision"), ("all", "success"),
                               ("all", "collision")]
    assert m.values.tolist() == [["#1 m1", "▲", "", "▼", ""], ["#2 m2", "", "·", "=", ""]]


def test_the_page_colours_each_verdict_cell_and_its_tables_sort(report):
    page = (report / "report.html").read_text(encoding="utf-8")
    comp = pd.read_csv(report / "comparisons.csv")
    matrix = page[page.index('<table class="matrix">'):]
    matrix = matrix[: matrix.index("</table>")]
    cells = re.findall(r'<td class="v v-(\w+)" title="(\w+)">(.)</td>', matrix)
    assert cells and all(a == b for a, b, _ in cells)
    shown = [g for g in pd.unique(comp["family"]) if "/" not in g]  # kinds are left to the comparison tables
    assert len(cells) == len(comp[comp["family"].isin(shown)])
    assert sorted(v for v, _, _ in cells) == sorted(comp.loc[comp["family"].isin(shown), "verdict"])
    assert page.count('<table class="sortable">') >= 5


def test_invalid_episodes_are_named_and_the_report_still_written(tmp_path):
    """Episodes whose state turned non-finite (a plugin's NaN: the ``invalid`` outcome, neither success,
    collision nor stall, their continuous metrics NaN) break no table: the report is written, names how many
    per setting and family, and counts them in no rate."""
    df = make_rows()
    df["invalid"] = False
    bad = (df["method"] == "direction_velocity") & (df["family"] == "trap") & (df["field"] < 3)
    df.loc[bad, ["success", "collision", "stalled", "invalid"]] = [False, False, False, True]
    for column in ("min_clearance", "time_to_goal", "path_length", "path_ratio", "final_distance", "control_effort",
                   "jerk_rms", "min_ttc", "spl"):
        df.loc[bad, column] = math.nan
    path = write_sweep(tmp_path / "invalid.parquet", df)
    out = tmp_path / "report"
    assert main(["report", str(path), "--out", str(out), "--resamples", str(RESAMPLES), "--gallery", "0"]) == 0
    md = (out / "report.md").read_text()
    assert f"{int(bad.sum())} episode(s) turned non-finite" in md
    assert "trap: 3" in md and "clutter:" not in md.split("turned non-finite")[1].split("\n")[0]
