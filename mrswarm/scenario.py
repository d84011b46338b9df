"""Scenario files: YAML validated on load, errors that name the file and the field.

A scenario describes one experiment: the swarm, its origin, the mission, the UAVs and
how long to fly. ``load_scenario`` applies ``--set a.b=value`` overrides before validation,
so an override that breaks a rule is reported like a bad file.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator
from pydantic_core import PydanticCustomError

from uav_stack.config import AgentConfig, AvoidanceConfig, GcsConfig, MissionConfig, NetworkConfig, VirtualUavConfig
from uav_stack.geo import GeoPoint, LocalFrame


class ScenarioError(ValueError):
    """A scenario that cannot be used; the message names the file and every bad field."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Origin(_Model):
    lat: float = Field(ge=-90, le=90)
    lon: float = Field(ge=-180, le=180)
    alt: float = Field(ge=-500, le=9000, description="metres AMSL")


class Area(_Model):
    x_min: float
    x_max: float
    y_min: float
    y_max: float

    @model_validator(mode="after")
    def _ordered(self) -> Area:
        if not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ValueError("need x_min < x_max and y_min < y_max")
        if (self.x_max - self.x_min) * (self.y_max - self.y_min) > 25e6:
            raise ValueError("area larger than 25 km^2")
        return self

    def as_tuple(self) -> tuple[float, float, float, float]:
        return (self.x_min, self.x_max, self.y_min, self.y_max)


class Mission(_Model):
    type: Literal["coverage", "goto", "idle"] = "coverage"
    strategy: Literal["lawnmower", "random"] = "lawnmower"
    area: Area | None = None
    sensor_radius: float = Field(10.0, gt=0, le=200, description="footprint radius used for coverage, m")
    overlap: float = Field(0.2, ge=0, lt=0.9)
    land_when_done: bool = False

    @model_validator(mode="after")
    def _needs_area(self) -> Mission:
        if self.type == "coverage" and self.area is None:
            raise ValueError("a coverage mission needs an area")
        return self

    @property
    def lane_spacing(self) -> float:
        return 2 * self.sensor_radius * (1 - self.overlap)


class Flight(_Model):
    altitude: float = Field(15.0, ge=2, le=120, description="mission altitude above the origin, m")
    speed: float = Field(5.0, gt=0, le=15)
    safety_distance: float = Field(5.0, gt=0, le=100, description="separation avoidance keeps, m")
    collision_distance: float = Field(1.0, gt=0, le=20, description="closer than this counts as a collision, m")
    time_horizon: float = Field(4.0, gt=0, le=30)
    avoidance: bool = True

    @model_validator(mode="after")
    def _distances(self) -> Flight:
        if self.collision_distance >= self.safety_distance:
            raise ValueError("collision_distance must be smaller than safety_distance")
        return self


class Discovery(_Model):
    key: str | None = Field(None, min_length=16, description="the swarm's discovery key; default: a fresh one per run")
    period: float = Field(1.0, ge=0.2, le=10, description="seconds between beacons")
    ttl: float = Field(3.0, gt=0, le=60, description="the server forgets nodes silent this long, s")

    @model_validator(mode="after")
    def _ttl(self) -> Discovery:
        if self.ttl < 2 * self.period:
            raise ValueError("ttl must be at least two beacon periods")
        return self


class Network(_Model):
    connectivity: Literal["discovery", "rendezvous"] = "discovery"
    mode: Literal["peer", "client"] = "peer"
    pose_feed: Literal["direct", "edge"] = "direct"
    netem: dict[str, Any] | None = Field(None, description="netem shim: per-link impairments (docs/netem.md)")

    @field_validator("netem")
    @classmethod
    def _netem(cls, v: dict[str, Any] | None) -> dict[str, Any] | None:
        if v is not None:
            from swarmnet.netem import NetemConfigError, parse_netem

            try:
                parse_netem(v)
            except NetemConfigError as exc:  # reads "network.netem: v2v.loss.p: must be ..."
                raise PydanticCustomError("netem_config", "{error}", {"error": str(exc)}) from None
        return v

    discovery: Discovery = Discovery()

    @model_validator(mode="before")
    @classmethod
    def _default_connectivity(cls, data: Any) -> Any:
        # client mode means "through the edge router": it implies the rendezvous topology
        if isinstance(data, dict) and "connectivity" not in data and data.get("mode") == "client":
            data = {**data, "connectivity": "rendezvous"}
        return data

    @model_validator(mode="after")
    def _client_needs_router(self) -> Network:
        if self.mode == "client" and self.connectivity != "rendezvous":
            raise ValueError("mode 'client' routes through the edge router: set connectivity: rendezvous")
        return self


class Spawn(_Model):
    pattern: Literal["line", "grid"] = "grid"
    spacing: float = Field(8.0, gt=0, le=500)
    center: tuple[float, float] = (0.0, 0.0)


class Fleet(_Model):
    count: int = Field(ge=1, le=500)
    first_id: int = Field(1, ge=1, le=65535)
    spawn: Spawn = Spawn()
    rtf: float = Field(1.0, gt=0, le=1.0, description="target real-time factor of the virtual FCUs")
    flavour: Literal["px4", "ardupilot"] = Field("px4", description="autopilot the virtual FCUs emulate")


class Uav(_Model):
    id: int = Field(ge=1, le=65535)
    start: tuple[float, float]
    goal: tuple[float, float] | None = None
    rtf: float = Field(1.0, gt=0, le=1.0)
    heading: float = Field(0.0, description="initial heading, degrees from north")
    flavour: Literal["px4", "ardupilot"] = Field("px4", description="px4, or ardupilot for MAVProxy users (docs/gcs.md)")


class Gcs(_Model):
    """Ground-station access (docs/gcs.md): each agent's MAVLink router and the override limits."""

    mavlink: bool = Field(False, description="route every UAV's FCU to ground stations")
    host: str = Field("127.0.0.1", min_length=1, max_length=253, description="where the ground station (QGC) listens")
    port: int | None = Field(14550, ge=1, le=65535, description="UAVs of shard k (ids 240k+1..240k+240) send to port + k")
    listen_base: int | None = Field(None, ge=1, le=65535, description="UAV i also listens on listen_base + i")
    geofence: Area | None = Field(None, description="goto limits; default: the mission area, or starts and goals + 50 m")
    max_alt: float = Field(120.0, gt=2, le=1000, description="highest goto altitude above the origin, m")


class Docker(_Model):
    """Settings of the container runtime (``runtime: docker`` or ``mrswarm run --runtime docker``)."""

    image: str | None = Field(None, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.:/@-]{0,199}$",
                              description="image to run (default mrswarm:<version>, see `mrswarm deploy build`)")
    cpus: float = Field(0.5, gt=0, le=64, description="CPU limit per UAV container, cores")
    memory_mb: int = Field(256, ge=64, le=65536, description="memory limit per UAV container, MB")
    multicast: Literal["drop", "allow"] = Field(
        "drop", description="drop: no multicast or broadcast between containers, like a cellular network")


class Scenario(_Model):
    name: str = Field(pattern=r"^[A-Za-z0-9_\-]{1,64}$")
    description: str = ""
    swarm: str = Field("alpha", pattern=r"^[A-Za-z0-9_\-]{1,32}$")
    seed: int = Field(0, ge=0)
    duration: float = Field(gt=0, le=7200, description="seconds of mission after the start command")
    origin: Origin
    network: Network = Network()
    flight: Flight = Flight()
    mission: Mission
    fleet: Fleet | None = None
    uavs: list[Uav] | None = None
    gcs: Gcs = Gcs()
    runtime: Literal["process", "docker"] = "process"
    docker: Docker = Docker()

    @field_validator("uavs")
    @classmethod
    def _unique_ids(cls, v: list[Uav] | None) -> list[Uav] | None:
        if v is not None:
            ids = [u.id for u in v]
            dup = sorted({i for i in ids if ids.count(i) > 1})
            if dup:
                raise ValueError(f"duplicate UAV ids {dup}")
            if not v:
                raise ValueError("at least one UAV")
        return v

    @model_validator(mode="after")
    def _fleet_or_uavs(self) -> Scenario:
        if (self.fleet is None) == (self.uavs is None):
            raise ValueError("give either 'fleet' (count + spawn pattern) or an explicit 'uavs' list, not both")
        if self.mission.type == "goto":
            missing = [u.id for u in self.uav_list() if u.goal is None]
            if missing:
                raise ValueError(f"a goto mission needs a goal for every UAV; missing for {missing}")
        ids = [u.id for u in self.uav_list()]
        if max(ids) > 65535:
            raise ValueError("UAV ids must stay <= 65535")
        self._check_spawn_spacing()
        g = self.gcs
        if g.mavlink:
            from uav_stack.sysid import allocate_sysid

            if g.port is not None and g.port + allocate_sysid(max(ids))[0] > 65535:
                raise ValueError("gcs.port + the highest shard is above 65535")
            if g.listen_base is not None and g.listen_base + max(ids) > 65535:
                raise ValueError(f"gcs.listen_base + the highest UAV id ({max(ids)}) is above 65535")
            if g.port is None and g.listen_base is None:
                raise ValueError("gcs.mavlink needs gcs.port or gcs.listen_base")
        return self

    def _check_spawn_spacing(self) -> None:
        pts = [u.start for u in self.uav_list()]
        for i in range(len(pts)):
            for j in range(i + 1, len(pts)):
                d = math.dist(pts[i], pts[j])
                if d < self.flight.safety_distance:
                    raise ValueError(
                        f"UAVs spawn {d:.1f} m apart, closer than flight.safety_distance ({self.flight.safety_distance} m)"
                    )

    def uav_list(self) -> list[Uav]:
        if self.uavs is not None:
            return list(self.uavs)
        f = self.fleet
        assert f is not None
        return [Uav(id=f.first_id + i, start=p, rtf=f.rtf, flavour=f.flavour) for i, p in enumerate(spawn_points(f.count, f.spawn))]

    def geofence(self) -> tuple[float, float, float, float]:
        """Where a ground station may send a UAV (goto): gcs.geofence, else the mission area, else
        the box around every start and goal plus 50 m."""
        if self.gcs.geofence is not None:
            return self.gcs.geofence.as_tuple()
        if self.mission.area is not None:
            return self.mission.area.as_tuple()
        pts = [u.start for u in self.uav_list()] + [u.goal for u in self.uav_list() if u.goal is not None]
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

    # ---- per-UAV configuration for the runtime ----------------------------------------------
    def virtual_uav_configs(self, network: NetworkConfig, record_dir: str | None) -> list[VirtualUavConfig]:
        origin = GeoPoint(self.origin.lat, self.origin.lon, self.origin.alt)
        frame = LocalFrame(origin)
        fl, m = self.flight, self.mission
        if self.network.netem is not None:  # the per-link seeds default to the scenario's seed
            network = replace(network, netem={"seed": self.seed, **self.network.netem})
        out = []
        for u in self.uav_list():
            lat, lon, alt = frame.to_geodetic(u.start[0], u.start[1], 0.0)
            mission = MissionConfig(
                type=m.type,
                strategy=m.strategy,
                area=m.area.as_tuple() if m.area else (-1.0, 1.0, -1.0, 1.0),
                lane_spacing=m.lane_spacing,
                goal=u.goal,
                land_when_done=m.land_when_done,
            )
            agent = AgentConfig(
                swarm=self.swarm, uav=u.id, origin=origin, fcu="", realm="virtual", altitude=fl.altitude, speed=fl.speed,
                seed=self.seed, autostart=False, record_dir=record_dir, mission=mission,
                avoidance=AvoidanceConfig(enabled=fl.avoidance, safety_distance=fl.safety_distance, time_horizon=fl.time_horizon),
                network=network,
                gcs=GcsConfig(mavlink_endpoints=self.mavlink_endpoints(u.id), geofence=self.geofence(), max_alt=self.gcs.max_alt),
            )
            out.append(VirtualUavConfig(agent=agent, home=GeoPoint(lat, lon, alt), target_rtf=u.rtf, heading=math.radians(u.heading),
                                        flavour=u.flavour))
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
        return key.strip(), yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        raise ScenarioError(f"--set {text!r}: bad value: {exc}") from None


def format_errors(path: str, err: ValidationError) -> str:
    lines = [f"{path}: invalid scenario ({err.error_count()} problem{'s' if err.error_count() > 1 else ''})"]
    for e in err.errors():
        loc = ".".join(str(x) for x in e["loc"]) or "(top level)"
        msg = e["msg"]
        if e["type"] == "extra_forbidden":
            msg = "unknown field (check the spelling; see docs/scenarios.md)"
        lines.append(f"  {loc}: {msg}")
    return "\n".join(lines)


def load_scenario(path: str | Path, overrides: list[str] | None = None) -> Scenario:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read: {exc.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark else ""
        raise ScenarioError(f"{path}{where}: not valid YAML: {getattr(exc, 'problem', exc)}") from None
    if not isinstance(data, dict):
        raise ScenarioError(f"{path}: a scenario must be a YAML mapping, got {type(data).__name__}")
    for o in overrides or []:
        key, value = parse_override(o)
        _set_path(data, key, value)
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(format_errors(str(path), exc)) from None
