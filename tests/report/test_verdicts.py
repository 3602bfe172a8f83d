"""Verdicts of the comparison table on hand-made paired data with a known answer.

A tiny shift measured on many pairs is significant yet inside the relevance margin: "equivalent",
not "better". A shift beyond the margin is "better" (or "worse"). Every estimate and interval is
the one :mod:`jaxapf.stats` computes directly on the same pairs.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from jaxapf import stats
from jaxapf.report import ReportOptions
from jaxapf.report.tables import compare, summarize

N = 400


def _rows(shift: float, success_x: np.ndarray, success_y: np.ndarray) -> pd.DataFrame:
    """Two settings on ``N`` fields of one family: min_clearance of #1 = #0's + ``shift`` + tiny noise."""
    rng = np.random.default_rng(0)
    base = rng.uniform(0.5, 2.0, N)
    noise = rng.normal(0.0, 1e-3, N)
    rows = []
    for setting, clearance, success in ((0, base, success_y), (1, base + shift + noise, success_x)):
        for f in range(N):
            rows.append(dict(setting=setting, method=("basic", "direction")[setting], family="clutter",
                             kind="clutter", field=f, seed=0, success=bool(success[f]),
                             collision=False, stalled=not bool(success[f]),
                             min_clearance=float(clearance[f]),
                             time_to_goal=20.0 + 0.01 * f if success[f] else np.nan))
    return pd.DataFrame(rows)


def _compare(df: pd.DataFrame, **options) -> pd.DataFrame:
    opts = ReportOptions(resamples=200, **options)
    comp = compare(df, {1: 0}, {0: "#0 basic", 1: "#1 direction"}, opts)
    return comp[comp["family"] == "clutter"].set_index("metric")


def test_significant_shift_inside_the_margin_is_equivalent_not_better():
    ok = np.ones(N, bool)
    comp = _compare(_rows(0.01, ok, ok), margins=(("min_clearance", 0.05),))
    row = comp.loc["min_clearance"]
    assert row["significant"]  # 400 pairs all shifted by +0.01 m: the signed-rank test sees it
    assert row["delta_hi"] < 0.05
    assert row["p_equivalence_holm"] <= 0.05  # and the adjusted equivalence test sees it is small
    assert row["verdict"] == "equivalent"


def test_shift_beyond_the_margin_is_better_and_worse_when_reversed():
    ok = np.ones(N, bool)
    assert _compare(_rows(0.2, ok, ok), margins=(("min_clearance", 0.05),)).loc["min_clearance", "verdict"] == "better"
    assert _compare(_rows(-0.2, ok, ok), margins=(("min_clearance", 0.05),)).loc["min_clearance", "verdict"] == "worse"


def test_no_margin_no_equivalence():
    ok = np.ones(N, bool)
    comp = _compare(_rows(0.0, ok, ok), margins=())
    # min_clearance has a registry margin; the verdict is never "better" for a zero shift
    assert comp.loc["min_clearance", "verdict"] in ("equivalent", "inconclusive")


def test_rate_difference_and_interval_are_tangos_and_shift_is_hodges_lehmann_at_the_rows_level():
    rng = np.random.default_rng(1)
    sx, sy = rng.uniform(size=N) < 0.7, rng.uniform(size=N) < 0.6
    df = _rows(0.1, sx, sy)
    comp = _compare(df)
    row = comp.loc["success"]
    pairs = stats.RatePairs(int(np.sum(sx & ~sy)), int(np.sum(~sx & sy)), N)
    assert (row["delta"], row["delta_lo"], row["delta_hi"]) == pytest.approx(
        (pairs.estimate, *pairs.interval(row["confidence"])))
    assert (row["delta_lo_95"], row["delta_hi_95"]) == pytest.approx(pairs.interval(0.95))
    assert row["discordant"] == f"b={pairs.b}, c={pairs.c}"
    x = df[df.setting == 1]["min_clearance"].to_numpy()
    y = df[df.setting == 0]["min_clearance"].to_numpy()
    row = comp.loc["min_clearance"]
    est, lo, hi = stats.hodges_lehmann_paired(x, y, row["confidence"])
    assert (row["delta"], row["delta_lo"], row["delta_hi"]) == pytest.approx((est, lo, hi))
    assert row["conditioning"] == "all pairs"
    assert row["holm_family"] == "exploratory: min_clearance" and comp.loc["success", "holm_family"] == "primary"


def test_an_exploratory_metric_a_kind_or_a_gallery_changes_no_primary_verdict():
    """The primary family (success and collision, per family and pooled) is the question's: a report that adds
    an exploratory metric or splits a family into kinds gives the same primary rows."""
    rng = np.random.default_rng(4)
    sx, sy = rng.uniform(size=N) < 0.66, rng.uniform(size=N) < 0.6
    df = _rows(0.02, sx, sy)
    df["family"] = np.where(df["field"] % 2, "clutter", "trap")
    base = compare(df.drop(columns=["time_to_goal"]), {1: 0}, {0: "#0", 1: "#1"}, ReportOptions(resamples=200))
    df["kind"] = np.where(df["field"] % 4 < 2, "a", "b")
    more = compare(df, {1: 0}, {0: "#0", 1: "#1"}, ReportOptions(resamples=200, gallery=0))
    assert set(more["family"]) - set(base["family"])  # the kinds are new groups
    assert set(more["metric"]) - set(base["metric"]) == {"time_to_goal"}
    columns = ["family", "metric", "p", "p_holm", "confidence", "delta_lo", "delta_hi", "verdict"]
    pick = lambda c: c[c["holm_family"] == "primary"][columns].reset_index(drop=True)  # noqa: E731
    pd.testing.assert_frame_equal(pick(base), pick(more))


def test_efficiency_compared_where_both_succeed_unless_asked_otherwise():
    rng = np.random.default_rng(2)
    sx, sy = rng.uniform(size=N) < 0.7, rng.uniform(size=N) < 0.6
    df = _rows(0.0, sx, sy)
    both = _compare(df).loc["time_to_goal"]
    assert both["conditioning"] == "both succeed" and both["n_pairs"] == int(np.sum(sx & sy))
    # time_to_goal is NaN where a setting failed, so "all pairs" keeps the finite pairs: the same here
    every = _compare(df, efficiency="all-pairs").loc["time_to_goal"]
    assert every["conditioning"] == "all pairs" and every["n_pairs"] == int(np.sum(sx & sy))


def test_solvable_column_gives_rates_among_solvable_fields():
    ok = np.ones(N, bool)
    df = _rows(0.0, ok, ok)
    df["solvable"] = df["field"] % 4 != 0
    df.loc[df["field"] % 4 == 0, "success"] = False
    opts = ReportOptions(resamples=200)
    summary = summarize(df, [0, 1], df.groupby("setting").first(), {0: "#0", 1: "#1"}, opts)
    row = summary[(summary["setting"] == 1) & (summary["family"] == "clutter")].iloc[0]
    assert row["n_solvable"] == 3 * N // 4
    assert row["success_solvable_rate"] == 1.0
    assert row["success_rate"] == pytest.approx(0.75)


def test_the_headline_group_is_all_or_the_one_family_never_one_of_its_kinds():
    from jaxapf.report.tables import headline

    assert headline(["trap", "trap/concave", "trap/on_line"]) == "trap"
    assert headline(["clutter", "trap", "trap/concave", "all"]) == "all"


@pytest.mark.parametrize("margin, message", [
    (("success", 1.0), "a rate's margin is a proportion below 1"),
    (("min_clearance", float("inf")), "must be a finite number > 0"),
    (("min_clearance", 0.0), "must be a finite number > 0"),
    (("speed", 0.1), "'speed' is not a metric"),
])
def test_bad_margins_are_refused_in_one_line(margin, message):
    from jaxapf.report import ReportError

    with pytest.raises(ReportError, match=message):
        ReportOptions(margins=(margin,))


def test_a_declared_primary_family_replaces_the_default():
    ok = np.ones(N, bool)
    comp = _compare(_rows(0.01, ok, ok), primary=("min_clearance",))
    assert comp.loc["min_clearance", "holm_family"] == "primary"
    assert comp.loc["success", "holm_family"] == "exploratory: success"
    from jaxapf.report import ReportError

    with pytest.raises(ReportError, match="--primary speed: 'speed' is not a metric"):
        ReportOptions(primary=("speed",))
