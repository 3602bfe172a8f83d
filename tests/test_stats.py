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


def test_mcnemar_hand_computed():
    # 12 pairs: 3 both succeed, 1 only x, 7 only y, 1 neither -> b = 1, c = 7.
    x = np.array([1, 1, 1, 1] + [0] * 7 + [0], bool)
    y = np.array([1, 1, 1, 0] + [1] * 7 + [0], bool)
    res = stats.mcnemar_exact(x, y)
    assert (res.b, res.c) == (1, 7)
    # b ~ Bin(8, ½): P(b <= 1) = (C(8,0) + C(8,1)) / 2⁸ = 9/256; two-sided p = 2 · 9/256 = 18/256.
    assert res.pvalue == pytest.approx(18 / 256, rel=1e-12)
    assert stats.mcnemar_exact(y, x).pvalue == pytest.approx(res.pvalue)
    # no discordant pair: nothing to test, p = 1
    assert stats.mcnemar_exact(x, x).pvalue == 1.0


def test_wilcoxon_matches_scipy_exact_without_ties():
    rng = np.random.default_rng(3)
    for n in (6, 11, 20):
        x, y = rng.normal(size=n) + 0.4, rng.normal(size=n)
        ours = stats.wilcoxon_paired(x, y)
        ref = sst.wilcoxon(x - y, method="exact")
        assert ours.statistic == pytest.approx(ref.statistic)
        assert ours.pvalue == pytest.approx(ref.pvalue, rel=1e-9)


def test_wilcoxon_exact_with_ties_and_zeros():
    # ties among |d| and zero differences: compare with the full enumeration of the 2^n signs
    d = np.array([1.0, -1.0, 2.0, 2.0, 3.0, 0.0, 3.0, 4.0, -2.0, 0.0])
    ours = stats.wilcoxon_paired(d, np.zeros_like(d))
    nz = d[d != 0]
    ranks = sst.rankdata(np.abs(nz))
    t_obs = ranks[nz > 0].sum()
    signs = (np.arange(2 ** nz.size)[:, None] >> np.arange(nz.size)) & 1
    t_all = signs @ ranks
    p = min(1.0, 2 * min(np.mean(t_all <= t_obs + 1e-9), np.mean(t_all >= t_obs - 1e-9)))
    assert ours.pvalue == pytest.approx(p, rel=1e-12)
    assert ours.n == 10 and ours.n_nonzero == 8
    assert stats.wilcoxon_paired([1.0, 2.0], [1.0, 2.0]).pvalue == 1.0
    assert math.isnan(stats.wilcoxon_paired([], []).pvalue)


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


def _newcombe_reference(a, b, c, d, conf):
    """Newcombe's method 10 written out from the paper's formulas (scalar arithmetic throughout)."""
    n = a + b + c + d
    z = sst.norm.ppf(0.5 + conf / 2)

    def wilson(k):
        p = k / n
        centre = (2 * n * p + z * z) / (2 * (n + z * z))
        half = z * math.sqrt(z * z + 4 * n * p * (1 - p)) / (2 * (n + z * z))
        return centre - half, centre + half

    p1, p2 = (a + b) / n, (a + c) / n
    (l1, u1), (l2, u2) = wilson(a + b), wilson(a + c)
    big_a, denom = a * d - b * c, (a + b) * (c + d) * (a + c) * (b + d)
    corrected = big_a - n / 2 if big_a > n / 2 else (0 if big_a >= 0 else big_a)
    phi = corrected / math.sqrt(denom) if denom else 0.0
    delta = math.sqrt(max((p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2, 0))
    eps = math.sqrt(max((p2 - l2) ** 2 - 2 * phi * (p2 - l2) * (u1 - p1) + (u1 - p1) ** 2, 0))
    return (b - c) / n, (b - c) / n - delta, (b - c) / n + eps


def test_paired_proportion_difference_published_and_hand_computed():
    # Fagerland, Lydersen & Laake (Stat. Med. 2014; their book §8 and R package contingencytables)
    # work Newcombe's square-and-add interval on Cavo et al. (2012): a = 59, b = 6, c = 16, d = 80,
    # estimate -10/161 = -0.0621, 95 % CI -0.1186 to -0.0046.
    est, lo, hi = stats.paired_proportion_difference(*_table(59, 6, 16, 80))
    assert est == pytest.approx(-10 / 161, rel=1e-12)
    assert lo == pytest.approx(-0.1186, abs=5e-5)
    assert hi == pytest.approx(-0.0046, abs=5e-5)
    # Bentur et al. (2009), a = 1, b = 1, c = 7, d = 12, n = 21: ad - bc = 5 lies in [0, n/2], so the
    # corrected φ̂ = 0 and the interval is plain square-and-add of the marginal Wilson intervals:
    #   p̂x = 2/21 = 0.095238, Wilson [0.026519, 0.289141]; p̂y = 8/21 = 0.380952, Wilson [0.207510, 0.591213]
    #   L = -6/21 - sqrt((0.095238 - 0.026519)² + (0.591213 - 0.380952)²) = -0.285714 - 0.221206 = -0.506920
    #   U = -6/21 + sqrt((0.380952 - 0.207510)² + (0.289141 - 0.095238)²) = -0.285714 + 0.260155 = -0.025559
    est, lo, hi = stats.paired_proportion_difference(*_table(1, 1, 7, 12))
    assert est == pytest.approx(-6 / 21, rel=1e-12)
    assert lo == pytest.approx(-0.506920, abs=2e-6)
    assert hi == pytest.approx(-0.025559, abs=2e-6)
    # negative ad - bc (φ̂ = A/√D uncorrected) and the other branches against the written-out formulas
    for cells in [(2, 10, 8, 1), (12, 9, 2, 21), (0, 0, 0, 5), (0, 3, 0, 0), (40, 0, 0, 0)]:
        assert stats.paired_proportion_difference(*_table(*cells)) == pytest.approx(
            _newcombe_reference(*cells, 0.95), abs=1e-12)


@settings(max_examples=300, deadline=None)
@given(cells=st.tuples(*[st.integers(0, 60)] * 4), conf=st.sampled_from([0.8, 0.9, 0.95, 0.99]))
def test_paired_proportion_difference_properties(cells, conf):
    x, y = _table(*cells)
    est, lo, hi = stats.paired_proportion_difference(x, y, conf)
    if sum(cells) == 0:
        assert all(math.isnan(v) for v in (est, lo, hi))
        return
    assert -1.0 <= lo <= est <= hi <= 1.0
    assert est == pytest.approx(stats.mean(x.astype(float)) - stats.mean(y.astype(float)))
    assert (est, lo, hi) == pytest.approx(_newcombe_reference(*cells, conf), abs=1e-12)
    est_s, lo_s, hi_s = stats.paired_proportion_difference(y, x, conf)  # swapping x and y mirrors it
    assert (est_s, lo_s, hi_s) == pytest.approx((-est, -hi, -lo), abs=1e-12)
    wide = stats.paired_proportion_difference(x, y, 0.995)
    assert wide[1] <= lo + 1e-12 and hi <= wide[2] + 1e-12


def test_paired_proportion_difference_errors():
    with pytest.raises(ValueError, match="confidence"):
        stats.paired_proportion_difference([True], [False], confidence=1.0)
    with pytest.raises(ValueError, match="differ in size"):
        stats.paired_proportion_difference([True, False], [False])


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


def test_equivalence_rate_is_tango_score_test():
    # p_upper = Φ(Z(δ = margin)); p_lower = 1 - Φ(Z(δ = -margin)); Z with the restricted MLE
    for a, b, c, d in [(59, 6, 16, 80), (10, 0, 0, 10), (3, 12, 1, 30), (0, 5, 9, 0)]:
        n = a + b + c + d
        for margin in (0.05, 0.2, 0.45):
            res = stats.equivalence_test(*_table(a, b, c, d), margin, kind="rate")
            assert res.p_upper == pytest.approx(sst.norm.cdf(_tango_reference(b, c, n, margin)), abs=1e-6)
            assert res.p_lower == pytest.approx(sst.norm.sf(_tango_reference(b, c, n, -margin)), abs=1e-6)
            assert res.p == max(res.p_lower, res.p_upper)
    # inverting it gives Tango's interval: Fagerland et al. (2014) report -0.1240 to -0.0054 (95 %) for
    # Cavo et al.; the margin at which the lower test has p = 0.025 is the lower limit
    from scipy.optimize import brentq

    x, y = _table(59, 6, 16, 80)
    limit = brentq(lambda m: stats.equivalence_test(x, y, m, kind="rate").p_lower - 0.025, 0.07, 0.5)
    assert limit == pytest.approx(0.1240, abs=5e-5)


def test_equivalence_hand_cases():
    # no discordant pair among n = 10, margin 0.1: q̃ = 0, Z = (0 - 10·0.1)/sqrt(10·0.1·0.9) = -1.054093,
    # p = Φ(-1.054093) = 0.145920 on each side -> not shown (a Wald test, se = 0, would claim it).
    # n = 100: Z = -10/sqrt(100·0.09) = -3.333333, p = 0.000429 -> equivalent.
    res = stats.equivalence_test(*_table(5, 0, 0, 5), 0.1, kind="rate")
    assert res.p_lower == pytest.approx(0.145920, abs=1e-6) and res.p_upper == pytest.approx(0.145920, abs=1e-6)
    assert not res.equivalent
    res = stats.equivalence_test(*_table(50, 0, 0, 50), 0.1, kind="rate")
    assert res.p == pytest.approx(0.000429, abs=1e-6) and res.equivalent
    # identical samples, many pairs, generous margin: equivalent; the same for continuous values
    rng = np.random.default_rng(8)
    x = rng.uniform(size=2000) < 0.3
    assert stats.equivalence_test(x, x, 0.02, kind="rate").equivalent
    v = rng.normal(size=2000)
    res = stats.equivalence_test(v, v, 0.01, kind="continuous")
    assert res.equivalent and res.p < 1e-6
    # a clear shift beyond the margin: not equivalent (the side it lies beyond has p near 1)
    res = stats.equivalence_test(v + 1.0 + 0.1 * rng.normal(size=2000), v, 0.5, kind="continuous")
    assert not res.equivalent and res.p_upper > 0.99 and res.p_lower < 1e-6
    res = stats.equivalence_test(*_table(40, 30, 0, 30), 0.1, kind="rate")  # Δ = 0.3
    assert not res.equivalent and res.p_upper > 0.99
    # continuous, small n: exact one-sided signed-rank tests on d ± margin. d = 1..6, margin 10:
    # every d + 10 > 0 and every d - 10 < 0, so both p = P(T+ = 21) = 2⁻⁶
    res = stats.equivalence_test(np.arange(1.0, 7.0), np.zeros(6), 10.0, kind="continuous")
    assert res.p_lower == pytest.approx(2.0 ** -6) and res.p_upper == pytest.approx(2.0 ** -6) and res.equivalent
    # no pairs
    res = stats.equivalence_test([], [], 0.1, kind="rate")
    assert math.isnan(res.p) and not res.equivalent
    assert math.isnan(stats.equivalence_test([], [], 0.1, kind="continuous").p)


def test_equivalence_errors():
    with pytest.raises(ValueError, match="kind"):
        stats.equivalence_test([1.0], [1.0], 0.1, kind="rates")
    with pytest.raises(ValueError, match="margin"):
        stats.equivalence_test([1.0], [1.0], 0.0, kind="continuous")
    with pytest.raises(ValueError, match="margin"):
        stats.equivalence_test([True], [True], 1.0, kind="rate")
    with pytest.raises(ValueError, match="confidence"):
        stats.equivalence_test([1.0], [1.0], 0.1, kind="continuous", confidence=1.5)
    with pytest.raises(ValueError, match="differ in size"):
        stats.equivalence_test([True, False], [True], 0.1, kind="rate")


def test_equivalence_rate_agrees_with_interval_rule():
    # TOST at α (p <= 0.05) is the 1 - 2α = 90 % interval inside (-margin, margin). Tango's test and
    # Newcombe's interval are different approximations, so they may disagree only when an end of the
    # interval lies within a small distance of the margin.
    rng = np.random.default_rng(9)
    disagree = 0
    for _ in range(1500):
        cells = rng.multinomial(int(rng.integers(30, 500)), rng.dirichlet(np.ones(4)))
        margin = float(rng.uniform(0.02, 0.4))
        x, y = _table(*cells)
        equivalent = stats.equivalence_test(x, y, margin, kind="rate", confidence=0.95).equivalent
        _, lo, hi = stats.paired_proportion_difference(x, y, confidence=0.90)
        if equivalent != (-margin < lo and hi < margin):
            disagree += 1
            assert min(abs(lo + margin), abs(hi - margin)) < 0.01, (cells, margin, lo, hi)
    assert disagree < 15  # 1 %


def test_equivalence_continuous_agrees_with_hodges_lehmann_interval():
    # for continuous data (no ties, no zeros) and n <= 50 both are exact and the rule holds exactly:
    # TOST at α <=> the 1 - 2α Hodges–Lehmann interval lies inside (-margin, margin)
    rng = np.random.default_rng(10)
    for _ in range(300):
        n = int(rng.integers(6, 51))
        d = rng.normal(rng.uniform(-1, 1), 1, size=n)
        margin = float(rng.uniform(0.05, 1.5))
        res = stats.equivalence_test(d, np.zeros(n), margin, kind="continuous", confidence=0.95)
        _, lo, hi = stats.hodges_lehmann_paired(d, np.zeros(n), confidence=0.90)
        assert res.equivalent == (-margin < lo and hi < margin)


def test_verdicts_adjust_both_tests_alike_over_the_study():
    """Three comparisons: a clear difference, one whose equivalence p = 0.03 is significant alone but
    not after Holm over three (0.03 x 2 = 0.06, the second smallest), and a null. Holm must move
    the equivalence p-values exactly as it moves the difference p-values; NaN rows stay out of m."""
    lo, hi = [0.10, -0.01, -0.2], [0.30, 0.01, 0.3]
    p, p_eq = [0.001, 0.5, 0.9], [0.9, 0.03, 0.001]
    p_holm, p_eq_holm, out = stats.verdicts(lo, hi, p, p_eq, 0.05, True)
    np.testing.assert_allclose(p_holm, stats.holm(p))
    np.testing.assert_allclose(p_eq_holm, [0.9, 0.06, 0.003])
    assert out == ["better", "inconclusive", "equivalent"]
    assert stats.verdict(-0.01, 0.01, 0.5, 0.03, 0.05, True) == "equivalent"  # the same row alone
    # lower is better per row; a NaN row is inconclusive and leaves m = 2 for the others
    p_holm, _, out = stats.verdicts([0.1, 0.1, np.nan], [0.3, 0.3, np.nan], [0.02, 0.02, np.nan],
                                    [0.9, 0.9, np.nan], 0.05, [True, False, True])
    np.testing.assert_allclose(p_holm[:2], [0.04, 0.04])
    assert out == ["better", "worse", "inconclusive"]


def test_verdict_every_branch():
    v = stats.verdict
    # significant, interval beyond 0, reaching past the margin: better / worse
    assert v(0.05, 0.30, 0.001, 0.9, 0.1, True) == "better"
    assert v(-0.30, -0.05, 0.001, 0.9, 0.1, True) == "worse"
    # significant and the interval beyond 0 but straddling the margin: still better (direction shown,
    # relevance not excluded)
    assert v(0.02, 0.15, 0.01, 0.2, 0.1, True) == "better"
    # significant, interval inside the margin, equivalence not shown: better (a direction, shown; its
    # irrelevance is not): the unadjusted interval alone never makes "equivalent"
    assert v(0.01, 0.04, 0.001, 0.2, 0.1, True) == "better"
    # lower is better (collisions): a negative difference is an improvement
    assert v(-0.30, -0.05, 0.001, 0.9, 0.1, False) == "better"
    assert v(0.05, 0.30, 0.001, 0.9, 0.1, False) == "worse"
    # the equivalence test rejects: equivalent, significant or not
    assert v(0.01, 0.04, 0.001, 0.03, 0.1, True) == "equivalent"
    assert v(-0.04, -0.01, 0.001, 0.01, 0.1, False) == "equivalent"
    assert v(-0.03, 0.04, 0.6, 0.01, 0.1, True) == "equivalent"
    # not significant, interval inside the margin but the equivalence test does not reject: inconclusive
    assert v(-0.03, 0.04, 0.6, 0.2, 0.1, True) == "inconclusive"
    # otherwise inconclusive: wide interval; significant p but interval touching 0 (methods disagree)
    assert v(-0.2, 0.3, 0.4, 0.6, 0.1, True) == "inconclusive"
    assert v(0.0, 0.3, 0.04, 0.6, 0.1, True) == "inconclusive"
    assert v(0.05, 0.3, 0.06, 0.6, 0.1, True) == "inconclusive"  # interval beyond 0, test not significant
    # alpha is the caller's (e.g. compare the Holm-adjusted p with it)
    assert v(0.05, 0.30, 0.02, 0.9, 0.1, True, alpha=0.01) == "inconclusive"
    assert v(-0.01, 0.01, 0.5, 0.02, 0.1, True, alpha=0.01) == "inconclusive"
    # margin 0 switches relevance off; NaN (no pairs) is inconclusive
    assert v(0.001, 0.002, 0.001, math.nan, 0.0, True) == "better"
    assert v(-0.001, 0.002, 0.5, 0.0, 0.0, True) == "inconclusive"
    assert v(math.nan, math.nan, math.nan, math.nan, 0.1, True) == "inconclusive"
    assert set(stats.VERDICTS) == {"better", "worse", "equivalent", "inconclusive"}
    with pytest.raises(ValueError, match="alpha"):
        v(0.0, 1.0, 0.5, 0.5, 0.1, True, alpha=1.0)
    with pytest.raises(ValueError, match="margin"):
        v(0.0, 1.0, 0.5, 0.5, -0.1, True)
    with pytest.raises(ValueError, match="lower > upper"):
        v(1.0, 0.0, 0.5, 0.5, 0.1, True)


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


def test_the_rate_row_and_the_paired_row_are_their_parts():
    """stats.rate_row and stats.paired_rate_row, the rows every table of rates and every paired comparison
    of rates show, are Wilson's interval and Newcombe's, McNemar's and the TOST, each exactly."""
    rng = np.random.default_rng(3)
    x, y = rng.random(200) < 0.6, rng.random(200) < 0.5
    r = stats.rate_row(x, 0.9)
    lo, hi = stats.wilson_interval(int(x.sum()), 200, 0.9)
    assert (r.k, r.n, r.rate, r.lo, r.hi) == (int(x.sum()), 200, x.mean(), float(lo), float(hi))
    p = stats.paired_rate_row(x, y, 0.02, confidence=0.9, equivalence_confidence=0.95)
    test = stats.mcnemar_exact(x, y)
    assert (p.difference, p.lo, p.hi) == stats.paired_proportion_difference(x, y, 0.9)
    assert (p.b, p.c, p.p) == (test.b, test.c, test.pvalue)
    assert p.p_equivalence == stats.equivalence_test(x, y, 0.02, kind="rate", confidence=0.95).p
    assert np.isnan(stats.paired_rate_row(x, y).p_equivalence)  # no margin, no equivalence test
    empty = stats.paired_rate_row(x[:0], y[:0], 0.02)
    assert np.isnan([empty.difference, empty.lo, empty.hi, empty.p_equivalence]).all() and empty.p == 1.0
