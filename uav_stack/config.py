"""Configuration of one agent and its virtual FCU: the file a UAV process reads.

The scenario loader (``mrswarm.scenario``) builds these from a scenario and a runtime writes
them as JSON; a UAV process decodes that with ``VirtualUavConfig.load`` (msgspec: types and
ranges checked, unknown fields refused, errors naming the field). Light imports only: a UAV
process loads no YAML and no netem modules unless its swarm uses netem.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta, field

from discovery.options import ProxyOptions
from swarmnet.keyspace import SWARM_RE
from swarmnet.schema import Config, ConfigError, decode_json
from swarmnet.security.credentials import Credentials
from uav_stack.failsafe import FailsafeConfig
from uav_stack.geo import GeoPoint

Connectivity = Literal["rendezvous", "static", "discovery"]
ZenohMode = Literal["peer", "client"]
PoseFeed = Literal["direct", "edge"]  # direct: a message per neighbour pose; edge: batches from the edge router
MissionType = Literal["coverage", "goto", "idle"]
CoverageStrategy = Literal["lawnmower", "random"]
Flavour = Literal["px4", "ardupilot"]  # the autopilot a virtual FCU emulates
UavId = Annotated[int, Meta(ge=1, le=65535, description="UAV id")]
Rect = tuple[float, float, float, float]  # x_min, x_max, y_min, y_max (ENU m)
Hz = Annotated[float, Meta(gt=0.0, le=1000.0, description="Hz")]


class NetworkConfig(Config, frozen=True):
    """How the node reaches its swarm (``swarmnet.connectivity``, docs/discovery.md)."""

    connectivity: Connectivity = "rendezvous"
    endpoints: tuple[str, ...] = ()  # Zenoh endpoints to connect to (the rendezvous or edge router)
    mode: ZenohMode = "peer"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    pose_feed: PoseFeed = "direct"
    discovery: ProxyOptions | None = None  # connectivity "discovery": the server and the swarm's key
    # mutual TLS and access control (docs/security.md); the identity defaults to uav-<id>.<swarm>.
    # None: plain TCP without access control, which only `network.security: off` (or `--insecure`) asks for
    security: Credentials | None = None
    # the network.netem mapping (swarmnet.netem.config.NetemSpec; None: no shim). Plain data here:
    # the node validates it when it applies it, as it does a runtime change, so a UAV without
    # netem never loads the netem modules.
    netem: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        if self.connectivity == "discovery":
            if self.discovery is None:
                raise ConfigError("discovery", "required with connectivity 'discovery' (the server and the swarm's key)")
            if self.mode != "peer":
                raise ConfigError("mode", "discovery connects peers directly; client mode needs connectivity 'rendezvous'")


class MissionConfig(Config, frozen=True):
    type: MissionType = "coverage"
    strategy: CoverageStrategy = "lawnmower"  # coverage only
    area: Rect = (-100.0, 100.0, -100.0, 100.0)  # x_min, x_max, y_min, y_max (ENU m)
    lane_spacing: Annotated[float, Meta(gt=0.0, description="m")] = 16.0
    goal: tuple[float, float] | None = None  # goto: x, y (ENU m)
    goal_tolerance: Annotated[float, Meta(gt=0.0, description="m")] = 1.5
    land_when_done: bool = False


class AvoidanceConfig(Config, frozen=True):
    enabled: bool = True
    safety_distance: Annotated[float, Meta(gt=0.0, description="m between UAV centres that avoidance keeps")] = 5.0
    time_horizon: Annotated[float, Meta(gt=0.0, description="s")] = 4.0
    stale_after: Annotated[float, Meta(gt=0.0, description="neighbours older than this are ignored, s")] = 1.0


class MavlinkSigning(Config, frozen=True):
    """MAVLink 2 signing on the router's ground-station links (docs/security.md)."""

    # a passphrase file; the key is its SHA-256, as MAVProxy's `signing key <passphrase>` derives it
    key_file: Annotated[str, Meta(min_length=1, description="path of the passphrase file")]
    require: bool = True  # refuse (and count) unsigned frames from ground stations; False: accept them, counted

    def read_key(self) -> bytes:
        """The 32-byte secret; :class:`~swarmnet.schema.ConfigError` on ``key_file`` if the file is unusable."""
        from uav_stack.mavlink_signing import SigningKeyError, read_key_file

        try:
            return read_key_file(self.key_file)
        except SigningKeyError as exc:
            raise ConfigError("key_file", str(exc)) from None


class GcsConfig(Config, frozen=True):
    """Ground-station access: the agent's MAVLink router and the limits of override commands."""

    mavlink_endpoints: tuple[str, ...] = ()  # udpout:HOST:PORT / udpin:HOST:PORT; empty = no router
    # local address of the router's udpout sockets; None: the address that routes to each ground station
    bind: str | None = None
    signing: MavlinkSigning | None = None  # sign the ground-station links (None: unsigned, open to local processes)
    sysid: Annotated[int, Meta(ge=0, le=250)] = 0  # MAVLink sysid of this UAV's FCU; 0 = uav_stack.sysid.allocate_sysid(uav)
    geofence: Rect | None = None  # goto limits x_min, x_max, y_min, y_max (ENU m); None = mission area
    min_alt: float = 2.0  # goto altitude limits above the swarm origin, m
    max_alt: float = 120.0


class AgentConfig(Config, frozen=True):
    swarm: Annotated[str, Meta(pattern=SWARM_RE.pattern)]
    uav: UavId
    origin: GeoPoint  # the swarm's ENU origin
    fcu: str  # pymavlink connection string
    # local address of a udpout FCU link's socket; None: the address that routes to the FCU (127.0.0.1 for a local one)
    fcu_bind: str | None = None
    realm: Literal["virtual", "physical"] = "virtual"
    altitude: float = 20.0  # mission altitude above the swarm origin, m
    speed: Annotated[float, Meta(gt=0.0, description="cruise speed, m/s")] = 5.0
    seed: int = 0
    pose_rate_hz: Hz = 10.0
    telemetry_rate_hz: Hz = 2.0
    control_rate_hz: Hz = 10.0
    stale_after: Annotated[float, Meta(gt=0.0, description="s")] = 1.0
    autostart: bool = False  # start the mission without waiting for a "start" command
    record_dir: str | None = None
    mission: MissionConfig = field(default_factory=MissionConfig)
    avoidance: AvoidanceConfig = field(default_factory=AvoidanceConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    gcs: GcsConfig = field(default_factory=GcsConfig)
    failsafe: FailsafeConfig = field(default_factory=FailsafeConfig)  # companion failsafes (uav_stack/failsafe.py)

    @property
    def mavlink_sysid(self) -> int:
        """The FCU's (and the companion's) MAVLink system id (docs/gcs.md, "System ids")."""
        from uav_stack.sysid import allocate_sysid

        return self.gcs.sysid or allocate_sysid(self.uav)[1]

    def to_json(self) -> str:
        return msgspec.json.encode(self).decode()

    @classmethod
    def load(cls, path: str | Path) -> AgentConfig:
        """Read a JSON file; :class:`~swarmnet.schema.ConfigError` names the bad field."""
        return decode_json(Path(path).read_bytes(), cls)


class VirtualUavConfig(Config, frozen=True):
    """One virtual UAV process: its FCU and its agent."""

    agent: AgentConfig
    home: GeoPoint  # where the virtual FCU spawns (landed)
    target_rtf: Annotated[float, Meta(gt=0.0, le=1.0, description="target real-time factor")] = 1.0
    physics_hz: Hz = 50.0
    flavour: Flavour = "px4"
    heading: float = 0.0  # initial yaw, rad (NED)
    # stop the process after this long (None: until signalled)
    duration: Annotated[float, Meta(gt=0.0, description="s")] | None = None

    def to_json(self) -> str:
        return msgspec.json.encode(self).decode()

    @classmethod
    def load(cls, path: str | Path) -> VirtualUavConfig:
        """Read a JSON file (what a runtime wrote); :class:`~swarmnet.schema.ConfigError` names the bad field."""
        return decode_json(Path(path).read_bytes(), cls)
