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

    def add(self, value: float) -> None:
        self.add_at(self.index(value), value)

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

    def percentile(self, q: float) -> float:
        """q in [0, 100]; NaN if empty."""
        if self.n == 0:
            return math.nan
        rank = max(1, math.ceil(self.n * q / 100.0))
        acc = 0
        for i in sorted(self.bins):
            acc += self.bins[i]
            if acc >= rank:
                return min(self.upper_edge(i), self.max) if i < self.NBINS - 1 else self.max
        return self.max

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


class PoseAges:
    """The two ages of the poses a node takes in, kept apart (all in s, on the node's wall clock):

    * **transport age**: the sender's stamp (when it sampled and published the pose) to the
      pose's arrival in this process (the receive callback's stamp; for a pose the netem shim
      held, the time the emulated link delivered it). Per sending UAV (``links``) and overall.
    * **age at use**: arrival to the first time the controller used the pose (avoidance),
      which the owner reports with :meth:`used`. It is bounded by the control period.

    An age cannot be negative when both stamps come from one clock (one host). Between hosts
    whose clocks disagree a pose can arrive "before" it was sent: such ages are counted in
    ``negative`` (with the most negative one in ``most_negative``) instead of entering a histogram.
    """

    __slots__ = ("transport", "links", "use", "negative", "most_negative")

    def __init__(self) -> None:
        self.transport = LogHistogram()
        self.links: dict[int, LogHistogram] = {}
        self.use = LogHistogram()
        self.negative: Counter[str] = Counter()
        self.most_negative = 0.0

    def arrived(self, src: int, age: float) -> None:
        """A pose from UAV ``src`` arrived ``age`` s after its sender stamped it."""
        if age < 0.0:
            self._negative("transport", age)
            return
        h = self.links.get(src)
        if h is None:
            h = self.links[src] = LogHistogram()
        i = LogHistogram.index(age)  # once for both histograms (a log10 per pose)
        self.transport.add_at(i, age)
        h.add_at(i, age)

    def used(self, age: float) -> None:
        """A pose was first used by the controller ``age`` s after it arrived."""
        if age < 0.0:  # only if the wall clock stepped back between arrival and use
            self._negative("use", age)
            return
        self.use.add(age)

    def _negative(self, which: str, age: float) -> None:
        self.negative[which] += 1
        if age < self.most_negative:
            self.most_negative = age

    def to_dict(self, links: bool = True) -> dict[str, Any]:
        """``links=False`` leaves out the per-link histograms (the bulk of it with many neighbours)."""
        out = {
            "transport_age": self.transport.to_dict(),
            "use_age": self.use.to_dict(),
            "negative_ages": dict(self.negative),
            "most_negative_age": self.most_negative,
        }
        if links:
            out["transport_age_links"] = self.links_dict()
        return out

    def links_dict(self) -> dict[str, Any]:
        """The per-link transport-age histograms, by sending UAV."""
        return {str(u): h.to_dict() for u, h in self.links.items()}


# LogHistogram.index's constants as module globals (it runs for every pose): 1 + (log10(v) - log10(LO)) * 50
_LO, _PER_DECADE, _OVERFLOW = LogHistogram.LO, LogHistogram.PER_DECADE, LogHistogram.NBINS - 1
_LOG_LO = math.log10(_LO)
_log10 = math.log10


@dataclass
class NodeStats:
    """What a node sent, received and rejected; the rejections are also logged (rate-limited)."""

    sent: Counter[str] = field(default_factory=Counter)
    received: Counter[str] = field(default_factory=Counter)
    rejected: Counter[str] = field(default_factory=Counter)
    refused: Counter[str] = field(default_factory=Counter)  # links refused (swarmnet/security/links.py)
    ages: PoseAges = field(default_factory=PoseAges)
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

    def to_dict(self, links: bool = True) -> dict[str, Any]:
        return {
            "sent": dict(self.sent),
            "received": dict(self.received),
            "rejected": dict(self.rejected),
            "refused": dict(self.refused),
            **self.ages.to_dict(links),
        }
