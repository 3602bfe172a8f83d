"""A verdict a reviewer can check from its cell: where the interval and margin shown do not decide it, the
cell says which adjusted test did (jaxapf.stats.verdict_basis), in the report and in compare.md."""

import re

import pandas as pd
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxapf import stats
from jaxapf.compare.protocol import _why
from jaxapf.report.tables import comparison_table

ALPHA = 0.05


def _row(delta, lo, hi, p_holm, p_eq, margin, verdict=None, *, metric="success", up=True, value=0.5, baseline=0.5):
    verdict = verdict or stats.verdict(lo, hi, p_holm, p_eq, margin, up)
    return {"setting": 1, "label": "#1 direction_velocity", "baseline": 0, "family": "clutter", "metric": metric,
            "n_pairs": 512, "conditioning": "all", "value": value, "baseline_value": baseline, "delta": delta,
            "delta_lo": lo, "delta_hi": hi, "verdict": verdict, "p_holm": p_holm, "significant": p_holm <= ALPHA,
            "margin": margin, "p_equivalence_holm": p_eq, "mde": 0.01, "poi": 0.5, "poi_lo": 0.4, "poi_hi": 0.6,
            "test": "McNemar", "discordant": "3/5", "higher_is_better": up}


def _cell(row) -> tuple[str, str]:
    table = comparison_table(pd.DataFrame([row]), row["metric"])
    return table["verdict"].iloc[0], table["decided by"].iloc[0]


def test_an_interval_inside_the_margin_that_is_not_equivalent_says_why():
    """crossing: 99.8 % vs 99.8 %, Δ +0 [−0.917, +0.917] pp inside ±2 pp, TOST p Holm 0.072: inconclusive."""
    row = _row(0.0, -0.00917, 0.00917, 1.0, 0.072, 0.02)
    assert _cell(row) == ("inconclusive", "TOST p Holm 0.072 > 0.05; p Holm 1.000 > 0.05")
    assert _why(pd.Series(row)) == " (TOST p Holm 0.072 > 0.05; p Holm 1.000 > 0.05)"


def test_a_significant_test_whose_interval_holds_zero_says_why():
    """spl on trap: the Wilcoxon test significant (p Holm < 0.001), the Hodges–Lehmann interval through 0."""
    row = _row(0.001, -0.002, 0.004, 0.0004, 0.2, 0.05, metric="spl", value=0.5, baseline=0.5)
    assert _cell(row) == ("inconclusive", "TOST p Holm 0.200 > 0.05; p Holm <0.001 but CI includes 0")


def test_an_equivalent_shift_beside_far_apart_medians_says_what_was_compared():
    """spl in clutter: medians 0 vs 0.943, the paired shift −0.0116 inside ±0.05: equivalent, and the cell says
    that the paired differences were compared, not the medians."""
    row = _row(-0.0116, -0.02, -0.004, 0.01, 0.001, 0.05, metric="spl", value=0.0, baseline=0.943)
    verdict, basis = _cell(row)
    assert verdict == "equivalent"
    assert basis == "TOST p Holm 0.001 ≤ 0.05; medians differ by -0.943, the test compares paired differences"


def test_an_interval_excluding_zero_and_the_margin_that_is_inconclusive_says_why():
    """clutter success −4.69 [−7.93, −1.41] pp with p Holm 0.081: inconclusive, because of the adjusted test."""
    row = _row(-0.0469, -0.0793, -0.0141, 0.081, 0.9, 0.02)
    assert _cell(row) == ("inconclusive", "TOST p Holm 0.900 > 0.05; p Holm 0.081 > 0.05")
    assert "p Holm 0.081 > 0.05" in _why(pd.Series(row))


def test_a_verdict_that_follows_from_its_interval_adds_nothing_to_compare_md():
    row = _row(-0.0469, -0.0793, -0.0141, 0.001, 0.9, 0.02)
    assert row["verdict"] == "worse" and _why(pd.Series(row)) == ""
    assert _cell(row) == ("worse", "p Holm 0.001 ≤ 0.05, CI excludes 0")


def _p_in(basis: str, name: str) -> float:
    """The p-value the basis states for ``name`` (``TOST p Holm`` or ``p Holm``)."""
    found = re.search(rf"(?:^|; ){name} (<0\.001|[0-9.]+)", basis)
    return 0.0 if found[1] == "<0.001" else float(found[1])


@settings(max_examples=400, deadline=None)
@given(lo=st.floats(-0.2, 0.2), width=st.floats(0.0, 0.2), p=st.floats(0, 1), q=st.floats(0, 1),
       margin=st.sampled_from([0.0, 0.02, 0.05]), up=st.booleans())
def test_no_cell_shows_a_verdict_its_interval_contradicts_without_saying_why(lo, width, p, q, margin, up):
    """Over random comparisons: an interval inside the margin marked other than equivalent, or one excluding 0
    and the margin marked inconclusive, always comes with the adjusted test that decided, and that test's
    p-value (as printed) is on the side of α the verdict needs."""
    hi = lo + width
    row = _row((lo + hi) / 2, lo, hi, p, q, margin, up=up)
    verdict, basis = _cell(row)
    a, b = (lo, hi) if up else (-hi, -lo)
    inside = margin > 0 and -margin < a and b < margin
    outside = (a > 0 or b < 0) and not inside
    why = _why(pd.Series(row))
    if inside and verdict != "equivalent":
        assert _p_in(basis, "TOST p Holm") > ALPHA - 1e-3 and why
    if outside and verdict == "inconclusive":
        assert _p_in(basis, "p Holm") > ALPHA - 1e-3 and why
    if verdict == "equivalent":
        assert _p_in(basis, "TOST p Holm") <= ALPHA
    if verdict in ("better", "worse"):
        assert _p_in(basis, "p Holm") <= ALPHA and (a > 0 if verdict == "better" else b < 0)
    assert bool(why) == (not stats.verdict_visible(lo, hi, margin, verdict, up))


def test_visibility_by_hand():
    assert stats.verdict_visible(-0.01, 0.01, 0.02, "equivalent")
    assert not stats.verdict_visible(-0.01, 0.03, 0.02, "equivalent")
    assert stats.verdict_visible(0.01, 0.05, 0.02, "better") and not stats.verdict_visible(0.01, 0.015, 0.02, "better")
    assert stats.verdict_visible(0.01, 0.05, 0.02, "worse", higher_is_better=False)
    assert stats.verdict_visible(-0.05, 0.05, 0.02, "inconclusive")
    assert not stats.verdict_visible(-0.05, -0.03, 0.02, "inconclusive")
