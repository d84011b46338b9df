"""Counters and the ages of the poses a node takes in (in histograms: groundfloor.histogram)."""

from __future__ import annotations

import logging
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from groundfloor.histogram import LogHistogram

log = logging.getLogger(__name__)


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

    **Transport ages are filed when read.** A UAV of 50 takes in about 500 poses a second, and
    filing each into two histograms as it came (a log10, two dict updates, four Python calls)
    cost as much as decoding it. :meth:`arrived` and :meth:`arrived_many` only note the sender
    and the age (:meth:`used` and :meth:`used_many` the age at use); reading :attr:`transport`,
    :attr:`links` or :attr:`use` files what was noted in a few numpy operations, as do
    :data:`FILE_AT` notes unread. The agent reads the ages of all and at use once a second, the
    per-sender histograms (a dict entry per sender and bin) every ten.
    """

    __slots__ = ("_transport", "_links", "_use", "negative", "most_negative", "_srcs", "_ages", "_uses", "_link_notes",
                 "_link_noted", "exclude")

    FILE_AT = 8192  # notes kept unread at most (a node that nobody reads stays bounded)

    def __init__(self) -> None:
        self._transport = LogHistogram()
        self._links: dict[int, LogHistogram] = {}
        self._use = LogHistogram()
        self.negative: Counter[str] = Counter()
        self.most_negative = 0.0
        self._srcs: list[int] = []  # noted, not yet filed: sending UAV ...
        self._ages: list[float] = []  # ... and transport age, s
        self._uses: list[float] = []  # ages at use, s
        self._link_notes: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (senders, bins, ages) in transport, not links
        self._link_noted = 0
        # a UAV whose poses come back with the others' (a pool's member: its shared session notes
        # every pose the pool takes in, swarmnet/shared_session.py): its own are no link, left out
        self.exclude: int | None = None

    @property
    def transport(self) -> LogHistogram:
        """Every transport age taken in so far, whatever its sender."""
        self._file()
        return self._transport

    @property
    def links(self) -> dict[int, LogHistogram]:
        """The transport ages by sending UAV."""
        self._file()
        self._file_links()
        return self._links

    @property
    def use(self) -> LogHistogram:
        """Every age at use so far."""
        self._file_uses()
        return self._use

    def arrived(self, src: int, age: float) -> None:
        """A pose from UAV ``src`` arrived ``age`` s after its sender stamped it."""
        self._srcs.append(src)
        self._ages.append(age)
        if len(self._ages) >= self.FILE_AT:
            self._file()

    def arrived_many(self, srcs: list[int], ages: list[float]) -> None:
        """Poses from UAVs ``srcs`` arrived ``ages`` s after their senders stamped them (one batch)."""
        self._srcs += srcs
        self._ages += ages
        if len(self._ages) >= self.FILE_AT:
            self._file()

    def _file(self) -> None:
        """File the noted ages into the histogram of all (a few distinct bins: cheap each second);
        the per-sender histograms, read less often, get theirs when :attr:`links` is read."""
        if not self._ages:
            return
        ages = np.array(self._ages, dtype=np.float64)
        srcs = np.array(self._srcs, dtype=np.int64)
        self._ages.clear()
        self._srcs.clear()
        if self.exclude is not None:
            mine = srcs == self.exclude
            if mine.any():
                srcs, ages = srcs[~mine], ages[~mine]
                if not ages.size:
                    return
        keep = self._count_negative("transport", ages)
        if keep is not None:  # a NaN age stays, as add_at keeps it
            srcs, ages = srcs[keep], ages[keep]
            if not ages.size:
                return
        bins = LogHistogram.indices(ages)
        self._transport.add_many(bins, ages)
        self._link_notes.append((srcs, bins, ages))
        self._link_noted += ages.size
        if self._link_noted >= self.FILE_AT:
            self._file_links()

    def _file_links(self) -> None:
        """File the ages already in the histogram of all into each sender's histogram."""
        if not self._link_notes:
            return
        srcs, bins, ages = (np.concatenate(x) for x in zip(*self._link_notes, strict=True))
        self._link_notes.clear()
        self._link_noted = 0
        # one sort by (sender, bin), then each distinct pair's count into its sender's dict
        order = np.lexsort((bins, srcs))
        srcs, bins, ages = srcs[order], bins[order], ages[order]
        keys = srcs * _NBINS + bins
        firsts = np.flatnonzero(np.diff(keys, prepend=keys[0] - 1))  # where each (sender, bin) run starts
        counts = np.diff(firsts, append=keys.size)
        links = self._links
        for key, c in zip(keys[firsts].tolist(), counts.tolist(), strict=True):
            u, i = divmod(key, _NBINS)
            h = links.get(u)
            if h is None:
                h = links[u] = LogHistogram()
            h.bins[i] = h.bins.get(i, 0) + c
        # count, sum and maximum per sender
        starts = np.flatnonzero(np.diff(srcs, prepend=srcs[0] - 1))
        finite = np.where(ages == ages, ages, 0.0)  # NaN counts, as in LogHistogram.add_at, but adds nothing
        sums = np.add.reduceat(finite, starts)
        maxes = np.maximum.reduceat(finite, starts)
        ns = np.diff(starts, append=srcs.size)
        for u, n, t, m in zip(srcs[starts].tolist(), ns.tolist(), sums.tolist(), maxes.tolist(), strict=True):
            h = links[u]
            h.n += n
            h.total += t
            if m > h.max:
                h.max = m

    def used(self, age: float) -> None:
        """A pose was first used by the controller ``age`` s after it arrived."""
        self._uses.append(age)
        if len(self._uses) >= self.FILE_AT:
            self._file_uses()

    def used_many(self, ages: list[float]) -> None:
        """Poses were first used by the controller ``ages`` s after they arrived."""
        self._uses += ages
        if len(self._uses) >= self.FILE_AT:
            self._file_uses()

    def _file_uses(self) -> None:
        if self._uses:
            uses = np.array(self._uses, dtype=np.float64)
            self._uses.clear()
            keep = self._count_negative("use", uses)
            if keep is not None:
                uses = uses[keep]
            self._use.add_many(LogHistogram.indices(uses), uses)

    def _count_negative(self, which: str, ages: np.ndarray) -> np.ndarray | None:
        """Count the ``ages`` below zero under ``which``; return the mask of those to keep, or
        None if all are kept. A transport age is negative only between hosts whose clocks
        disagree; an age at use only if the wall clock stepped back between arrival and use."""
        negative = ages < 0.0
        if not negative.any():
            return None
        self.negative[which] += int(negative.sum())
        self.most_negative = min(self.most_negative, float(ages[negative].min()))
        return ~negative

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


_NBINS = LogHistogram.NBINS  # (sender, bin) pairs flattened into one key


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
