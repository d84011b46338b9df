"""The world's configuration: a scenario's ``world:`` section and what the world service process reads.

Angles are degrees counter-clockwise from east (the ENU convention of the swarm frame), and a
wind's direction is where the air goes *to* (the plume and the fire are carried that way).
Positions are ENU metres from the swarm origin. Light imports only (msgspec, no numpy).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

import msgspec
from msgspec import Meta, field

from groundfloor.schema import Config, ConfigError, decode_json
from swarmnet.keyspace import SWARM_RE
from uav_stack.config import ActuatorSpec, NetworkConfig, Point, SensorSpec, Zone
from uav_stack.geo import GeoPoint

Metres = Annotated[float, Meta(gt=0.0, le=100000.0, description="m")]
Seconds = Annotated[float, Meta(ge=0.0, le=86400.0, description="s")]


class Wind(Config, frozen=True):
    """One wind for the whole world: it carries the plume and drives the fire.

    ``turn_deg`` after ``turn_after_s`` seconds of experiment: the time-variant part of the Reina
    et al. cone (theta_r = 100 degrees counter-clockwise after T_r = 60 s).
    """

    speed: Annotated[float, Meta(ge=0.0, le=60.0, description="m/s")] = 0.0
    direction_deg: float = 0.0  # where the air goes to, counter-clockwise from east
    turn_deg: float = 0.0
    turn_after_s: Seconds | None = None

    def direction_at(self, t: float) -> float:
        """Degrees, at ``t`` seconds of experiment."""
        turned = self.turn_after_s is not None and t >= self.turn_after_s
        return self.direction_deg + (self.turn_deg if turned else 0.0)


class ConePlume(Config, frozen=True, tag="cone", tag_field="model"):
    """The diffusion cone of Reina et al.: the pollutant is present (reading 1) within ``width_deg``
    around the wind's direction from the source, out to ``range_m`` (None: everywhere downwind)."""

    source: Point
    width_deg: Annotated[float, Meta(gt=0.0, lt=360.0, description="full opening angle, degrees")] = 45.0
    range_m: Metres | None = None


Stability = Literal["A", "B", "C", "D", "E", "F"]


class GaussianPlume(Config, frozen=True, tag="gaussian", tag_field="model"):
    """A steady Gaussian plume from a point source carried by the wind, with ground reflection;
    dispersion after Briggs (open country) for a Pasquill stability class. Readings in mg/m^3."""

    source: Point
    height_m: Annotated[float, Meta(ge=0.0, le=1000.0, description="release height above the origin, m")] = 15.0
    rate_g_s: Annotated[float, Meta(gt=0.0, le=1e6, description="emission rate, g/s")] = 1.0
    stability: Stability = "D"
    min_wind: Annotated[float, Meta(gt=0.0, le=10.0, description="wind speed used below this, m/s")] = 0.5


Plume = ConePlume | GaussianPlume


class FuelPatch(Config, frozen=True):
    """An area of other fuel density: 0 for a road, a river, a firebreak."""

    polygon: tuple[Point, ...]
    density: Annotated[float, Meta(ge=0.0, le=1.0)]

    def __post_init__(self) -> None:
        if len(self.polygon) < 3:
            raise ConfigError("polygon", f"needs at least 3 vertices, got {len(self.polygon)}")


class Rect(Config, frozen=True):
    x_min: float
    x_max: float
    y_min: float
    y_max: float

    def __post_init__(self) -> None:
        if not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ConfigError("", "need x_min < x_max and y_min < y_max")


class Fire(Config, frozen=True):
    """A spreading fire on a grid of cells (world/fire.py has the model and its equations).

    The heat model of Lentzas' thesis (a burning tree heats up by one unit per tick, sets the
    trees within a distance alight past a threshold, burns out at a maximum), on cells with a
    fuel density, and with wind: the heat a burning cell needs to set a neighbour alight is
    ``spread_heat / (fuel * (1 + wind_factor * wind_speed * cos(angle to the wind)))``.
    """

    area: Rect
    ignite: tuple[Point, ...]  # cells set alight when the experiment starts
    cell_m: Annotated[float, Meta(gt=0.1, le=1000.0, description="cell size, m")] = 5.0
    heat_rate: Annotated[float, Meta(gt=0.0, le=1e6, description="heat units per second while burning")] = 10.0
    spread_heat: Annotated[float, Meta(gt=0.0, le=1e9, description="heat at which a cell sets its neighbours alight")] = 50.0
    burnout_heat: Annotated[float, Meta(gt=0.0, le=1e9, description="heat at which a cell (fuel 1) has burnt out")] = 150.0
    spread_distance_m: Metres = 7.5
    wind_factor: Annotated[float, Meta(ge=0.0, le=10.0, description="s/m: how much the wind speeds the spread")] = 0.1
    fuel: Annotated[float, Meta(ge=0.0, le=1.0, description="density everywhere but the patches")] = 1.0
    patches: tuple[FuelPatch, ...] = ()
    suppression_per_l: Annotated[float, Meta(gt=0.0, le=1e9, description="heat removed per litre sprayed")] = 40.0
    step_s: Annotated[float, Meta(gt=0.0, le=10.0, description="model time step, s")] = 0.1

    def __post_init__(self) -> None:
        a = self.area
        cells = math.ceil((a.x_max - a.x_min) / self.cell_m) * math.ceil((a.y_max - a.y_min) / self.cell_m)
        if cells > 1_000_000:
            raise ConfigError("cell_m", f"makes {cells} cells; at most 1,000,000")
        if not self.ignite:
            raise ConfigError("ignite", "at least one cell to set alight")


class Target(Config, frozen=True):
    """A moving virtual target: along ``path`` at ``speed``, round and round (``loop``) or back and forth."""

    id: Annotated[int, Meta(ge=1, le=65535)]
    path: tuple[Point, ...]
    speed: Annotated[float, Meta(ge=0.0, le=100.0, description="m/s")] = 2.0
    loop: bool = True

    def __post_init__(self) -> None:
        if not self.path:
            raise ConfigError("path", "at least one point")


class Airspace(Config, frozen=True):
    """The airspace feed: the edge tells every swarm where the other swarms' UAVs are (position
    and velocity only, like Remote ID), on ``mrs/airspace/<swarm>/traffic``."""

    feed: bool = True
    rate_hz: Annotated[float, Meta(gt=0.0, le=50.0, description="Hz")] = 5.0


class WorldConfig(Config, frozen=True):
    """A scenario's ``world:`` section: what the world service simulates and serves."""

    wind: Wind = field(default_factory=Wind)
    plume: Plume | None = None
    fire: Fire | None = None
    targets: tuple[Target, ...] = ()
    zones: tuple[Zone, ...] = ()  # no-fly zones and obstacles: every UAV's avoidance keeps out (uav_stack)
    sensors: tuple[SensorSpec, ...] = ()  # every UAV carries these (virtual: readings from the world service)
    actuators: tuple[ActuatorSpec, ...] = ()
    airspace: Airspace = field(default_factory=Airspace)
    tick_hz: Annotated[float, Meta(ge=10.0, le=1000.0, description="service loop rate, Hz")] = 100.0

    def __post_init__(self) -> None:
        names = [s.name for s in self.sensors]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ConfigError("sensors", f"two sensors named {dup[0]!r}")
        kinds = {s.type for s in self.sensors}
        if "pollutant" in kinds and self.plume is None:
            raise ConfigError("sensors", "a pollutant sensor needs a plume")
        if kinds & {"fire", "alarm"} and self.fire is None:
            raise ConfigError("sensors", "fire and alarm sensors need a fire")
        if "target" in kinds and not self.targets:
            raise ConfigError("sensors", "a target sensor needs targets")
        ids = [t.id for t in self.targets]
        if len(set(ids)) != len(ids):
            raise ConfigError("targets", "two targets with one id")


class ServedSwarm(Config, frozen=True):
    """A swarm the world service serves: its name, its frame's origin, how to reach it."""

    name: Annotated[str, Meta(pattern=SWARM_RE.pattern)]
    origin: GeoPoint
    network: NetworkConfig


class WorldServiceConfig(Config, frozen=True):
    """What ``python -m world`` (``mrswarm world``) reads: the world, the swarms, where to record."""

    world: WorldConfig
    swarms: tuple[ServedSwarm, ...]
    record_dir: str | None = None
    seed: int = 0
    start: Literal["mission", "now"] = "mission"  # experiment time 0: a UAV's first mission state, or at once
    duration: Annotated[float, Meta(gt=0.0, description="s")] | None = None  # stop after this long
    # lock-step time (swarmnet/lockstep.py): the simulated time the run's clock starts at, s since the Unix
    # epoch; the world then steps when the run's leader steps it, once a tick. None: the wall clock
    lockstep_epoch: Annotated[float, Meta(gt=0.0, description="s")] | None = None

    def __post_init__(self) -> None:
        if not self.swarms:
            raise ConfigError("swarms", "at least one swarm to serve")
        names = [s.name for s in self.swarms]
        if len(set(names)) != len(names):
            raise ConfigError("swarms", "a swarm listed twice")

    def to_json(self) -> str:
        return msgspec.json.encode(self).decode()

    @classmethod
    def load(cls, path: str | Path) -> WorldServiceConfig:
        return decode_json(Path(path).read_bytes(), cls)
