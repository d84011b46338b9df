"""Scenario files: YAML validated on load, errors that name the file and the field.

A scenario describes one experiment: the swarm, its origin, the mission, the UAVs and
how long to fly. ``load_scenario`` applies ``--set a.b=value`` overrides before validation,
so an override that breaks a rule is reported like a bad file:
``scenarios/x.yaml: flight.sped: unknown field (expected one of: ...)``.

The types are msgspec Structs (``groundfloor.schema``). Where a section has the shape of a lower
layer's settings it is that type: ``network.netem`` is :class:`~swarmnet.netem.config.NetemSpec`,
``network.discovery`` is :class:`~discovery.options.DiscoveryService`, ``docker`` is
:class:`~deploy.settings.ContainerSettings`.
"""

from __future__ import annotations

import math
import os
import stat
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from msgspec import Meta, field
from msgspec.structs import force_setattr, replace

from deploy.plan import NetworkPlan, SwarmPlan
from deploy.settings import ContainerSettings
from discovery.options import DiscoveryService, Key
from groundfloor import strict_yaml
from groundfloor.errors import MrswarmError
from groundfloor.process import usable_cores
from groundfloor.schema import Config, ConfigError, convert, to_builtins
from mrswarm.scenario.behaviour_check import check_mission, check_per_uav, uav_behaviour
from mrswarm.scenario.faults import UAV_PROCESS, FaultSpec, check_against, fit_to_duration
from swarmnet.feed import DEFAULT_WINDOW
from swarmnet.interest import Interest, PoolMembers
from swarmnet.keyspace import SWARM_RE
from swarmnet.netem.config import NetemSpec
from uav_stack.config import (
    MAX_POOL,
    AgentConfig,
    AvoidanceConfig,
    CoverageStrategy,
    Firefighting,
    Flavour,
    GcsConfig,
    LeaseS,
    MavlinkSigning,
    MissionConfig,
    MissionType,
    NetworkConfig,
    PlumeSeeking,
    PoseFeed,
    UavId,
    VirtualUavConfig,
    ZenohMode,
)
from uav_stack.failsafe import FailsafeConfig
from uav_stack.geo import GeoPoint, LocalFrame
from uav_stack.sysid import allocate_sysid
from world.config import WorldConfig

MAX_FLEET = 1000  # UAVs of one fleet: what pools of virtual UAVs carry on a 2-core machine (docs/scale.md)
MAX_OFFSET_M = 50_000.0  # every position of a scenario lies within this of the origin (east and north)
MAX_SCENARIO_BYTES = 1024 * 1024  # a scenario file larger than this is refused unread
MAX_COVERAGE_CELLS = 1_000_000  # analysis and live coverage grids (memory: mrswarm/results/coverage.py)
MIN_COVERAGE_CELL_M = 0.5
RESOLVE_TIMEOUT_S = 5.0
# fleet.pool: auto pools the virtual UAVs above this many on the machine (where the network, too, turns to
# the edge feed), one pool per core: at 50 UAVs a pool took 41 % less CPU and a thirteenth of the memory
# per UAV than a process each (docs/scale.md#pooled-virtual-uavs-fleetpool)
POOL_ABOVE = 25

Rtf = Annotated[float, Meta(gt=0.0, le=1.0, description="target real-time factor of the virtual FCU")]
FeedWindowMs = Annotated[float, Meta(ge=0.0, le=1000.0, description="ms a pose may wait at the edge for a batch")]
Port = Annotated[int, Meta(ge=1, le=65535)]
Coord = Annotated[float, Meta(ge=-MAX_OFFSET_M, le=MAX_OFFSET_M, description="m from the origin")]
Heading = Annotated[float, Meta(ge=-360.0, le=360.0, description="degrees from north")]


class ScenarioError(ValueError, MrswarmError):
    """A scenario that cannot be used; the message names the file and the field."""


class Origin(Config, frozen=True):
    lat: Annotated[float, Meta(ge=-90.0, le=90.0, description="degrees")]
    lon: Annotated[float, Meta(ge=-180.0, le=180.0, description="degrees")]
    alt: Annotated[float, Meta(ge=-500.0, le=9000.0, description="metres AMSL")]

    def point(self) -> GeoPoint:
        return GeoPoint(self.lat, self.lon, self.alt)


class Area(Config, frozen=True):
    """A rectangle in the swarm's ENU frame, metres from the origin."""

    x_min: Coord
    x_max: Coord
    y_min: Coord
    y_max: Coord

    def __post_init__(self) -> None:
        if not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ConfigError("", "need x_min < x_max and y_min < y_max")
        if (self.x_max - self.x_min) * (self.y_max - self.y_min) > 25e6:
            raise ConfigError("", "area larger than 25 km^2")

    def as_tuple(self) -> tuple[float, float, float, float]:
        return (self.x_min, self.x_max, self.y_min, self.y_max)


class UavMission(Config, frozen=True):
    """One UAV's own behaviour mission (``mission.per_uav.<id>``): another behaviour, and/or parameters over the mission's."""

    behaviour: Annotated[str, Meta(min_length=1, max_length=200)] | None = None
    params: dict[str, Any] = field(default_factory=dict)


class Mission(Config, frozen=True):
    type: MissionType = "coverage"
    strategy: CoverageStrategy = "lawnmower"
    area: Area | None = None
    sensor_radius: Annotated[float, Meta(gt=0.0, le=200.0, description="footprint radius used for coverage, m")] = 10.0
    overlap: Annotated[float, Meta(ge=0.0, lt=0.9, description="lawnmower lane overlap")] = 0.2
    land_when_done: bool = False
    plume: PlumeSeeking | None = None  # plume missions (docs/world.md)
    wildfire: Firefighting | None = None  # wildfire missions (docs/world.md)
    # a behaviour of one's own (docs/sdk.md): package.module:Class or a registered name; it implies type behaviour
    behaviour: Annotated[str, Meta(min_length=1, max_length=200)] | None = None
    params: dict[str, Any] = field(default_factory=dict)  # validated by the behaviour's Params
    per_uav: dict[UavId, UavMission] = field(default_factory=dict)  # UAV id -> its own behaviour and/or params
    budget_ms: Annotated[float, Meta(gt=0.0, le=10000.0, description="time budget of one step, ms")] = 20.0
    max_faults: Annotated[int, Meta(ge=1, le=1000, description="faults in a row that stop the behaviour")] = 3
    hold_s: Annotated[float, Meta(ge=0.0, le=600.0, description="s a stopped behaviour's UAV holds, then lands")] = 5.0

    def __post_init__(self) -> None:
        check_mission(self)
        if self.type in ("coverage", "plume") and self.area is None:
            raise ConfigError("area", f"a {self.type} mission needs an area")
        if self.type == "wildfire" and self.wildfire is None:
            raise ConfigError("wildfire", "a wildfire mission needs its section (hub, fire_hint)")
        if self.area is not None:
            a, cell = self.area, self.coverage_cell_m
            cells = math.ceil((a.x_max - a.x_min) / cell) * math.ceil((a.y_max - a.y_min) / cell)
            if cells > MAX_COVERAGE_CELLS:
                km2 = (a.x_max - a.x_min) * (a.y_max - a.y_min) / 1e6
                raise ConfigError("sensor_radius", f"{self.sensor_radius:g} m over {km2:.3g} km^2 gives {cells:,} "
                                  f"coverage cells; at most {MAX_COVERAGE_CELLS:,} (raise it or shrink mission.area)")

    def sensors_needed(self) -> list[tuple[str, str]]:
        """(sensor name, the field naming it) of every sensor this mission reads."""
        if self.type == "plume":
            p = self.plume or PlumeSeeking()
            return [(p.sensor, "mission.plume.sensor")] + ([(p.wind_sensor, "mission.plume.wind_sensor")]
                                                           if p.strategy == "seek" else [])
        if self.type == "wildfire" and self.wildfire is not None:
            w = self.wildfire
            return [(w.camera, "mission.wildfire.camera"), (w.tank, "mission.wildfire.tank"),
                    (w.alarm, "mission.wildfire.alarm")]
        return []

    @property
    def coverage_cell_m(self) -> float:
        """The side of a coverage cell, m: half the sensor radius, at least :data:`MIN_COVERAGE_CELL_M` (the
        analysis and the live estimate cut the area alike, mrswarm/results/coverage.py)."""
        return max(self.sensor_radius / 2.0, MIN_COVERAGE_CELL_M)

    @property
    def lane_spacing(self) -> float:
        return 2 * self.sensor_radius * (1 - self.overlap)


class Flight(Config, frozen=True):
    altitude: Annotated[float, Meta(ge=2.0, le=120.0, description="mission altitude above the origin, m")] = 15.0
    speed: Annotated[float, Meta(gt=0.0, le=15.0, description="cruise speed, m/s")] = 5.0
    safety_distance: Annotated[float, Meta(gt=0.0, le=100.0, description="separation avoidance keeps, m")] = 5.0
    collision_distance: Annotated[float, Meta(gt=0.0, le=20.0, description="closer counts as a collision, m")] = 1.0
    time_horizon: Annotated[float, Meta(gt=0.0, le=30.0, description="ORCA time horizon, s")] = 4.0
    avoidance: bool = True

    def __post_init__(self) -> None:
        if self.collision_distance >= self.safety_distance:
            raise ConfigError("collision_distance", "must be smaller than safety_distance")


class Security(Config, frozen=True):
    """Who may speak on the swarm's network (docs/security.md).

    ``mtls`` (the default): every Zenoh link is mutual TLS under access control generated from
    the swarm's roster, with throw-away credentials made per run in ``<run>/keys`` unless
    ``keys`` names the swarm's key directory (``mrswarm keys init``; relative to the current
    directory). ``off``: plain TCP, no access control; the run warns at start and its summary
    says so. YAML reads an unquoted ``off`` as false, so ``mode: off`` and ``security: off`` both work.
    """

    mode: Literal["mtls", "off"] | bool = "mtls"
    keys: Annotated[str, Meta(min_length=1)] | None = None

    def __post_init__(self) -> None:
        if self.mode is False:
            force_setattr(self, "mode", "off")
        elif self.mode is True:
            raise ConfigError("mode", "must be mtls or off, got true")
        if self.mode == "off" and self.keys is not None:
            raise ConfigError("keys", "a key directory needs mode mtls (security off uses no keys)")

    @property
    def enabled(self) -> bool:
        return self.mode == "mtls"


LARGE_FLEET_FEED_WINDOW_MS = 5.0
"""The edge feed's batch window (ms) a scenario of more than :data:`MESH_MAX_UAVS` UAVs takes unless
it sets ``network.feed_window_ms``. There the machine's CPU is what runs out, and every batch wakes
every UAV's Zenoh and pose-inlet threads: at N = 50 on 2 cores a 5 ms window carried an instant's
poses in 1.7 batches instead of 2.4 and cost each UAV 2–5 % less CPU (5.4 % with every round
lower, then 2.2 % in a second run), for 1.6 ms more transport age (p50) and 1.8 ms less age at
use: poses used as fresh as before (docs/benchmarks.md, 2026-11-29). Smaller swarms keep the
feed's 3 ms, the lower latency."""

MESH_MAX_UAVS = 25
"""Up to this many UAVs on one machine (every swarm of the airspace counted), the default network
is the peer mesh with a message per pose; above it, client mode through the edge router with the
edge pose feed. On 2 cores the peer mesh flew 25 UAVs in real time and 50 at RTF 0.46, client mode
50 at 0.999 (docs/benchmarks.md)."""


class Network(Config, frozen=True):
    """How the swarm's nodes meet and what they exchange (docs/scenarios.md).

    ``connectivity``, ``mode`` and ``pose_feed`` left unset are chosen for the fleet's size by
    :meth:`sized_for`, which :class:`Scenario` applies: a scenario always holds them resolved.
    """

    connectivity: Literal["discovery", "rendezvous"] | None = None  # default: discovery, or rendezvous in client mode (sized_for)
    mode: ZenohMode | None = None  # default: peer, or client above MESH_MAX_UAVS UAVs
    pose_feed: PoseFeed | None = None  # default: direct, or edge above MESH_MAX_UAVS UAVs or with interest
    lease_s: LeaseS = 3.0  # a node silent this long is gone; raise it on an overloaded machine (docs/scale.md)
    interest: Interest | None = None  # spatial interest (docs/scale.md); needs pose_feed: edge
    # the edge feed's batch window, ms: a pose waits at most this long at the edge for others to
    # share its batch (0: forward at once); with pose_feed: direct it is not used. Default: 3, or
    # LARGE_FLEET_FEED_WINDOW_MS above MESH_MAX_UAVS UAVs (sized_for)
    feed_window_ms: FeedWindowMs | None = None
    netem: NetemSpec | None = None  # netem shim: per-link impairments (docs/netem.md)
    discovery: DiscoveryService = field(default_factory=DiscoveryService)
    security: Security | bool = field(default_factory=Security)  # `security: off` (false) is short for mode off
    # every UAV ticks (and publishes its pose) on the wall clock's grid, all at the same instants,
    # its control as soon as the others' poses of the instant are in: poses used a few ms old
    # rather than 50, fewer and fuller edge-feed batches, less CPU (docs/scale.md). false: each
    # UAV on its own grid, no simultaneous wake-ups (the transport age of a crowded machine)
    align_ticks: bool = True

    def __post_init__(self) -> None:
        if self.security is False:
            force_setattr(self, "security", Security(mode="off"))
        elif self.security is True:
            force_setattr(self, "security", Security())
        if self.interest is not None and self.pose_feed == "direct":
            raise ConfigError("interest", "the edge pose feed does the filtering: set pose_feed: edge")
        if self.mode == "client" and self.connectivity == "discovery":
            raise ConfigError("mode", "mode 'client' routes through the edge router: set connectivity: rendezvous")

    @property
    def topology(self) -> tuple[Literal["discovery", "rendezvous"], ZenohMode, PoseFeed]:
        """``(connectivity, mode, pose_feed)`` as :meth:`sized_for` chose them (a scenario's network always is)."""
        c, m, f = self.connectivity, self.mode, self.pose_feed
        assert c is not None and m is not None and f is not None, "a Network outside a Scenario: call sized_for first"
        return c, m, f

    @property
    def feed_window_s(self) -> float:
        """The edge feed's batch window, s, as :meth:`sized_for` chose it (a scenario's network always has one)."""
        w = self.feed_window_ms
        assert w is not None, "a Network outside a Scenario: call sized_for first"
        return w / 1000.0

    def sized_for(self, uavs: int, needs_discovery: bool = False, pooled: bool = False, lockstep: bool = False) -> Network:
        """This network with every unset choice made for ``uavs`` UAVs on one machine.

        Up to :data:`MESH_MAX_UAVS`: the peer mesh (``discovery``, ``peer``, ``direct``), the
        lowest latency. Above it, every pose to every UAV costs more CPU than the machine has, so
        the unset choices become client mode through the edge router (``rendezvous``) and the
        edge pose feed: one link and one batch per window per UAV, the window
        :data:`LARGE_FLEET_FEED_WINDOW_MS` wide rather than 3 ms. ``needs_discovery`` (faults
        on the discovery server) keeps the peer topology. ``pooled`` (virtual UAVs in pools,
        ``fleet.pool``) chooses as for a large fleet: a pool's one session speaks for its UAVs
        through the edge router (docs/scale.md). A choice the scenario made is kept; client mode
        always means ``rendezvous``. ``lockstep`` (``time: lockstep``) keeps every pose direct: the
        lock-step clock relies on every message crossing the edge router in the order it was put.
        """
        big = uavs > MESH_MAX_UAVS or pooled
        mode = self.mode
        if mode is None:
            mode = "client" if big and self.connectivity != "discovery" and not needs_discovery else "peer"
        connectivity = self.connectivity or ("rendezvous" if mode == "client" else "discovery")
        # interest always means the edge feed (a lock-step scenario then refuses it, naming network.interest)
        feed = self.pose_feed or ("edge" if (big and not lockstep) or self.interest is not None else "direct")
        window = self.feed_window_ms
        if window is None:
            window = LARGE_FLEET_FEED_WINDOW_MS if big else DEFAULT_WINDOW * 1000.0
        return replace(self, connectivity=connectivity, mode=mode, pose_feed=feed, feed_window_ms=window)

    @property
    def secured(self) -> Security:
        """``security`` as a :class:`Security` (``__post_init__`` turned a bool into one)."""
        assert isinstance(self.security, Security)
        return self.security


class Spawn(Config, frozen=True):
    pattern: Literal["line", "grid"] = "grid"
    spacing: Annotated[float, Meta(gt=0.0, le=500.0, description="m")] = 8.0
    center: tuple[Coord, Coord] = (0.0, 0.0)  # x, y (ENU m)


class Fleet(Config, frozen=True):
    count: Annotated[int, Meta(ge=1, le=MAX_FLEET)]  # virtual UAVs (pooled above 25 by default: fleet.pool)
    first_id: UavId = 1
    spawn: Spawn = field(default_factory=Spawn)
    rtf: Rtf = 1.0
    flavour: Flavour = "px4"
    restart: Literal["no", "on-failure"] = "no"  # on-failure: a crashed UAV process is started again and rejoins
    # virtual UAVs per process: 1, a process each (isolated); more, pools of that many sharing one
    # process, one virtual FCU and one loop, each UAV still its own agent, id and keys (docs/scale.md);
    # auto: a process each up to POOL_ABOVE UAVs on the machine, above that one pool per core
    pool: Annotated[int, Meta(ge=1, le=256, description="virtual UAVs per process")] | Literal["auto"] = "auto"


DEFAULT_WAIT_S = 120.0  # s an external UAV's agent has to report ready (docs/scenarios.md, "Physical and external UAVs")


class Uav(Config, frozen=True):
    """One UAV of an explicit ``uavs`` list: a virtual one (its flight controller simulated by this
    run), or, with ``fcu``, one whose flight controller is external (a real autopilot, a SITL).

    An external UAV's agent is started by the runner on this machine against ``fcu``
    (``agent: runner``), or runs on the UAV's companion computer and joins the run by itself
    (``agent: companion``; the runner writes its configuration and waits for it). Either way it
    counts like any other UAV: separation, encounters, summary, figures, recording, map.
    """

    id: UavId
    start: tuple[Coord, Coord]  # x, y (ENU m); an external UAV: where it stands (its autopilot's home)
    goal: tuple[Coord, Coord] | None = None  # goto missions
    rtf: Rtf = 1.0
    heading: Heading = 0.0  # initial heading, degrees from north
    flavour: Flavour = "px4"  # px4, or ardupilot for MAVProxy users (docs/gcs.md)
    # an external flight controller's MAVLink connection string (udpin:127.0.0.1:14540 for PX4 SITL,
    # tcp:127.0.0.1:5760 for ArduPilot SITL, serial:/dev/ttyACM0:921600 for a Pixhawk); None: a virtual FCU
    fcu: Annotated[str, Meta(min_length=1, max_length=256)] | None = None
    realm: Literal["virtual", "physical"] | None = None  # default: physical with an external fcu, else virtual
    agent: Literal["runner", "companion"] = "runner"  # who runs an external UAV's agent: this machine, or its companion
    # s the runner waits for an external UAV's agent to report ready (GPS lock, EKF, someone starting the companion)
    wait_s: Annotated[float, Meta(gt=0.0, le=3600.0, description="s")] = DEFAULT_WAIT_S

    def __post_init__(self) -> None:
        if self.fcu is None:
            for name, value, default in (("realm", self.realm, "virtual"), ("wait_s", self.wait_s, DEFAULT_WAIT_S),
                                         ("agent", self.agent, "runner")):
                if value is not None and value != default:
                    raise ConfigError(name, f"only for a UAV whose flight controller is external: give its fcu "
                                            f"(e.g. udpin:127.0.0.1:14540), or leave {name} out")
            force_setattr(self, "realm", "virtual")
            return
        from uav_stack.config import fcu_url_problem

        problem = fcu_url_problem(self.fcu)
        if problem:
            raise ConfigError("fcu", f"{self.fcu}: {problem}")
        virtual_only: list[tuple[str, object, object, str]] = [
            ("rtf", self.rtf, 1.0, "the real-time factor of a virtual FCU"),
            ("flavour", self.flavour, "px4", "the autopilot a virtual FCU emulates"),
            ("heading", self.heading, 0.0, "a virtual FCU's initial heading")]
        for name, given, usual, what in virtual_only:
            if given != usual:
                raise ConfigError(name, f"{what}; UAV {self.id}'s flight controller is external ({self.fcu})")
        if self.realm is None:
            force_setattr(self, "realm", "physical")

    @property
    def external(self) -> bool:
        """Its flight controller is not this run's (``fcu`` given)."""
        return self.fcu is not None

    @property
    def realm_name(self) -> Literal["virtual", "physical"]:
        """``realm`` as ``__post_init__`` resolved it."""
        assert self.realm is not None
        return self.realm


def uav_list(fleet: Fleet | None, uavs: tuple[Uav, ...] | None) -> list[Uav]:
    """A swarm's UAVs: the explicit list, or the fleet's spawn points."""
    if uavs is not None:
        return list(uavs)
    assert fleet is not None
    points = spawn_points(fleet.count, fleet.spawn)
    return [Uav(id=fleet.first_id + i, start=p, rtf=fleet.rtf, flavour=fleet.flavour) for i, p in enumerate(points)]


class OtherSwarm(Config, frozen=True):
    """Another swarm sharing the airspace (docs/world.md, "Shared airspace"): its own name and
    discovery key, its own UAVs and (by default the scenario's) mission. The runner starts and
    commands it beside the scenario's swarm, each through its own session; the two never see
    each other's data, only the airspace feed of the world service tells each where the other
    swarm's UAVs are."""

    swarm: Annotated[str, Meta(pattern=SWARM_RE.pattern)]
    fleet: Fleet | None = None
    uavs: tuple[Uav, ...] | None = None
    mission: Mission | None = None
    key: Key | None = None  # its discovery key; None: a fresh one per run

    def __post_init__(self) -> None:
        if (self.fleet is None) == (self.uavs is None):
            raise ConfigError("", "give either 'fleet' or 'uavs', not both")

    def uav_list(self) -> list[Uav]:
        return uav_list(self.fleet, self.uavs)


class Gcs(Config, frozen=True):
    """Ground-station access (docs/gcs.md): each agent's MAVLink router and the override limits."""

    mavlink: bool = True  # route every UAV's FCU to ground stations (QGC on this machine sees every UAV)
    host: Annotated[str, Meta(min_length=1, max_length=253)] = "127.0.0.1"  # where the ground station (QGC) listens
    port: Port | None = 14550  # UAVs of shard k (ids 240k+1..240k+240) send to port + k
    listen_base: Port | None = None  # UAV i also listens on listen_base + i
    geofence: Area | None = None  # goto limits; default: the mission area, or starts and goals + 50 m
    max_alt: Annotated[float, Meta(gt=2.0, le=1000.0, description="highest goto altitude above the origin, m")] = 120.0
    # the MAVLink signing key of every router's ground-station links (docs/security.md); None: the run's own
    # (mavlink.key in its key directory, made with its certificates)
    signing: MavlinkSigning | None = None
    # route unsigned frames from ground stations too (MAVSDK cannot sign): any local process can command every UAV
    allow_unsigned: bool = False
    # the run also ends once every UAV is on the ground, however it got there (a ground station's land --all, a
    # takeover); by default only the duration or the mission's own end (every UAV done, or landed by its mission) end it
    landing_ends_run: bool = False

    def __post_init__(self) -> None:
        if self.signing is not None and not self.mavlink:
            raise ConfigError("signing", "signs the MAVLink routers' links: set gcs.mavlink: true too")
        if self.allow_unsigned and not self.mavlink:
            raise ConfigError("allow_unsigned", "opens the MAVLink routers' links: set gcs.mavlink: true too")


class Scenario(Config, kw_only=True, frozen=True):
    name: Annotated[str, Meta(pattern=r"^[A-Za-z0-9_\-]{1,64}$")]
    description: str = ""
    swarm: Annotated[str, Meta(pattern=SWARM_RE.pattern)] = "alpha"
    seed: Annotated[int, Meta(ge=0)] = 0
    duration: Annotated[float, Meta(gt=0.0, le=7200.0, description="seconds of mission after the start command")]
    origin: Origin
    network: Network = field(default_factory=Network)
    flight: Flight = field(default_factory=Flight)
    mission: Mission
    fleet: Fleet | None = None
    uavs: tuple[Uav, ...] | None = None
    gcs: Gcs = field(default_factory=Gcs)
    runtime: Literal["process", "docker"] = "process"
    docker: ContainerSettings = field(default_factory=ContainerSettings)
    failsafe: FailsafeConfig = field(default_factory=FailsafeConfig)  # companion failsafes (docs/reliability.md)
    faults: tuple[FaultSpec, ...] = ()  # chaos: faults injected during the mission (docs/reliability.md)
    world: WorldConfig | None = None  # the world service: plume, fire, targets, zones, sensors (docs/world.md)
    other_swarms: tuple[OtherSwarm, ...] = ()  # more swarms in the same airspace
    # real: every part on the wall clock; lockstep: the pools of virtual UAVs, the network shim and the runner
    # advance in simulated time together, as fast as the CPU allows (docs/campaigns.md)
    time: Literal["real", "lockstep"] = "real"

    def __post_init__(self) -> None:
        if self.uavs is not None:
            if not self.uavs:
                raise ConfigError("uavs", "at least one UAV")
            ids = [u.id for u in self.uavs]
            dup = sorted({i for i in ids if ids.count(i) > 1})
            if dup:
                raise ConfigError("uavs", f"duplicate UAV ids {dup}")
        if (self.fleet is None) == (self.uavs is None):
            raise ConfigError("", "give either 'fleet' (count + spawn pattern) or an explicit 'uavs' list, not both")
        uavs = self.uav_list()
        check_per_uav(self.mission, {u.id for u in uavs})
        if self.mission.type == "goto":
            missing = [u.id for u in uavs if u.goal is None]
            if missing:
                raise ConfigError("mission", f"a goto mission needs a goal for every UAV; missing for {missing}")
        top = max(u.id for u in uavs)
        if top > 65535:
            raise ConfigError("fleet.first_id", "UAV ids must stay <= 65535")
        self._check_other_swarms()
        needs_discovery = any("discovery" in f.kind for f in self.faults)
        lockstep = self.time == "lockstep"
        force_setattr(self, "network", self.network.sized_for(len(self.all_uavs()), needs_discovery, self.pool_size > 1,
                                                              lockstep))
        self._check_world()
        self._check_spawn_spacing(self.all_uavs())
        for u in self.all_uavs():
            if max(abs(u.start[0]), abs(u.start[1])) > MAX_OFFSET_M:
                raise ConfigError("fleet.spawn" if self.fleet is not None else "uavs",
                                  f"UAV {u.id} spawns at {u.start}, farther than {MAX_OFFSET_M:g} m from the origin")
        if self.faults:
            check_against(self.faults, {u.id for u in uavs}, self.duration, self.network.topology[0])
        self._check_external()
        self._check_pools()
        if lockstep:
            self._check_lockstep()
        g = self.gcs
        if g.mavlink:

            if g.port is not None and g.port + allocate_sysid(top)[0] > 65535:
                raise ConfigError("gcs.port", "plus the highest shard is above 65535")
            if g.listen_base is not None and g.listen_base + top > 65535:
                raise ConfigError("gcs.listen_base", f"plus the highest UAV id ({top}) is above 65535")
            if g.port is None and g.listen_base is None:
                raise ConfigError("gcs.mavlink", "needs gcs.port or gcs.listen_base")

    def _check_other_swarms(self) -> None:
        names = [self.swarm] + [o.swarm for o in self.other_swarms]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ConfigError("other_swarms", f"swarm {dup[0]!r} listed twice")
        ids = [u.id for u in self.all_uavs()]
        dup_ids = sorted({i for i in ids if ids.count(i) > 1})
        if dup_ids:  # every UAV is a process named by its id, and writes uav<id>.csv in the run folder
            raise ConfigError("other_swarms", f"UAV ids must differ across swarms; {dup_ids} appear twice")
        for i, o in enumerate(self.other_swarms):
            m = o.mission or self.mission
            if m.type == "goto" and any(u.goal is None for u in o.uav_list()):
                raise ConfigError(f"other_swarms.{i}", "a goto mission needs a goal for every UAV")

    @property
    def pool_size(self) -> int:
        """Virtual UAVs per process, ``fleet.pool`` resolved: ``auto`` is 1 up to :data:`POOL_ABOVE`
        UAVs on the machine, with the container runtime, or with process faults in the schedule;
        above, one pool per core."""
        pool = self.fleet.pool if self.fleet is not None else 1
        if pool != "auto":
            return pool
        n = len(self.all_uavs())
        if self.time == "lockstep":  # only pools follow the lock-step clock: one per core
            return max(2, min(MAX_POOL, math.ceil(n / usable_cores())))
        if n <= POOL_ABOVE or self.runtime != "process" or any(f.kind in UAV_PROCESS for f in self.faults):
            return 1
        return min(MAX_POOL, math.ceil(n / usable_cores()))

    def _check_lockstep(self) -> None:
        """``time: lockstep``: what the lock-step clock steps (pools of virtual UAVs of one swarm, through
        the edge router, every pose direct) is all the run may have."""
        def no(name: str, why: str) -> ConfigError:
            return ConfigError(name, f"{why}, which lock-step time cannot step (time: lockstep; docs/campaigns.md)")

        external = [u.id for u in self.all_uavs() if u.external]
        if external:
            raise no("uavs", f"UAV(s) {external} fly a physical or external flight controller on the wall clock")
        if self.runtime != "process":
            raise no("runtime", "the container runtime runs a UAV per container")
        if self.fleet is None:
            raise no("uavs", "an explicit uavs list is flown a process per UAV; give a fleet")
        if self.pool_size < 2:
            raise no("fleet.pool", "fleet.pool: 1 runs a process per UAV")
        for i, f in enumerate(self.faults):  # as with a fleet.pool given (_check_pools): lock-step's pools are 'auto' too
            if f.kind in UAV_PROCESS:
                raise no(f"faults.{i}", f"{f.kind} acts on a UAV's process, which its pool shares with other UAVs")
        if self.fleet.restart != "no":
            raise no("fleet.restart", "a restarted pool would start its clock again")
        if self.fleet.rtf != 1.0:
            raise no("fleet.rtf", f"a target real-time factor ({self.fleet.rtf:g}) paces the FCU on the wall clock")
        if self.other_swarms:
            raise no("other_swarms", "a second swarm has a clock of its own")
        net = self.network
        connectivity, mode, feed = net.topology
        if mode != "client" or connectivity != "rendezvous":
            raise no("network.mode", f"{mode} mode over {connectivity} has links that bypass the edge router")
        if net.interest is not None:
            raise no("network.interest", "spatial interest batches poses on the wall clock")
        if feed != "direct":
            raise no("network.pose_feed", "the edge feed batches poses on the wall clock")

    def _check_pools(self) -> None:
        """Pools (``fleet.pool`` > 1): the process runtime hosts them; a process fault would hit a whole pool."""
        if self.fleet is None or self.fleet.pool in (1, "auto"):
            return
        assert isinstance(self.fleet.pool, int)
        if self.runtime != "process":
            raise ConfigError("fleet.pool", "pools of virtual UAVs run with the process runtime (runtime: process); "
                                            "the container runtime runs a container per UAV")
        for i, f in enumerate(self.faults):
            if f.kind in UAV_PROCESS:
                raise ConfigError(f"faults.{i}", f"{f.kind} acts on a UAV's process, which a pool shares with "
                                                 f"{self.fleet.pool - 1} other UAVs: use fleet.pool: 1 for process faults")

    def pool_layout(self) -> list[tuple[str, tuple[int, ...]]]:
        """The pools of this run, each a swarm and the ids of its virtual UAVs, in the order they
        start (``pool1``, ``pool2``, ...); empty with a process per UAV. A pool holds UAVs of one
        swarm (one shared session, one pool certificate) with one flavour and one RTF (one virtual
        FCU steps a pool) and one MAVLink shard (a virtual FCU's vehicles have distinct system ids:
        uav_stack/sysid.py), at most ``fleet.pool`` of them."""
        size = self.pool_size
        if size == 1:
            return []
        groups: dict[tuple[str, str, float, int], list[int]] = {}
        for swarm, uavs in [(self.swarm, self.uav_list()), *((o.swarm, o.uav_list()) for o in self.other_swarms)]:
            for u in uavs:
                if not u.external:
                    groups.setdefault((swarm, u.flavour, u.rtf, allocate_sysid(u.id)[0]), []).append(u.id)
        return [(key[0], tuple(g[i:i + size])) for key, g in groups.items() for i in range(0, len(g), size)]

    def pool_numbers(self, swarm: str) -> dict[int, tuple[int, ...]]:
        """The pools of :meth:`pool_layout` in ``swarm``, by number: pool ``k`` is the layout's k-th
        (``pool<k>``, certificate ``pool-<k>``), with the UAVs its certificate speaks for."""
        return {k: uavs for k, (s, uavs) in enumerate(self.pool_layout(), start=1) if s == swarm}

    def pools(self, configs: list[VirtualUavConfig]) -> list[list[VirtualUavConfig]]:
        """The virtual UAVs grouped into the processes that host them: one each, or the pools of
        :meth:`pool_layout`."""
        layout = self.pool_layout()
        if not layout:
            return [[c] for c in configs]
        by_id = {c.agent.uav: c for c in configs}
        return [[by_id[u] for u in uavs] for _, uavs in layout]

    def _check_external(self) -> None:
        """External flight controllers: process runtime only, no faults injected into them."""
        external = {u.id for u in self.external_uavs()}
        if not external:
            return
        if self.runtime == "docker":
            places = [("uavs", self.uavs or ())] + [(f"other_swarms.{j}.uavs", o.uavs or ())
                                                    for j, o in enumerate(self.other_swarms)]
            where, u = next((f"{name}.{i}.fcu", u) for name, us in places for i, u in enumerate(us) if u.external)
            raise ConfigError(where, f"UAV {u.id}'s flight controller is external: its agent runs as a process on this "
                                     "machine or on its companion (runtime: process); the container runtime runs virtual UAVs")
        for i, f in enumerate(self.faults):
            hit = sorted(set(f.targets()) & external)
            if hit:
                raise ConfigError(f"faults.{i}", f"UAV {hit[0]}'s flight controller is external: faults are injected "
                                                 "into virtual UAVs only")

    def _check_world(self) -> None:
        missions = [("mission", self.mission)] + [(f"other_swarms.{i}.mission", o.mission) for i, o in
                                                   enumerate(self.other_swarms) if o.mission is not None]
        w = self.world
        sensors = {s.name for s in w.sensors} if w is not None else set()
        for where, m in missions:
            needed = m.sensors_needed()
            if needed and w is None:
                raise ConfigError("world", f"a {m.type} mission ({where}) needs a world section with its sensors")
            for name, field_name in needed:
                if name not in sensors:
                    raise ConfigError(f"{where}.{field_name.split('.', 1)[1]}",
                                      f"no sensor {name!r} in world.sensors (there: {', '.join(sorted(sensors)) or 'none'})")
            if m.type == "wildfire" and m.wildfire is not None and w is not None \
                    and m.wildfire.spray not in {a.name for a in w.actuators}:
                raise ConfigError(f"{where}.wildfire.spray", f"no actuator {m.wildfire.spray!r} in world.actuators")

    def _check_spawn_spacing(self, uavs: list[Uav]) -> None:
        pts = [u.start for u in uavs]
        for i in range(len(pts)):
            for j in range(i + 1, len(pts)):
                d = math.dist(pts[i], pts[j])
                if d < self.flight.safety_distance:
                    raise ConfigError("uavs" if self.uavs is not None else "fleet.spawn",
                                      f"UAVs spawn {d:.1f} m apart, closer than flight.safety_distance "
                                      f"({self.flight.safety_distance} m)")

    def uav_list(self) -> list[Uav]:
        """The UAVs of the scenario's swarm (``all_uavs``: those of the other swarms too)."""
        return uav_list(self.fleet, self.uavs)

    def all_uavs(self) -> list[Uav]:
        return self.uav_list() + [u for o in self.other_swarms for u in o.uav_list()]

    def swarm_of(self) -> dict[int, str]:
        """The swarm of every UAV id."""
        out = {u.id: self.swarm for u in self.uav_list()}
        for o in self.other_swarms:
            out.update({u.id: o.swarm for u in o.uav_list()})
        return out

    def geofence(self) -> tuple[float, float, float, float]:
        """Where a ground station may send a UAV (goto): gcs.geofence, else the mission area, else
        the box around every start and goal plus 50 m."""
        if self.gcs.geofence is not None:
            return self.gcs.geofence.as_tuple()
        if self.mission.area is not None:
            return self.mission.area.as_tuple()
        pts = [u.start for u in self.all_uavs()] + [u.goal for u in self.all_uavs() if u.goal is not None]
        xs, ys = [p[0] for p in pts], [p[1] for p in pts]
        return (min(xs) - 50.0, max(xs) + 50.0, min(ys) - 50.0, max(ys) + 50.0)

    def mavlink_endpoints(self, uav: int) -> tuple[str, ...]:
        """The router endpoints of one UAV (docs/gcs.md, "System ids and ports")."""
        g = self.gcs
        if not g.mavlink:
            return ()
        from uav_stack.sysid import allocate_sysid

        out = []
        if g.port is not None:
            out.append(f"udpout:{g.host}:{g.port + allocate_sysid(uav)[0]}")
        if g.listen_base is not None:
            out.append(f"udpin:{g.host}:{g.listen_base + uav}")
        return tuple(out)

    # ---- the network plan (deploy/plan.py) --------------------------------------------------------
    def network_plan(self, keys: Mapping[str, Path | None]) -> NetworkPlan:
        """The run's network, planned once (``deploy/plan.py``) for every runtime to place: the swarms named
        in ``keys`` (each with its key directory; None: plain TCP), in the airspace's order, the scenario's
        own first (a Swarm stack deploys that one only), on the network this scenario chose. Every swarm
        without a discovery key in the scenario gets a fresh one for this run. The pools of
        :meth:`pool_layout`, numbered as their certificates are (``pool-<n>``), go with it: with
        spatial interest the edge sends each pool one near batch (docs/scale.md)."""
        from discovery.protocol import new_key

        own = self.network
        connectivity, mode, pose_feed = own.topology
        given = {self.swarm: own.discovery.key} | {o.swarm: o.key for o in self.other_swarms}
        if unknown := [s for s in keys if s not in given]:
            raise ValueError(f"no swarm {unknown} in scenario {self.name}")
        if self.swarm not in keys:
            raise ValueError(f"the plan of scenario {self.name} starts with its own swarm, {self.swarm}")
        swarms = tuple(SwarmPlan(s, keys[s], given[s] or new_key()) for s in given if s in keys)
        pools = {s.name: tuple(PoolMembers(number=k, uavs=uavs) for k, uavs in self.pool_numbers(s.name).items())
                 for s in swarms}
        return NetworkPlan(swarms, connectivity, mode, pose_feed, feed_window_s=own.feed_window_s, interest=own.interest,
                           discovery=own.discovery, lease_s=own.lease_s, pools={k: v for k, v in pools.items() if v})

    # ---- per-UAV configuration for the runtime ----------------------------------------------
    def virtual_uav_configs(self, network: NetworkConfig, record_dir: str | None,
                            other: OtherSwarm | None = None, mavlink_key: str | None = None) -> list[VirtualUavConfig]:
        """One UAV process's configuration per virtual UAV of the scenario's swarm (or of ``other``), on
        the network the runtime started (the external ones: :meth:`external_agent_configs`). Their MAVLink
        signing key: ``gcs.signing``, else ``mavlink_key`` (a run without key directory makes one), else
        ``mavlink.key`` in their key directory."""
        frame = LocalFrame(self.origin.point())
        out = []
        for u, agent in self._agent_configs(network, record_dir, other, mavlink_key):
            if u.external:
                continue
            lat, lon, alt = frame.to_geodetic(u.start[0], u.start[1], 0.0)
            out.append(VirtualUavConfig(agent=agent, home=GeoPoint(lat, lon, alt), target_rtf=u.rtf,
                                        heading=math.radians(u.heading), flavour=u.flavour))
        return out

    def external_agent_configs(self, network: NetworkConfig, record_dir: str | None,
                               other: OtherSwarm | None = None, mavlink_key: str | None = None) -> list[AgentConfig]:
        """The agent's configuration of every UAV whose flight controller is external (``uavs[].fcu``), for
        ``mrswarm agent --config``: the runner's own (``agent: runner``, recording into ``record_dir``)
        or a companion computer's (``agent: companion``, recording where its ``--record-dir`` says)."""
        return [replace(agent, record_dir=record_dir if u.agent == "runner" else None)
                for u, agent in self._agent_configs(network, record_dir, other, mavlink_key) if u.external]

    def external_uavs(self) -> list[Uav]:
        """Every UAV of the airspace whose flight controller is external."""
        return [u for u in self.all_uavs() if u.external]

    def start_geodetic(self, u: Uav) -> GeoPoint:
        """Where ``u`` starts as latitude, longitude and altitude (an external autopilot's home goes there)."""
        lat, lon, alt = LocalFrame(self.origin.point()).to_geodetic(u.start[0], u.start[1], 0.0)
        return GeoPoint(lat, lon, alt)

    def _agent_configs(self, network: NetworkConfig, record_dir: str | None,
                       other: OtherSwarm | None, mavlink_key: str | None) -> list[tuple[Uav, AgentConfig]]:
        origin = self.origin.point()
        fl = self.flight
        m = self.mission if other is None or other.mission is None else other.mission
        swarm, uavs = (self.swarm, self.uav_list()) if other is None else (other.swarm, other.uav_list())
        w = self.world
        if self.network.netem is not None:  # the per-link seeds default to the scenario's seed
            netem = to_builtins(self.network.netem)
            netem.setdefault("seed", self.seed)
            network = replace(network, netem=netem)
        out = []
        for u in uavs:
            behaviour, params = uav_behaviour(m, u.id)
            mission = MissionConfig(
                type=m.type,
                strategy=m.strategy,
                area=m.area.as_tuple() if m.area else (-1.0, 1.0, -1.0, 1.0),
                lane_spacing=m.lane_spacing,
                goal=u.goal,
                land_when_done=m.land_when_done,
                plume=m.plume,
                wildfire=m.wildfire,
                behaviour=behaviour,
                params=params,
                budget_ms=m.budget_ms, max_faults=m.max_faults, hold_s=m.hold_s,
            )
            agent = AgentConfig(
                swarm=swarm, uav=u.id, origin=origin, fcu=u.fcu or "", realm=u.realm_name, altitude=fl.altitude,
                speed=fl.speed, seed=self.seed, autostart=False, record_dir=record_dir, mission=mission,
                avoidance=AvoidanceConfig(enabled=fl.avoidance, safety_distance=fl.safety_distance, time_horizon=fl.time_horizon,
                                          zones=w.zones if w is not None else ()),
                network=network,
                gcs=GcsConfig(mavlink_endpoints=self.mavlink_endpoints(u.id), geofence=self.geofence(), max_alt=self.gcs.max_alt,
                              signing=self.gcs.signing or MavlinkSigning(key_file=mavlink_key),
                              allow_unsigned=self.gcs.allow_unsigned),
                failsafe=self.failsafe,
                sensors=w.sensors if w is not None else (), actuators=w.actuators if w is not None else (),
                traffic=w is not None and w.airspace.feed and bool(self.other_swarms),
                align_ticks=self.network.align_ticks,
            )
            out.append((u, agent))
        return out


def spawn_points(n: int, spawn: Spawn) -> list[tuple[float, float]]:
    cx, cy = spawn.center
    s = spawn.spacing
    if spawn.pattern == "line":
        return [(cx + (i - (n - 1) / 2) * s, cy) for i in range(n)]
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    return [(cx + (i % cols - (cols - 1) / 2) * s, cy + (i // cols - (rows - 1) / 2) * s) for i in range(n)]


# ---- loading ------------------------------------------------------------------------------------
def _set_path(data: dict[str, Any], dotted: str, value: Any) -> None:
    parts = dotted.split(".")
    cur: Any = data
    for i, p in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(cur, list):
            try:
                idx = int(p)
                target = cur[idx]
            except (ValueError, IndexError):
                raise ScenarioError(f"--set {dotted}: '{p}' is not an index of a {len(cur)}-item list") from None
            if last:
                cur[idx] = value
            else:
                cur = target
        elif isinstance(cur, dict):
            if last:
                cur[p] = value
            else:
                cur = cur.setdefault(p, {})
        else:
            raise ScenarioError(f"--set {dotted}: '{'.'.join(parts[:i])}' is not a mapping or list")


def parse_override(text: str) -> tuple[str, Any]:
    if "=" not in text:
        raise ScenarioError(f"--set {text!r}: expected key.path=value")
    key, raw = text.split("=", 1)
    try:
        return key.strip(), strict_yaml.load(raw)
    except yaml.YAMLError as exc:
        raise ScenarioError(f"--set {text!r}: bad value: {exc}") from None


def parse_scenario(data: Any, where: str = "scenario") -> Scenario:
    """Validate a scenario mapping; :class:`ScenarioError` reads ``<where>: <field>: <what is wrong>``."""
    try:
        scn = convert(data, Scenario)
    except ConfigError as exc:
        raise ScenarioError(f"{where}: {exc}") from None
    if scn.gcs.mavlink:
        problem = resolve_problem(scn.gcs.host)
        if problem:
            raise ScenarioError(f"{where}: gcs.host: {problem}")
    return scn


def resolve_problem(host: str, timeout: float = RESOLVE_TIMEOUT_S) -> str:
    """"" if ``host`` resolves to an address, else why not (bounded: a dead resolver cannot hang validation)."""
    import concurrent.futures
    import socket

    pool = concurrent.futures.ThreadPoolExecutor(1)
    try:
        pool.submit(socket.getaddrinfo, host, None).result(timeout)
    except concurrent.futures.TimeoutError:
        return f"{host!r} did not resolve within {timeout:g} s"
    except (OSError, UnicodeError) as exc:
        return f"cannot resolve {host!r}: {getattr(exc, 'strerror', None) or exc}"
    finally:
        pool.shutdown(wait=False)
    return ""


def read_scenario_text(path: Path) -> str:
    """The file's text, if it is a regular UTF-8 file of at most :data:`MAX_SCENARIO_BYTES` (never blocks on a FIFO
    or reads a device without end)."""
    try:
        st = os.stat(path)
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read: {exc.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        kind = "a folder" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode) else \
            "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "not a regular file"
        raise ScenarioError(f"{path}: not a regular file ({kind}); a scenario is a YAML file")
    if st.st_size > MAX_SCENARIO_BYTES:
        raise ScenarioError(f"{path}: {st.st_size:,} bytes; a scenario is at most {MAX_SCENARIO_BYTES:,} bytes")
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_SCENARIO_BYTES + 1)
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read: {exc.strerror}") from None
    if len(data) > MAX_SCENARIO_BYTES:
        raise ScenarioError(f"{path}: more than {MAX_SCENARIO_BYTES:,} bytes; a scenario is at most that")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{path}: not UTF-8 text (byte {exc.start}: {data[exc.start:exc.start + 1]!r}); "
                            "a scenario is a YAML file") from None


def load_scenario(path: str | Path, overrides: list[str] | None = None, notes: list[str] | None = None) -> Scenario:
    """The scenario file with ``--set`` overrides, validated. A ``duration`` override shortens the schedule too:
    the faults that no longer fit are left out, and ``notes`` (if given) gets a sentence for each, and for a
    timed world event that will not come (:func:`shortened`)."""
    path = Path(path)
    text = read_scenario_text(path)
    try:
        data = strict_yaml.load(text)  # duplicate keys and over-deep nesting are errors with their line, too
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark else ""
        raise ScenarioError(f"{path}{where}: not valid YAML: {getattr(exc, 'problem', exc)}") from None
    if not isinstance(data, dict):
        raise ScenarioError(f"{path}: a scenario must be a YAML mapping, got {type(data).__name__}")
    shorter = False
    for o in overrides or []:
        key, value = parse_override(o)
        _set_path(data, key, value)
        shorter = shorter or key == "duration"
    said = fit_to_duration(data, data["duration"]) if shorter and isinstance(data.get("duration"), int | float) else []
    scn = parse_scenario(data, str(path))
    if shorter:
        said += shortened(scn)
    if notes is not None:
        notes += said
    return scn


def shortened(scn: Scenario) -> list[str]:
    """What a shortened mission will not see besides its faults: a wind turn after its end."""
    w = scn.world
    if w is not None and w.wind.turn_after_s is not None and w.wind.turn_after_s >= scn.duration:
        return [f"world.wind.turn_after_s: the wind turns at {w.wind.turn_after_s:g} s, after the {scn.duration:g} s mission: "
                "it will not turn"]
    return []
