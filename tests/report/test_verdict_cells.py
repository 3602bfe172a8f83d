"""A verdict a reviewer checks from its cell: every interval printed beside a verdict is the one that decided
it (at the level Holm allows its comparison within its declared family), so the verdict follows from the
interval and the margin alone, in comparisons.csv, the report's tables and compare.md; and every claim it
makes is one Holm makes within the family."""

import numpy as np
import pandas as pd
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf import stats
from jaxapf.report import ReportOptions
from jaxapf.report.tables import compare, comparison_table

ALPHA = 0.05


def _read(cell: str) -> tuple[float, float]:
    """The interval a table cell prints: ``+1.2 [-0.3, +2.7] at 99.6 %``."""
    inner = cell.split("[", 1)[1].split("]", 1)[0]
    lo, hi = (float(v) for v in inner.split(","))
    return lo, hi


@st.composite
def studies(draw):
    """A random study: a few settings, each flying the baseline's fields with its own success and clearance
    (some settings identical to the baseline, some tiny or large shifts), one or two families."""
    n = draw(st.integers(8, 160))
    settings_ = draw(st.integers(1, 4))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    rows = []
    base_success = rng.uniform(size=n) < draw(st.floats(0.2, 0.95))
    base_clear = rng.uniform(0.2, 2.0, n)
    for s in range(settings_ + 1):
        flip = draw(st.floats(0.0, 0.3)) if s else 0.0
        shift = draw(st.sampled_from([0.0, 0.001, 0.03, 0.3, -0.3])) if s else 0.0
        success = np.where(rng.uniform(size=n) < flip, ~base_success, base_success)
        clearance = base_clear + shift + (rng.normal(0, 0.01, n) if s and shift else 0.0)
        for f in range(n):
            rows.append(dict(setting=s, method="basic" if s == 0 else f"m{s}", family="ab"[f % 2], kind="k",
                             field=f, seed=0, success=bool(success[f]), collision=not bool(success[f]),
                             stalled=False, min_clearance=float(clearance[f])))
    frame = pd.DataFrame(rows)
    labels = {s: f"#{s}" for s in range(settings_ + 1)}
    return frame, {s: 0 for s in range(1, settings_ + 1)}, labels


@settings(max_examples=40, deadline=None)
@given(studies())
def test_no_cell_shows_a_verdict_its_interval_contradicts_and_every_claim_is_holms(study):
    frame, pairs, labels = study
    comp = compare(frame, pairs, labels, ReportOptions(resamples=100))
    for _, r in comp.iterrows():
        margin = float(np.nan_to_num(r["margin"], nan=0.0))
        up = bool(r["higher_is_better"])
        assert r["verdict"] == stats.verdict(r["delta_lo"], r["delta_hi"], margin, up)
        if r["verdict"] in ("better", "worse"):
            assert r["p_holm"] <= ALPHA
        if r["verdict"] == "equivalent":
            assert r["p_equivalence_holm"] <= ALPHA
        elif r["p_equivalence_holm"] <= ALPHA:
            raise AssertionError(f"Holm shows equivalence but the interval does not: {dict(r)}")
        if np.isfinite(r["delta_lo"]):
            assert r["delta_lo"] <= r["delta"] <= r["delta_hi"]
            assert r["delta_lo"] <= r["delta_lo_95"] + 1e-12 and r["delta_hi_95"] <= r["delta_hi"] + 1e-12
    for metric in pd.unique(comp["metric"]):
        table = comparison_table(comp, metric)
        column = next(c for c in table.columns if "CI at its level" in c)
        scale = 100.0 if metric in ("success", "collision", "stalled") else 1.0
        rows = comp[comp["metric"] == metric]
        for (_, r), cell, verdict in zip(rows.iterrows(), table[column], table["verdict"]):
            if "no " in cell or cell == "–":
                assert verdict == "inconclusive"
                continue
            lo, hi = _read(cell)
            # the printed bounds are rounded to 3 significant digits; away from the edges they give the verdict
            margin = scale * float(np.nan_to_num(r["margin"], nan=0.0))
            edges = [0.0, margin, -margin]
            if all(abs(v - e) > 2e-3 * max(1.0, abs(e)) for v in (lo, hi) for e in edges):
                assert verdict == stats.verdict(lo, hi, margin, bool(r["higher_is_better"]))


def _three_settings() -> pd.DataFrame:
    rng = np.random.default_rng(3)
    frame = []
    for s in range(3):
        success = rng.uniform(size=60) < 0.5 + 0.1 * s
        for f in range(60):
            frame.append(dict(setting=s, method=f"m{s}", family="ab"[f % 2], kind="k", field=f, seed=0,
                              success=bool(success[f]), collision=False, stalled=not bool(success[f]),
                              min_clearance=float(rng.uniform(0.2, 2.0))))
    return pd.DataFrame(frame)


def test_the_holm_family_of_each_row_reproduces_its_p_holm():
    comp = compare(_three_settings(), {1: 0, 2: 0}, {0: "#0", 1: "#1", 2: "#2"}, ReportOptions(resamples=100))
    assert set(comp.loc[comp["metric"].isin(["success", "collision"]), "holm_family"]) == {"primary"}
    assert set(comp.loc[comp["metric"] == "stalled", "holm_family"]) == {"exploratory: stalled"}
    for _, rows in comp.groupby("holm_family"):
        np.testing.assert_array_equal(stats.holm(rows["p"].to_numpy()), rows["p_holm"].to_numpy())
        np.testing.assert_array_equal(stats.holm(rows["p_equivalence"].to_numpy()),
                                      rows["p_equivalence_holm"].to_numpy())


def test_a_question_about_the_pooled_groups_declares_them_alone_primary():
    """primary_pooled (the scorecard's question): success and collision pooled over the families are the primary
    family, per family they are exploratory within their metric, and Holm runs over each family so declared."""
    options = ReportOptions(resamples=100, primary_pooled=True)
    comp = compare(_three_settings(), {1: 0, 2: 0}, {0: "#0", 1: "#1", 2: "#2"}, options)
    primary = comp[comp["holm_family"] == "primary"]
    assert len(primary) == 4 and set(primary["family"]) == {"all"}
    assert set(primary["metric"]) == {"success", "collision"}
    per_family = comp[comp["family"] != "all"]
    assert set(per_family["holm_family"]) == {"exploratory: success", "exploratory: collision", "exploratory: stalled",
                                              "exploratory: min_clearance"}
    for _, rows in comp.groupby("holm_family"):
        np.testing.assert_array_equal(stats.holm(rows["p"].to_numpy()), rows["p_holm"].to_numpy())


def test_cells_by_hand():
    """Two comparisons, one family: the table's cell shows the interval at its level and why it decided."""
    row = dict(setting=1, label="#1", baseline=0, family="clutter", metric="success", n_pairs=512,
               conditioning="all pairs", value=0.5, baseline_value=0.48, delta=0.02, delta_lo=0.004, delta_hi=0.036,
               confidence=0.975, verdict="better", holm_family="primary", p_holm=0.01, significant=True,
               margin=0.02, p_equivalence_holm=0.9, mde=0.01, poi=0.51, poi_lo=0.5, poi_hi=0.52, test="score",
               discordant="b=20, c=10", higher_is_better=True)
    table = comparison_table(pd.DataFrame([row]), "success")
    assert table["Δ pp [CI at its level]"].iloc[0] == "+2 [+0.4, +3.6] at 97.5 %"
    assert table["decided by"].iloc[0] == "97.5 % CI above 0"
    assert table["Holm family"].iloc[0] == "primary"
    inside = row | dict(delta=0.0, delta_lo=-0.01, delta_hi=0.012, confidence=0.99, verdict="equivalent")
    assert comparison_table(pd.DataFrame([inside]), "success")["decided by"].iloc[0] == "99 % CI inside ±0.02"
    none = row | dict(metric="min_clearance", delta=0.1, delta_lo=np.nan, delta_hi=np.nan, n_pairs=4,
                      verdict="inconclusive", value=1.0, baseline_value=0.9, margin=0.05)
    cell = comparison_table(pd.DataFrame([none]), "min_clearance")
    assert cell["HL shift [CI at its level]"].iloc[0] == "+0.1 [no 97.5 % CI from 4 pairs]"
    assert cell["decided by"].iloc[0] == "no 97.5 % CI with these pairs"
