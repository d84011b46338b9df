"""Counters and a mergeable latency histogram for swarm nodes."""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

log = logging.getLogger(__name__)


class LogHistogram:
    """Fixed log-spaced bins (10 us .. 1000 s, 50 per decade): cheap to add, exact to merge.

    Percentiles are read at the upper edge of the bin holding the rank, so they are
    accurate to one bin (about 5 %), which is plenty for p50/p99 of message ages.
    """

    LO = 1e-5
    PER_DECADE = 50
    DECADES = 8
    NBINS = PER_DECADE * DECADES + 2  # + underflow (incl. <= 0) and overflow

    __slots__ = ("counts", "n", "total", "max")

    def __init__(self) -> None:
        self.counts = [0] * self.NBINS
        self.n = 0
        self.total = 0.0
        self.max = 0.0

    def _index(self, value: float) -> int:
        if not value > self.LO:  # also NaN
            return 0
        i = 1 + int(math.log10(value / self.LO) * self.PER_DECADE)
        return i if i < self.NBINS - 1 else self.NBINS - 1

    def add(self, value: float) -> None:
        self.counts[self._index(value)] += 1
        self.n += 1
        if value == value:
            self.total += value
            if value > self.max:
                self.max = value

    def upper_edge(self, i: int) -> float:
        if i == 0:
            return self.LO
        if i >= self.NBINS - 1:
            return math.inf
        return self.LO * 10 ** (i / self.PER_DECADE)

    def percentile(self, q: float) -> float:
        """q in [0, 100]; NaN if empty."""
        if self.n == 0:
            return math.nan
        rank = max(1, math.ceil(self.n * q / 100.0))
        acc = 0
        for i, c in enumerate(self.counts):
            acc += c
            if acc >= rank:
                return min(self.upper_edge(i), self.max) if i < self.NBINS - 1 else self.max
        return self.max

    @property
    def mean(self) -> float:
        return self.total / self.n if self.n else math.nan

    def merge(self, other: LogHistogram) -> None:
        for i, c in enumerate(other.counts):
            self.counts[i] += c
        self.n += other.n
        self.total += other.total
        self.max = max(self.max, other.max)

    def to_dict(self) -> dict[str, Any]:
        nz = {i: c for i, c in enumerate(self.counts) if c}
        return {"lo": self.LO, "per_decade": self.PER_DECADE, "bins": nz, "n": self.n, "total": self.total, "max": self.max}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LogHistogram:
        h = cls()
        if d.get("lo") != cls.LO or d.get("per_decade") != cls.PER_DECADE:
            raise ValueError("histogram with different binning")
        for i, c in d["bins"].items():
            h.counts[int(i)] = int(c)
        h.n, h.total, h.max = int(d["n"]), float(d["total"]), float(d["max"])
        return h


@dataclass
class NodeStats:
    """What a node sent, received and rejected; the rejections are also logged (rate-limited)."""

    sent: Counter[str] = field(default_factory=Counter)
    received: Counter[str] = field(default_factory=Counter)
    rejected: Counter[str] = field(default_factory=Counter)
    refused: Counter[str] = field(default_factory=Counter)  # links refused (swarmnet/security/links.py)
    pose_age: LogHistogram = field(default_factory=LogHistogram)
    _last_log: float = 0.0
    _suppressed: int = 0

    def reject(self, reason: str, key: str, detail: str = "") -> None:
        self.rejected[reason] += 1
        now = time.monotonic()
        if now - self._last_log >= 1.0:  # at most one log line per second per node
            extra = f" (+{self._suppressed} more rejections suppressed)" if self._suppressed else ""
            log.warning("rejected message on %s: %s %s%s", key, reason, detail, extra)
            self._last_log = now
            self._suppressed = 0
        else:
            self._suppressed += 1

    def to_dict(self) -> dict[str, Any]:
        return {
            "sent": dict(self.sent),
            "received": dict(self.received),
            "rejected": dict(self.rejected),
            "refused": dict(self.refused),
            "pose_age": self.pose_age.to_dict(),
        }
