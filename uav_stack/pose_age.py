"""Per-second pose-age figures of one UAV, for the "pose age over time" plot.

Once a second (from the agent's stats write, never per message) the log appends one CSV
row, flushed at once, so a crash loses at most a second:

* ``poses``, ``age_p50_ms``, ``age_p99_ms``, ``age_mean_ms``: the poses applied to the
  neighbour table during that second and their age on arrival (now - the sender's sampling
  time), from the difference of two snapshots of the node's cumulative age histogram, so the
  receive path pays nothing extra. Percentiles are bin centres (bins are 4.7 % wide).
* ``aoi_mean_ms``, ``aoi_max_ms``, ``neighbours``: the age of information at the sampling
  instant over every neighbour in the table (how old our knowledge of each one is now);
  unlike the arrival age it keeps growing while a link drops messages or is down.
"""

from __future__ import annotations

import math
from pathlib import Path

from swarmnet.node import SwarmNode
from swarmnet.stats import LogHistogram
from uav_stack.recorder import AppendLog, RecordHealth

COLUMNS = ("t_wall", "poses", "age_p50_ms", "age_p99_ms", "age_mean_ms", "aoi_mean_ms", "aoi_max_ms", "neighbours")


def _bin_centre(i: int) -> float:
    if i == 0:
        return 0.0
    return LogHistogram.LO * 10 ** ((i - 0.5) / LogHistogram.PER_DECADE)


def _percentile(counts: list[int], n: int, q: float) -> float:
    rank = max(1, math.ceil(n * q / 100.0))
    acc = 0
    for i, c in enumerate(counts):
        acc += c
        if acc >= rank:
            return _bin_centre(i)
    return math.nan


class PoseAgeLog:
    def __init__(self, path: str | Path, node: SwarmNode, health: RecordHealth | None = None):
        self.path = Path(path)
        self._log = AppendLog(self.path, ",".join(COLUMNS) + "\n", health)  # errors degrade, never raise
        self.node = node
        h = node.stats.pose_age
        self._counts = list(h.counts)
        self._n, self._total = h.n, h.total

    def sample(self, now: float) -> None:
        h = self.node.stats.pose_age
        diff = [a - b for a, b in zip(h.counts, self._counts, strict=True)]
        n = h.n - self._n
        total = h.total - self._total
        self._counts, self._n, self._total = list(h.counts), h.n, h.total
        ms = lambda v: f"{1000.0 * v:.1f}" if v == v else ""  # noqa: E731
        p50 = _percentile(diff, n, 50) if n else math.nan
        p99 = _percentile(diff, n, 99) if n else math.nan
        mean = total / n if n else math.nan
        ages = [n_.age(now) for n_ in self.node.neighbours]
        aoi_mean = sum(ages) / len(ages) if ages else math.nan
        aoi_max = max(ages) if ages else math.nan
        self._log.add(f"{now:.3f},{n},{ms(p50)},{ms(p99)},{ms(mean)},{ms(aoi_mean)},{ms(aoi_max)},{len(ages)}\n")
        self._log.flush(now)

    def close(self) -> None:
        self._log.close()
