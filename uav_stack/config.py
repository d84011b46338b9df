"""Plain-dataclass configuration of one agent (and its virtual FCU).

The scenario loader (``mrswarm.scenario``, pydantic) validates YAML and produces these;
the UAV process only parses their JSON form, so it never imports pydantic or YAML (each
costs MBs of RSS per process, and a swarm runs dozens of processes).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from uav_stack.geo import GeoPoint


@dataclass(frozen=True)
class NetworkConfig:
    connectivity: str = "rendezvous"  # rendezvous | static | discovery (options: server, key/key_file, advertise, period)
    endpoints: tuple[str, ...] = ()
    mode: str = "peer"  # peer | client
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    pose_feed: str = "direct"  # direct: a message per neighbour pose; edge: batches from the edge router
    options: dict[str, Any] = field(default_factory=dict)  # strategy-specific settings
    netem: dict[str, Any] | None = None  # netem shim config (network.netem, docs/netem.md); None: no shim


@dataclass(frozen=True)
class MissionConfig:
    type: str = "coverage"  # coverage | goto | idle
    strategy: str = "lawnmower"  # coverage: lawnmower | random
    area: tuple[float, float, float, float] = (-100.0, 100.0, -100.0, 100.0)  # x_min, x_max, y_min, y_max (ENU m)
    lane_spacing: float = 16.0
    goal: tuple[float, float] | None = None  # goto
    goal_tolerance: float = 1.5
    land_when_done: bool = False


@dataclass(frozen=True)
class AvoidanceConfig:
    enabled: bool = True
    safety_distance: float = 5.0  # m between UAV centres that avoidance keeps
    time_horizon: float = 4.0
    stale_after: float = 1.0


@dataclass(frozen=True)
class GcsConfig:
    """Ground-station access: the agent's MAVLink router and the limits of override commands."""

    mavlink_endpoints: tuple[str, ...] = ()  # udpout:HOST:PORT / udpin:HOST:PORT; empty = no router
    sysid: int = 0  # MAVLink sysid of this UAV's FCU; 0 = uav_stack.sysid.allocate_sysid(uav)
    geofence: tuple[float, float, float, float] | None = None  # goto limits x_min, x_max, y_min, y_max (ENU m); None = mission area
    min_alt: float = 2.0  # goto altitude limits above the swarm origin, m
    max_alt: float = 120.0


@dataclass(frozen=True)
class AgentConfig:
    swarm: str
    uav: int
    origin: GeoPoint
    fcu: str  # pymavlink connection string
    realm: str = "virtual"
    altitude: float = 20.0  # mission altitude above the swarm origin, m
    speed: float = 5.0  # cruise speed, m/s
    seed: int = 0
    pose_rate_hz: float = 10.0
    telemetry_rate_hz: float = 2.0
    control_rate_hz: float = 10.0
    stale_after: float = 1.0
    autostart: bool = False  # start the mission without waiting for a "start" command
    record_dir: str | None = None
    mission: MissionConfig = field(default_factory=MissionConfig)
    avoidance: AvoidanceConfig = field(default_factory=AvoidanceConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    gcs: GcsConfig = field(default_factory=GcsConfig)

    @property
    def mavlink_sysid(self) -> int:
        """The FCU's (and the companion's) MAVLink system id (docs/gcs.md, "System ids")."""
        from uav_stack.sysid import allocate_sysid

        return self.gcs.sysid or allocate_sysid(self.uav)[1]

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> AgentConfig:
        d = dict(d)
        d["origin"] = GeoPoint(**d["origin"])
        m = dict(d.get("mission", {}))
        for k in ("area", "goal"):
            if m.get(k) is not None:
                m[k] = tuple(m[k])
        d["mission"] = MissionConfig(**m)
        d["avoidance"] = AvoidanceConfig(**d.get("avoidance", {}))
        n = dict(d.get("network", {}))
        for k in ("endpoints", "listen"):
            if k in n:
                n[k] = tuple(n[k])
        d["network"] = NetworkConfig(**n)
        g = dict(d.get("gcs", {}))
        if "mavlink_endpoints" in g:
            g["mavlink_endpoints"] = tuple(g["mavlink_endpoints"])
        if g.get("geofence") is not None:
            g["geofence"] = tuple(g["geofence"])
        d["gcs"] = GcsConfig(**g)
        return cls(**d)


@dataclass(frozen=True)
class VirtualUavConfig:
    """One virtual UAV process: its FCU and its agent."""

    agent: AgentConfig
    home: GeoPoint  # where the virtual FCU spawns (landed)
    target_rtf: float = 1.0
    physics_hz: float = 50.0
    flavour: str = "px4"
    heading: float = 0.0  # initial yaw, rad (NED)
    duration: float | None = None  # stop the process after this many seconds (None: until signalled)

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> VirtualUavConfig:
        d = dict(d)
        d["agent"] = AgentConfig.from_dict(d["agent"])
        d["home"] = GeoPoint(**d["home"])
        return cls(**d)

    @classmethod
    def load(cls, path: str | Path) -> VirtualUavConfig:
        return cls.from_dict(json.loads(Path(path).read_text()))
