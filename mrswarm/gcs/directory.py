"""Who is alive: the seam between ``mrswarm gcs nodes`` and where the node list comes from.

Today the list comes from Zenoh liveliness tokens (``mrs/<swarm>/alive/<role>/<id>``) plus what
the observer has heard from each UAV. The discovery server's registry (issue 3) knows more
(software version, Zenoh locators, first seen); it plugs in as another :class:`NodeDirectory`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

from swarmnet.observer import SwarmObserver


@dataclass(frozen=True)
class NodeInfo:
    """One node as ``gcs nodes`` lists it (the fields of the discovery registry)."""

    id: int
    role: str  # uav | gcs | edge | observer
    realm: str = "-"  # virtual | physical, when known
    version: str = "-"
    address: str = "-"  # Zenoh locators, when known
    last_seen: float = math.nan  # wall time of the latest message from it (NaN: liveliness only)
    alive: bool = True


class NodeDirectory(Protocol):
    def nodes(self) -> list[NodeInfo]: ...


class LivelinessDirectory:
    """Nodes from liveliness tokens, completed with the observer's per-UAV data."""

    def __init__(self, obs: SwarmObserver):
        self.obs = obs

    def nodes(self) -> list[NodeInfo]:
        obs = self.obs
        prefix = f"{obs.keys.prefix}/alive/"
        seen: dict[tuple[str, int], NodeInfo] = {}
        for key in obs.node.alive:
            if not key.startswith(prefix):
                continue
            parts = key[len(prefix):].split("/")
            if len(parts) != 2 or not parts[1].isdigit():
                continue
            role, nid = parts[0], int(parts[1])
            info = NodeInfo(nid, role)
            if role == "uav" and nid in obs.uavs:
                v = obs.uavs[nid]
                realm = "-"
                for m in (v.pose, v.telemetry, v.state):
                    if m is not None:
                        realm = m.realm.label
                        break
                times = [t for t in (v.pose_recv if v.pose else None, v.state_recv if v.state else None,
                                     v.telemetry.t_wall if v.telemetry else None) if t]
                info = NodeInfo(nid, role, realm, last_seen=max(times) if times else math.nan)
            seen[(role, nid)] = info
        # UAVs we hear from without a liveliness token (it dropped, or it never declared one)
        for uav, v in obs.uavs.items():
            if ("uav", uav) not in seen and (v.pose or v.state or v.telemetry):
                times = [t for t in (v.pose_recv if v.pose else None, v.state_recv if v.state else None) if t]
                seen[("uav", uav)] = NodeInfo(uav, "uav", last_seen=max(times) if times else math.nan, alive=False)
        return sorted(seen.values(), key=lambda n: (n.role != "uav", n.role, n.id))
