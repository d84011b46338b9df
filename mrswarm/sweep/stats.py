"""Statistics of a cell's runs: mean, median, sample standard deviation and a Student-t confidence interval.

The interval of the mean of ``n`` values is ``mean ± t(1 - (1 - level) / 2, n - 1) · s / √n`` with
``s`` the sample standard deviation (``n - 1`` in its denominator), as the paper mrswarm follows
reports its results. The t quantile is computed here rather than taken from scipy, which is only a
test dependency (tens of MB for one function): for the integer degrees of freedom an interval over
runs has, the two-sided t distribution function has a closed form, a finite sum (Abramowitz and
Stegun 26.7.3-4), and the quantile is its inverse by bisection, to double precision. Above
:data:`CLOSED_FORM_MAX_DF` degrees of freedom the Cornish-Fisher expansion about the normal
quantile is used instead (its error there is below 1e-12).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

CLOSED_FORM_MAX_DF = 1000
DEFAULT_LEVEL = 0.95


def t_two_sided(t: float, df: int) -> float:
    """P(|T| <= t) for Student's t with ``df`` (a positive integer) degrees of freedom."""
    if df < 1:
        raise ValueError(f"degrees of freedom must be a positive integer, got {df}")
    t = abs(t)
    theta = math.atan(t / math.sqrt(df))
    s, c = math.sin(theta), math.cos(theta)
    if df % 2 == 1:  # (2/π) [θ + sin θ (cos θ + 2/3 cos³θ + ... + (2·4···(ν-3))/(1·3···(ν-2)) cos^(ν-2) θ)]
        total, coef, power = 0.0, 1.0, c
        for j in range((df - 1) // 2):
            if j:
                coef *= 2 * j / (2 * j + 1)
                power *= c * c
            total += coef * power
        return min(1.0, 2.0 / math.pi * (theta + s * total))
    # sin θ (1 + 1/2 cos²θ + (1·3)/(2·4) cos⁴θ + ... + (1·3···(ν-3))/(2·4···(ν-2)) cos^(ν-2) θ)
    total, coef, power = 0.0, 1.0, 1.0
    for j in range(df // 2):
        if j:
            coef *= (2 * j - 1) / (2 * j)
            power *= c * c
        total += coef * power
    return min(1.0, s * total)


def t_quantile(p: float, df: int) -> float:
    """The ``p`` quantile of Student's t with ``df`` degrees of freedom (``0 < p < 1``)."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"p must lie in (0, 1), got {p}")
    if df < 1:
        raise ValueError(f"degrees of freedom must be a positive integer, got {df}")
    if p == 0.5:
        return 0.0
    if p < 0.5:
        return -t_quantile(1.0 - p, df)
    level = 2.0 * p - 1.0  # P(|T| <= q) for the upper quantile q
    if df > CLOSED_FORM_MAX_DF:
        return _cornish_fisher(p, df)
    lo, hi = 0.0, 1.0
    while t_two_sided(hi, df) < level:
        lo, hi = hi, hi * 2.0
        if hi > 1e12:  # p within 1e-24 of 1 with one degree of freedom: beyond double precision anyway
            return hi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        if t_two_sided(mid, df) < level:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _cornish_fisher(p: float, df: int) -> float:
    z = statistics.NormalDist().inv_cdf(p)
    v = float(df)
    return (z + (z**3 + z) / (4 * v) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * v**2)
            + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * v**3)
            + (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / (92160 * v**4))


@dataclass(frozen=True)
class Summary:
    """One metric over a cell's runs. ``runs``: the runs of the cell; ``n``: those that have a value (a coverage
    time that a run never reached has none). ``ci_low``/``ci_high``: the interval of the mean at ``level``,
    None with fewer than two values."""

    runs: int
    n: int
    mean: float | None
    median: float | None
    std: float | None
    ci_low: float | None
    ci_high: float | None
    level: float = DEFAULT_LEVEL

    @property
    def half_width(self) -> float | None:
        if self.ci_low is None or self.ci_high is None:
            return None
        return (self.ci_high - self.ci_low) / 2.0


def summarise(values: Sequence[float | None], level: float = DEFAULT_LEVEL) -> Summary:
    """Mean, median, sample standard deviation and the t interval of the mean of the values that are there
    (None and NaN are left out, and counted in ``runs`` only)."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"confidence level must lie in (0, 1), got {level}")
    xs = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    n = len(xs)
    if n == 0:
        return Summary(runs=len(values), n=0, mean=None, median=None, std=None, ci_low=None, ci_high=None, level=level)
    mean = math.fsum(xs) / n
    median = statistics.median(xs)
    if n == 1:
        return Summary(runs=len(values), n=1, mean=mean, median=median, std=None, ci_low=None, ci_high=None, level=level)
    std = statistics.stdev(xs)
    half = t_quantile(1.0 - (1.0 - level) / 2.0, n - 1) * std / math.sqrt(n)
    return Summary(runs=len(values), n=n, mean=mean, median=median, std=std, ci_low=mean - half, ci_high=mean + half,
                   level=level)
