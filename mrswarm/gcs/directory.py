"""Who is alive: the seam between ``mrswarm gcs nodes`` and where the node list comes from.

The list comes from Zenoh liveliness tokens (``mrs/<swarm>/alive/<role>/<id>``) plus what the
observer has heard from each UAV (:class:`LivelinessDirectory`). When the swarm uses the
discovery server and its key is known (``--run`` of a discovery run, or ``--discovery`` with
``--discovery-key-file``), its registry adds the software version and Zenoh locators
(:class:`RegistryDirectory`); :func:`merge` joins the two lists.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
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


class RegistryDirectory:
    """Nodes from the discovery server's registry (one authenticated query)."""

    def __init__(self, server: str, swarm: str, key: str, timeout: float = 0.5, attempts: int = 3):
        self.server, self.swarm, self.key = server, swarm, key
        self.timeout, self.attempts = timeout, attempts

    def nodes(self) -> list[NodeInfo]:
        """Raises :class:`discovery.client.QueryTimeout` when the server does not answer."""
        from discovery.client import query_registry

        rows, _stats = query_registry(self.server, self.swarm, self.key, timeout=self.timeout, attempts=self.attempts)
        out = []
        for r in rows:
            e = r.entry
            out.append(NodeInfo(e.node, e.role, e.realm or "-", e.software or "-",
                                ", ".join(e.locators) or r.address or "-", last_seen=r.last_seen))
        return out


def merge(live: list[NodeInfo], registry: list[NodeInfo]) -> list[NodeInfo]:
    """Liveliness rows completed with the registry's version, locators and realm; registry-only rows added.

    A node is alive if it holds a liveliness token or the registry heard it within its TTL.
    Last-seen times are this machine's where known (the registry's come from the server's clock).
    """
    by_key = {(n.role, n.id): n for n in live}
    for r in registry:
        n = by_key.get((r.role, r.id))
        if n is None:
            by_key[(r.role, r.id)] = r
            continue
        last = r.last_seen if math.isnan(n.last_seen) else n.last_seen
        by_key[(r.role, r.id)] = replace(n, realm=n.realm if n.realm != "-" else r.realm, version=r.version,
                                         address=r.address, last_seen=last, alive=True)
    return sorted(by_key.values(), key=lambda n: (n.role != "uav", n.role, n.id))
