r"""Statistics of ``jaxapf report``: pure functions over numpy arrays (no pandas, no JAX).

Every function takes plain arrays and returns plain numbers or arrays; randomness (bootstrap) comes
only from a ``numpy.random.Generator`` seeded with the ``seed`` argument, so every interval is
reproducible on its own. Definitions (and why these and not others) are in ``docs/report.md``.

=====================================  ================================================================
function                               what
=====================================  ================================================================
:func:`wilson_interval`                Wilson score interval of a binomial proportion
:func:`iqm`                            interquartile mean (25 % trimmed mean, as rliable)
:func:`bootstrap_ci`                   percentile bootstrap CI of a statistic, stratified resampling
:func:`paired_bootstrap_ci`            CI of ``stat(x) - stat(y)`` resampling *pairs* (stratified)
:func:`mcnemar_exact`                  exact McNemar test (binomial test on the discordant pairs)
:func:`wilcoxon_paired`                Wilcoxon signed-rank test on paired differences
:func:`probability_of_improvement_paired`  ``P(x_i > y_i) + ½ P(x_i = y_i)`` over the pairs
:func:`paired_proportion_difference`   ``p_x - p_y`` of paired booleans, Newcombe's hybrid score CI
:func:`hodges_lehmann_paired`          Hodges–Lehmann paired shift, signed-rank (Walsh average) CI
:func:`equivalence_test`               two one-sided tests (TOST) of ``|Δ| < margin``, rates or shifts
:func:`verdict`                        better / worse / equivalent / inconclusive, weighing relevance
:func:`verdicts`                       a study's verdicts: Holm on both tests, then :func:`verdict`
:func:`minimum_detectable_difference`  smallest difference the paired test detects (power 0.8)
:func:`holm`                           Holm step-down adjusted p-values
:func:`performance_profile`            fraction of values above each threshold τ
:func:`ecdf`                           empirical CDF
=====================================  ================================================================
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np
from scipy import stats as _st

__all__ = [
    "DEFAULT_RESAMPLES",
    "verdict_basis",
    "verdict_visible",
    "format_p",
    "wilson_interval",
    "iqm",
    "median",
    "mean",
    "bootstrap_ci",
    "bootstrap_cis",
    "paired_bootstrap_ci",
    "McNemarResult",
    "mcnemar_exact",
    "WilcoxonResult",
    "wilcoxon_paired",
    "pair_scores",
    "probability_of_improvement_paired",
    "paired_proportion_difference",
    "hodges_lehmann_paired",
    "EquivalenceResult",
    "equivalence_test",
    "RateRow",
    "rate_row",
    "PairedRateRow",
    "paired_rate_row",
    "VERDICTS",
    "VERDICT_RULE",
    "verdict",
    "verdicts",
    "minimum_detectable_difference",
    "holm",
    "performance_profile",
    "ecdf",
]

#: Bootstrap resamples used by the report unless told otherwise (``--resamples``).
DEFAULT_RESAMPLES = 2000

#: Upper bound on the number of elements of one resampled block (resamples × sample size), so that
#: large samples are bootstrapped in chunks of resamples instead of one huge index matrix.
_BLOCK = 4_000_000

Statistic = Callable[..., np.ndarray]


def _z(confidence: float) -> float:
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence = {confidence!r} must lie strictly between 0 and 1")
    return float(_st.norm.ppf(0.5 + confidence / 2.0))


# --------------------------------------------------------------------------------------------
# proportions
# --------------------------------------------------------------------------------------------


def wilson_interval(successes, n, confidence: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    r"""Wilson score interval of a binomial proportion ``p̂ = successes / n``.

    .. math::
        \frac{\hat p + z^2/2n}{1 + z^2/n} \pm \frac{z}{1 + z^2/n}
        \sqrt{\frac{\hat p(1-\hat p)}{n} + \frac{z^2}{4n^2}},\qquad z = \Phi^{-1}(1 - \alpha/2).

    Unlike the Wald interval it never leaves [0, 1] and does not collapse to a point at
    ``p̂ ∈ {0, 1}``. Vectorised over ``successes`` and ``n``; ``n == 0`` gives ``(nan, nan)``.
    Returns ``(lower, upper)`` (0-d arrays for scalar input), clipped to [0, 1].
    """
    k = np.asarray(successes, dtype=np.float64)
    n = np.asarray(n, dtype=np.float64)
    if np.any(k < 0) or np.any(k > n):
        raise ValueError("wilson_interval needs 0 <= successes <= n")
    z = _z(confidence)
    z2 = z * z
    safe_n = np.where(n > 0, n, 1.0)
    p = k / safe_n
    denom = 1.0 + z2 / safe_n
    centre = (p + z2 / (2.0 * safe_n)) / denom
    half = z / denom * np.sqrt(np.maximum(p * (1.0 - p) / safe_n + z2 / (4.0 * safe_n * safe_n), 0.0))
    lo = np.where(n > 0, np.clip(centre - half, 0.0, 1.0), np.nan)
    hi = np.where(n > 0, np.clip(centre + half, 0.0, 1.0), np.nan)
    # p̂ = 0 / 1 give exactly 0 / 1 in exact arithmetic; remove rounding noise.
    lo = np.where((n > 0) & (k == 0), 0.0, lo)
    hi = np.where((n > 0) & (k == n), 1.0, hi)
    return lo, hi


# --------------------------------------------------------------------------------------------
# location statistics
# --------------------------------------------------------------------------------------------


def iqm(x, axis: int = -1) -> np.ndarray:
    """Interquartile mean: the mean of the middle half, ``scipy.stats.trim_mean(x, 0.25)``.

    ``floor(n/4)`` values are cut at each end (so for ``n`` not a multiple of 4 slightly more than
    half is averaged), exactly as rliable's ``IQM``. NaN for an empty sample.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.shape[axis] == 0:
        return np.full(np.delete(x.shape, axis if axis >= 0 else x.ndim + axis), np.nan)[()]
    return np.asarray(_st.trim_mean(x, 0.25, axis=axis))[()]


def median(x, axis: int = -1) -> np.ndarray:
    """Median (``numpy.median``); NaN for an empty sample (without a warning)."""
    x = np.asarray(x, dtype=np.float64)
    if x.shape[axis] == 0:
        return np.full(np.delete(x.shape, axis if axis >= 0 else x.ndim + axis), np.nan)[()]
    return np.asarray(np.median(x, axis=axis))[()]


def mean(x, axis: int = -1) -> np.ndarray:
    """Mean; NaN for an empty sample (without a warning)."""
    x = np.asarray(x, dtype=np.float64)
    if x.shape[axis] == 0:
        return np.full(np.delete(x.shape, axis if axis >= 0 else x.ndim + axis), np.nan)[()]
    return np.asarray(np.mean(x, axis=axis))[()]


# --------------------------------------------------------------------------------------------
# bootstrap
# --------------------------------------------------------------------------------------------


def _strata_index(n: int, strata) -> list[np.ndarray]:
    """Row indices of every stratum (one stratum of everything when ``strata`` is None)."""
    if strata is None:
        return [np.arange(n)]
    strata = np.asarray(strata)
    if strata.shape != (n,):
        raise ValueError(f"strata has shape {strata.shape}; expected ({n},)")
    _, codes = np.unique(strata, return_inverse=True)
    return [np.flatnonzero(codes == c) for c in range(codes.max() + 1)] if n else []


def _resample_index(rng: np.random.Generator, groups: list[np.ndarray], count: int) -> np.ndarray:
    """(count, n) indices: each row draws ``len(g)`` rows with replacement inside every stratum ``g``."""
    parts = [g[rng.integers(0, len(g), size=(count, len(g)))] for g in groups if len(g)]
    return np.concatenate(parts, axis=1)


def _percentile(values: np.ndarray, confidence: float) -> tuple[float, float]:
    values = values[np.isfinite(values)]
    if values.size == 0:
        return math.nan, math.nan
    alpha = 1.0 - confidence
    lo, hi = np.quantile(values, [alpha / 2.0, 1.0 - alpha / 2.0])
    return float(lo), float(hi)


def _bootstrap(arrays: tuple[np.ndarray, ...], replicate: Callable[..., np.ndarray], strata, n_resamples: int,
               seed: int) -> np.ndarray:
    """(k, n_resamples) replicates: ``replicate`` maps a block of resampled rows to k values per resample."""
    n = arrays[0].shape[0]
    groups = _strata_index(n, strata)
    rng = np.random.default_rng(seed)
    chunk = max(1, min(n_resamples, _BLOCK // max(n, 1)))
    out = []
    done = 0
    while done < n_resamples:
        count = min(chunk, n_resamples - done)
        idx = _resample_index(rng, groups, count)
        out.append(np.asarray(replicate(*(a[idx] for a in arrays)), dtype=np.float64).reshape(-1, count))
        done += count
    return np.concatenate(out, axis=1)


#: A sample with at most this many distinct values (0/1 outcomes, per-pair scores 0/½/1) has the
#: bootstrap distribution of its mean drawn from multinomial counts: same distribution, O(resamples).
_FEW_VALUES = 16


def _mean_few_values(x: np.ndarray, strata, n_resamples: int, seed: int) -> np.ndarray | None:
    """Bootstrap replicates of ``mean(x)`` via multinomial counts per stratum, or None if ``x`` has
    many distinct values. Resampling ``n_s`` rows with replacement from a stratum whose values
    occur with frequencies ``f`` gives counts ``~ Multinomial(n_s, f)``, so this is the same
    distribution as the row resampling of :func:`_bootstrap`."""
    values, codes = np.unique(x, return_inverse=True)
    if values.size > _FEW_VALUES:
        return None
    rng = np.random.default_rng(seed)
    total = np.zeros(n_resamples)
    for g in _strata_index(x.size, strata):
        if g.size == 0:
            continue
        freq = np.bincount(codes[g], minlength=values.size) / g.size
        counts = rng.multinomial(g.size, freq, size=n_resamples)
        total += counts @ values
    return total / x.size


def bootstrap_ci(x, statistic: Statistic = np.mean, *, strata=None, n_resamples: int = DEFAULT_RESAMPLES,
                 confidence: float = 0.95, seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of ``statistic(x)``.

    Stratified: every resample draws, with replacement, as many rows from each stratum (e.g.
    scenario family) as the stratum has, so the mix of strata is the same in every resample and
    only the within-stratum variability enters the interval (rliable's stratified bootstrap).
    The mean of a sample with few distinct values (0/1 outcomes, per-pair scores) is resampled
    through multinomial counts per stratum: the same bootstrap distribution, at O(resamples) cost.

    Args:
      x: (n,) sample (must not contain NaN; filter first).
      statistic: reduces along ``axis=-1`` (``np.mean``, ``np.median``, :func:`iqm`, ...).
      strata: optional (n,) labels.
      n_resamples, confidence, seed: as named; ``numpy.random.default_rng(seed)`` drives it.

    Returns ``(lower, upper)``; ``(nan, nan)`` for an empty sample.
    """
    return bootstrap_cis(x, (statistic,), strata=strata, n_resamples=n_resamples, confidence=confidence,
                         seed=seed)[0]


def bootstrap_cis(x, statistics: Sequence[Statistic], *, strata=None, n_resamples: int = DEFAULT_RESAMPLES,
                  confidence: float = 0.95, seed: int = 0) -> list[tuple[float, float]]:
    """:func:`bootstrap_ci` of each of ``statistics`` (e.g. the median and the IQM), every one from
    the same resamples, drawn once: each interval is the one :func:`bootstrap_ci` gives with ``seed``."""
    x = np.asarray(x, dtype=np.float64).reshape(-1)
    if x.size == 0:
        return [(math.nan, math.nan)] * len(statistics)
    reps: list = [_mean_few_values(x, strata, n_resamples, seed) if s in (np.mean, mean) else None
                  for s in statistics]
    rest = [s for s, r in zip(statistics, reps) if r is None]
    if rest:
        drawn = iter(_bootstrap(*_sorted_resamples(x, rest), strata, n_resamples, seed))
        reps = [next(drawn) if r is None else r for r in reps]
    return [_percentile(r, confidence) for r in reps]


def _sorted_median(s: np.ndarray) -> np.ndarray:
    """:func:`median` of rows already sorted along the last axis."""
    n = s.shape[-1]
    return s[..., n // 2] if n % 2 else np.mean(s[..., n // 2 - 1:n // 2 + 1], axis=-1)


def _sorted_iqm(s: np.ndarray) -> np.ndarray:
    """:func:`iqm` of rows already sorted along the last axis (``floor(n/4)`` cut at each end)."""
    cut = s.shape[-1] // 4
    return np.mean(s[..., cut:s.shape[-1] - cut], axis=-1)


#: Order statistics computed from one sort of a block of resamples: numpy's vectorised sort is several
#: times faster than the two partitions and copies of ``np.median`` and ``trim_mean`` (the IQM's
#: replicates then sum the same values in sorted order: equal to rounding).
_FROM_SORTED = {median: _sorted_median, np.median: _sorted_median, iqm: _sorted_iqm}


def _replicates(statistics: Sequence[Statistic]) -> Callable[[np.ndarray], np.ndarray]:
    """A block of resamples -> the stacked replicates of each statistic (one sort for the order statistics)."""
    def replicate(xb):
        s = np.sort(xb, axis=-1) if any(f in _FROM_SORTED for f in statistics) else None
        return np.stack([_FROM_SORTED[f](s) if f in _FROM_SORTED else f(xb, axis=-1) for f in statistics])
    return replicate


def _sorted_resamples(x: np.ndarray, statistics: Sequence[Statistic]) -> tuple[tuple[np.ndarray], Callable]:
    """What :func:`_bootstrap` resamples for ``statistics`` of ``x``, and how a block becomes replicates.
    Order statistics of up to 65,536 values resample the 16-bit ranks of ``x``: numpy sorts those by radix,
    several times faster than the floats, and the sorted ranks index the sorted values, so every
    replicate equals the one from sorting the resampled values."""
    if x.size > 1 << 16 or not all(f in _FROM_SORTED for f in statistics):
        return (x,), _replicates(statistics)
    order = np.argsort(x, kind="stable")
    ranks = np.empty(x.size, np.uint16)
    ranks[order] = np.arange(x.size)
    ordered = x[order]

    def replicate(rb):
        s = ordered[np.sort(rb, axis=-1, kind="stable")]
        return np.stack([_FROM_SORTED[f](s) for f in statistics])
    return (ranks,), replicate


def _paired(x, y, dtype: Any = np.float64) -> tuple[np.ndarray, np.ndarray]:
    """``x`` and ``y`` as flat arrays of ``dtype``; a :class:`ValueError` if they differ in size."""
    x = np.asarray(x, dtype=dtype).reshape(-1)
    y = np.asarray(y, dtype=dtype).reshape(-1)
    if x.shape != y.shape:
        raise ValueError(f"paired samples differ in size: {x.shape} vs {y.shape}")
    return x, y


def paired_bootstrap_ci(x, y, statistic: Statistic = np.mean, *, strata=None,
                        n_resamples: int = DEFAULT_RESAMPLES, confidence: float = 0.95,
                        seed: int = 0) -> tuple[float, float, float]:
    """Estimate and percentile CI of ``statistic(x) - statistic(y)`` for *paired* samples.

    Every resample draws pairs ``(x_i, y_i)`` (the same index for both), stratified as in
    :func:`bootstrap_ci`, so the positive correlation that common random numbers induce between
    ``x`` and ``y`` narrows the interval as it should. For ``statistic = np.mean`` the estimate is
    the mean paired difference (for 0/1 data: the difference in rates).

    Returns ``(estimate, lower, upper)``; NaNs for no pairs.
    """
    x, y = _paired(x, y)
    if x.size == 0:
        return math.nan, math.nan, math.nan
    estimate = float(statistic(x, axis=-1) - statistic(y, axis=-1))
    if statistic in (np.mean, mean):  # mean(x*) - mean(y*) = mean((x - y)*): one sample of differences
        return (estimate, *bootstrap_ci(x - y, mean, strata=strata, n_resamples=n_resamples,
                                        confidence=confidence, seed=seed))
    reps = _bootstrap((x, y), lambda xb, yb: statistic(xb, axis=-1) - statistic(yb, axis=-1),
                      strata, n_resamples, seed)[0]
    return (estimate, *_percentile(reps, confidence))


# --------------------------------------------------------------------------------------------
# paired tests
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class McNemarResult:
    """``b`` = pairs with x true and y false, ``c`` = x false and y true, two-sided exact ``pvalue``."""

    b: int
    c: int
    pvalue: float


def mcnemar_exact(x, y) -> McNemarResult:
    """Exact McNemar test of paired binary outcomes.

    Under H0 (same marginal rate) each discordant pair is equally likely to be ``(1, 0)`` or
    ``(0, 1)``, so ``b ~ Binomial(b + c, ½)``; the p-value is
    ``scipy.stats.binomtest(b, b + c, 0.5)`` (two-sided). No discordant pair: p = 1.
    """
    _, b, c, _ = _paired_counts(x, y)
    p = 1.0 if b + c == 0 else float(_st.binomtest(b, b + c, 0.5).pvalue)
    return McNemarResult(b, c, min(p, 1.0))


@dataclasses.dataclass(frozen=True)
class WilcoxonResult:
    """Signed-rank ``statistic`` (scipy's), ``pvalue`` (two-sided), ``n`` pairs, ``n_nonzero`` non-tied pairs."""

    statistic: float
    pvalue: float
    n: int
    n_nonzero: int


#: Up to this many non-zero differences the signed-rank p-value is exact (:func:`_signed_rank_exact`).
EXACT_WILCOXON_MAX = 100


def _signed_rank_null(twice: np.ndarray) -> np.ndarray:
    """Null distribution of ``2 T+`` for the doubled (mid)ranks ``twice`` (integers):
    ``dist[t] = P(Σ twice_i B_i = t)``, ``B_i ~ Bernoulli(½)`` independent, ``t = 0..Σ twice``."""
    total = int(np.sum(twice))
    dist = np.zeros(total + 1)
    dist[0] = 1.0
    for r in twice:
        shifted = np.zeros_like(dist)
        shifted[r:] = dist[: total + 1 - r]
        dist = 0.5 * (dist + shifted)
    return dist


def _signed_rank_exact(d: np.ndarray) -> tuple[float, float]:
    """Exact two-sided signed-rank test of the non-zero differences ``d``, ties included.

    Conditional on the (mid)ranks ``r_i`` of ``|d_i|``, under H0 each sign is + or − with
    probability ½ independently, so ``T+ = Σ r_i [d_i > 0]`` has the distribution of a sum of
    independent ``r_i · Bernoulli(½)``. Midranks are multiples of ½, so ``2 T+`` is an integer and
    the distribution is a convolution over integers (O(n³) at worst). This is the permutation
    test that ``scipy.stats.wilcoxon`` runs for ties, without enumerating 2^n sign patterns.
    Returns ``(min(T+, T-), p)``, p = ``min(1, 2 min(P(T+ <= t), P(T+ >= t)))``.
    """
    ranks = _st.rankdata(np.abs(d))
    twice = np.rint(2.0 * ranks).astype(np.int64)
    total = int(twice.sum())
    dist = _signed_rank_null(twice)
    t_plus = int(twice[d > 0].sum())
    lower = float(dist[: t_plus + 1].sum())
    upper = float(dist[t_plus:].sum())
    p = min(1.0, 2.0 * min(lower, upper))
    stat = min(t_plus, total - t_plus) / 2.0
    return float(stat), float(p)


def wilcoxon_paired(x, y) -> WilcoxonResult:
    """Wilcoxon signed-rank test of ``x_i - y_i`` (two-sided).

    Zero differences are dropped (Wilcoxon's original treatment, scipy's ``zero_method="wilcox"``;
    with common random numbers many pairs can be exactly equal, e.g. when a gain does not change
    the trajectory). Up to :data:`EXACT_WILCOXON_MAX` non-zero differences the p-value is exact,
    ties handled by midranks (:func:`_signed_rank_exact`); beyond, ``scipy.stats.wilcoxon`` with
    the normal approximation (tie-corrected). The statistic is ``min(T+, T-)``, as scipy's.
    Every difference zero: statistic 0, p = 1. No pairs: NaNs.
    """
    d = _paired_differences(x, y, "wilcoxon_paired")
    nonzero = int(np.count_nonzero(d))
    if d.size == 0:
        return WilcoxonResult(math.nan, math.nan, 0, 0)
    if nonzero == 0:
        return WilcoxonResult(0.0, 1.0, int(d.size), 0)
    if nonzero <= EXACT_WILCOXON_MAX:
        stat, p = _signed_rank_exact(d[d != 0])
        return WilcoxonResult(stat, p, int(d.size), nonzero)
    res = _st.wilcoxon(d, zero_method="wilcox", alternative="two-sided", method="approx")
    return WilcoxonResult(float(res.statistic), float(min(res.pvalue, 1.0)), int(d.size), nonzero)


def pair_scores(x, y, higher_is_better: bool = True) -> np.ndarray:
    """Per-pair improvement score: 1 if ``x_i`` beats ``y_i``, ½ if equal, 0 otherwise."""
    x, y = _paired(x, y)
    better = x > y if higher_is_better else x < y
    return better.astype(np.float64) + 0.5 * (x == y)


def probability_of_improvement_paired(x, y, higher_is_better: bool = True) -> float:
    """``P(x_i > y_i) + ½ P(x_i = y_i)`` over the *pairs* ``i`` (``<`` when lower is better).

    rliable's probability of improvement compares every ``x`` with every ``y`` (Mann–Whitney); with
    common random numbers the natural question is "on the same field, how often is x better",
    so only matching pairs are compared. ½ = no difference. NaN for no pairs.
    """
    scores = pair_scores(x, y, higher_is_better)
    return float(np.mean(scores)) if scores.size else math.nan


# --------------------------------------------------------------------------------------------
# estimates of paired differences (what the paired tests are about)
# --------------------------------------------------------------------------------------------


def _paired_counts(x, y) -> tuple[int, int, int, int]:
    """``(a, b, c, d)`` of paired booleans: both true, only x, only y, neither."""
    x, y = _paired(x, y, bool)
    a = int(np.sum(x & y))
    b = int(np.sum(x & ~y))
    c = int(np.sum(~x & y))
    return a, b, c, int(x.size) - a - b - c


def _paired_differences(x, y, who: str) -> np.ndarray:
    """Finite ``x - y`` of paired samples (a shape mismatch or a non-finite value is an error)."""
    x, y = _paired(x, y)
    d = x - y
    if np.any(~np.isfinite(d)):
        raise ValueError(f"{who} needs finite values; filter the pairs first")
    return d


def paired_proportion_difference(x, y, confidence: float = 0.95) -> tuple[float, float, float]:
    r"""Difference of paired proportions ``p_x - p_y`` with Newcombe's hybrid score interval.

    With ``a`` pairs where both are true, ``b`` only x, ``c`` only y, ``d`` neither (``n`` pairs),
    the estimate is ``θ̂ = p̂_x - p̂_y = (b - c) / n``: the difference that McNemar's test
    (:func:`mcnemar_exact`) is about. The interval is Newcombe's (1998) method 10, the "square
    and add" of the Wilson intervals ``[l_x, u_x]``, ``[l_y, u_y]`` of the two marginal
    proportions (:func:`wilson_interval`), corrected for their correlation ``φ̂``:

    .. math::
        L = θ̂ - \sqrt{(p̂_x - l_x)^2 - 2φ̂(p̂_x - l_x)(u_y - p̂_y) + (u_y - p̂_y)^2},\quad
        U = θ̂ + \sqrt{(p̂_y - l_y)^2 - 2φ̂(p̂_y - l_y)(u_x - p̂_x) + (u_x - p̂_x)^2},

    where ``φ̂`` is the phi coefficient of the 2×2 table with Newcombe's continuity correction:
    with ``A = ad - bc`` and ``D = (a+b)(c+d)(a+c)(b+d)``, ``φ̂ = (A - n/2)/√D`` if ``A > n/2``,
    0 if ``0 <= A <= n/2``, ``A/√D`` if ``A < 0``, and 0 when ``D = 0``. This is the form of
    Newcombe, "Improved confidence intervals for the difference between binomial proportions
    based on paired data", Stat. Med. 17 (1998) 2635–2650, as given by Fagerland, Lydersen & Laake,
    Stat. Med. 33 (2014) 2850–2875 ("Newcombe square-and-add"), who recommend it; it reproduces
    their worked example (Cavo et al. 2012: −0.0621, 95 % CI −0.1186 to −0.0046). It never
    leaves [−1, 1] (``L >= l_x - u_y``), contains ``θ̂``, and swapping x and y negates it.

    Returns ``(estimate, lower, upper)``; NaNs for no pairs.
    """
    _z(confidence)
    a, b, c, d = _paired_counts(x, y)
    n = a + b + c + d
    if n == 0:
        return math.nan, math.nan, math.nan
    px, py = (a + b) / n, (a + c) / n
    lx, ux = (float(v) for v in wilson_interval(a + b, n, confidence))
    ly, uy = (float(v) for v in wilson_interval(a + c, n, confidence))
    cross = a * d - b * c  # Python ints: exact
    margins = (a + b) * (c + d) * (a + c) * (b + d)
    if margins == 0 or 0 <= cross <= n / 2:
        phi = 0.0
    else:
        phi = ((cross - n / 2) if cross > 0 else cross) / math.sqrt(margins)
    theta = (b - c) / n
    dl, du = px - lx, uy - py  # distances that pull θ down
    el, eu = py - ly, ux - px  # distances that push θ up
    lower = theta - math.sqrt(max(dl * dl - 2.0 * phi * dl * du + du * du, 0.0))
    upper = theta + math.sqrt(max(el * el - 2.0 * phi * el * eu + eu * eu, 0.0))
    return theta, max(lower, -1.0), min(upper, 1.0)


#: Up to this many pairs the Hodges–Lehmann interval takes its rank from the exact null
#: distribution of the signed-rank statistic; beyond, from its normal approximation.
EXACT_HL_MAX = 50

#: At most this many Walsh sums are ever held in memory at once (8 MiB of float64 plus indices).
_WALSH_MATERIALISE = 1 << 20


def _walsh_rank(n: int, confidence: float) -> int:
    """The rank ``k`` of the distribution-free interval ``[W_(k), W_(M+1-k)]`` of the Walsh averages.

    For a continuous distribution symmetric about ``θ`` the interval misses ``θ`` below (above)
    exactly when the signed-rank statistic of ``d - θ`` is ``<= k - 1`` (``>= M - k + 1``), so
    its coverage is ``1 - 2 P(T+ <= k - 1)``; ``k`` is the largest rank with
    ``P(T+ <= k - 1) <= α/2``. Exact (ranks ``1..n``, :func:`_signed_rank_null`) up to
    :data:`EXACT_HL_MAX` pairs; beyond, the normal approximation with continuity correction,
    ``P(T+ <= k - 1) ≈ Φ((k - ½ - M/2) / σ)``, ``σ² = n(n+1)(2n+1)/24``, which gives
    ``k = floor(M/2 - zσ + ½)``. 0 when no rank attains the confidence (``2^{1-n} > α``).
    """
    z = _z(confidence)
    alpha = 1.0 - confidence
    m = n * (n + 1) // 2
    if n <= EXACT_HL_MAX:
        cdf = np.cumsum(_signed_rank_null(2 * np.arange(1, n + 1))[::2])  # P(T+ <= t), t = 0..M
        k = int(np.searchsorted(cdf, alpha / 2.0 * (1.0 + 1e-9), side="right"))
    else:
        sigma = math.sqrt(n * (n + 1) * (2 * n + 1) / 24.0)
        k = math.floor(m / 2.0 - z * sigma + 0.5)
    return max(0, min(k, (m + 1) // 2))


def _walsh_sums(d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The sums ``d_i + d_j`` for ``lo_i <= j < hi_i``, every row ``i``."""
    width = hi - lo
    rows = np.repeat(np.arange(d.size), width)
    cols = np.arange(int(width.sum())) - np.repeat(np.cumsum(width) - width - lo, width)
    return d[rows] + d[cols]


def _walsh_split(d: np.ndarray, pivot: float, strict: bool) -> np.ndarray:
    """Per row ``i`` of the sorted ``d``: the first column ``j >= i`` with ``d_i + d_j >= pivot``
    (``> pivot`` when not ``strict``), the comparison made on the floating-point sums themselves.

    ``searchsorted`` on ``pivot - d_i`` finds it up to rounding; the repair steps then move each
    row over whole blocks of tied values until the sums on both sides agree (a few steps)."""
    n = d.size
    rows = np.arange(n)
    side = "left" if strict else "right"
    pos = np.maximum(np.searchsorted(d, pivot - d, side=side), rows)
    past = (lambda s: s >= pivot) if strict else (lambda s: s > pivot)
    while True:
        left = np.flatnonzero(pos > rows)
        left = left[past(d[left] + d[pos[left] - 1])]  # the column before already qualifies
        right = np.flatnonzero(pos < n)
        right = right[~past(d[right] + d[pos[right]])]  # this column does not qualify yet
        if left.size == 0 and right.size == 0:
            return pos
        pos[left] = np.maximum(np.searchsorted(d, d[pos[left] - 1], side="left"), left)
        pos[right] = np.searchsorted(d, d[pos[right]], side="right")


def _walsh_kth(d: np.ndarray, k: int) -> float:
    """The ``k``-th smallest (1-based) of the ``n(n+1)/2`` sums ``d_i + d_j``, ``i <= j``, of sorted ``d``.

    Selection in the implicit sorted matrix ``d_i + d_j`` (rows sorted along ``j``), after
    Johnson & Mizoguchi (SIAM J. Comput. 7, 1978): candidate columns ``[lo_i, hi_i)`` per row;
    the pivot is the weighted median of the rows' middle candidates, so every round removes at
    least a quarter of the candidates; counting the sums below the pivot is one vectorised
    ``searchsorted`` (:func:`_walsh_split`). Once at most :data:`_WALSH_MATERIALISE` candidates
    are left they are materialised and partitioned. Time O(n log n · log n), memory O(n) plus
    that bound: never the full n(n+1)/2 array.
    """
    n = d.size
    rows = np.arange(n)
    lo, hi = rows.copy(), np.full(n, n)
    while True:
        width = hi - lo
        count = int(width.sum())
        if count <= _WALSH_MATERIALISE:
            rank = k - int((lo - rows).sum())  # rank among the candidates
            return float(np.partition(_walsh_sums(d, lo, hi), rank - 1)[rank - 1])
        live = np.flatnonzero(width > 0)
        middle = d[live] + d[(lo[live] + hi[live] - 1) // 2]
        order = np.argsort(middle, kind="stable")
        weight = np.cumsum(width[live][order])
        pivot = float(middle[order][np.searchsorted(weight, count / 2.0)])
        below = _walsh_split(d, pivot, strict=True)  # columns < below: sums < pivot
        upto = _walsh_split(d, pivot, strict=False)  # columns < upto: sums <= pivot
        n_below, n_upto = int((below - rows).sum()), int((upto - rows).sum())
        if n_below < k <= n_upto:
            return pivot
        if k <= n_below:
            hi = np.maximum(np.minimum(hi, below), lo)
        else:
            lo = np.minimum(np.maximum(lo, upto), hi)


def hodges_lehmann_paired(x, y, confidence: float = 0.95) -> tuple[float, float, float]:
    r"""Hodges–Lehmann estimate of the paired shift with its distribution-free interval.

    With ``d = x - y`` (``n`` pairs) and the ``M = n(n+1)/2`` Walsh averages
    ``W_ij = (d_i + d_j)/2, i <= j``, the estimate is ``median(W)``: the shift ``θ`` for which
    the signed-rank statistic of ``d - θ`` is balanced, i.e. the estimate the Wilcoxon
    signed-rank test (:func:`wilcoxon_paired`) is about. Zero differences are kept, as in the
    standard definition (Hollander & Wolfe, *Nonparametric Statistical Methods*, §3.2); they
    are dropped only by the *test*. The interval is ``[W_(k), W_(M+1-k)]`` (k-th smallest and
    k-th largest), ``k`` from the signed-rank null distribution (:func:`_walsh_rank`: exact up
    to :data:`EXACT_HL_MAX` pairs, normal approximation with continuity correction beyond); its
    coverage is at least ``confidence`` for continuous differences symmetric about the shift
    (with ties it is approximate, as for every rank interval). When no rank attains the
    confidence (n <= 5 at 95 %), the interval is ``(-inf, inf)``: no distribution-free
    statement is possible.

    Memory: the Walsh averages are never materialised (``n = 10 000`` has 5·10⁷ of them);
    each order statistic is selected in O(n) memory plus at most 2²⁰ candidates
    (:func:`_walsh_kth`), in a fraction of a second for that ``n``.

    Returns ``(estimate, lower, upper)``; NaNs for no pairs.
    """
    _z(confidence)
    d = np.sort(_paired_differences(x, y, "hodges_lehmann_paired"))
    n = d.size
    if n == 0:
        return math.nan, math.nan, math.nan
    m = n * (n + 1) // 2
    if m % 2:
        estimate = _walsh_kth(d, (m + 1) // 2) / 2.0
    else:
        estimate = (_walsh_kth(d, m // 2) + _walsh_kth(d, m // 2 + 1)) / 4.0
    k = _walsh_rank(n, confidence)
    if k == 0:
        return float(estimate), -math.inf, math.inf
    return float(estimate), _walsh_kth(d, k) / 2.0, _walsh_kth(d, m + 1 - k) / 2.0


# --------------------------------------------------------------------------------------------
# equivalence, relevance, power
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class EquivalenceResult:
    """Two one-sided tests: ``p_lower`` of H0 ``Δ <= -margin``, ``p_upper`` of H0 ``Δ >= margin``,
    ``p = max(p_lower, p_upper)``; ``equivalent`` when ``p <= α``, ``α = 1 - confidence``."""

    p_lower: float
    p_upper: float
    p: float
    equivalent: bool


def _tango_z(b: int, c: int, n: int, delta: float) -> float:
    r"""Tango's score statistic for H0 ``p_x - p_y = delta`` (``0 < delta < 1``) of paired booleans.

    ``Z = (b - c - nδ) / \sqrt{n(2 q̃ + δ(1 - δ))}``, where ``q̃`` is the maximum-likelihood
    estimate of ``P(only y)`` under H0 (cells ``q + δ``, ``q``, rest concordant), the positive
    root of ``2n q² + w q - c δ(1-δ) = 0``, ``w = -b - c + (2n - b + c) δ``. For ``δ > 0`` the
    variance is at least ``nδ(1 - δ) > 0``, so no discordant pair still gives a finite statistic.
    """
    w = -b - c + (2 * n - b + c) * delta
    disc = 8.0 * n * c * delta * (1.0 - delta)
    root = math.sqrt(w * w + disc)
    q = 2.0 * c * delta * (1.0 - delta) / (root + w) if w > 0 else (root - w) / (4.0 * n)
    return (b - c - n * delta) / math.sqrt(n * (2.0 * q + delta * (1.0 - delta)))


def _signed_rank_one_sided(e: np.ndarray, alternative: str) -> float:
    """One-sided signed-rank p-value of ``e`` (H1: location ``> 0`` for "greater", ``< 0`` for
    "less"), treated exactly as :func:`wilcoxon_paired` treats its differences: zeros dropped,
    midranks, exact up to :data:`EXACT_WILCOXON_MAX` non-zero values, scipy's normal
    approximation beyond. No non-zero value: p = 1."""
    nz = e[e != 0]
    if nz.size == 0:
        return 1.0
    if nz.size > EXACT_WILCOXON_MAX:
        res = _st.wilcoxon(nz, zero_method="wilcox", alternative=alternative, method="approx")
        return float(min(res.pvalue, 1.0))
    twice = np.rint(2.0 * _st.rankdata(np.abs(nz))).astype(np.int64)
    dist = _signed_rank_null(twice)
    t_plus = int(twice[nz > 0].sum())
    p = dist[t_plus:].sum() if alternative == "greater" else dist[: t_plus + 1].sum()
    return float(min(p, 1.0))


def equivalence_test(x, y, margin: float, *, kind: str, confidence: float = 0.95) -> EquivalenceResult:
    r"""Two one-sided tests (TOST) that the paired difference ``Δ`` (x minus y) lies in ``(-margin, margin)``.

    ``p_lower`` tests H0 ``Δ <= -margin`` against ``Δ > -margin``, ``p_upper`` tests H0
    ``Δ >= margin`` against ``Δ < margin``; equivalence is shown at level ``α = 1 - confidence``
    when both reject, ``p = max(p_lower, p_upper) <= α`` (Schuirmann 1987). Each one-sided test
    at α corresponds to one side of a ``1 - 2α`` interval (90 % for α = 0.05).

    ``kind="rate"`` (booleans; ``Δ = p_x - p_y = (b - c)/n`` as in
    :func:`paired_proportion_difference`, ``0 < margin < 1``): Tango's score test (Tango,
    Stat. Med. 17 (1998) 891–908; :func:`_tango_z`), the statistic whose inversion is Tango's
    score interval. Chosen over the Wald test with the discordant-pair standard error
    ``√(b + c - (b - c)²/n) / n``, which is 0 when no pair is discordant and then "proves"
    equivalence from any number of pairs; the score test evaluates the variance under each
    null (``Δ = ±margin``), which keeps it positive; Liu, Hsueh, Hsieh & Chen (Stat. Med. 21
    (2002) 231–245) compare the two for paired equivalence and recommend the restricted-MLE test.
    ``p_upper = Φ(Z(b, c, margin))``, ``p_lower = Φ(Z(c, b, margin))`` (the lower test is the
    upper one with x and y swapped).

    ``kind="continuous"``: ``Δ`` is the shift of the differences ``d = x - y``, tested by the
    one-sided Wilcoxon signed-rank test of ``d + margin`` (H1 location > 0) and of
    ``d - margin`` (H1 location < 0), computed as :func:`wilcoxon_paired` computes its test
    (zeros dropped, midranks, exact up to :data:`EXACT_WILCOXON_MAX` non-zero differences).
    It agrees with the rule "the ``1 - 2α`` :func:`hodges_lehmann_paired` interval lies inside
    ``(-margin, margin)``" exactly for untied differences up to :data:`EXACT_HL_MAX` pairs (both
    exact), approximately beyond (normal approximations) and with ties or zeros.

    No pairs: NaN p-values, not equivalent.
    """
    _z(confidence)
    if not (math.isfinite(margin) and margin > 0):
        raise ValueError(f"margin = {margin!r} must be positive and finite")
    alpha = 1.0 - confidence
    if kind == "rate":
        if margin >= 1:
            raise ValueError(f"margin = {margin!r} must lie strictly between 0 and 1 for kind='rate'")
        a, b, c, d = _paired_counts(x, y)
        n = a + b + c + d
        if n == 0:
            return EquivalenceResult(math.nan, math.nan, math.nan, False)
        p_upper = float(_st.norm.cdf(_tango_z(b, c, n, margin)))
        p_lower = float(_st.norm.cdf(_tango_z(c, b, n, margin)))
    elif kind == "continuous":
        diff = _paired_differences(x, y, "equivalence_test")
        if diff.size == 0:
            return EquivalenceResult(math.nan, math.nan, math.nan, False)
        p_lower = _signed_rank_one_sided(diff + margin, "greater")
        p_upper = _signed_rank_one_sided(diff - margin, "less")
    else:
        raise ValueError(f"kind = {kind!r} must be 'rate' or 'continuous'")
    p = max(p_lower, p_upper)
    return EquivalenceResult(p_lower, p_upper, p, bool(p <= alpha))


#: The four verdicts of :func:`verdict`.
VERDICTS = ("better", "worse", "equivalent", "inconclusive")

#: The rule of :func:`verdict` in one sentence, for every report and study that prints verdicts.
VERDICT_RULE = ("verdict: equivalent when the Holm-adjusted equivalence test (TOST within the margin) rejects; "
                "otherwise better or worse when the Holm-adjusted difference test is significant and the "
                "difference's 95 % interval excludes 0 on that side (the estimate may still be smaller than the "
                "margin: relevance is then not shown either way); inconclusive otherwise. Holm runs over every "
                "comparison of the study, separately for the difference and the equivalence tests")


class RateRow(NamedTuple):
    """A rate: ``k`` of ``n`` episodes, ``rate = k/n`` and its Wilson interval ``[lo, hi]``."""

    k: int
    n: int
    rate: float
    lo: float
    hi: float


def rate_row(outcomes, confidence: float = 0.95) -> RateRow:
    """The rate of the true ``outcomes`` (booleans, ``n >= 1``) with its Wilson interval: the row every
    table of rates shows (the report, the tuners' proofs, the studies)."""
    k, n = int(np.sum(outcomes)), len(outcomes)
    lo, hi = wilson_interval(k, n, confidence)
    return RateRow(k, n, k / n, float(lo), float(hi))


class PairedRateRow(NamedTuple):
    """``x`` against ``y`` on the same fields: the difference of rates with Newcombe's interval, the
    discordant pairs ``b`` (x only) and ``c`` (y only), the exact McNemar ``p`` and the TOST
    ``p_equivalence`` within the margin (NaN without one)."""

    difference: float
    lo: float
    hi: float
    b: int
    c: int
    p: float
    p_equivalence: float


def paired_rate_row(x, y, margin: float | None = None, *, confidence: float = 0.95,
                    equivalence_confidence: float = 0.95) -> PairedRateRow:
    """The paired comparison of two rates (booleans ``x``, ``y`` on the same fields), ready for
    :func:`verdicts`: :func:`paired_proportion_difference`, :func:`mcnemar_exact` and, with a ``margin``,
    :func:`equivalence_test`; no pairs give NaN."""
    test = mcnemar_exact(x, y)
    if len(x) == 0:
        return PairedRateRow(math.nan, math.nan, math.nan, test.b, test.c, test.pvalue, math.nan)
    diff, lo, hi = paired_proportion_difference(x, y, confidence)
    p_eq = (math.nan if margin is None else
            equivalence_test(x, y, margin, kind="rate", confidence=equivalence_confidence).p)
    return PairedRateRow(diff, lo, hi, test.b, test.c, test.pvalue, p_eq)


def verdict(lo: float, hi: float, p_difference: float, p_equivalence: float, margin: float,
            higher_is_better: bool, alpha: float = 0.05) -> str:
    """Verdict of one comparison of x against y, weighing significance *and* relevance.

    Args:
      lo, hi: confidence interval of the difference ``Δ = x - y`` (e.g. of
        :func:`paired_proportion_difference` or :func:`hodges_lehmann_paired`).
      p_difference: p-value of the test of ``Δ = 0`` (McNemar / Wilcoxon), *adjusted* for the
        study's multiplicity (:func:`verdicts` does both adjustments).
      p_equivalence: TOST p-value of ``|Δ| < margin`` (:func:`equivalence_test`), adjusted alike.
      margin: the smallest difference that matters (>= 0; 0 switches relevance off).
      higher_is_better: direction of the metric (``collision``: False).
      alpha: level of both tests.

    Rule (:data:`VERDICT_RULE`), with "up" meaning better for x (the interval is mirrored when
    lower is better):

    * **"equivalent"** when the equivalence test rejects (``p_equivalence <= alpha``), whether or
      not the difference test is significant: a real but irrelevant difference is equivalent;
    * otherwise **"better"** / **"worse"** when the difference test is significant
      (``p_difference <= alpha``) *and* the whole interval lies beyond 0 in that direction;
    * otherwise **"inconclusive"**.

    Both relevance and direction rest on multiplicity-adjusted tests, so "equivalent" carries the
    same family-wise error control as "better" and "worse". An interval inside the margin is *not*
    taken as equivalence by itself: the interval is unadjusted, and at the study's multiplicity
    it would claim equivalence more easily than the adjusted tests claim a difference.

    Why "better" needs the interval beyond 0 and not beyond the margin: the verdict states the
    *direction* the data establish; relevance overrides it only when the data establish that
    the difference is too small to matter (the equivalence-trial criterion, Schuirmann 1987).
    Requiring the whole interval beyond the margin would test superiority *by* the margin, a
    stronger question that leaves most real improvements "inconclusive". A "better" difference
    may therefore be smaller than the margin; the interval in the report shows how large it may
    be. Both the p-value and the interval are required so that the verdict never contradicts
    the interval shown next to it (the exact McNemar test and the score interval can disagree at
    the edge). NaN inputs count as "not significant", so a comparison without pairs is
    "inconclusive".
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha = {alpha!r} must lie strictly between 0 and 1")
    if not (math.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin = {margin!r} must be non-negative and finite")
    if lo > hi:
        raise ValueError(f"interval ({lo!r}, {hi!r}) has lower > upper")
    if not higher_is_better:
        lo, hi = -hi, -lo
    if margin > 0 and p_equivalence <= alpha:
        return "equivalent"
    if p_difference <= alpha and (lo > 0 or hi < 0):
        return "better" if lo > 0 else "worse"
    return "inconclusive"


def verdicts(lo, hi, p_difference, p_equivalence, margin, higher_is_better,
             alpha: float = 0.05) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The verdicts of a whole study: Holm over all its comparisons, then :func:`verdict` per row.

    Every study and report calls this one function, so every claim (better, worse and equivalent
    alike) gets the same correction. The arguments are sequences over the study's comparisons
    (``margin`` and ``higher_is_better`` may be scalars); NaN p-values do not count in Holm's
    ``m`` and give "inconclusive". Returns ``(p_holm, p_equivalence_holm, verdicts)``.
    """
    p_holm = holm(np.asarray(p_difference, np.float64))
    p_eq_holm = holm(np.asarray(p_equivalence, np.float64))
    n = p_holm.size
    lo, hi = np.broadcast_to(np.asarray(lo, np.float64), (n,)), np.broadcast_to(np.asarray(hi, np.float64), (n,))
    margin = np.broadcast_to(np.nan_to_num(np.asarray(margin, np.float64), nan=0.0), (n,))
    up = np.broadcast_to(np.asarray(higher_is_better, bool), (n,))
    out = [verdict(float(a), float(b), float(p), float(q), float(m), bool(u), alpha)
           for a, b, p, q, m, u in zip(lo, hi, p_holm, p_eq_holm, margin, up)]
    return p_holm, p_eq_holm, out


def format_p(p: float) -> str:
    """A p-value as every table prints it: three decimals, ``<0.001`` below, ``–`` where there is none."""
    p = float(p)
    return "–" if not math.isfinite(p) else "<0.001" if p < 0.001 else f"{p:.3f}"


def verdict_basis(lo: float, hi: float, p_holm: float, p_equivalence_holm: float, margin: float,
                  higher_is_better: bool, alpha: float = 0.05) -> str:
    """What decided :func:`verdict` on these (Holm-adjusted) inputs, in a few words a table cell holds, so a
    reader checks the verdict from its cell: the equivalence test (TOST within ``±margin``) for
    *equivalent*; the difference test and the interval's side for *better*/*worse*; for *inconclusive*
    each condition that failed. The interval shown beside a verdict is the 95 % one, unadjusted; an
    interval inside the margin that is not *equivalent*, or one excluding 0 that is *inconclusive*, is
    explained here by the adjusted p-value that fell short."""
    found = verdict(lo, hi, p_holm, p_equivalence_holm, margin, higher_is_better, alpha)
    a = f"{alpha:g}"
    tost = f"TOST p Holm {format_p(p_equivalence_holm)}"
    diff = f"p Holm {format_p(p_holm)}"
    if found == "equivalent":
        return f"{tost} ≤ {a}"
    if found in ("better", "worse"):  # hidden only where the interval lies inside the margin: why not equivalent
        shown = verdict_visible(lo, hi, margin, found, higher_is_better)
        return f"{diff} ≤ {a}, CI excludes 0" + ("" if shown else f"; {tost} > {a}")
    reasons = [f"{tost} > {a}" if margin > 0 and math.isfinite(p_equivalence_holm) else "no margin"
               if margin <= 0 else "no TOST"]
    excludes = lo > 0 or hi < 0
    if not math.isfinite(p_holm):
        reasons.append("no pairs")
    elif p_holm > alpha:
        reasons.append(f"{diff} > {a}")
    elif not excludes:
        reasons.append(f"{diff} but CI includes 0")
    return "; ".join(reasons)


def verdict_visible(lo: float, hi: float, margin: float, verdict_: str, higher_is_better: bool = True) -> bool:
    """Whether ``verdict_`` follows from the interval ``[lo, hi]`` and the ``margin`` alone, as a reader checks
    it: *equivalent* inside ``(-margin, margin)``; *better*/*worse* wholly beyond 0 on its side and not
    inside the margin; *inconclusive* holding 0 and not inside the margin. Where it does not, the cell
    shows :func:`verdict_basis`."""
    if not higher_is_better:
        lo, hi = -hi, -lo
    inside = margin > 0 and -margin < lo and hi < margin
    return {"equivalent": inside, "better": lo > 0 and not inside, "worse": hi < 0 and not inside,
            "inconclusive": lo <= 0 <= hi and not inside}.get(verdict_, False)


def minimum_detectable_difference(x, y, *, kind: str, alpha: float = 0.05, power: float = 0.8) -> float:
    r"""Smallest true paired difference the two-sided test at ``alpha`` detects with ``power`` at this ``n``.

    Normal approximation, ``K = Φ⁻¹(1 - α/2) + Φ⁻¹(power)`` (1.96 + 0.84 = 2.80 by default):

    * ``kind="rate"`` (McNemar): with the observed discordant fraction ``ψ̂ = (b + c)/n``,
      ``MDE = K √(ψ/n)``, ψ = the discordant probability: Connor's sample-size formula for
      McNemar's test (Biometrics 43 (1987) 207–211), ``n = (z_α √ψ + z_β √(ψ - δ²))² / δ²``,
      solved for δ with ``ψ - δ² ≈ ψ`` (slightly conservative). A true difference δ needs at
      least a fraction δ of discordant pairs, so ``ψ = max(ψ̂, δ)``; solving gives
      ``MDE = max(K √(ψ̂/n), K²/n)``, which stays positive when no pair is discordant.
    * ``kind="continuous"`` (Wilcoxon signed-rank): ``MDE = K √(π/3) · sd(d) / √n`` with ``sd``
      the sample standard deviation (ddof 1) of ``d = x - y``: the normal-theory (z-test)
      detectable shift, inflated by the inverse asymptotic relative efficiency of the
      signed-rank test under normality, ``3/π`` (Hodges & Lehmann 1956): the Wilcoxon test needs
      ``π/3`` times as many pairs, i.e. ``√(π/3) ≈ 1.023`` times the shift at the same ``n``. (For
      heavy-tailed differences the Wilcoxon test does better than this; the sd then overstates
      the MDE.) ``sd(d) = 0``: 0.

    ``inf`` when no difference is detectable: the smallest attainable two-sided exact p-value
    with ``n`` pairs is ``2^{1-n}`` (every pair discordant / of one sign), so for
    ``2^{1-n} > alpha`` (n <= 5 at 5 %) nothing can be detected; a rate MDE above 1 is also
    ``inf``. NaN for no pairs (continuous: fewer than 2).
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha = {alpha!r} must lie strictly between 0 and 1")
    if not 0.5 <= power < 1.0:
        raise ValueError(f"power = {power!r} must lie in [0.5, 1)")
    k = float(_st.norm.ppf(1.0 - alpha / 2.0) + _st.norm.ppf(power))
    if kind == "rate":
        a, b, c, d = _paired_counts(x, y)
        n = a + b + c + d
        if n == 0:
            return math.nan
        mde = max(k * math.sqrt((b + c) / n / n), k * k / n)
        return math.inf if (2.0 ** (1 - n) > alpha or mde > 1.0) else float(mde)
    if kind == "continuous":
        diff = _paired_differences(x, y, "minimum_detectable_difference")
        n = diff.size
        if n < 2:
            return math.nan
        if 2.0 ** (1 - n) > alpha:
            return math.inf
        return float(k * math.sqrt(math.pi / 3.0) * np.std(diff, ddof=1) / math.sqrt(n))
    raise ValueError(f"kind = {kind!r} must be 'rate' or 'continuous'")


# --------------------------------------------------------------------------------------------
# multiplicity
# --------------------------------------------------------------------------------------------


def holm(pvalues) -> np.ndarray:
    r"""Holm step-down adjusted p-values (family-wise error control, any dependence).

    With the ``m`` finite p-values sorted ascending, ``p̃_(i) = max_{j <= i} min(1, (m - j + 1) p_(j))``
    (1-based). Rejecting ``p̃ <= α`` controls the probability of any false rejection at α. NaN
    entries stay NaN and do not count in ``m``.
    """
    p = np.asarray(pvalues, dtype=np.float64)
    out = np.full(p.shape, np.nan)
    flat = p.reshape(-1)
    ok = np.flatnonzero(np.isfinite(flat))
    if ok.size == 0:
        return out
    if np.any((flat[ok] < 0) | (flat[ok] > 1)):
        raise ValueError("p-values must lie in [0, 1]")
    m = ok.size
    order = ok[np.argsort(flat[ok], kind="stable")]
    scaled = np.minimum(1.0, (m - np.arange(m)) * flat[order])
    adjusted = np.maximum.accumulate(scaled)
    result = out.reshape(-1)
    result[order] = adjusted
    return result.reshape(p.shape)


# --------------------------------------------------------------------------------------------
# distributions
# --------------------------------------------------------------------------------------------


def performance_profile(x, taus) -> np.ndarray:
    """Fraction of ``x`` strictly above each threshold ``τ`` (rliable's score distribution).

    Non-increasing in ``τ``; NaN everywhere for an empty sample.
    """
    x = np.sort(np.asarray(x, dtype=np.float64).reshape(-1))
    taus = np.asarray(taus, dtype=np.float64)
    if x.size == 0:
        return np.full(taus.shape, np.nan)
    return 1.0 - np.searchsorted(x, taus, side="right") / x.size


def ecdf(x) -> tuple[np.ndarray, np.ndarray]:
    """Empirical CDF: sorted values and ``F(x_(i)) = i / n`` (i = 1..n); draw as a post-step."""
    x = np.sort(np.asarray(x, dtype=np.float64).reshape(-1))
    return x, np.arange(1, x.size + 1) / max(x.size, 1)
