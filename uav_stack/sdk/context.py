"""What a behaviour sees and can do at each step: :class:`Context`.

Positions are in the swarm's ENU frame (metres from the swarm's origin: x east, y north, z up),
velocities in m/s of wall-clock time (what the vehicle really does, also under a slowed
simulator), times in seconds. One Context per UAV lives for the whole flight; the adapter
(:mod:`uav_stack.sdk.adapter`) refreshes it before each step.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import msgspec

from uav_stack.sensors import SensorReading

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class Neighbour:
    """Another UAV of the swarm as its last shared pose shows it."""

    uav: int
    x: float  # m, ENU
    y: float
    z: float  # m above the swarm's origin
    vx: float  # m/s
    vy: float
    vz: float
    age: float  # s since the pose was sampled (network delay and staleness; >= 0)
    realm: str  # "virtual" or "physical"

    @property
    def position(self) -> tuple[float, float]:
        """``(x, y)``, m."""
        return (self.x, self.y)

    @property
    def velocity(self) -> tuple[float, float]:
        """``(vx, vy)``, m/s."""
        return (self.vx, self.vy)


@dataclass(frozen=True, slots=True)
class Message(Generic[T]):
    """A swarm message received on one of the behaviour's topics, decoded into its type."""

    src: int  # the sending UAV
    topic: str
    body: T
    sent_at: float  # wall time the sender sent it, s
    age: float  # s from sending to this step (>= 0)
    unicast: bool  # sent to this UAV alone (send_to), not to the swarm


class Outbox:
    """Where a Context's sends go: the adapter's sender (bound to the UAV's swarm node)."""

    def __init__(self, send: Callable[[str, msgspec.Struct, int | None], bool]) -> None:
        self.send = send


class Context:
    """One UAV's view of itself and its swarm at a step, and what its behaviour can do.

    Own state: :attr:`uav`, :attr:`swarm`, :attr:`realm`, :attr:`phase`, :attr:`x`, :attr:`y`,
    :attr:`z` (m, ENU), :attr:`vx`, :attr:`vy`, :attr:`vz` (m/s), :attr:`yaw` (rad, ENU,
    counter-clockwise from east), :attr:`lat`, :attr:`lon` (degrees), :attr:`alt` (m AMSL),
    :attr:`battery` (remaining fraction 0..1; -1: not reported). Times: :attr:`t` (wall, s),
    :attr:`sim_t` (the flight controller's clock, s since its boot), :attr:`dt` (s since the
    previous step), :attr:`mission_t` (s since the mission started). The flight: :attr:`speed`
    (cruise speed, m/s), :attr:`altitude` (the altitude target, m above the origin),
    :attr:`area` (the scenario's ``mission.area`` as x_min, x_max, y_min, y_max, or None),
    :attr:`goal` (this UAV's ``uavs[].goal`` as x, y, or None).
    """

    def __init__(self, uav: int, swarm: str, realm: str, speed: float, altitude: float,
                 area: tuple[float, float, float, float] | None, goal: tuple[float, float] | None, outbox: Outbox,
                 logger: logging.Logger,
                 neighbours: Callable[[float], list[Neighbour]], sensors: Callable[[], Mapping[str, SensorReading | None]],
                 record: Callable[[str, float], bool], actuate: Callable[[str, float], bool] | None = None,
                 blocked: Callable[[float, float], bool] | None = None) -> None:
        self.uav = uav
        self.swarm = swarm
        self.realm = realm
        self.speed = speed
        self.altitude = altitude
        self.area = area
        self.goal = goal  # this UAV's goal (x, y), m ENU, from the scenario's uavs[].goal; None: none given
        self.log = logger  # a logging.Logger: lines go to the UAV process's log, prefixed with the UAV id
        self.phase = ""
        self.x = self.y = self.z = math.nan
        self.vx = self.vy = self.vz = 0.0
        self.yaw = 0.0
        self.lat = self.lon = self.alt = math.nan
        self.battery = -1.0
        self.t = 0.0
        self.sim_t = 0.0
        self.dt = 0.0
        self.mission_t = 0.0
        self.members: tuple[int, ...] = ()  # the swarm's UAV ids alive, this one included, sorted
        self._outbox = outbox
        self._neighbours_of = neighbours
        self._neighbours: list[Neighbour] | None = None
        self._sensors = sensors
        self._record = record
        self._actuate = actuate
        self._blocked = blocked
        self._messages: dict[str, list[Message[Any]]] = {}

    # ---- the adapter's side ---------------------------------------------------------------
    def _refresh(self, messages: dict[str, list[Message[Any]]]) -> None:
        self._neighbours = None
        self._messages = messages

    # ---- own state ------------------------------------------------------------------------
    @property
    def position(self) -> tuple[float, float]:
        """``(x, y)``, m ENU."""
        return (self.x, self.y)

    @property
    def velocity(self) -> tuple[float, float]:
        """``(vx, vy)``, m/s."""
        return (self.vx, self.vy)

    # ---- the swarm ------------------------------------------------------------------------
    @property
    def neighbours(self) -> Sequence[Neighbour]:
        """Every other UAV whose pose is fresh, as last heard (built once per step, when first asked)."""
        if self._neighbours is None:
            self._neighbours = self._neighbours_of(self.t)
        return self._neighbours

    def neighbours_within(self, radius: float) -> list[Neighbour]:
        """The neighbours at most ``radius`` (m, horizontal) away."""
        r2 = radius * radius
        x, y = self.x, self.y
        return [n for n in self.neighbours if (n.x - x) ** 2 + (n.y - y) ** 2 <= r2]

    # ---- sensors --------------------------------------------------------------------------
    @property
    def sensors(self) -> Mapping[str, SensorReading | None]:
        """The newest reading of each of the UAV's sensors by name (None: none yet); empty without a payload."""
        return self._sensors()

    def reading(self, sensor: str) -> SensorReading | None:
        """The newest reading of ``sensor`` (None: none yet, or no such sensor)."""
        return self._sensors().get(sensor)

    # ---- actuators and the airspace --------------------------------------------------------
    def actuate(self, actuator: str, amount: float) -> bool:
        """Ask the UAV's actuator ``actuator`` to release ``amount`` (its unit: litres for a spray) now,
        where the UAV is; the world service (or the real device) applies it. False if the UAV has no such
        actuator or ``amount`` is not a positive finite number (nothing is released)."""
        if self._actuate is None or not isinstance(amount, (int, float)) or not (math.isfinite(amount) and amount > 0.0):
            return False
        return self._actuate(actuator, float(amount))

    def blocked(self, x: float, y: float) -> bool:
        """True if the point ``(x, y)`` (m, ENU) lies in one of the scenario's no-fly zones at the
        altitude target, with their margin: a target there cannot be
        reached, collision avoidance keeps the UAV out."""
        return self._blocked is not None and self._blocked(x, y)

    # ---- messages -------------------------------------------------------------------------
    @property
    def messages(self) -> Mapping[str, list[Message[Any]]]:
        """The messages received since the previous step, by topic (only the behaviour's topics, decoded)."""
        return self._messages

    def inbox(self, topic: str) -> list[Message[Any]]:
        """The messages received on ``topic`` since the previous step, oldest first."""
        return self._messages.get(topic, [])

    def send(self, topic: str, msg: msgspec.Struct) -> bool:
        """Broadcast ``msg`` (of the type ``messages[topic]`` declares) to the whole swarm.

        Sent on ``mrs/<swarm>/<this uav>/msg/<topic>``. False (and counted) if it could not be:
        an undeclared topic, a body of another type, larger than ``max_message_bytes``."""
        return self._outbox.send(topic, msg, None)

    def send_to(self, uav: int, topic: str, msg: msgspec.Struct) -> bool:
        """Send ``msg`` to one UAV (unicast, ``mrs/<swarm>/<this uav>/to/<uav>/<topic>``); as :meth:`send`."""
        return self._outbox.send(topic, msg, uav)

    # ---- records --------------------------------------------------------------------------
    def record(self, name: str, value: float) -> bool:
        """A named value into the flight's records: ``behaviour_uav<N>.csv`` of the run folder (time, name,
        value), the flight recording (``/uav/<N>/behaviour/values`` of run.mcap) and the UAV's stats (its last
        value). ``name``: up to 64 characters of ``[A-Za-z0-9_.-]``, at most 64 names per UAV; ``value``: a number
        (NaN and infinities too). False (counted and logged, never raised) if it is refused."""
        return self._record(name, value)
