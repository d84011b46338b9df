"""The agent's sensors and actuators: one interface, whether a real driver or the world service feeds it.

A behaviour that needs a sensor gets a :class:`Payload`: sensors and actuators by name. A
:class:`Sensor` has a name and its newest :class:`SensorReading`; an :class:`Actuator` has a
name and takes an amount. That is all a behaviour sees, so it cannot tell a real sensor from a
virtual one. In the virtual case (the Reina et al. virtual-sensing design, over Zenoh instead
of a TCP server): the world service at the edge computes each reading from the UAV's shared
pose and pushes it to the UAV's own key; :class:`VirtualSensor` keeps the newest one, and
:class:`VirtualActuator` sends the request to the world, which applies it where it tracks the
UAV. A real UAV with a real sensor builds a :class:`Payload` from its drivers instead (any
object with ``name`` and ``latest()``), and the same behaviour flies.

:class:`VirtualPayload` also holds the airspace feed (:class:`TrafficTable`): the other swarms'
UAVs, converted from the geodetic feed into this swarm's ENU frame, for collision avoidance.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from groundfloor.histogram import LogHistogram
from swarmnet.messages import Reading, Traffic
from swarmnet.node import SwarmNode
from swarmnet.sensing import UavSensing
from uav_stack.behaviours.base import NeighbourView
from uav_stack.config import ActuatorSpec, AgentConfig, SensorSpec
from uav_stack.geo import LocalFrame

Point3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class SensorReading:
    """What a sensor says: a scalar, and detections as points ``(x, y, v)`` in the swarm's ENU frame (m)."""

    sensor: str
    t: float  # wall time the reading describes, s
    value: float
    points: tuple[Point3, ...] = ()

    def age(self, now: float) -> float:
        return now - self.t


class Sensor(Protocol):
    """A sensor as behaviours see it."""

    @property
    def name(self) -> str: ...

    def latest(self) -> SensorReading | None:
        """The newest reading (None: none yet)."""
        ...


class Actuator(Protocol):
    """An actuator as behaviours see it."""

    @property
    def name(self) -> str: ...

    def actuate(self, amount: float) -> None:
        """Release ``amount`` (the actuator's unit: litres for a spray) now, where the UAV is."""
        ...


@dataclass
class Payload:
    """A UAV's sensors and actuators by name."""

    sensors: Mapping[str, Sensor] = field(default_factory=dict)
    actuators: Mapping[str, Actuator] = field(default_factory=dict)

    def sensor(self, name: str) -> Sensor:
        try:
            return self.sensors[name]
        except KeyError:
            raise KeyError(f"this UAV has no sensor {name!r} (it has: {', '.join(sorted(self.sensors)) or 'none'})") from None

    def actuator(self, name: str) -> Actuator:
        try:
            return self.actuators[name]
        except KeyError:
            raise KeyError(f"this UAV has no actuator {name!r} (it has: {', '.join(sorted(self.actuators)) or 'none'})") \
                from None


class VirtualSensor:
    """A sensor fed by the world service: keeps the newest reading and measures what arrives.

    ``delay`` is the arrival time minus the instant the reading describes (the sensor's
    latency plus the transport), ``wait`` the time from its arrival to the control tick that took
    it in (up to one tick), ``interval`` the EWMA of the time between readings.
    """

    def __init__(self, spec: SensorSpec):
        self.spec = spec
        self._latest: SensorReading | None = None
        self.received = 0
        self.out_of_order = 0
        self.delay = LogHistogram()
        self.wait = LogHistogram()
        self.interval = 0.0
        self._last_recv = math.nan

    @property
    def name(self) -> str:
        return self.spec.name

    def latest(self) -> SensorReading | None:
        return self._latest

    def feed(self, r: Reading, now: float, arrived: float | None = None) -> None:
        """Take in ``r`` at ``now`` (the control tick), which arrived at ``arrived`` (default: now)."""
        self.received += 1
        at = now if arrived is None else arrived
        self.delay.add(at - r.t_meas)
        self.wait.add(max(now - at, 0.0))
        if self._last_recv == self._last_recv:
            dt = now - self._last_recv
            self.interval = dt if self.interval == 0.0 else 0.8 * self.interval + 0.2 * dt
        self._last_recv = now
        if self._latest is not None and r.t_meas < self._latest.t:
            self.out_of_order += 1
            return
        self._latest = SensorReading(r.sensor, r.t_meas, r.value, r.points)

    def stats(self) -> dict[str, Any]:
        def ms(v: float) -> float | None:
            return round(v * 1000.0, 2) if v == v else None

        return {"type": self.spec.type, "received": self.received, "out_of_order": self.out_of_order,
                "rate_hz": round(1.0 / self.interval, 2) if self.interval > 0 else 0.0,
                "delay_ms": {"p50": ms(self.delay.percentile(50)), "p99": ms(self.delay.percentile(99)),
                             "max": ms(self.delay.max) if self.delay.n else None},
                "delay_hist": self.delay.to_dict(),
                "wait_ms": {"p50": ms(self.wait.percentile(50)), "p99": ms(self.wait.percentile(99))},
                "wait_hist": self.wait.to_dict()}


class VirtualActuator:
    """An actuator whose effect the world service applies (the world also keeps its tank)."""

    def __init__(self, spec: ActuatorSpec, link: UavSensing):
        self.spec = spec
        self.link = link
        self.requests = 0
        self.requested = 0.0

    @property
    def name(self) -> str:
        return self.spec.name

    def actuate(self, amount: float) -> None:
        if not (math.isfinite(amount) and amount > 0.0):
            return
        self.link.actuate(self.spec.name, amount)
        self.requests += 1
        self.requested += amount


@dataclass(frozen=True, slots=True)
class Intruder:
    """Another swarm's UAV in this swarm's ENU frame (m, m/s), from the airspace feed."""

    track: int
    t: float  # when its position was sampled, wall s
    x: float
    y: float
    z: float
    vx: float
    vy: float

    def age(self, now: float) -> float:
        return max(0.0, now - self.t)


class TrafficTable:
    """The newest report per track of the airspace feed, in this swarm's frame; forgotten after ``forget_after`` s."""

    def __init__(self, frame: LocalFrame, forget_after: float = 5.0):
        self.frame = frame
        self.forget_after = forget_after
        self.tracks: dict[int, Intruder] = {}
        self.messages = 0

    def update(self, t: Traffic) -> None:
        self.messages += 1
        for r in t.reports:
            old = self.tracks.get(r.track)
            if old is not None and old.t >= r.t_wall:
                continue
            x, y, z = self.frame.to_enu(r.lat, r.lon, r.alt)
            self.tracks[r.track] = Intruder(r.track, r.t_wall, x, y, z, r.ve, r.vn)

    def current(self, now: float) -> list[Intruder]:
        for k in [k for k, v in self.tracks.items() if now - v.t > self.forget_after]:
            del self.tracks[k]
        return list(self.tracks.values())


class VirtualPayload(Payload):
    """The payload of a UAV served by the world service: virtual sensors, virtual actuators, traffic."""

    def __init__(self, node: SwarmNode, sensors: tuple[SensorSpec, ...], actuators: tuple[ActuatorSpec, ...],
                 frame: LocalFrame, traffic: bool = False, clock: Callable[[], float] | None = None):
        self.link = UavSensing(node, traffic=traffic)
        self.virtual = {s.name: VirtualSensor(s) for s in sensors}
        self.virtual_actuators = {a.name: VirtualActuator(a, self.link) for a in actuators}
        super().__init__(dict(self.virtual), dict(self.virtual_actuators))
        self.traffic = TrafficTable(frame) if traffic else None
        self.unknown = 0  # readings of a sensor this UAV does not have

    def poll(self, now: float) -> None:
        """Take in the readings and traffic that arrived (call once per tick, after ``node.poll``)."""
        readings, traffic = self.link.poll_arrivals()
        for at, r in readings:
            s = self.virtual.get(r.sensor)
            if s is None:
                self.unknown += 1
                continue
            s.feed(r, now, at)
        if self.traffic is not None:
            for t in traffic:
                self.traffic.update(t)

    def stats(self) -> dict[str, Any]:
        return {
            "sensors": {n: s.stats() for n, s in self.virtual.items()},
            "actuators": {n: {"requests": a.requests, "requested": round(a.requested, 3)}
                          for n, a in self.virtual_actuators.items()},
            "unknown_sensor_readings": self.unknown,
            "traffic": {"messages": self.traffic.messages, "tracks": len(self.traffic.tracks)} if self.traffic else None,
        }


def make_payload(cfg: AgentConfig, node: SwarmNode, frame: LocalFrame) -> VirtualPayload | None:
    """The UAV's virtual sensors, actuators and airspace feed, if its configuration has any."""
    if not (cfg.sensors or cfg.actuators or cfg.traffic):
        return None
    return VirtualPayload(node, cfg.sensors, cfg.actuators, frame, traffic=cfg.traffic)


def traffic_views(payload: VirtualPayload, x: float, y: float, z: float, now: float, reach2: float,
                  safety: float) -> list[NeighbourView]:
    """Other swarms' UAVs within ``sqrt(reach2)`` m of ``(x, y)``, as neighbours that do not share
    the avoidance effort (we cannot know how they avoid).

    Negative ids: a traffic track never collides with one of our UAV ids. Only traffic within
    two safety distances of our altitude ``z`` counts (avoidance is 2-D).
    """
    if payload.traffic is None:
        return []
    return [NeighbourView(uav=-1 - t.track, pos=(t.x, t.y), vel=(t.vx, t.vy), age=t.age(now), reciprocal=False)
            for t in payload.traffic.current(now)
            if (t.x - x) ** 2 + (t.y - y) ** 2 <= reach2 and abs(t.z - z) <= 2.0 * safety]
