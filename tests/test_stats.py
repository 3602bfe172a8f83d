"""Statistics of ``jaxapf report`` against hand computations, scipy and simulated coverage."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats as sst

from jaxapf import stats

Z95 = 1.959963984540054  # Φ⁻¹(0.975)


# --------------------------------------------------------------------------------------------
# Wilson
# --------------------------------------------------------------------------------------------


def test_wilson_hand_computed():
    # z = 1.959964, z² = 3.841459, n = 10: z²/n = 0.3841459, 1 + z²/n = 1.3841459.
    # 8/10: p̂ = 0.8; centre = (0.8 + z²/(2n)) / 1.3841459 = (0.8 + 0.1920729) / 1.3841459 = 0.7167401;
    #   half = (z / 1.3841459) · sqrt(0.8·0.2/10 + z²/(4n²)) = 1.4160232 · sqrt(0.016 + 0.0096036)
    #        = 1.4160232 · 0.1600113 = 0.2265777  ->  [0.4901624, 0.9433178].
    lo, hi = stats.wilson_interval(8, 10)
    assert lo == pytest.approx(0.4901624, abs=1e-6)
    assert hi == pytest.approx(0.9433178, abs=1e-6)
    # 0/10: centre = half = (z²/(2n)) / (1 + z²/n) = 0.1920729 / 1.3841459 = 0.1387664
    #   -> [0, 2 · 0.1387664] = [0, 0.2775328] (the upper bound is (z²/n) / (1 + z²/n)).
    lo, hi = stats.wilson_interval(0, 10)
    assert lo == 0.0
    assert hi == pytest.approx(0.2775328, abs=1e-6)
    # 10/10 mirrors 0/10: [1 - 0.2775328, 1] = [0.7224672, 1].
    lo, hi = stats.wilson_interval(10, 10)
    assert lo == pytest.approx(0.7224672, abs=1e-6)
    assert hi == 1.0


def test_wilson_vectorised_and_degenerate():
    lo, hi = stats.wilson_interval(np.array([0, 8, 10]), np.array([0, 10, 10]))
    assert math.isnan(lo[0]) and math.isnan(hi[0])
    assert lo[1] == pytest.approx(0.4901624, abs=1e-6)
    assert hi[2] == 1.0
    with pytest.raises(ValueError):
        stats.wilson_interval(11, 10)
    with pytest.raises(ValueError):
        stats.wilson_interval(1, 10, confidence=1.0)


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 2000), frac=st.floats(0, 1), conf=st.sampled_from([0.8, 0.9, 0.95, 0.99]))
def test_wilson_contains_estimate_and_stays_in_unit_interval(n, frac, conf):
    k = int(round(frac * n))
    lo, hi = stats.wilson_interval(k, n, conf)
    p = k / n
    assert 0.0 <= lo <= p <= hi <= 1.0
    lo99, hi99 = stats.wilson_interval(k, n, 0.995)
    assert lo99 <= lo + 1e-12 and hi <= hi99 + 1e-12  # higher confidence, wider interval


# --------------------------------------------------------------------------------------------
# McNemar, Wilcoxon, probability of improvement
# --------------------------------------------------------------------------------------------


def test_the_score_test_at_zero_is_mcnemars_asymptotic_test():
    # b = 1, c = 7: Z = (1 - 7)/sqrt(8) = -2.121320, p = 2 Φ(-2.121320) = 0.033895 (the chi-squared form
    # (b - c)²/(b + c) = 4.5 on 1 df gives the same p)
    r = stats.RatePairs.of(*_table(3, 1, 7, 1))
    assert (r.b, r.c, r.n) == (1, 7, 12)
    assert r.p_difference() == pytest.approx(0.033895, abs=1e-6)
    assert r.p_difference() == pytest.approx(sst.chi2.sf(4.5, 1), rel=1e-12)
    assert stats.RatePairs(7, 1, 12).p_difference() == r.p_difference()
    assert stats.RatePairs(0, 0, 12).p_difference() == 1.0  # no discordant pair: nothing to test
    assert math.isnan(stats.RatePairs(0, 0, 0).p_difference())


def test_the_shift_test_is_the_signed_rank_test_without_ties():
    """The test dual to the Walsh-average interval is Wilcoxon's for untied non-zero differences: exact up to
    50 pairs, the normal approximation with continuity correction beyond (scipy's)."""
    rng = np.random.default_rng(3)
    for n in (6, 11, 20, 50):
        x, y = rng.normal(size=n) + 0.4, rng.normal(size=n)
        ref = sst.wilcoxon(x - y, method="exact")
        assert stats.ShiftPairs.of(x, y).p_difference() == pytest.approx(ref.pvalue, rel=1e-9)
    for n in (51, 300):
        d = rng.normal(0.15, 1, size=n)
        ref = sst.wilcoxon(d, method="approx", correction=True)
        assert stats.ShiftPairs.of(d, np.zeros(n)).p_difference() == pytest.approx(ref.pvalue, rel=1e-9)
    # a zero difference counts on both sides (kept, as the estimate keeps it): never more significant
    d = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.0])
    assert stats.ShiftPairs.of(d, np.zeros(7)).p_difference() >= sst.wilcoxon(d[:6], method="exact").pvalue
    assert stats.ShiftPairs.of([1.0, 2.0], [1.0, 2.0]).p_difference() == 1.0
    assert math.isnan(stats.ShiftPairs.of([], []).p_difference())


def test_probability_of_improvement_counts_pairs():
    x = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    y = np.array([0.0, 2.0, 4.0, 4.0, 1.0])
    # pairs: win, tie, loss, tie, win -> (2 + ½·2) / 5 = 0.6; lower-is-better: (1 + ½·2) / 5 = 0.4
    assert stats.probability_of_improvement_paired(x, y) == pytest.approx(0.6)
    assert stats.probability_of_improvement_paired(x, y, higher_is_better=False) == pytest.approx(0.4)
    # pairing matters: x is worse than y on every pair (0), although an all-pairs (rliable)
    # comparison would give (1 win + ½·2 ties) / 9 = 2/9.
    assert stats.probability_of_improvement_paired([1.0, 2.0, 3.0], [2.0, 3.0, 4.0]) == 0.0
    # collisions (lower is better): x collides on 1 of 4 fields, y on 3, on the same fields once
    xc, yc = np.array([1, 0, 0, 0]), np.array([1, 1, 1, 0])
    assert stats.probability_of_improvement_paired(xc, yc, higher_is_better=False) == pytest.approx((2 + 0.5 * 2) / 4)


# --------------------------------------------------------------------------------------------
# Holm
# --------------------------------------------------------------------------------------------


def test_holm_known_example():
    # sorted: 0.005·4 = 0.02, 0.01·3 = 0.03, 0.03·2 = 0.06, 0.04·1 = 0.04 -> max-accumulate 0.06
    p = [0.01, 0.04, 0.03, 0.005, math.nan]
    adj = stats.holm(p)
    np.testing.assert_allclose(adj[:4], [0.03, 0.06, 0.06, 0.02])
    assert math.isnan(adj[4])
    assert stats.holm([0.5, 0.9]).tolist() == [1.0, 1.0]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0, 1), min_size=1, max_size=40))
def test_holm_properties(p):
    p = np.array(p)
    adj = stats.holm(p)
    assert np.all(adj >= p - 1e-15) and np.all(adj <= 1.0)
    order = np.argsort(p, kind="stable")
    assert np.all(np.diff(adj[order]) >= -1e-15)  # monotone in the raw p-value
    assert adj[order[0]] == pytest.approx(min(1.0, p.size * p[order[0]]))


# --------------------------------------------------------------------------------------------
# IQM, bootstrap
# --------------------------------------------------------------------------------------------


def test_iqm_known_arrays():
    assert stats.iqm(np.arange(1, 9)) == pytest.approx(4.5)  # mean(3, 4, 5, 6)
    assert stats.iqm([0, 1, 2, 3, 4, 5, 6, 100]) == pytest.approx(3.5)  # mean(2, 3, 4, 5): outlier gone
    assert stats.iqm([100, 1, 4, 3, 2]) == pytest.approx(3.0)  # n = 5: floor(5/4) = 1 cut per end
    assert math.isnan(stats.iqm([]))
    np.testing.assert_allclose(stats.iqm(np.array([[1, 2, 3, 4], [5, 6, 7, 80]]), axis=-1), [2.5, 6.5])


def test_bootstrap_coverage_of_normal_mean():
    # 1000 samples of n = 40 from N(1, 2²). The percentile interval of the mean is
    # x̄ ± 1.96·σ̂/√n with the plug-in σ̂ (divisor n), whose exact coverage for normal data is
    # P(|t_39| <= 1.96·sqrt(40/39)) ≈ 0.94; the bootstrap's own noise takes off a little more.
    # Binomial sd of the observed coverage over 1000 reps: 0.8 %.
    rng = np.random.default_rng(1)
    covered = 0
    reps = 1000
    for i in range(reps):
        x = rng.normal(1.0, 2.0, size=40)
        lo, hi = stats.bootstrap_ci(x, np.mean, n_resamples=400, seed=i)
        covered += lo <= 1.0 <= hi
    assert 0.91 <= covered / reps <= 0.965


def test_bootstrap_is_stratified_and_reproducible():
    # constant within each stratum: a stratified resample always has the same mix, so the mean
    # never moves; unstratified resampling does move it
    x = np.array([0.0] * 10 + [1.0] * 30)
    strata = np.array(["a"] * 10 + ["b"] * 30)
    lo, hi = stats.bootstrap_ci(x, np.mean, strata=strata, n_resamples=300)
    assert lo == pytest.approx(0.75) and hi == pytest.approx(0.75)
    lo_u, hi_u = stats.bootstrap_ci(x, np.mean, n_resamples=300)
    assert lo_u < 0.7 and hi_u > 0.8
    again = stats.bootstrap_ci(x, np.mean, n_resamples=300, seed=5)
    assert stats.bootstrap_ci(x, np.mean, n_resamples=300, seed=5) == again
    assert all(math.isnan(v) for v in stats.bootstrap_ci([], np.mean))


def test_bootstrap_of_binary_mean_fast_path_matches_row_resampling():
    # the multinomial shortcut for few distinct values and plain row resampling estimate the same
    # percentiles (up to one lattice step 1/n of the resampled mean)
    rng = np.random.default_rng(4)
    x = (rng.uniform(size=50) < 0.3).astype(float)
    strata = np.repeat([0, 1], 25)
    fast = stats.bootstrap_ci(x, np.mean, strata=strata, n_resamples=4000, seed=1)
    slow = stats.bootstrap_ci(x, lambda a, axis: np.mean(a, axis=axis), strata=strata, n_resamples=4000, seed=1)
    assert fast == pytest.approx(slow, abs=1 / 50 + 1e-9)


def test_paired_bootstrap_uses_pairs():
    rng = np.random.default_rng(2)
    base = rng.normal(0, 5, size=60)  # large field-to-field variation shared by both methods
    x, y = base + 1.0 + rng.normal(0, 0.1, 60), base + rng.normal(0, 0.1, 60)
    est, lo, hi = stats.paired_bootstrap_ci(x, y, np.mean, n_resamples=500)
    assert est == pytest.approx(np.mean(x - y))
    assert lo < 1.0 < hi and hi - lo < 0.2  # unpaired, the interval would be ~ 2·1.96·5·sqrt(2/60) wide
    est, lo, hi = stats.paired_bootstrap_ci(base + 2.0, base, stats.iqm, n_resamples=200)
    assert est == pytest.approx(2.0) and lo == pytest.approx(2.0) and hi == pytest.approx(2.0)


# --------------------------------------------------------------------------------------------
# distributions
# --------------------------------------------------------------------------------------------


def test_performance_profile_and_ecdf():
    x = [0.1, 0.2, 0.2, 0.4]
    np.testing.assert_allclose(stats.performance_profile(x, [0.0, 0.1, 0.2, 0.3, 0.4]), [1.0, 0.75, 0.25, 0.25, 0.0])
    xs, f = stats.ecdf([3.0, 1.0, 2.0])
    np.testing.assert_allclose(xs, [1, 2, 3])
    np.testing.assert_allclose(f, [1 / 3, 2 / 3, 1])
    assert np.all(np.isnan(stats.performance_profile([], [0.0, 1.0])))


# --------------------------------------------------------------------------------------------
# paired estimates: difference of proportions (Newcombe), Hodges–Lehmann
# --------------------------------------------------------------------------------------------


def _table(a, b, c, d):
    """Paired booleans with a pairs (1, 1), b pairs (1, 0), c pairs (0, 1), d pairs (0, 0)."""
    x = np.array([True] * a + [True] * b + [False] * c + [False] * d)
    y = np.array([True] * a + [False] * b + [True] * c + [False] * d)
    return x, y


def test_tangos_interval_published_and_by_an_independent_solver():
    # Fagerland, Lydersen & Laake (Stat. Med. 2014) give Tango's 95 % interval for Cavo et al. (2012),
    # a = 59, b = 6, c = 16, d = 80: -0.1240 to -0.0054
    r = stats.RatePairs.of(*_table(59, 6, 16, 80))
    assert r.estimate == pytest.approx(-10 / 161, rel=1e-12)
    assert r.interval(0.95) == pytest.approx((-0.1240, -0.0054), abs=5e-5)
    from scipy.optimize import brentq

    # the ends solve Z(δ) = ±z with the restricted MLE found numerically (_tango_reference)
    for b, c, n in [(6, 16, 161), (0, 0, 20), (12, 3, 40), (5, 0, 5), (30, 28, 500)]:
        z = sst.norm.ppf(0.995)
        lo, hi = stats.RatePairs(b, c, n).interval(0.99)
        f = lambda delta, t, b=b, c=c, n=n: _tango_reference(b, c, n, delta) - t  # noqa: E731
        mid = min(max((b - c) / n, -1 + 1e-9), 1 - 1e-9)
        want_lo = brentq(f, -1 + 1e-9, mid, args=(z,)) if f(-1 + 1e-9, z) > 0 else -1.0
        want_hi = brentq(f, mid, 1 - 1e-9, args=(-z,)) if f(1 - 1e-9, -z) < 0 else 1.0
        assert (lo, hi) == pytest.approx((want_lo, want_hi), abs=2e-6)


@settings(max_examples=300, deadline=None)
@given(cells=st.tuples(*[st.integers(0, 60)] * 4), conf=st.sampled_from([0.8, 0.9, 0.95, 0.99]))
def test_tangos_interval_properties(cells, conf):
    r = stats.RatePairs.of(*_table(*cells))
    lo, hi = r.interval(conf)
    if sum(cells) == 0:
        assert math.isnan(lo) and math.isnan(hi) and math.isnan(r.estimate)
        return
    assert -1.0 <= lo <= r.estimate <= hi <= 1.0
    swapped = stats.RatePairs(r.c, r.b, r.n).interval(conf)  # swapping x and y mirrors it
    assert swapped == pytest.approx((-hi, -lo), abs=1e-12)
    wide = r.interval(0.995)
    assert wide[0] <= lo + 1e-12 and hi <= wide[1] + 1e-12


def _walsh_brute_force(d, k):
    """(HL, W_(k), W_(M+1-k)) from every Walsh average, materialised and sorted."""
    d = np.asarray(d, dtype=float)
    i, j = np.triu_indices(d.size)
    walsh = np.sort((d[i] + d[j]) / 2)
    if k == 0:
        return float(np.median(walsh)), -math.inf, math.inf
    return float(np.median(walsh)), walsh[k - 1], walsh[-k]


def _enumerated_rank(n, conf):
    """Largest k with P(T+ <= k - 1) <= α/2, T+ over all 2ⁿ equally likely sign patterns of ranks 1..n."""
    signs = (np.arange(2 ** n)[:, None] >> np.arange(n)) & 1
    t_plus = signs @ np.arange(1, n + 1)
    cdf = np.cumsum(np.bincount(t_plus)) / 2 ** n
    return int(np.sum(cdf <= (1 - conf) / 2 + 1e-12))


def test_walsh_rank_against_enumeration_and_tables():
    for n in range(1, 15):
        for conf in (0.9, 0.95, 0.99):
            assert stats._walsh_rank(n, conf) == _enumerated_rank(n, conf), (n, conf)
    # tabulated two-sided 5 % critical values of the signed-rank statistic: n = 20 -> 52, n = 30 -> 137,
    # n = 50 -> 434 (k = critical value + 1)
    assert [stats._walsh_rank(n, 0.95) for n in (20, 30, 50)] == [53, 138, 435]
    # the normal approximation with continuity correction, used from n = 51, is within one rank at n = 50:
    # floor(1275/2 - 1.959964·sqrt(50·51·101/24) + ½) = floor(637.5 - 1.959964·103.5910 + 0.5) = 435
    sigma = math.sqrt(50 * 51 * 101 / 24)
    assert abs(math.floor(1275 / 2 - Z95 * sigma + 0.5) - stats._walsh_rank(50, 0.95)) <= 1
    assert stats._walsh_rank(5, 0.95) == 0 and stats._walsh_rank(6, 0.95) == 1  # 2·2⁻⁶ = 0.031 <= 0.05


def test_hodges_lehmann_hand_computed():
    # d = 1..5: the 15 Walsh averages are 1, 1.5, 2, 2, 2.5, 2.5, 3, 3, 3, 3.5, 3.5, 4, 4, 4.5, 5 -> median 3;
    # with 5 pairs no rank reaches 95 % (the best interval [min, max] has coverage 1 - 2·2⁻⁵ = 0.9375)
    est, lo, hi = stats.hodges_lehmann_paired([1.0, 2.0, 3.0, 4.0, 5.0], np.zeros(5))
    assert est == 3.0 and lo == -math.inf and hi == math.inf
    # at 90 % it does: P(T+ <= 0) = 1/32 <= 0.05 < P(T+ <= 1) = 2/32 -> k = 1, the interval [1, 5]
    assert stats.hodges_lehmann_paired([1.0, 2.0, 3.0, 4.0, 5.0], np.zeros(5), 0.9) == (3.0, 1.0, 5.0)
    # d = 1..6: 21 Walsh averages, median 3.5; k = 1 at 95 % (2⁻⁶ <= 0.025 < 2·2⁻⁶) -> [1, 6]
    assert stats.hodges_lehmann_paired(np.arange(1.0, 7.0) + 10, np.full(6, 10.0)) == (3.5, 1.0, 6.0)
    # zero differences are kept: d = (0, 0, 0, 4) has Walsh averages 0 ×6, 2 ×3, 4 -> median 0
    assert stats.hodges_lehmann_paired([5.0, 5.0, 5.0, 9.0], [5.0, 5.0, 5.0, 5.0])[0] == 0.0
    assert all(math.isnan(v) for v in stats.hodges_lehmann_paired([], []))
    with pytest.raises(ValueError, match="finite"):
        stats.hodges_lehmann_paired([1.0, math.nan], [0.0, 0.0])
    with pytest.raises(ValueError, match="differ in size"):
        stats.hodges_lehmann_paired([1.0, 2.0], [0.0])
    with pytest.raises(ValueError, match="confidence"):
        stats.hodges_lehmann_paired([1.0, 2.0], [0.0, 0.0], confidence=0.0)


@pytest.mark.parametrize("materialise", [None, 7])
def test_hodges_lehmann_matches_brute_force(monkeypatch, materialise):
    # materialise = 7 forces the selection rounds (normally only n > ~1450 needs them) on small samples
    if materialise is not None:
        monkeypatch.setattr(stats, "_WALSH_MATERIALISE", materialise)
    rng = np.random.default_rng(5)
    for n in (1, 2, 6, 7, 12, 25, 50, 51, 90, 200):
        for data in (rng.standard_t(2, size=n),  # heavy tails, no ties
                     np.round(rng.normal(0.3, 1.0, size=n), 1),  # many ties and zero differences
                     np.full(n, 0.1), 1e6 + rng.normal(size=n)):  # all tied; huge offset (rounding)
            base = rng.normal(size=n)
            ours = stats.hodges_lehmann_paired(base + data, base, 0.95)
            ref = _walsh_brute_force((base + data) - base, stats._walsh_rank(n, 0.95))
            assert ours == pytest.approx(ref, rel=1e-13, abs=1e-13), (n, data[:3])


def test_hodges_lehmann_interval_coverage():
    # shifted symmetric (t with 5 degrees of freedom) differences: for n = 20 the exact interval
    # [W_(53), W_(158)] has coverage 1 - 2 P(T+ <= 52) = 0.952; 1000 replications, binomial sd 0.7 %.
    # n = 80 uses the normal approximation (600 replications, sd 0.9 %).
    rng = np.random.default_rng(6)
    for n, reps in ((20, 1000), (80, 600)):
        covered = 0
        for _ in range(reps):
            d = 0.7 + rng.standard_t(5, size=n)
            _, lo, hi = stats.hodges_lehmann_paired(d, np.zeros(n))
            covered += lo <= 0.7 <= hi
        assert 0.93 <= covered / reps <= 0.975, (n, covered / reps)


def test_hodges_lehmann_large_sample_bounded_memory():
    # n = 10 000 pairs have 50 005 000 Walsh averages (400 MB as float64); the selection keeps the peak
    # far below that. The results are checked as order statistics by counting the sums d_i + d_j
    # (i <= j) below and at each value, a block of rows at a time.
    import tracemalloc

    rng = np.random.default_rng(7)
    n = 10_000
    d = np.round(rng.standard_t(3, size=n), 3)  # ties as well
    tracemalloc.start()
    est, lo, hi = stats.hodges_lehmann_paired(d, np.zeros(n))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 64e6
    m = n * (n + 1) // 2
    k = stats._walsh_rank(n, 0.95)
    ds = np.sort(d)
    values = np.array([lo, hi, est]) * 2  # as sums
    below = np.zeros(3, np.int64)
    upto = np.zeros(3, np.int64)
    for start in range(0, n, 500):
        rows = np.arange(start, min(start + 500, n))
        sums = ds[rows, None] + ds[None, :]
        upper = np.arange(n)[None, :] >= rows[:, None]
        below += [(upper & (sums < v)).sum() for v in values]
        upto += [(upper & (sums <= v)).sum() for v in values]
    assert below[0] < k <= upto[0]  # lower bound = k-th smallest
    assert below[1] < m + 1 - k <= upto[1]  # upper bound = k-th largest
    assert below[2] <= m // 2 and upto[2] >= m // 2 + 1  # median of an even number of averages


# --------------------------------------------------------------------------------------------
# equivalence (TOST), verdict, minimum detectable difference
# --------------------------------------------------------------------------------------------


def _tango_reference(b, c, n, delta):
    """Score statistic of H0 p_x - p_y = delta with the restricted MLE found numerically."""
    from scipy.optimize import minimize_scalar

    def nll(q):  # cells: only x = q + delta, only y = q, concordant 1 - 2q - delta
        cells = np.array([q + delta, q, 1 - 2 * q - delta])
        counts = np.array([b, c, n - b - c])
        return -np.sum(np.where(counts > 0, counts * np.log(np.maximum(cells, 1e-300)), 0.0))

    q_lo, q_hi = max(0.0, -delta), (1 - delta) / 2
    q = minimize_scalar(nll, bounds=(q_lo, q_hi), method="bounded", options={"xatol": 1e-13}).x
    var = n * ((2 * q + delta) - delta ** 2)  # n Var(b/n - c/n) under the restricted fit
    return (b - c - n * delta) / math.sqrt(var)


def test_the_equivalence_test_of_a_rate_is_tangos_two_one_sided_tests_doubled():
    # q = 2 max(Φ(Z(margin)), 1 - Φ(Z(-margin))), Z with the restricted MLE: the level at which the two-sided
    # interval first lies inside the margin
    for a, b, c, d in [(59, 6, 16, 80), (10, 0, 0, 10), (3, 12, 1, 30), (0, 5, 9, 0)]:
        n = a + b + c + d
        for margin in (0.05, 0.2, 0.45):
            upper = sst.norm.cdf(_tango_reference(b, c, n, margin))
            lower = sst.norm.sf(_tango_reference(b, c, n, -margin))
            q = stats.RatePairs(b, c, n).p_equivalence(margin)
            assert q == pytest.approx(min(1.0, 2 * max(upper, lower)), abs=2e-6)
    # no discordant pair among n = 10, margin 0.1: q̃ = 0, Z = (0 - 10·0.1)/sqrt(10·0.1·0.9) = -1.054093,
    # each side p = Φ(-1.054093) = 0.145920, q = 0.291840: not shown (a Wald test, se = 0, would claim it).
    # n = 100: Z = -3.333333, q = 2 · 0.000429 = 0.000858
    assert stats.RatePairs(0, 0, 10).p_equivalence(0.1) == pytest.approx(0.291840, abs=1e-6)
    assert stats.RatePairs(0, 0, 100).p_equivalence(0.1) == pytest.approx(0.000858, abs=1e-6)
    assert stats.RatePairs(30, 0, 100).p_equivalence(0.1) > 0.99  # Δ = 0.3: far outside
    assert math.isnan(stats.RatePairs(0, 0, 0).p_equivalence(0.1))
    with pytest.raises(ValueError, match="margin"):
        stats.RatePairs(1, 0, 3).p_equivalence(1.0)


def test_the_equivalence_test_of_a_shift_by_hand():
    # d = 1..6, margin 10: every Walsh average lies inside (-10, 10), s = 0, q = 2 P(T+ <= 0) = 2 · 2⁻⁶
    assert stats.ShiftPairs.of(np.arange(1.0, 7.0), np.zeros(6)).p_equivalence(10.0) == pytest.approx(2.0 ** -5)
    rng = np.random.default_rng(8)
    v = rng.normal(size=2000)
    assert stats.ShiftPairs.of(v, v).p_equivalence(0.01) < 1e-6
    assert stats.ShiftPairs.of(v + 1.0 + 0.1 * rng.normal(size=2000), v).p_equivalence(0.5) == 1.0
    with pytest.raises(ValueError, match="margin"):
        stats.ShiftPairs.of([1.0], [0.0]).p_equivalence(0.0)


def _check_duality(evidence, margin):
    """The tests are the interval's own: 0 leaves the 1 - γ interval exactly past p, the interval lies inside
    the margin exactly from q on (checked just either side of each, for the levels a family of up to 50,000
    comparisons at α = 0.05 gives; far below them 1 - γ no longer holds γ's digits)."""
    p, q = evidence.p_difference(), evidence.p_equivalence(margin)
    for gamma, outside in ((p * (1 - 1e-7), False), (p * (1 + 1e-7), True)):
        if 1e-6 < gamma < 1:
            lo, hi = evidence.interval(1 - gamma)
            assert (not lo <= 0 <= hi) == outside, (gamma, p, lo, hi)
    for gamma, inside in ((q * (1 - 1e-7), False), (q * (1 + 1e-7), True)):
        if 1e-6 < gamma < 1:
            lo, hi = evidence.interval(1 - gamma)
            assert (-margin < lo and hi < margin) == inside, (gamma, q, lo, hi)


@settings(max_examples=150, deadline=None)
@given(cells=st.tuples(*[st.integers(0, 80)] * 4), margin=st.floats(0.01, 0.5))
def test_a_rates_tests_are_its_intervals_own(cells, margin):
    if sum(cells) == 0:
        return
    _check_duality(stats.RatePairs.of(*_table(*cells)), margin)


@settings(max_examples=150, deadline=None)
@given(n=st.integers(2, 120), shift=st.floats(-1, 1), margin=st.floats(0.05, 1.5), seed=st.integers(0, 2**31 - 1),
       ties=st.booleans())
def test_a_shifts_tests_are_its_intervals_own(n, shift, margin, seed, ties):
    d = np.random.default_rng(seed).normal(shift, 1, size=n)
    _check_duality(stats.ShiftPairs.of(np.round(d, 1) if ties else d, np.zeros(n)), margin)


def test_verdict_is_read_from_the_interval():
    v = stats.verdict
    assert v(0.05, 0.30, 0.1, True) == "better" and v(-0.30, -0.05, 0.1, True) == "worse"
    assert v(0.02, 0.15, 0.1, True) == "better"  # beyond 0, straddling the margin: a direction, not its size
    assert v(-0.30, -0.05, 0.1, False) == "better" and v(0.05, 0.30, 0.1, False) == "worse"  # lower is better
    assert v(0.01, 0.04, 0.1, True) == "equivalent"  # inside the margin, whether or not it excludes 0
    assert v(-0.03, 0.04, 0.1, True) == "equivalent"
    assert v(-0.2, 0.3, 0.1, True) == "inconclusive" and v(0.0, 0.3, 0.1, True) == "inconclusive"
    assert v(0.001, 0.002, 0.0, True) == "better"  # margin 0: no relevance
    assert v(math.nan, math.nan, 0.1, True) == "inconclusive" and v(-math.inf, math.inf, 0.1, True) == "inconclusive"
    assert set(stats.VERDICTS) == {"better", "worse", "equivalent", "inconclusive"}
    with pytest.raises(ValueError, match="lower > upper"):
        v(1.0, 0.0, 0.1, True)


def test_decide_gives_each_row_the_level_holm_allows_it_within_its_family():
    """Three rates in one family, one in another: the levels by hand (α p/p_Holm, or α q/q_Holm where
    equivalence is shown), the interval at that level, and Holm never crossing families."""
    rows = [stats.RatePairs(40, 10, 400), stats.RatePairs(25, 12, 400), stats.RatePairs(3, 2, 2000),
            stats.RatePairs(25, 12, 400)]
    d = stats.decide(rows, 0.02, True, ["a", "a", "a", "b"], 0.05)
    p = np.array([r.p_difference() for r in rows])
    q = np.array([r.p_equivalence(0.02) for r in rows])
    np.testing.assert_array_equal(d.p_holm[:3], stats.holm(p[:3]))
    np.testing.assert_array_equal(d.p_equivalence_holm[:3], stats.holm(q[:3]))
    assert d.p_holm[3] == p[3] and d.p_equivalence_holm[3] == q[3]  # a family of its own: unadjusted
    # row 0: far from equivalence, the smallest p of three: level α p/p_Holm = α/3 (q's share is larger)
    assert d.p_holm[0] == pytest.approx(3 * p[0]) and d.confidence[0] == pytest.approx(1 - 0.05 / 3)
    assert (d.lo[0], d.hi[0]) == rows[0].interval(d.confidence[0]) and d.verdict[0] == "better"
    # row 2: 2,000 pairs, 5 discordant: equivalence shown, level α q/q_Holm, interval inside ±0.02
    assert d.p_equivalence_holm[2] <= 0.05 and d.verdict[2] == "equivalent"
    assert 1 - d.confidence[2] == pytest.approx(0.05 * q[2] / d.p_equivalence_holm[2])
    # the same evidence alone in its family gets a wider level than in a family of three
    assert d.confidence[3] <= d.confidence[1]
    assert all(v == stats.verdict(lo, hi, 0.02, True) for v, lo, hi in zip(d.verdict, d.lo, d.hi))
    # no pairs: NaN, inconclusive, out of Holm's m
    d = stats.decide([stats.RatePairs(0, 0, 0), stats.RatePairs(40, 10, 400)], 0.02, True)
    assert math.isnan(d.confidence[0]) and d.verdict[0] == "inconclusive" and d.p_holm[1] == p[0]
    with pytest.raises(ValueError, match="alpha"):
        stats.decide(rows, 0.02, True, alpha=1.0)


def test_minimum_detectable_difference_hand_computed():
    # K = Φ⁻¹(0.975) + Φ⁻¹(0.8) = 1.959964 + 0.841621 = 2.801585, K² = 7.848880
    # rates, n = 100, b + c = 10: ψ̂ = 0.1, K·sqrt(0.1/100) = 2.801585·0.0316228 = 0.0885939 > K²/n = 0.0784888
    mdd = stats.minimum_detectable_difference
    assert mdd(*_table(45, 6, 4, 45), kind="rate") == pytest.approx(0.0885939, abs=1e-6)
    # no discordant pair: ψ = max(0, δ) gives δ = K²/n = 0.0784888 (not 0)
    assert mdd(*_table(50, 0, 0, 50), kind="rate") == pytest.approx(0.0784888, abs=1e-6)
    # n = 8: K²/8 = 0.981110 is still a difference; n = 7: K²/7 = 1.121 > 1, nothing detectable;
    # n = 5: even 5 discordant pairs of one sign give p = 2·2⁻⁵ = 0.0625 > 0.05
    assert mdd(*_table(4, 0, 0, 4), kind="rate") == pytest.approx(0.981110, abs=1e-6)
    assert mdd(*_table(4, 0, 0, 3), kind="rate") == math.inf
    assert mdd(*_table(0, 5, 0, 0), kind="rate") == math.inf
    # Connor's formula solved back: n = K² ψ / δ² at the detectable δ
    assert 2.801585 ** 2 * 0.1 / 0.0885939 ** 2 == pytest.approx(100, rel=1e-5)
    # continuous: d = 1..9, sd = sqrt(60/8) = 2.738613, n = 9:
    # K·sqrt(π/3)·sd/3 = 2.801585·1.023327·2.738613/3 = 2.617143
    d = np.arange(1.0, 10.0)
    assert mdd(d + 3.0, np.full(9, 3.0), kind="continuous") == pytest.approx(2.617143, abs=1e-6)
    assert mdd(np.ones(9), np.zeros(9), kind="continuous") == 0.0  # no spread
    assert mdd(d[:5], np.zeros(5), kind="continuous") == math.inf
    assert math.isnan(mdd([1.0], [0.0], kind="continuous")) and math.isnan(mdd([], [], kind="rate"))
    # higher power or a smaller alpha need a larger difference
    assert mdd(d, 0 * d, kind="continuous", power=0.9) > mdd(d, 0 * d, kind="continuous")
    assert mdd(d, 0 * d, kind="continuous", alpha=0.01) > mdd(d, 0 * d, kind="continuous")
    with pytest.raises(ValueError, match="kind"):
        mdd(d, d, kind="shift")
    with pytest.raises(ValueError, match="power"):
        mdd(d, d, kind="continuous", power=1.0)
    with pytest.raises(ValueError, match="alpha"):
        mdd(d, d, kind="continuous", alpha=0.0)
    with pytest.raises(ValueError, match="differ in size"):
        mdd(d, d[:3], kind="continuous")


@pytest.mark.parametrize("n, strata", [(40, None), (300, 3), (5000, 2)])
def test_bootstrap_cis_gives_each_statistics_bootstrap_ci(n, strata):
    """Several statistics from one set of resamples (the report's median and IQM): each interval is
    exactly the one bootstrap_ci gives alone with the same seed, also when the draws come in chunks."""
    rng = np.random.default_rng(n)
    x = rng.normal(size=n)
    labels = rng.integers(0, strata, n) if strata else None
    together = stats.bootstrap_cis(x, [stats.median, stats.iqm, stats.mean], strata=labels, n_resamples=900, seed=5)
    alone = [stats.bootstrap_ci(x, f, strata=labels, n_resamples=900, seed=5) for f in (stats.median, stats.iqm,
                                                                                       stats.mean)]
    assert together == alone
    empty = stats.bootstrap_cis(np.empty(0), [stats.median, stats.iqm])
    assert len(empty) == 2 and all(math.isnan(v) for pair in empty for v in pair)


@given(st.integers(1, 60), st.integers(0, 2**31 - 1))
@settings(max_examples=60, deadline=None)
def test_the_bootstraps_order_statistics_from_one_sort_are_the_median_and_the_iqm(n, seed):
    """The report's median and IQM replicates come from one sort of each block of resamples: the median
    exactly numpy's, the IQM scipy's trim_mean(x, 0.25) to rounding (the same values, summed sorted)."""
    x = np.random.default_rng(seed).normal(size=(5, n)) * 10.0 ** np.random.default_rng(seed).integers(-3, 4)
    s = np.sort(x, axis=-1)
    assert np.array_equal(stats._FROM_SORTED[stats.median](s), np.median(x, axis=-1))
    np.testing.assert_allclose(stats._FROM_SORTED[stats.iqm](s), sst.trim_mean(x, 0.25, axis=-1),
                               rtol=1e-13, atol=1e-13 * np.abs(x).max())


@given(st.lists(st.one_of(st.floats(-5, 5), st.sampled_from([0.0, 1.0, np.inf])), min_size=1, max_size=300),
       st.integers(1, 3), st.integers(0, 2**31 - 1))
@settings(max_examples=80, deadline=None)
def test_order_statistics_resampled_as_ranks_equal_resampled_values(values, strata, seed):
    """Median and IQM resample the 16-bit ranks of the sample (numpy radix-sorts those): every replicate,
    hence every interval, is the one sorting the resampled values gives, ties and +inf (no obstacle) included."""
    x = np.asarray(values)
    labels = np.random.default_rng(seed).integers(0, strata, x.size) if strata > 1 else None
    f = (stats.median, stats.iqm)
    ranks = stats._bootstrap(*stats._sorted_resamples(x, f), labels, 300, seed)
    direct = stats._bootstrap((x,), stats._replicates(f), labels, 300, seed)
    assert stats._sorted_resamples(x, f)[0][0].dtype == np.uint16
    np.testing.assert_array_equal(ranks, direct)


def test_the_rate_row_is_wilsons():
    """stats.rate_row, the row every table of rates shows, is Wilson's interval exactly."""
    rng = np.random.default_rng(3)
    x = rng.random(200) < 0.6
    r = stats.rate_row(x, 0.9)
    lo, hi = stats.wilson_interval(int(x.sum()), 200, 0.9)
    assert (r.k, r.n, r.rate, r.lo, r.hi) == (int(x.sum()), 200, x.mean(), float(lo), float(hi))


def test_the_seeds_interval_by_hand():
    # 1, 2, 3: mean 2, s = 1, t_{0.975, 2} = 4.302653, half width 4.302653/√3 = 2.484138
    assert stats.seed_interval([1.0, 2.0, 3.0]) == pytest.approx((2.0, 2.0 - 2.484138, 2.0 + 2.484138), abs=1e-6)
    mean, lo, hi = stats.seed_interval([0.5])
    assert mean == 0.5 and math.isnan(lo) and math.isnan(hi)
    assert all(math.isnan(v) for v in stats.seed_interval([]))


def test_an_answer_is_no_wider_than_its_verdicts():
    a = stats.answer
    assert a(["better"] * 3) == "Yes"
    assert a(["worse", "equivalent", "worse"]) == "No" and a(["equivalent"]) == "No"
    assert a(["inconclusive"] * 3) == "Not shown" and a(["worse", "inconclusive"]) == "Not shown"
    assert a(["better", "inconclusive", "equivalent"]) == "In part"
    assert a(["better", "worse", "inconclusive"]) == "Mixed"
    assert set(stats.ANSWERS) == {a(v) for v in (["better"], ["worse"], ["inconclusive"], ["better", "equivalent"],
                                                 ["better", "worse"])}
    with pytest.raises(ValueError, match="non-empty"):
        a([])
    with pytest.raises(ValueError, match="non-empty"):
        a(["maybe"])
