"""The missions that read sensors, written on the SDK: find a plume's source, fight a wildfire.

Registered by name (``mission.behaviour: plume``, ``wildfire``; :data:`~uav_stack.sdk.loader.BUILTINS`),
they are what ``mission.type: plume`` and ``wildfire`` fly (:func:`~uav_stack.sdk.builtins.builtin_mission`),
with the mission's section (``mission.plume``, ``mission.wildfire``) as their parameters. They
fly the algorithms of :mod:`uav_stack.behaviours.plume` (:class:`~uav_stack.behaviours.plume.PlumeSearch`)
and :mod:`uav_stack.behaviours.firefighting` (:class:`~uav_stack.behaviours.firefighting.FireFighter`)
through the public API, and double as its examples of a behaviour that

- reads the UAV's sensors from its Context (``ctx.reading``: the virtual sensors the world
  service feeds, or a real UAV's drivers, alike),
- drives an actuator (``ctx.actuate``: the wildfire's spray, litres the world releases where the UAV is),
- shares what it senses as typed swarm messages (``plume/detection``, ``plume/estimate``,
  ``fire/cells``), and
- says what it is doing in the UAV's state detail (``status``: the plume's search, surge, cast or
  stopped; the firefighter's idle, on duty, fire fighting or returning).

Their messages are ``array_like`` Structs: on the wire, inside the SDK's envelope
``[sent_at, dst, fields]``, the fields are the plain list the algorithms always shared. The world
service reads the source estimates (:func:`estimate_in`) to record the localisation error.
"""

from __future__ import annotations

import math
import random
from typing import Annotated, Any

import msgspec
from msgspec import Meta

from uav_stack.behaviours.base import Rect, SelfState
from uav_stack.behaviours.firefighting import CELLS_TOPIC, MAX_SHARED_CELLS, FireFighter
from uav_stack.behaviours.plume import DETECTION_TOPIC, ESTIMATE_TOPIC, PlumeSearch
from uav_stack.config import ActuatorSpec, Firefighting, PlumeSeeking
from uav_stack.sdk.behaviour import Behaviour
from uav_stack.sdk.context import Context
from uav_stack.sdk.intents import Velocity
from uav_stack.sensors import Payload, SensorReading

Area = tuple[float, float, float, float]  # x_min, x_max, y_min, y_max (m, ENU)
_SPRAY = ActuatorSpec(name="spray")


# ---- the messages ---------------------------------------------------------------------------
class PlumeDetection(msgspec.Struct, frozen=True, array_like=True):
    """``plume/detection``: where a UAV sensed the pollutant (its most upwind detection since its last one)."""

    x: float  # m, ENU
    y: float
    t: float  # wall time of the reading, s
    wind_deg: float  # where the air carried the pollutant, degrees counter-clockwise from east


class PlumeEstimate(msgspec.Struct, frozen=True, array_like=True):
    """``plume/estimate``: where a UAV places the source, once a second (the world service records it)."""

    x: float  # m, ENU
    y: float
    t: float  # wall time of the estimate, s


class FireCells(msgspec.Struct, frozen=True, array_like=True):
    """``fire/cells``: what a UAV's camera sees, once a second: the burning cells in its footprint
    (the disc of ``radius`` round ``x, y``), inside which every other cell is out."""

    x: float  # m, ENU: the footprint's centre (the UAV)
    y: float
    radius: float  # m
    cells: Annotated[list[tuple[float, float]], Meta(max_length=MAX_SHARED_CELLS)]  # burning cells, x, y (m)
    t: float  # wall time of the camera's reading, s


def estimate_in(body: Any) -> PlumeEstimate | None:
    """The estimate a ``plume/estimate`` message carries (``body``: its SDK envelope, untrusted), or None."""
    try:
        _sent_at, _dst, fields = body
        e = msgspec.convert(fields, PlumeEstimate)
    except (msgspec.ValidationError, TypeError, ValueError):
        return None
    return e if math.isfinite(e.x) and math.isfinite(e.y) else None


# ---- what the algorithms read and drive, from the Context -------------------------------------
class _ContextSensor:
    """A sensor as :mod:`uav_stack.sensors` defines it, read through the Context."""

    def __init__(self, ctx: Context, name: str) -> None:
        self.ctx = ctx
        self.name = name

    def latest(self) -> SensorReading | None:
        return self.ctx.reading(self.name)


class _ContextActuator:
    """An actuator as :mod:`uav_stack.sensors` defines it, driven through the Context."""

    def __init__(self, ctx: Context, name: str) -> None:
        self.ctx = ctx
        self.name = name

    def actuate(self, amount: float) -> None:
        self.ctx.actuate(self.name, amount)


def _payload(ctx: Context, sensors: tuple[str, ...], actuators: tuple[str, ...] = ()) -> Payload:
    return Payload({n: _ContextSensor(ctx, n) for n in sensors}, {n: _ContextActuator(ctx, n) for n in actuators})


def _me(ctx: Context) -> SelfState:
    return SelfState(uav=ctx.uav, pos=(ctx.x, ctx.y), vel=(ctx.vx, ctx.vy), t=ctx.t)


def _plain(msg: msgspec.Struct) -> Any:
    return msgspec.to_builtins(msg)


# ---- plume ------------------------------------------------------------------------------------
class PlumeParams(PlumeSeeking, frozen=True):
    """``mission.plume`` (strategy, sensors, threshold, ...), the area it searches and its draws' seed."""

    area: Area | None = None  # None: the scenario's mission.area
    seed: int = 0  # the draws of UAV u: random.Random(seed * 1_000_003 + u)


class PlumeSource(Behaviour[PlumeParams]):
    """Find a pollutant plume and locate its source, together (:mod:`uav_stack.behaviours.plume`):
    search with random legs, surge up the plume against the wind, cast across it when lost (or, the
    ``stop`` strategy, the e-puck rule); share the detections, broadcast the source estimate. Never done."""

    Params = PlumeParams
    messages = {DETECTION_TOPIC: PlumeDetection, ESTIMATE_TOPIC: PlumeEstimate}

    def setup(self, ctx: Context) -> None:
        p = self.params
        area = p.area if p.area is not None else ctx.area
        if area is None:
            raise ValueError("no area: give params.area or the scenario's mission.area")
        rng = random.Random(p.seed * 1_000_003 + ctx.uav)
        self.algorithm = PlumeSearch(p, Rect(*area), ctx.speed, _payload(ctx, (p.sensor, p.wind_sensor)), rng)

    def step(self, ctx: Context) -> Velocity:
        a = self.algorithm
        for m in ctx.inbox(DETECTION_TOPIC):  # the others' detections; their estimates are the world's to read
            a.receive(m.src, DETECTION_TOPIC, _plain(m.body), ctx.t)
        v = a.velocity(_me(ctx), ctx.members)
        for topic, body in a.outbox():
            msg = msgspec.convert(body, self.messages[topic])
            ctx.send(topic, msg)
            if isinstance(msg, PlumeEstimate):  # once a second: into the flight's records too
                ctx.record("estimate.x", msg.x)
                ctx.record("estimate.y", msg.y)
        return Velocity(*v)

    @property
    def status(self) -> str:
        return self.algorithm.state if hasattr(self, "algorithm") else "search"


# ---- wildfire ---------------------------------------------------------------------------------
class WildfireParams(Firefighting, frozen=True):
    """``mission.wildfire`` (hub, fire hint, sensors, spray), the spray's tank and disc, and the draws' seed."""

    capacity_l: Annotated[float, Meta(gt=0.0, le=1e5, description="the spray's tank, litres")] = _SPRAY.capacity_l
    spray_radius_m: Annotated[float, Meta(gt=0.0, le=500.0, description="the sprayed disc, m")] = _SPRAY.radius_m
    seed: int = 0  # the search draws of UAV u: random.Random(seed * 1_000_003 + u)


class Wildfire(Behaviour[WildfireParams]):
    """Fight a wildfire: the state machine of Lentzas' thesis (:mod:`uav_stack.behaviours.firefighting`).
    Wait at the hub with a full tank for the alarm, fly to the nearest burning cell the swarm knows
    of, spray it (``ctx.actuate``), return to refill when the tank is empty or the fire is out;
    share what the camera sees. Targets inside a no-fly zone are skipped (``ctx.blocked``). Never done."""

    Params = WildfireParams
    messages = {CELLS_TOPIC: FireCells}

    def setup(self, ctx: Context) -> None:
        p = self.params
        payload = _payload(ctx, (p.camera, p.tank, p.alarm), (p.spray,))
        rng = random.Random(p.seed * 1_000_003 + ctx.uav)
        self.algorithm = FireFighter(p, ctx.speed, payload, p.capacity_l, p.spray_radius_m, rng,
                                     lambda q: not ctx.blocked(q[0], q[1]))

    def step(self, ctx: Context) -> Velocity:
        a = self.algorithm
        for m in ctx.inbox(CELLS_TOPIC):
            a.receive(m.src, CELLS_TOPIC, _plain(m.body), ctx.t)
        v = a.velocity(_me(ctx), ctx.members)
        for topic, body in a.outbox():  # once a second (with a fresh camera reading)
            ctx.send(topic, msgspec.convert(body, self.messages[topic]))
            ctx.record("sprayed_l", a.sprayed_l)
        return Velocity(*v)

    @property
    def status(self) -> str:
        return self.algorithm.state if hasattr(self, "algorithm") else "idle"
