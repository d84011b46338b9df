"""Wildfire missions: the firefighting state machine of Lentzas' thesis (Table 1), with communication.

States and transitions (the thesis' table; "fire" is the detection system's alarm, a sensor
counting the burning cells, and the UAV's downward camera, a sensor listing the burning
cells in its footprint):

============== ================================ ============== ================================
 state          input                            next state     output
============== ================================ ============== ================================
 idle           fire burning, tank full          on duty        fly towards the fire
                no fire / tank not full          idle           refill at the hub
 on duty        a burning cell under the UAV     fire fighting  spray
                fire not found                   on duty        fly towards the fire
                fire taken out                   returning      fly back to the hub
 fire fighting  fire burning under the UAV       fire fighting  spray
                local fire taken out             on duty        fly towards the fire
                global fire taken out            returning      fly back to the hub
                tank empty                       returning      fly back to the hub
 returning      at the hub                       idle           (refill)
                not at the hub                   returning      fly back to the hub
============== ================================ ============== ================================

"Towards the fire" is where the swarm knows it to be: the thesis' robots had only the first
report of the detection system (``fire_hint``); here every UAV also broadcasts what its camera
sees once a second (``fire/cells``: the burning cells in its footprint, and the footprint,
inside which every other known cell is out), and flies to the nearest burning cell it knows
of. With none known, it flies to the last known fire and searches around it (random points
within ``search_radius``). The tank, its refilling at the hub and the effect of spraying are the world's
(a virtual actuator and a ``tank`` sensor); the UAV only asks for litres.

The first time the alarm goes up, the UAVs leave the hub one after another in the order of their
ids, :data:`DEPART_GAP_S` apart, not as a pack: eight UAVs waiting 6 m apart that all set off
for the same fire reached the no-fly zone in its way together, and squeezed between its edge and
each other they came closer than the safety distance. Later departures (after a refill) are
spread out by the refills themselves.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Sequence
from typing import Any

from uav_stack.behaviours.base import SelfState, Vec2, is_finite
from uav_stack.config import Firefighting
from uav_stack.sensors import Payload, SensorReading

CELLS_TOPIC = "fire/cells"
SHARE_PERIOD = 1.0  # s between two broadcasts of what the camera sees
FRESH_S = 1.5  # a reading older than this says nothing about now
FULL = 0.98  # of the capacity: the tank counts as full
EMPTY_L = 0.05  # litres: the tank counts as empty
MAX_SHARED_CELLS = 48
HUB_INSIDE = 0.8  # of the hub's radius: far enough inside to refill, so wait there
DEPART_GAP_S = 1.5  # s between two UAVs leaving the hub at the first alarm (7.5 m at 5 m/s, one and a half safety distances)

IDLE, ON_DUTY, FIGHTING, RETURNING = "idle", "on duty", "fire fighting", "returning"


def _cell_key(x: float, y: float) -> tuple[int, int]:
    return (round(x * 2.0), round(y * 2.0))  # 0.5 m: the same cell from every UAV's reading


class FireFighter:
    """Table 1 (module docstring) for one UAV; a Behaviour and a Cooperative."""

    topics = (CELLS_TOPIC,)

    def __init__(self, cfg: Firefighting, speed: float, payload: Payload, capacity_l: float, spray_radius_m: float,
                 rng: random.Random, reachable: Callable[[Vec2], bool] | None = None):
        self.cfg = cfg
        self.speed = speed
        self.camera = payload.sensor(cfg.camera)
        self.tank = payload.sensor(cfg.tank)
        self.alarm = payload.sensor(cfg.alarm)
        self.spray = payload.actuator(cfg.spray)
        self.capacity = capacity_l
        self.spray_radius = spray_radius_m
        self.rng = rng
        self.reachable = reachable or (lambda p: True)
        self.state = IDLE
        self.known: dict[tuple[int, int], tuple[float, float, float]] = {}  # burning cells: key -> (x, y, t seen)
        self.last_fire: Vec2 = cfg.fire_hint
        self.search_point: Vec2 | None = None
        self._searched_from: Vec2 | None = None  # the last known fire a search started from
        self.sprayed_l = 0.0
        self.transitions: list[tuple[float, str, str]] = []
        self._last_spray = math.nan
        self._next_share = 0.0
        self._out: list[tuple[str, Any]] = []
        self._seen_t = -math.inf
        self._alarm_at: float | None = None  # when this UAV first saw the fire burning: the swarm's departures begin

    @property
    def done(self) -> bool:
        return False

    @property
    def status(self) -> str:
        return self.state

    # -- inputs -----------------------------------------------------------------------------------
    def _fresh(self, r: SensorReading | None, now: float) -> SensorReading | None:
        return r if r is not None and r.age(now) <= FRESH_S else None

    def _fire_burning(self, now: float) -> bool | None:
        a = self._fresh(self.alarm.latest(), now)
        return None if a is None else a.value > 0.5

    def _tank_l(self, now: float) -> float | None:
        t = self._fresh(self.tank.latest(), now)
        return None if t is None else t.value

    def _look(self, me: SelfState, now: float) -> None:
        """Update the known cells from the camera: what it lists burns, the rest of its footprint does not."""
        r = self._fresh(self.camera.latest(), now)
        if r is None or r.t <= self._seen_t:
            return
        self._seen_t = r.t
        radius = r.value if math.isfinite(r.value) else 0.0  # the camera's footprint: every burning cell in it is listed
        self._clear(me.pos, radius, r.points)
        for x, y, _heat in r.points:
            self.known[_cell_key(x, y)] = (x, y, r.t)
        if r.points:
            self.last_fire = min(((p[0], p[1]) for p in r.points), key=lambda q: math.dist(q, me.pos))
        if now >= self._next_share:
            self._next_share = now + SHARE_PERIOD
            pts = sorted(r.points, key=lambda p: -p[2])[:MAX_SHARED_CELLS]
            self._out.append((CELLS_TOPIC, [round(me.pos[0], 2), round(me.pos[1], 2), round(radius, 2),
                                            [[round(p[0], 2), round(p[1], 2)] for p in pts], r.t]))

    def _clear(self, centre: Vec2, radius: float, burning: Sequence[tuple[float, float, float]]) -> None:
        keep = {_cell_key(p[0], p[1]) for p in burning}
        for k, (x, y, _t) in list(self.known.items()):
            if k not in keep and math.dist((x, y), centre) <= radius:
                del self.known[k]

    def receive(self, src: int, topic: str, body: Any, now: float) -> None:
        """``fire/cells`` from another UAV: ``[x, y, radius, [[x, y], ...], t]``."""
        if topic != CELLS_TOPIC or not isinstance(body, list) or len(body) != 5 or not isinstance(body[3], list):
            return
        try:
            cx, cy, radius, t = float(body[0]), float(body[1]), float(body[2]), float(body[4])
            cells = [(float(c[0]), float(c[1])) for c in body[3][:MAX_SHARED_CELLS]]
        except (TypeError, ValueError, IndexError):
            return
        if not all(math.isfinite(v) for v in (cx, cy, radius, t)) or not all(map(is_finite, cells)):
            return
        self._clear((cx, cy), radius, [(x, y, 0.0) for x, y in cells])
        for x, y in cells:
            self.known[_cell_key(x, y)] = (x, y, t)
        if cells:
            self.last_fire = cells[0]

    def outbox(self) -> list[tuple[str, Any]]:
        out, self._out = self._out, []
        return out

    # -- the state machine --------------------------------------------------------------------------
    def _go(self, state: str, now: float) -> None:
        if state != self.state:
            self.transitions.append((now, self.state, state))
            self.state = state
            self.search_point = None

    def velocity(self, me: SelfState, members: Sequence[int] = ()) -> Vec2:
        if not is_finite(me.pos):
            return (0.0, 0.0)
        now = me.t
        self._look(me, now)
        burning = self._fire_burning(now)
        tank = self._tank_l(now)
        hub = self.cfg.hub
        if self.state == IDLE:
            full = tank is not None and tank >= FULL * self.capacity
            if burning and self._alarm_at is None:
                self._alarm_at = now
            if burning and full and self._my_turn(me.uav, members, now):
                self._go(ON_DUTY, now)
            elif math.dist(me.pos, hub) <= HUB_INSIDE * self.cfg.hub_radius:
                return (0.0, 0.0)  # anywhere in the hub will do (the thesis' assumption): no crowding at its centre
            else:
                return self._towards(me.pos, hub)
        if self.state == RETURNING:
            if math.dist(me.pos, hub) <= HUB_INSIDE * self.cfg.hub_radius:
                self._go(IDLE, now)
                return (0.0, 0.0)
            return self._towards(me.pos, hub)
        if tank is not None and tank <= EMPTY_L:
            self._go(RETURNING, now)
            return self._towards(me.pos, hub)
        if burning is False:  # the detection system says the whole fire is out
            self._go(RETURNING, now)
            return self._towards(me.pos, hub)
        under = self._burning_under(me.pos)
        if self.state == FIGHTING:
            if under is None:  # local fire taken out
                self._go(ON_DUTY, now)
            else:
                self._spray(now)
                return self._towards(me.pos, under, slow_within=self.cfg.arrive_m * 2)
        # on duty
        self._last_spray = math.nan
        if under is not None and math.dist(me.pos, under) <= self.cfg.arrive_m:
            self._go(FIGHTING, now)
            self._spray(now)
            return (0.0, 0.0)
        target = self._target(me.pos)
        return self._towards(me.pos, target, slow_within=self.cfg.arrive_m * 2)

    def _my_turn(self, me: int, members: Sequence[int], now: float) -> bool:
        """At the first alarm, the UAVs leave in the order of their ids, DEPART_GAP_S apart (module docstring)."""
        if self._alarm_at is None or self.transitions:
            return True  # not the first departure
        rank = sorted({*members, me}).index(me)
        return now >= self._alarm_at + rank * DEPART_GAP_S

    def _burning_under(self, p: Vec2) -> Vec2 | None:
        """The nearest known burning cell within the spray's reach."""
        best = None
        for x, y, _t in self.known.values():
            d = math.dist(p, (x, y))
            if d <= self.spray_radius and (best is None or d < best[0]):
                best = (d, (x, y))
        return None if best is None else best[1]

    def _target(self, p: Vec2) -> Vec2:
        cells = [(x, y) for x, y, _t in self.known.values() if self.reachable((x, y))]
        if cells:
            self.search_point = None
            return min(cells, key=lambda q: math.dist(p, q))
        # nothing known: to the last known fire (at first, the detection system's report), then search around it
        if self._searched_from != self.last_fire:
            if math.dist(p, self.last_fire) > self.cfg.arrive_m:
                return self.last_fire
            self._searched_from = self.last_fire
            self.search_point = None
        if self.search_point is None or math.dist(p, self.search_point) < self.cfg.arrive_m:
            for _ in range(20):
                a = self.rng.uniform(0.0, math.tau)
                r = self.cfg.search_radius * math.sqrt(self.rng.random())
                q = (self.last_fire[0] + r * math.cos(a), self.last_fire[1] + r * math.sin(a))
                if self.reachable(q):
                    self.search_point = q
                    break
            else:
                self.search_point = self.last_fire
        return self.search_point

    def _spray(self, now: float) -> None:
        dt = now - self._last_spray if self._last_spray == self._last_spray else 0.1
        self._last_spray = now
        amount = self.cfg.spray_rate_l_s * min(max(dt, 0.0), 0.5)
        if amount > 0.0:
            self.spray.actuate(amount)
            self.sprayed_l += amount

    def _towards(self, p: Vec2, target: Vec2, slow_within: float = 0.0) -> Vec2:
        dx, dy = target[0] - p[0], target[1] - p[1]
        d = math.hypot(dx, dy)
        if d <= 1e-6:
            return (0.0, 0.0)
        speed = self.speed if d >= slow_within or slow_within <= 0 else self.speed * max(d / slow_within, 0.2)
        speed = min(speed, d)  # arrive, do not overshoot a point
        return (dx / d * speed, dy / d * speed)
