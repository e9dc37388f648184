"""Uncertainty of a leaderboard's aggregates, and whether two rows on the same frames differ beyond noise.

An Acc. is k successes of n frames: its 95% interval is Wilson's score interval, which (unlike the normal
approximation) stays inside [0, 1] and is not zero-width at 0 or n successes. A mean (RTE, RRE) gets a seeded
percentile bootstrap interval over its frames. Two rows scored on the same frames are compared paired, frame by
frame: Acc. by McNemar's exact test (a binomial test on the frames only one of the two registers), an error by a
paired bootstrap of the mean per-frame difference over the frames both rows average.

scipy computes all of it (`binomtest(...).proportion_ci(method="wilson")`, `binomtest` for McNemar's exact p,
`bootstrap` for both bootstraps) rather than code of our own: the formulas are easy to get subtly wrong at the
edges (0 or n successes, one discordant frame) and scipy's are tested against published values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import binomtest, bootstrap

LEVEL = 0.95
DRAWS = 2000  # bootstrap resamples: the interval's ends move by well under the rounding shown at this count
SEED = 0  # every bootstrap is seeded, so a board is the same file on every machine
ALPHA = 0.05  # a difference with p below this is called significant


def wilson(successes: int, n: int, level: float = LEVEL) -> tuple[float, float]:
    """The Wilson score interval of a proportion, as fractions; NaN for no trials."""
    if n == 0:
        return math.nan, math.nan
    ci = binomtest(int(successes), int(n)).proportion_ci(confidence_level=level, method="wilson")
    return float(ci.low), float(ci.high)


def bootstrap_mean(values: np.ndarray, level: float = LEVEL, seed: int = SEED) -> tuple[float, float]:
    """The percentile bootstrap interval of the mean of `values` (NaN ones left out); NaN below two values."""
    values = np.asarray(values, dtype=float)
    values = values[~np.isnan(values)]
    if len(values) < 2 or not np.isfinite(values).all():
        return math.nan, math.nan
    result = bootstrap((values,), np.mean, n_resamples=DRAWS, confidence_level=level, method="percentile",
                       rng=np.random.default_rng(seed))  # fmt: skip
    return float(result.confidence_interval.low), float(result.confidence_interval.high)


@dataclass(frozen=True)
class Paired:
    """A paired test of row A against row B: the p-value and what it was computed from."""

    test: str  # "McNemar" or "paired bootstrap"
    p: float
    detail: str  # "2 vs 0 frames" (registered by one row only), or the mean difference's interval

    @property
    def significant(self) -> bool:
        return self.p < ALPHA

    def __str__(self) -> str:
        verdict = "significant" if self.significant else "not significant"
        return f"{verdict} ({self.test} p={self.p:.3g}; {self.detail})"


def mcnemar(a: np.ndarray, b: np.ndarray) -> Paired:
    """McNemar's exact test on per-frame successes (0/1, frames aligned): under the null each frame registered by
    exactly one row is A's or B's with probability 1/2, so p is the two-sided binomial p of the smaller count."""
    a, b = np.asarray(a, dtype=float) > 0.5, np.asarray(b, dtype=float) > 0.5
    only_a, only_b = int((a & ~b).sum()), int((~a & b).sum())
    p = 1.0 if only_a + only_b == 0 else float(binomtest(min(only_a, only_b), only_a + only_b, 0.5).pvalue)
    return Paired("McNemar", p, f"{only_a} vs {only_b} frames registered by one row only")


def paired_bootstrap(a: np.ndarray, b: np.ndarray, level: float = LEVEL, seed: int = SEED) -> Paired:
    """A's minus B's per-frame values over the frames both average (NaN in either: left out), resampled: p is twice
    the smaller share of resampled mean differences on either side of 0 (at most 1)."""
    diff = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    diff = diff[np.isfinite(diff)]
    if len(diff) < 2 or not diff.any():
        return Paired("paired bootstrap", 1.0, f"{len(diff)} frames in both, no difference to test")
    result = bootstrap((diff,), np.mean, n_resamples=DRAWS, confidence_level=level, method="percentile",
                       rng=np.random.default_rng(seed))  # fmt: skip
    draws = result.bootstrap_distribution
    p = min(1.0, 2.0 * min(float((draws <= 0).mean()), float((draws >= 0).mean())))
    low, high = result.confidence_interval
    return Paired("paired bootstrap", p, f"mean difference {diff.mean():+.3g}, 95% [{low:+.3g}, {high:+.3g}]")
