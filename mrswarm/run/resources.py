"""Will this machine carry the fleet? An estimate from the measured cost of a virtual UAV (docs/benchmarks.md).

``mrswarm run`` refuses a scenario whose fleet would need more CPU or memory than the machine
has (exit 2, with the estimate); ``--force`` runs it anyway. The figures are what
``benchmarks/scale.py`` measured per virtual UAV process on a 2-core VM, rounded up:

* CPU: 4 % of one core per UAV with the default direct pose feed (the peer mesh saturated two
  cores at 50 UAVs), 2.5 % with the edge feed or in client mode (2.16 % measured at 50 UAVs
  when this was set, 1.6-2.1 % since, as the VM's speed moved; at 100 UAVs the two cores are
  saturated and poses arrive late, so the margin stays); a slower target RTF does not make a
  UAV cheaper (its loop still runs at 10 Hz).
* Memory: 60 MB RSS per UAV process (53.5-59.7 MB measured), 75 MB per container (+13 MB for
  its containerd shim), plus 300 MB for the runner, the edge router and the discovery server.

The estimate must fit in :data:`CPU_SHARE` of the cores and :data:`MEMORY_SHARE` of the memory
available now (psutil).
"""

from __future__ import annotations

from dataclasses import dataclass

import psutil

from groundfloor.process import usable_cores
from mrswarm.scenario import Scenario

CPU_PER_UAV_DIRECT = 0.04  # cores
CPU_PER_UAV_BATCHED = 0.025
CPU_PER_UAV_POOLED = 0.008  # a UAV of a pool (fleet.pool) with its share of the edge router: 0.4-0.7 % measured at 100-250 UAVs
MB_PER_UAV_POOLED = 4.0  # 1.3-3.3 MB measured, with its share of the pool's interpreter
MB_PER_UAV_PROCESS = 60.0
MB_PER_UAV_CONTAINER = 75.0
MB_BASE = 300.0
CPU_SHARE = 0.9
MEMORY_SHARE = 0.8


@dataclass(frozen=True)
class ResourceEstimate:
    uavs: int
    cores_needed: float
    cores: int
    memory_mb_needed: float
    memory_mb_available: float

    @property
    def problem(self) -> str:
        """"" if it fits, else what does not."""
        out = []
        if self.cores_needed > CPU_SHARE * self.cores:
            out.append(f"about {self.cores_needed:.1f} cores of CPU, this machine has {self.cores}")
        if self.memory_mb_needed > MEMORY_SHARE * self.memory_mb_available:
            out.append(f"about {self.memory_mb_needed:,.0f} MB of memory, {self.memory_mb_available:,.0f} MB are available")
        return "; ".join(out)


def estimate(scn: Scenario) -> ResourceEstimate:
    n = len([u for u in scn.all_uavs() if u.agent != "companion"])  # every swarm of the airspace runs here (not a companion)
    batched = scn.network.pose_feed == "edge" or scn.network.mode == "client"
    per_core = CPU_PER_UAV_BATCHED if batched else CPU_PER_UAV_DIRECT
    per_mb = MB_PER_UAV_CONTAINER if scn.runtime == "docker" else MB_PER_UAV_PROCESS
    if scn.pool_size > 1:
        per_core, per_mb = min(per_core, CPU_PER_UAV_POOLED), MB_PER_UAV_POOLED
    cores = usable_cores()
    return ResourceEstimate(uavs=n, cores_needed=n * per_core, cores=cores, memory_mb_needed=MB_BASE + n * per_mb,
                            memory_mb_available=psutil.virtual_memory().available / 2**20)


def check_resources(scn: Scenario) -> str:
    """"" if the fleet fits this machine, else the message ``mrswarm run`` prints (naming ``fleet.count``)."""
    est = estimate(scn)
    problem = est.problem
    if not problem:
        return ""
    field = "fleet.count" if scn.fleet is not None else "uavs"
    return f"{field}: {est.uavs} virtual UAVs need {problem} (estimate from docs/benchmarks.md); use --force to run anyway"
