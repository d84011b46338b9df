"""Configuration of one agent and its virtual FCU: the file a UAV process reads.

The scenario loader (``mrswarm.scenario``) builds these from a scenario and a runtime writes
them as JSON; a UAV process decodes that with ``VirtualUavConfig.load`` (msgspec: types and
ranges checked, unknown fields refused, errors naming the field). Light imports only: a UAV
process loads no YAML and no netem modules unless its swarm uses netem.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta, field

from discovery.options import ProxyOptions
from groundfloor.schema import Config, ConfigError, decode_json
from swarmnet.interest import Interest
from swarmnet.keyspace import SWARM_RE
from swarmnet.security.credentials import Credentials
from uav_stack.failsafe import FailsafeConfig
from uav_stack.geo import GeoPoint

Connectivity = Literal["rendezvous", "static", "discovery"]
ZenohMode = Literal["peer", "client"]
PoseFeed = Literal["direct", "edge"]  # direct: a message per neighbour pose; edge: batches from the edge router
MissionType = Literal["coverage", "goto", "idle", "plume", "wildfire", "behaviour"]  # behaviour: the SDK's (docs/sdk.md)
CoverageStrategy = Literal["lawnmower", "random"]
Flavour = Literal["px4", "ardupilot"]  # the autopilot a virtual FCU emulates
UavId = Annotated[int, Meta(ge=1, le=65535, description="UAV id")]
Rect = tuple[float, float, float, float]  # x_min, x_max, y_min, y_max (ENU m)
Hz = Annotated[float, Meta(gt=0.0, le=1000.0, description="Hz")]
# Zenoh's lease: a node silent this long is declared gone (its links closed, its liveliness token
# dropped). 3 s finds a frozen UAV fast; on a machine so overloaded that a process can go 3 s
# without running (100 UAVs on 2 cores) the edge router closed live UAVs' sessions: raise it there.
LeaseS = Annotated[float, Meta(ge=0.5, le=60.0, description="s")]
Name = Annotated[str, Meta(pattern=r"^[A-Za-z0-9_\-]{1,32}$", description="1-32 characters of [A-Za-z0-9_-]")]
Point = tuple[float, float]  # x, y (ENU m)
SensorType = Literal["pollutant", "wind", "fire", "tank", "alarm", "target"]
ActuatorType = Literal["spray"]
ZoneKind = Literal["no_fly", "obstacle"]


# the schemes of a flight controller's connection string: pymavlink's, plus serial:<device>[:<baud>]
FCU_SCHEMES = ("udpin", "udpout", "udp", "udpbcast", "tcp", "tcpin", "serial")


def fcu_url_problem(url: str) -> str:
    """"" if ``url`` is a flight controller's connection string the agent can open, else what is wrong with it.

    Accepted: ``udpin:HOST:PORT``, ``udpout:HOST:PORT`` (``udp:`` is ``udpin:``), ``tcp:HOST:PORT``,
    ``tcpin:HOST:PORT``, ``udpbcast:HOST:PORT``, ``serial:<device>[:<baud>]`` and a bare serial
    device (``/dev/ttyACM0``)."""
    if not url:
        return "empty: a MAVLink connection string such as udpin:127.0.0.1:14540 or serial:/dev/ttyACM0:921600"
    if url.startswith("/dev/"):
        return ""
    scheme, sep, rest = url.partition(":")
    if not sep or scheme not in FCU_SCHEMES:
        return f"unknown scheme {scheme + ':' if sep else url!r}; use one of {', '.join(s + ':' for s in FCU_SCHEMES)} " \
               "or a serial device (/dev/ttyACM0)"
    if scheme == "serial":
        return "" if rest.lstrip("/") else "no serial device; use serial:/dev/ttyACM0:921600"
    host, sep, port = rest.rpartition(":")
    if not sep or not host:
        return f"expected {scheme}:HOST:PORT"
    if not port.isdigit() or not 0 < int(port) < 65536:
        return f"port {port!r} is not a port number (1-65535)"
    return ""


def pool_shares_session(connectivity: str) -> bool:
    """Pooled UAVs on this connectivity share their pool's one session (swarmnet/shared_session.py):
    every connectivity but discovery, whose beacons announce each UAV's own session."""
    return connectivity != "discovery"


class NetworkConfig(Config, frozen=True):
    """How the node reaches its swarm (``swarmnet.connectivity``, docs/discovery.md)."""

    connectivity: Connectivity = "rendezvous"
    endpoints: tuple[str, ...] = ()  # Zenoh endpoints to connect to (the rendezvous or edge router)
    mode: ZenohMode = "peer"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    pose_feed: PoseFeed = "direct"
    lease_s: LeaseS = 3.0
    # spatial interest (docs/scale.md): full-rate poses only from UAVs within a radius; needs pose_feed edge
    interest: Interest | None = None
    discovery: ProxyOptions | None = None  # connectivity "discovery": the server and the swarm's key
    # mutual TLS and access control (docs/security.md); the identity defaults to uav-<id>.<swarm>.
    # None: plain TCP without access control, which only `network.security: off` (or `--insecure`) asks for
    security: Credentials | None = None
    # the network.netem mapping (swarmnet.netem.config.NetemSpec; None: no shim). Plain data here:
    # the node validates it when it applies it, as it does a runtime change, so a UAV without
    # netem never loads the netem modules.
    netem: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        if self.interest is not None and self.pose_feed != "edge":
            raise ConfigError("interest", "the edge pose feed does the filtering: set pose_feed: edge")
        if self.connectivity == "discovery":
            if self.discovery is None:
                raise ConfigError("discovery", "required with connectivity 'discovery' (the server and the swarm's key)")
            if self.mode != "peer":
                raise ConfigError("mode", "discovery connects peers directly; client mode needs connectivity 'rendezvous'")


class SensorSpec(Config, frozen=True):
    """One sensor of every UAV's payload (docs/world.md): a virtual one computed at the edge from
    the UAV's shared pose, or a real one whose driver gives readings of the same shape.

    Types: ``pollutant`` (concentration at the UAV; 0/1 with the cone model), ``wind`` (the
    direction the air carries the plume to, degrees counter-clockwise from east), ``fire`` (the
    camera footprint's radius in m as the value, every burning cell in it as a point
    ``(x, y, heat)``), ``tank`` (litres left in the UAV's virtual tank), ``alarm`` (burning cells
    anywhere: the detection system), ``target`` (moving targets in range and field of view as
    points ``(x, y, id)``).
    """

    name: Name
    type: SensorType
    rate_hz: Hz = 10.0
    latency_s: Annotated[float, Meta(ge=0.0, le=10.0, description="measurement to delivery, s")] = 0.0
    noise: Annotated[float, Meta(ge=0.0, description="std of Gaussian noise: on the value, or on a point's position (m)")] = 0.0
    range_m: Annotated[float, Meta(gt=0.0, le=10000.0, description="how far it sees, m")] = 30.0
    fov_deg: Annotated[float, Meta(gt=0.0, le=360.0, description="field of view, degrees (fire: downward cone)")] = 360.0
    threshold: float | None = None  # binary output: 1.0 at or above this value, else 0.0


class ActuatorSpec(Config, frozen=True):
    """One virtual actuator of every UAV (docs/world.md); the world keeps its state (the tank)."""

    name: Name
    type: ActuatorType = "spray"
    capacity_l: Annotated[float, Meta(gt=0.0, le=1e5, description="tank capacity, litres")] = 20.0
    rate_l_s: Annotated[float, Meta(gt=0.0, le=1e3, description="most it releases, litres per second")] = 2.0
    radius_m: Annotated[float, Meta(gt=0.0, le=500.0, description="radius of the sprayed disc under the UAV, m")] = 6.0
    refill_at: Point | None = None  # the hub: the tank refills within refill_radius_m of it
    refill_radius_m: Annotated[float, Meta(gt=0.0, le=1000.0, description="m")] = 8.0
    refill_rate_l_s: Annotated[float, Meta(ge=0.0, le=1e3, description="litres per second at the hub")] = 4.0


class Zone(Config, frozen=True):
    """A no-fly zone or an obstacle: a polygon (ENU m) between two heights above the origin.

    Collision avoidance keeps every UAV out of it (``uav_stack.behaviours.zones``), physical
    UAVs included: it is part of each agent's configuration, on board before takeoff.
    """

    polygon: tuple[Point, ...]
    name: str = ""
    kind: ZoneKind = "no_fly"
    floor: Annotated[float, Meta(ge=-500.0, le=10000.0, description="m above the origin")] = -500.0
    ceiling: Annotated[float, Meta(ge=-500.0, le=10000.0, description="m above the origin")] = 10000.0

    def __post_init__(self) -> None:
        if len(self.polygon) < 3:
            raise ConfigError("polygon", f"needs at least 3 vertices, got {len(self.polygon)}")
        if not all(math.isfinite(v) for p in self.polygon for v in p):
            raise ConfigError("polygon", "vertices must be finite")
        area2 = sum(a[0] * b[1] - b[0] * a[1] for a, b in zip(self.polygon, self.polygon[1:] + self.polygon[:1], strict=True))
        if abs(area2) < 1e-6:
            raise ConfigError("polygon", "has no area")
        if self.floor >= self.ceiling:
            raise ConfigError("ceiling", f"must be above the floor ({self.floor:g} m), got {self.ceiling:g}")


class PlumeSeeking(Config, frozen=True):
    """A ``plume`` mission (docs/world.md): search the area, find the pollutant, locate its source.

    ``seek``: fly random legs; in the plume, surge against the wind; having lost it, cast
    across the wind, then search again. ``stop``: the Reina et al. e-puck experiment on UAVs:
    random legs, and a UAV that senses the pollutant stops with probability
    ``stop_probability`` per control step, moving on once it no longer senses it. Both share
    where they sensed the pollutant and estimate the source from every detection heard.
    """

    strategy: Literal["seek", "stop"] = "seek"
    sensor: Name = "pollutant"
    wind_sensor: Name = "wind"
    threshold: Annotated[float, Meta(ge=0.0, description="in the plume at or above this reading")] = 0.5
    stop_probability: Annotated[float, Meta(ge=0.0, le=1.0, description="per control step (stop)")] = 0.3
    cast_s: Annotated[float, Meta(gt=0.0, le=120.0, description="casting time before searching again, s")] = 10.0
    memory_s: Annotated[float, Meta(gt=0.0, le=3600.0, description="detections older than this are forgotten, s")] = 30.0


class Firefighting(Config, frozen=True):
    """A ``wildfire`` mission (docs/world.md): the firefighting state machine of Lentzas' thesis
    (Idle at the hub, On Duty, Fire Fighting, Returning), with the burning cells each UAV sees
    shared with the swarm."""

    hub: Point
    fire_hint: Point  # where the detection system reports the fire
    hub_radius: Annotated[float, Meta(gt=0.0, le=1000.0, description="m")] = 8.0
    camera: Name = "fire"
    tank: Name = "tank"
    alarm: Name = "alarm"
    spray: Name = "spray"
    spray_rate_l_s: Annotated[float, Meta(gt=0.0, le=1e3, description="litres per second while fighting")] = 2.0
    arrive_m: Annotated[float, Meta(gt=0.0, le=100.0, description="over a cell when this close, m")] = 2.5
    search_radius: Annotated[float, Meta(gt=0.0, le=5000.0, description="search around the hint, m")] = 25.0


class MissionConfig(Config, frozen=True):
    type: MissionType = "coverage"
    strategy: CoverageStrategy = "lawnmower"  # coverage only
    area: Rect = (-100.0, 100.0, -100.0, 100.0)  # x_min, x_max, y_min, y_max (ENU m)
    lane_spacing: Annotated[float, Meta(gt=0.0, description="m")] = 16.0
    goal: tuple[float, float] | None = None  # goto: x, y (ENU m)
    goal_tolerance: Annotated[float, Meta(gt=0.0, description="m")] = 1.5
    land_when_done: bool = False
    plume: PlumeSeeking | None = None  # plume missions (area: where to search)
    wildfire: Firefighting | None = None  # wildfire missions
    # type behaviour (docs/sdk.md): an import path (package.module:Class) or a registered name, its
    # parameters (this UAV's, validated by the behaviour's Params in the UAV process), and its guard
    behaviour: Annotated[str, Meta(min_length=1, max_length=200)] | None = None
    params: dict[str, Any] = field(default_factory=dict)
    budget_ms: Annotated[float, Meta(gt=0.0, le=10000.0, description="time budget of one step, ms")] = 20.0
    max_faults: Annotated[int, Meta(ge=1, le=1000, description="faults in a row that stop the behaviour")] = 3
    hold_s: Annotated[float, Meta(ge=0.0, le=600.0, description="s a stopped behaviour's UAV holds before landing")] = 5.0

    def __post_init__(self) -> None:
        if self.type == "behaviour" and self.behaviour is None:
            raise ConfigError("behaviour", "a behaviour mission needs its behaviour (package.module:Class or a registered name)")
        if self.behaviour is not None and self.type != "behaviour":
            raise ConfigError("type", f"a mission with a behaviour is of type behaviour, not {self.type!r}")


class AvoidanceConfig(Config, frozen=True):
    enabled: bool = True
    safety_distance: Annotated[float, Meta(gt=0.0, description="m between UAV centres that avoidance keeps")] = 5.0
    time_horizon: Annotated[float, Meta(gt=0.0, description="s")] = 4.0
    stale_after: Annotated[float, Meta(gt=0.0, description="neighbours older than this are ignored, s")] = 1.0
    zones: tuple[Zone, ...] = ()  # no-fly zones and obstacles the UAV never enters
    zone_margin: Annotated[float, Meta(ge=0.0, le=100.0, description="clearance kept from a zone, m")] = 3.0


class MavlinkSigning(Config, frozen=True):
    """The MAVLink 2 signing key of the router's ground-station links (docs/security.md)."""

    # a passphrase file; the key is its SHA-256, as MAVProxy's `signing key <passphrase>` and QGroundControl derive it.
    # None: mavlink.key in the UAV's key directory (network.security.keys, where `mrswarm keys` puts it)
    key_file: Annotated[str, Meta(min_length=1, description="path of the passphrase file")] | None = None

    def read_key(self) -> bytes:
        """The 32-byte secret; :class:`~groundfloor.schema.ConfigError` on ``key_file`` if the file is unusable."""
        from uav_stack.mavlink_signing import SigningKeyError, read_key_file

        if self.key_file is None:
            raise ConfigError("key_file", "no key file given")
        try:
            return read_key_file(self.key_file)
        except SigningKeyError as exc:
            raise ConfigError("key_file", str(exc)) from None


class GcsConfig(Config, frozen=True):
    """Ground-station access: the agent's MAVLink router and the limits of override commands."""

    mavlink_endpoints: tuple[str, ...] = ()  # udpout:HOST:PORT / udpin:HOST:PORT; empty = no router
    # local address of the router's udpout sockets; None: the address that routes to each ground station
    bind: str | None = None
    # the signing key: ground stations that sign with it may command; without one, telemetry only
    signing: MavlinkSigning = field(default_factory=MavlinkSigning)
    # route unsigned frames from ground stations too (MAVSDK cannot sign): any process that reaches an endpoint commands
    allow_unsigned: bool = False
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
    # tick on the wall clock's grid (whole multiples of the tick period since the Unix epoch), so
    # that every UAV whose clock is synchronised publishes its pose at the same instants, and
    # controls on the others' poses of that instant as soon as they are in, half a period later
    # at the latest (the edge feed's batches then carry a round of poses in a few, not one per
    # window) (uav_stack.runtime.run_loop, docs/scale.md). False: each UAV's grid starts when it
    # does, and a tick is one piece.
    align_ticks: bool = False
    stale_after: Annotated[float, Meta(gt=0.0, description="s")] = 1.0
    autostart: bool = False  # start the mission without waiting for a "start" command
    record_dir: str | None = None
    mission: MissionConfig = field(default_factory=MissionConfig)
    avoidance: AvoidanceConfig = field(default_factory=AvoidanceConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    gcs: GcsConfig = field(default_factory=GcsConfig)
    failsafe: FailsafeConfig = field(default_factory=FailsafeConfig)  # companion failsafes (uav_stack/failsafe.py)
    sensors: tuple[SensorSpec, ...] = ()  # the payload's sensors (virtual ones are fed by the world service)
    actuators: tuple[ActuatorSpec, ...] = ()
    traffic: bool = False  # take the airspace feed: other swarms' UAVs as traffic to avoid

    def __post_init__(self) -> None:
        m = self.mission
        names = {s.name for s in self.sensors}
        if len(names) != len(self.sensors):
            raise ConfigError("sensors", "two sensors with one name")
        needs: list[tuple[str, str]] = []
        if m.type == "plume":
            p = m.plume or PlumeSeeking()
            needs = [(p.sensor, "mission.plume.sensor")] + ([(p.wind_sensor, "mission.plume.wind_sensor")]
                                                            if p.strategy == "seek" else [])
        elif m.type == "wildfire":
            w = m.wildfire
            if w is None:
                raise ConfigError("mission.wildfire", "a wildfire mission needs its section (hub, fire_hint)")
            needs = [(w.camera, "mission.wildfire.camera"), (w.tank, "mission.wildfire.tank"),
                     (w.alarm, "mission.wildfire.alarm")]
            if w.spray not in {a.name for a in self.actuators}:
                raise ConfigError("mission.wildfire.spray", f"no actuator named {w.spray!r}")
        for name, where in needs:
            if name not in names:
                raise ConfigError(where, f"no sensor named {name!r} (sensors: {', '.join(sorted(names)) or 'none'})")

    def actuator(self, name: str) -> ActuatorSpec:
        return next(a for a in self.actuators if a.name == name)

    def mavlink_key_file(self) -> Path | None:
        """Where this UAV's MAVLink signing passphrase is: ``gcs.signing.key_file``, else
        ``mavlink.key`` in its key directory if there is one there; None: no key."""
        from swarmnet.security.roster import MAVLINK_KEY_FILE

        if self.gcs.signing.key_file is not None:
            return Path(self.gcs.signing.key_file)
        sec = self.network.security
        if sec is not None and (Path(sec.keys) / MAVLINK_KEY_FILE).is_file():
            return Path(sec.keys) / MAVLINK_KEY_FILE
        return None

    @property
    def mavlink_sysid(self) -> int:
        """The FCU's (and the companion's) MAVLink system id (docs/gcs.md, "System ids")."""
        from uav_stack.sysid import allocate_sysid

        return self.gcs.sysid or allocate_sysid(self.uav)[1]

    def to_json(self) -> str:
        return msgspec.json.encode(self).decode()

    @classmethod
    def load(cls, path: str | Path) -> AgentConfig:
        """Read a JSON file; :class:`~groundfloor.schema.ConfigError` names the bad field."""
        return decode_json(Path(path).read_bytes(), cls)


MAX_POOL = 256  # virtual UAVs in one pool process (uav_stack/pool.py, fleet.pool)


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
        """Read a JSON file (what a runtime wrote); :class:`~groundfloor.schema.ConfigError` names the bad field."""
        return decode_json(Path(path).read_bytes(), cls)
