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
:func:`probability_of_improvement_paired`  ``P(x_i > y_i) + ½ P(x_i = y_i)`` over the pairs
:func:`hodges_lehmann_paired`          Hodges–Lehmann paired shift, signed-rank (Walsh average) CI
:class:`RatePairs`                     paired booleans: Tango's score interval, McNemar and TOST
:class:`ShiftPairs`                    paired values: Walsh-average interval and its signed-rank tests
:func:`decide`                         a study's verdicts: Holm per family, each interval at its level
:func:`verdict`                        better / worse / equivalent / inconclusive, read from an interval
:func:`answer`                         Yes / No / Not shown / In part / Mixed from a question's verdicts
:func:`minimum_detectable_difference`  smallest difference the paired test detects (power 0.8)
:func:`seed_interval`                  mean over replicates (selection seeds) with its t interval
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
    "format_p",
    "format_level",
    "wilson_interval",
    "iqm",
    "median",
    "mean",
    "bootstrap_ci",
    "bootstrap_cis",
    "paired_bootstrap_ci",
    "pair_scores",
    "probability_of_improvement_paired",
    "hodges_lehmann_paired",
    "RatePairs",
    "ShiftPairs",
    "Evidence",
    "paired_evidence",
    "RateRow",
    "rate_row",
    "VERDICTS",
    "VERDICT_RULE",
    "ANSWERS",
    "ANSWER_RULE",
    "answer",
    "verdict",
    "Decision",
    "decide",
    "minimum_detectable_difference",
    "seed_interval",
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
    signed-rank test (:meth:`ShiftPairs.p_difference`) is about. Zero differences are kept, as in the
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
    if d.size == 0:
        return math.nan, math.nan, math.nan
    return (_walsh_median(d), *_walsh_interval(d, confidence))


def _walsh_median(d: np.ndarray) -> float:
    """The median of the Walsh averages of sorted ``d`` (``n >= 1``): the Hodges–Lehmann estimate."""
    m = d.size * (d.size + 1) // 2
    if m % 2:
        return float(_walsh_kth(d, (m + 1) // 2) / 2.0)
    return float((_walsh_kth(d, m // 2) + _walsh_kth(d, m // 2 + 1)) / 4.0)


def _walsh_interval(d: np.ndarray, confidence: float) -> tuple[float, float]:
    """``[W_(k), W_(M+1-k)]`` of sorted ``d`` (``n >= 1``), ``k`` by :func:`_walsh_rank`; ``(-inf, inf)`` at
    ``k = 0``."""
    m = d.size * (d.size + 1) // 2
    k = _walsh_rank(d.size, confidence)
    if k == 0:
        return -math.inf, math.inf
    return _walsh_kth(d, k) / 2.0, _walsh_kth(d, m + 1 - k) / 2.0


# --------------------------------------------------------------------------------------------
# the evidence of one paired comparison, at any level
# --------------------------------------------------------------------------------------------


def _tango_z(b: int, c: int, n: int, delta: float) -> float:
    r"""Tango's score statistic for H0 ``p_x - p_y = delta`` (``-1 < delta < 1``) of paired booleans.

    For ``δ > 0``: ``Z = (b - c - nδ) / \sqrt{n(2 q̃ + δ(1 - δ))}``, ``q̃`` the maximum-likelihood estimate of
    ``P(only y)`` under H0 (cells ``q + δ``, ``q``, rest concordant), the positive root of
    ``2n q² + w q - c δ(1-δ) = 0``, ``w = -b - c + (2n - b + c) δ``; the variance is at least
    ``nδ(1 - δ) > 0``, so no discordant pair still gives a finite statistic. For ``δ < 0`` the same with x
    and y swapped, ``Z(b, c, δ) = -Z(c, b, -δ)``; at ``δ = 0`` McNemar's ``(b - c)/√(b + c)`` (0 without
    a discordant pair). ``Z`` decreases in ``δ`` (Tango 1998), so ``{δ: |Z(δ)| <= z}`` is an interval.
    """
    if delta < 0:
        return -_tango_z(c, b, n, -delta)
    if delta == 0:
        return 0.0 if b + c == 0 else (b - c) / math.sqrt(b + c)
    w = -b - c + (2 * n - b + c) * delta
    disc = 8.0 * n * c * delta * (1.0 - delta)
    root = math.sqrt(w * w + disc)
    q = 2.0 * c * delta * (1.0 - delta) / (root + w) if w > 0 else (root - w) / (4.0 * n)
    return (b - c - n * delta) / math.sqrt(n * (2.0 * q + delta * (1.0 - delta)))


def _tango_root(b: int, c: int, n: int, target: float) -> float:
    """The ``δ`` in ``[-1, 1]`` where the decreasing :func:`_tango_z` crosses ``target`` (bisection to
    rounding; ``±1`` where it never does)."""
    lo, hi = -1.0, 1.0
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        if not lo < mid < hi:
            break
        if _tango_z(b, c, n, mid) > target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


class RatePairs(NamedTuple):
    r"""Paired booleans as the score statistic sees them: ``b`` pairs true only for x, ``c`` only for y,
    ``n`` pairs. One statistic, Tango's score :func:`_tango_z` of ``Δ = p_x - p_y = (b - c)/n``
    (Tango, Stat. Med. 17 (1998) 891–908), gives all three answers, so they agree exactly:

    * :meth:`interval`: Tango's score interval ``{δ: |Z(δ)| <= z}`` (Fagerland, Lydersen & Laake,
      Stat. Med. 33 (2014) 2850–2875, recommend it);
    * :meth:`p_difference`: ``2Φ(-|Z(0)|)``, the asymptotic McNemar test, the largest ``γ`` whose
      ``1 - γ`` interval holds 0 (Fagerland, Lydersen & Laake, BMC Med. Res. Methodol. 13 (2013) 91: it
      keeps its level and has more power than the exact conditional test);
    * :meth:`p_equivalence`: ``2 max(Φ(Z(m)), Φ(-Z(-m)))``, twice the two one-sided tests' p, the
      smallest ``γ`` whose ``1 - γ`` interval lies inside ``(-m, m)``.
    """

    b: int
    c: int
    n: int

    @classmethod
    def of(cls, x, y) -> "RatePairs":
        """The counts of paired booleans ``x``, ``y``."""
        _, b, c, _ = _paired_counts(x, y)
        return cls(b, c, len(np.asarray(x)))

    @property
    def estimate(self) -> float:
        return (self.b - self.c) / self.n if self.n else math.nan

    def interval(self, confidence: float) -> tuple[float, float]:
        if not self.n:
            return math.nan, math.nan
        z = _z(confidence)
        return _tango_root(self.b, self.c, self.n, z), _tango_root(self.b, self.c, self.n, -z)

    def p_difference(self) -> float:
        if not self.n:
            return math.nan
        return float(min(1.0, 2.0 * _st.norm.sf(abs(_tango_z(self.b, self.c, self.n, 0.0)))))

    def p_equivalence(self, margin: float) -> float:
        if not self.n:
            return math.nan
        if not 0 < margin < 1:
            raise ValueError(f"margin = {margin!r} must lie strictly between 0 and 1 for a rate")
        upper = _st.norm.cdf(_tango_z(self.b, self.c, self.n, margin))
        lower = _st.norm.sf(_tango_z(self.b, self.c, self.n, -margin))
        return float(min(1.0, 2.0 * max(upper, lower)))


def _signed_rank_cdf(n: int, t: int) -> float:
    """``P(T+ <= t)`` of the signed-rank statistic of ``n`` untied pairs, as :func:`_walsh_rank` takes it:
    exact up to :data:`EXACT_HL_MAX` pairs, ``Φ((t + ½ - M/2)/σ)`` beyond."""
    if t < 0:
        return 0.0
    m = n * (n + 1) // 2
    if n <= EXACT_HL_MAX:
        cdf = np.cumsum(_signed_rank_null(2 * np.arange(1, n + 1))[::2])
        return float(cdf[min(t, m)])
    sigma = math.sqrt(n * (n + 1) * (2 * n + 1) / 24.0)
    return float(_st.norm.cdf((t + 0.5 - m / 2.0) / sigma))


@dataclasses.dataclass(frozen=True, eq=False)
class ShiftPairs:
    r"""Paired differences ``d = x - y`` (finite, sorted) as the Hodges–Lehmann shift sees them. The
    interval ``[W_(k), W_(M+1-k)]`` of the ``M`` Walsh averages (:func:`hodges_lehmann_paired`) gives the
    tests its own duality defines, so they agree with it exactly:

    * :meth:`p_difference`: ``2 P(T+ <= t)``, ``t = min(#{W <= 0}, #{W >= 0})``: 0 leaves the interval
      exactly when ``k > t`` (the signed-rank test for untied non-zero differences; zero differences
      are kept, as the estimate keeps them, which makes it conservative);
    * :meth:`p_equivalence`: ``2 P(T+ <= s)``, ``s = max(#{W <= -m}, #{W >= m})``: the interval lies
      inside ``(-m, m)`` exactly when ``k > s``.
    """

    d: np.ndarray

    @classmethod
    def of(cls, x, y) -> "ShiftPairs":
        """The sorted finite differences of paired ``x``, ``y``."""
        return cls(np.sort(_paired_differences(x, y, "ShiftPairs")))

    @property
    def n(self) -> int:
        return int(self.d.size)

    @property
    def estimate(self) -> float:
        return _walsh_median(self.d) if self.n else math.nan

    def interval(self, confidence: float) -> tuple[float, float]:
        """The Walsh-average interval at ``confidence``; ``(-inf, inf)`` where too few pairs allow none."""
        _z(confidence)
        return _walsh_interval(self.d, confidence) if self.n else (math.nan, math.nan)

    def _count(self, pivot: float, strict: bool) -> int:
        """Walsh sums ``d_i + d_j`` (``i <= j``) below ``pivot`` (``strict``) or up to it."""
        return int((_walsh_split(self.d, pivot, strict) - np.arange(self.n)).sum())

    def _p(self, count: int) -> float:
        m = self.n * (self.n + 1) // 2
        return 1.0 if count >= (m + 1) // 2 else min(1.0, 2.0 * _signed_rank_cdf(self.n, count))

    def p_difference(self) -> float:
        if not self.n:
            return math.nan
        m = self.n * (self.n + 1) // 2
        return self._p(min(self._count(0.0, False), m - self._count(0.0, True)))

    def p_equivalence(self, margin: float) -> float:
        if not self.n:
            return math.nan
        if not (math.isfinite(margin) and margin > 0):
            raise ValueError(f"margin = {margin!r} must be positive and finite")
        m = self.n * (self.n + 1) // 2
        return self._p(max(self._count(-2.0 * margin, False), m - self._count(2.0 * margin, True)))


Evidence = RatePairs | ShiftPairs


def paired_evidence(x, y, *, kind: str) -> Evidence:
    """The paired evidence of ``x`` against ``y``: :class:`RatePairs` (``kind="rate"``, booleans) or
    :class:`ShiftPairs` (``kind="continuous"``, finite values)."""
    if kind == "rate":
        return RatePairs.of(x, y)
    if kind == "continuous":
        return ShiftPairs.of(x, y)
    raise ValueError(f"kind = {kind!r} must be 'rate' or 'continuous'")


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


# --------------------------------------------------------------------------------------------
# verdicts: declared families, each interval at the level that decides it
# --------------------------------------------------------------------------------------------


#: The four verdicts of :func:`verdict`.
VERDICTS = ("better", "worse", "equivalent", "inconclusive")

#: The rule of :func:`decide` in one sentence, for every report and study that prints verdicts.
VERDICT_RULE = ("verdict, read from the interval beside it: equivalent when it lies inside ±margin, else better or "
                "worse when it excludes 0 on that side, else inconclusive; each interval is at the level Holm "
                "allows its comparison within its declared family (primary: success and collision of each "
                "setting against its baseline; exploratory: one family per other metric)")


def verdict(lo: float, hi: float, margin: float, higher_is_better: bool) -> str:
    """The verdict an interval ``[lo, hi]`` of ``Δ = x - y`` states, with ``margin`` the smallest difference
    that matters (0: none) and "better" meaning better for x: **equivalent** when it lies inside
    ``(-margin, margin)``; otherwise **better** / **worse** when it lies wholly beyond 0 on that side;
    otherwise (or without an interval) **inconclusive**. :func:`decide` chooses the interval's level."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return "inconclusive"
    if lo > hi:
        raise ValueError(f"interval ({lo!r}, {hi!r}) has lower > upper")
    if not higher_is_better:
        lo, hi = -hi, -lo
    if margin > 0 and -margin < lo and hi < margin:
        return "equivalent"
    return "better" if lo > 0 else "worse" if hi < 0 else "inconclusive"


class Decision(NamedTuple):
    """:func:`decide`'s answer, arrays over the comparisons: the estimate; the difference test's ``p`` and
    the equivalence test's ``p_equivalence`` (NaN without a margin), each Holm-adjusted within the row's
    family; ``confidence``, the level of the interval ``[lo, hi]`` that decided ``verdict`` (NaN bounds
    where the data allow no interval at that level)."""

    estimate: np.ndarray
    p: np.ndarray
    p_equivalence: np.ndarray
    p_holm: np.ndarray
    p_equivalence_holm: np.ndarray
    confidence: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    verdict: list[str]


def _share(p: np.ndarray, adjusted: np.ndarray) -> np.ndarray:
    """``p / p_Holm``: the part of α Holm grants each test (``1/m`` where both underflow to 0)."""
    m = max(int(np.isfinite(p).sum()), 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(adjusted > 0, p / adjusted, 1.0 / m)


def decide(evidence: Sequence[Evidence], margin, higher_is_better, family=None, alpha: float = 0.05) -> Decision:
    r"""The verdicts of a study: Holm within each family, then each comparison's interval at its own level.

    ``margin`` (0 or NaN: none), ``higher_is_better`` and ``family`` (the Holm family of each row; one
    family by default) may be scalars. Within a family, Holm adjusts the difference tests ``p`` and,
    separately, the equivalence tests ``q``; each row then gets the level ``α_r``:

    * ``α_r = α q/q_Holm`` where equivalence is shown (``q_Holm <= α``),
    * ``α_r = α min(p/p_Holm, q/q_Holm)`` otherwise (without a margin ``α p/p_Holm``),

    and the verdict is read from the ``1 - α_r`` interval alone (:func:`verdict`). Since the tests are the
    interval's own (:class:`RatePairs`, :class:`ShiftPairs`), the interval holds 0 exactly when
    ``p > α_r`` and lies inside the margin exactly when ``q <= α_r``: *better*/*worse* only where Holm
    rejects ``Δ = 0`` and *equivalent* only where Holm rejects ``|Δ| >= margin``, at family-wise level α
    within each family, and no verdict contradicts its interval. The price: where both tests are near
    their thresholds and equivalence is not shown, a difference Holm finds may stay *inconclusive*.
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha = {alpha!r} must lie strictly between 0 and 1")
    evidence = list(evidence)
    n = len(evidence)
    margin = np.nan_to_num(np.broadcast_to(np.asarray(margin, np.float64), (n,)), nan=0.0)
    if np.any(margin < 0) or not np.all(np.isfinite(margin)):
        raise ValueError("margins must be non-negative and finite")
    up = np.broadcast_to(np.asarray(higher_is_better, bool), (n,))
    family = np.broadcast_to(np.asarray("" if family is None else family, object), (n,))
    p = np.array([e.p_difference() for e in evidence], np.float64)
    q = np.array([e.p_equivalence(m) if m > 0 else math.nan for e, m in zip(evidence, margin)], np.float64)
    p_holm, q_holm = np.full(n, np.nan), np.full(n, np.nan)
    share_p, share_q = np.full(n, np.nan), np.full(n, np.nan)
    for f in dict.fromkeys(family.tolist()):
        rows = np.flatnonzero(family == f)
        p_holm[rows], q_holm[rows] = holm(p[rows]), holm(q[rows])
        share_p[rows], share_q[rows] = _share(p[rows], p_holm[rows]), _share(q[rows], q_holm[rows])
    shown = q_holm <= alpha
    level = alpha * np.where(shown, share_q, np.fmin(share_p, share_q))
    level[~np.isfinite(p)] = np.nan
    lo, hi = np.full(n, np.nan), np.full(n, np.nan)
    for i, (e, a) in enumerate(zip(evidence, level)):
        if math.isfinite(a):
            bounds = e.interval(1.0 - a)
            if all(math.isfinite(v) for v in bounds):
                lo[i], hi[i] = bounds
    out = [verdict(float(a), float(b), float(m), bool(u)) for a, b, m, u in zip(lo, hi, margin, up)]
    estimate = np.array([e.estimate for e in evidence], np.float64)
    return Decision(estimate, p, q, p_holm, q_holm, 1.0 - level, lo, hi, out)


#: The answers of :func:`answer`, the bold first words of a yes/no question's answer.
ANSWERS = ("Yes", "No", "Not shown", "In part", "Mixed")

#: The rule of :func:`answer`, stated wherever such answers are given.
ANSWER_RULE = ("a yes/no answer is derived from the verdicts of its deciding comparisons (the question's side "
               "against the other, every selection seed and family it names): Yes where all are better; No "
               "where all are worse or equivalent; Mixed where some are better and some worse; In part where "
               "some are better and none worse; Not shown otherwise (none better, some inconclusive)")


def answer(verdicts: Sequence[str]) -> str:
    """The answer (:data:`ANSWERS`) that the ``verdicts`` of a question's deciding comparisons allow, by
    :data:`ANSWER_RULE`: no word wider than the verdicts."""
    found = list(verdicts)
    if not found or any(v not in VERDICTS for v in found):
        raise ValueError(f"verdicts {found!r} must be a non-empty list of {', '.join(VERDICTS)}")
    better, worse = found.count("better"), found.count("worse")
    if better == len(found):
        return "Yes"
    if better and worse:
        return "Mixed"
    if better:
        return "In part"
    return "No" if worse + found.count("equivalent") == len(found) else "Not shown"


def format_p(p: float) -> str:
    """A p-value as every table prints it: three decimals, ``<0.001`` below, ``–`` where there is none."""
    p = float(p)
    return "–" if not math.isfinite(p) else "<0.001" if p < 0.001 else f"{p:.3f}"


def format_level(confidence: float) -> str:
    """An interval's level as every table prints it: the decimals that show ``1 - confidence`` to two
    significant digits (``95 %``, ``97.5 %``, ``99.6 %``, ``99.988 %``)."""
    c = float(confidence)
    if not (math.isfinite(c) and 0.0 < c < 1.0):
        return "–"
    rest = np.format_float_positional(100.0 * (1.0 - c), precision=2, fractional=False, trim="-")
    digits = len(rest.partition(".")[2])
    return f"{100.0 * c:.{digits}f} %"


def verdict_basis(lo: float, hi: float, confidence: float, margin: float, higher_is_better: bool = True) -> str:
    """Why the interval gives its verdict, in the words of :func:`verdict` with its level, e.g. ``99.6 % CI
    inside ±0.02``, ``97.5 % CI above 0``, ``99.9 % CI holds 0``; where the data allow no interval at the
    level, that."""
    level = format_level(confidence)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return f"no {level} CI with these pairs" if math.isfinite(confidence) else "no pairs"
    found = verdict(lo, hi, margin, higher_is_better)
    if found == "equivalent":
        return f"{level} CI inside ±{margin:.3g}"
    if found == "inconclusive":
        return f"{level} CI holds 0" + (f", not inside ±{margin:.3g}" if margin > 0 else "")
    return f"{level} CI " + ("above 0" if lo > 0 else "below 0")


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


def seed_interval(values, confidence: float = 0.95) -> tuple[float, float, float]:
    """The mean of a few replicate values (e.g. one estimate per selection seed) with its Student-t interval
    over them, ``x̄ ± t_{n-1} s/√n``: the selection's randomness as a sample. NaN interval below two values."""
    x = np.asarray(values, np.float64).reshape(-1)
    if x.size == 0:
        return math.nan, math.nan, math.nan
    mean = float(x.mean())
    if x.size < 2:
        return mean, math.nan, math.nan
    _z(confidence)
    half = float(_st.t.ppf(0.5 + confidence / 2.0, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size))
    return mean, mean - half, mean + half


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
