"""A latency histogram: fixed log-spaced bins, sparse, cheap to add to and exact to merge.

It holds the ages and delays mrswarm reports (a pose's transport age and age at use, the netem
shim's delay, a sensor reading's delay), per link and overall, and travels in the counters
files as :meth:`LogHistogram.to_dict`, which any reader merges back (:meth:`LogHistogram.from_dict`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


class LogHistogram:
    """Fixed log-spaced bins (10 us .. 1000 s, 50 per decade), kept sparse: cheap to add, exact to merge.

    Percentiles are read at the upper edge of the bin holding the rank, so they are
    accurate to one bin (about 5 %), which is plenty for p50/p99 of message ages. Only the
    bins in use are stored (ages cluster in a few dozen of the 402), so a histogram per link
    stays small and its dict is cheap to write.
    """

    LO = 1e-5
    PER_DECADE = 50
    DECADES = 8
    NBINS = PER_DECADE * DECADES + 2  # + underflow (incl. <= 0) and overflow

    __slots__ = ("bins", "n", "total", "max")

    def __init__(self) -> None:
        self.bins: dict[int, int] = {}
        self.n = 0
        self.total = 0.0
        self.max = 0.0

    @staticmethod
    def index(value: float) -> int:
        """The bin of ``value`` (0: at most LO, also NaN; NBINS - 1: overflow)."""
        if not value > _LO:  # also NaN
            return 0
        i = 1 + int((_log10(value) - _LOG_LO) * _PER_DECADE)
        return i if i < _OVERFLOW else _OVERFLOW

    @staticmethod
    def indices(values: np.ndarray) -> np.ndarray:
        """:meth:`index` of every value (float64 array) at once."""
        with np.errstate(invalid="ignore", divide="ignore"):
            i = 1 + np.floor((np.log10(values) - _LOG_LO) * _PER_DECADE)
        i = np.where(values > _LO, i, 0.0)  # also NaN
        return np.minimum(i, _OVERFLOW).astype(np.int64)

    def add(self, value: float) -> None:
        self.add_at(self.index(value), value)

    def add_many(self, bins: np.ndarray, values: np.ndarray) -> None:
        """Add ``values`` (float64 array), whose bins (:meth:`indices`) are ``bins``."""
        if not values.size:
            return
        b = self.bins
        counts = np.bincount(bins)
        used = np.flatnonzero(counts)
        for i, c in zip(used.tolist(), counts[used].tolist(), strict=True):
            b[i] = b.get(i, 0) + c
        self.n += int(values.size)
        finite = values[values == values]
        if finite.size:
            self.total += float(finite.sum())
            self.max = max(self.max, float(finite.max()))

    def add_at(self, i: int, value: float) -> None:
        """Add ``value``, whose bin :meth:`index` is ``i``."""
        b = self.bins
        b[i] = b.get(i, 0) + 1
        self.n += 1
        if value == value:
            self.total += value
            if value > self.max:
                self.max = value

    @classmethod
    def upper_edge(cls, i: int) -> float:
        if i == 0:
            return cls.LO
        if i >= cls.NBINS - 1:
            return math.inf
        return cls.LO * 10 ** (i / cls.PER_DECADE)

    @classmethod
    def centre(cls, i: int) -> float:
        """The middle of bin ``i`` on the log scale (0 for the underflow bin)."""
        if i == 0:
            return 0.0
        return cls.LO * 10 ** ((i - 0.5) / cls.PER_DECADE)

    def bin_of(self, q: float) -> int | None:
        """The bin holding the ``q``-th percentile (q in [0, 100]); None if empty."""
        if self.n <= 0:
            return None
        rank = max(1, math.ceil(self.n * q / 100.0))
        acc = 0
        for i in sorted(self.bins):
            acc += self.bins[i]
            if acc >= rank:
                return i
        return None

    def percentile(self, q: float) -> float:
        """q in [0, 100], read at the upper edge of its bin (at most the largest value); NaN if empty."""
        if self.n == 0:
            return math.nan
        i = self.bin_of(q)
        if i is None:
            return self.max
        return min(self.upper_edge(i), self.max) if i < self.NBINS - 1 else self.max

    def centre_percentile(self, q: float) -> float:
        """q in [0, 100], read at the centre of its bin (unbiased on average, for a per-second mean); NaN if empty."""
        i = self.bin_of(q)
        return math.nan if i is None else self.centre(i)

    @property
    def mean(self) -> float:
        return self.total / self.n if self.n else math.nan

    def merge(self, other: LogHistogram) -> None:
        b = self.bins
        for i, c in other.bins.items():
            b[i] = b.get(i, 0) + c
        self.n += other.n
        self.total += other.total
        self.max = max(self.max, other.max)

    def copy(self) -> LogHistogram:
        h = LogHistogram()
        h.bins, h.n, h.total, h.max = dict(self.bins), self.n, self.total, self.max
        return h

    def since(self, earlier: LogHistogram) -> LogHistogram:
        """What was added after ``earlier`` (a :meth:`copy` of this histogram); its max is the
        upper edge of its highest bin (at most this histogram's max)."""
        h = LogHistogram()
        old = earlier.bins
        for i, c in self.bins.items():
            d = c - old.get(i, 0)
            if d:
                h.bins[i] = d
        h.n, h.total = self.n - earlier.n, self.total - earlier.total
        if h.bins:
            h.max = min(self.upper_edge(max(h.bins)), self.max)
        return h

    def to_dict(self) -> dict[str, Any]:
        return {"lo": self.LO, "per_decade": self.PER_DECADE, "bins": dict(self.bins), "n": self.n, "total": self.total,
                "max": self.max}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LogHistogram:
        h = cls()
        if d.get("lo") != cls.LO or d.get("per_decade") != cls.PER_DECADE:
            raise ValueError("histogram with different binning")
        for i, c in d["bins"].items():
            h.bins[int(i)] = int(c)
        h.n, h.total, h.max = int(d["n"]), float(d["total"]), float(d["max"])
        return h


# LogHistogram.index's constants as module globals (it runs for every pose): 1 + (log10(v) - log10(LO)) * 50
_LO, _PER_DECADE, _OVERFLOW = LogHistogram.LO, LogHistogram.PER_DECADE, LogHistogram.NBINS - 1
_LOG_LO = math.log10(_LO)
_log10 = math.log10
