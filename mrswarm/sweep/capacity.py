"""Room for one more run: a sweep flies runs side by side only when they cannot measure each other.

A run's RTF, pose ages and separations depend on the CPU it gets, so a second run beside the first
must not take CPU the first one needs. ``--parallel N`` (or ``auto``: up to the number of cores)
is a ceiling; below it a run starts only when all of these hold:

* **the estimate**: the cores every running run needs plus this one's fit in
  :data:`~mrswarm.run.resources.CPU_SHARE` of the machine's cores, and its memory fits in what is
  available. A run's need is the fleet's estimate (:func:`mrswarm.run.resources.estimate`, per UAV
  process) plus :data:`RUN_BASE_CORES` for the runner, the edge services and the flight
  recorder; once a run of the same cell has flown, the CPU it actually used (its CPU time over
  its wall time) with a margin of :data:`MEASURED_MARGIN`, if that is more;
* **the load**: the machine's CPU in use over the last :data:`LOAD_WINDOW_S` seconds (every
  process, not only the sweep's) plus this run's need fits in the same share: runs of other
  users count too;
* **settled**: the last run started at least :data:`SETTLE_S` seconds ago, so that its start-up
  (the heaviest moment of a run: every UAV process importing and connecting) shows in the load.

One run at a time is the default: on a machine as small as the 2-core one mrswarm is measured
on, a second coverage run of 10 UAVs does not fit beside the first. A scenario with a UAV whose
flight controller is external (``uavs[].fcu``: one real autopilot or SITL) never runs beside
another run: the sweep refuses ``--parallel`` for it (:func:`exclusive_problem`).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

import psutil

from groundfloor.process import usable_cores
from mrswarm.run.resources import CPU_SHARE, MEMORY_SHARE, estimate
from mrswarm.scenario import Scenario

RUN_BASE_CORES = 0.25  # the runner, discovery server, edge router and recorder: 0.13 cores measured for a 2-UAV run, and
# the analysis at its end takes a core for a few seconds
MEASURED_MARGIN = 1.25
LOAD_WINDOW_S = 10.0
SETTLE_S = 20.0


@dataclass(frozen=True)
class Need:
    cores: float
    memory_mb: float


def exclusive_problem(scn: Scenario) -> str:
    """Why runs of ``scn`` cannot fly beside another run on this machine ("" if they can)."""
    ext = scn.external_uavs()
    if not ext:
        return ""
    u = ext[0]
    where = next((f"uavs.{i}.fcu" for i, v in enumerate(scn.uavs or ()) if v.id == u.id), "other_swarms.uavs.fcu")
    return (f"{where}: UAV {u.id}'s flight controller is external ({u.fcu}): one autopilot flies one run at a time; "
            "sweep it with --parallel 1")


class Capacity:
    """Decides whether one more run may start now; fed the machine's CPU load every tick."""

    def __init__(self, limit: int, cores: int | None = None) -> None:
        self.limit = limit
        self.cores = cores or usable_cores()
        self._load: deque[tuple[float, float]] = deque()  # (monotonic time, busy share 0..1)
        self._measured: dict[str, float] = {}  # cell key -> cores used by its last finished run
        self.last_start = 0.0
        psutil.cpu_percent(None)  # the first call only starts the measurement

    def sample(self) -> float | None:
        """Record the machine's CPU use since the last call (share of all cores, 0..1) and return it."""
        now = time.monotonic()
        busy = psutil.cpu_percent(None) / 100.0
        self._load.append((now, busy))
        while self._load and self._load[0][0] < now - LOAD_WINDOW_S:
            self._load.popleft()
        return busy

    @property
    def busy_cores(self) -> float | None:
        """Cores in use over the last :data:`LOAD_WINDOW_S` s (None until it has been watched that long)."""
        if not self._load or self._load[-1][0] - self._load[0][0] < LOAD_WINDOW_S * 0.8:
            return None
        return sum(b for _, b in self._load) / len(self._load) * self.cores

    def measured(self, cell: str, cores: float) -> None:
        self._measured[cell] = cores

    def need(self, scn: Scenario, cell: str) -> Need:
        est = estimate(scn)
        cores = est.cores_needed + RUN_BASE_CORES
        if scn.time == "lockstep":  # as fast as the CPU allows: it takes the whole machine, a second run gains nothing
            cores = max(cores, float(self.cores))
        seen = self._measured.get(cell)
        if seen is not None:
            cores = max(cores, seen * MEASURED_MARGIN)
        return Need(cores=cores, memory_mb=est.memory_mb_needed)

    def admits(self, new: Need, running: list[Need]) -> str:
        """"" if a run needing ``new`` may start beside ``running``, else why it waits."""
        if not running:
            return ""
        if len(running) >= self.limit:
            return f"{len(running)} running (--parallel {self.limit})"
        budget = CPU_SHARE * self.cores
        planned = sum(n.cores for n in running) + new.cores
        if planned > budget:
            return f"the runs would need about {planned:.1f} cores, {budget:.1f} of {self.cores} may be used"
        since = time.monotonic() - self.last_start
        if since < SETTLE_S:
            return f"the last run started {since:.0f} s ago"
        busy = self.busy_cores
        if busy is None:
            return "watching the machine's load"
        if busy + new.cores > budget:
            return f"the machine uses {busy:.1f} of {self.cores} cores; another run needs about {new.cores:.1f}"
        available = psutil.virtual_memory().available / 2**20
        if new.memory_mb > MEMORY_SHARE * available:
            return f"another run needs about {new.memory_mb:,.0f} MB, {available:,.0f} MB are available"
        return ""

    def started(self) -> None:
        self.last_start = time.monotonic()


class ClusterCapacity(Capacity):
    """On a Docker Swarm: the nodes' room is Swarm's business (each job reserves its need); only the cap on the
    jobs submitted at once is the sweep's."""

    def sample(self) -> float | None:
        return None  # the nodes' load is not watched from here

    def admits(self, new: Need, running: list[Need]) -> str:
        if len(running) >= self.limit:
            return f"{len(running)} jobs submitted (--parallel {self.limit})"
        return ""
