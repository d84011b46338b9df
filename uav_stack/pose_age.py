"""Per-second figures of the two pose ages of one UAV, for its telemetry and the "pose age over time" plot.

Once a second (from the agent's stats write, never per message) :class:`AgeWindow` takes what
the node's cumulative histograms (``SwarmNode.stats.ages``) gained since the last second, so
the receive path pays nothing extra:

* ``poses``, ``transport_p50_ms``, ``transport_p99_ms``, ``transport_mean_ms``: the poses that
  arrived during that second and their transport age (the sender's stamp to the arrival in
  this process);
* ``used``, ``use_p50_ms``, ``use_p99_ms``: the poses the controller used for the first time
  during that second and their age at use (arrival to use).

Percentiles are bin centres (bins are 4.7 % wide). :class:`PoseAgeLog` appends them as one CSV
row, flushed at once (a crash loses at most a second), with the age of information at the
sampling instant over every neighbour in the table: ``aoi_mean_ms``, ``aoi_max_ms``,
``neighbours`` (how old our knowledge of each one is now; unlike the transport age it keeps
growing while a link drops messages or is down).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

from swarmnet.node import SwarmNode
from swarmnet.stats import PoseAges
from uav_stack.recorder import AppendLog, RecordHealth

COLUMNS = ("t_wall", "poses", "transport_p50_ms", "transport_p99_ms", "transport_mean_ms", "used", "use_p50_ms", "use_p99_ms",
           "aoi_mean_ms", "aoi_max_ms", "neighbours")


class AgeFigures(NamedTuple):
    """One second of a UAV's pose ages, in s (NaN: nothing in that second)."""

    poses: int
    transport_p50: float
    transport_p99: float
    transport_mean: float
    used: int
    use_p50: float
    use_p99: float


class AgeWindow:
    """What the node's pose-age histograms gained between two calls of :meth:`sample`."""

    def __init__(self, ages: PoseAges):
        self.ages = ages
        self._transport = ages.transport.copy()
        self._use = ages.use.copy()
        self.last = AgeFigures(0, math.nan, math.nan, math.nan, 0, math.nan, math.nan)

    def sample(self) -> AgeFigures:
        a = self.ages
        t, u = a.transport.since(self._transport), a.use.since(self._use)
        self._transport, self._use = a.transport.copy(), a.use.copy()
        self.last = AgeFigures(t.n, t.centre_percentile(50), t.centre_percentile(99), t.mean,
                               u.n, u.centre_percentile(50), u.centre_percentile(99))
        return self.last


class PoseAgeLog:
    """``age_uav<N>.csv``: one row per second of :class:`AgeFigures` and the age of information
    (an append-only log: a write error degrades, never raises)."""

    def __init__(self, path: str | Path, node: SwarmNode, health: RecordHealth | None = None):
        self.path = Path(path)
        self._log = AppendLog(self.path, ",".join(COLUMNS) + "\n", health)  # errors degrade, never raise
        self.node = node

    def write(self, now: float, f: AgeFigures) -> None:
        ms = lambda v: f"{1000.0 * v:.2f}" if v == v else ""  # noqa: E731
        ages = [n_.age(now) for n_ in self.node.neighbours]
        aoi_mean = sum(ages) / len(ages) if ages else math.nan
        aoi_max = max(ages) if ages else math.nan
        self._log.add(f"{now:.3f},{f.poses},{ms(f.transport_p50)},{ms(f.transport_p99)},{ms(f.transport_mean)},"
                      f"{f.used},{ms(f.use_p50)},{ms(f.use_p99)},{ms(aoi_mean)},{ms(aoi_max)},{len(ages)}\n")
        self._log.flush(now)

    def close(self) -> None:
        self._log.close()
