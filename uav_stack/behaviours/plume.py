"""Plume missions: find a pollutant with a virtual (or real) sensor and locate its source, together.

Two strategies (``PlumeSeeking.strategy``), both searching the area with random legs
(:class:`~uav_stack.behaviours.coverage.RandomDirectionCoverage`):

- ``stop``: the e-puck experiment of Reina et al. (virtual sensing in ARGoS) on UAVs: a UAV
  that senses the pollutant stops with probability ``stop_probability`` per control step, and
  moves on once it no longer senses it (the plume has turned away).
- ``seek``: in the plume, surge against the wind (the direction the air carries the pollutant,
  read from a wind sensor); having lost it, cast across the wind around the last point where it
  was sensed, wider each time, for ``cast_s``; then search again. Surging up a plume ends at
  its source, the narrow end of the plume.

Both share what they sense: at most twice a second a UAV broadcasts its most upwind detection
since the last one (``plume/detection``: x, y, wall time, wind direction), and every UAV
estimates the source as the mean of the three most upwind detections it knows, among those
made under the current wind direction (within ``WIND_MATCH_DEG``) and younger than
``memory_s``. Once a second it broadcasts that estimate (``plume/estimate``), which the world
service records against the true source (the localisation error of docs/world.md).
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from uav_stack.behaviours.base import Rect, SelfState, Vec2, is_finite
from uav_stack.behaviours.coverage import RandomDirectionCoverage
from uav_stack.config import PlumeSeeking
from uav_stack.sensors import Payload, SensorReading

DETECTION_TOPIC = "plume/detection"
ESTIMATE_TOPIC = "plume/estimate"
SHARE_PERIOD = 0.5  # s between two detection broadcasts of one UAV
ESTIMATE_PERIOD = 1.0  # s between two estimate broadcasts
WIND_MATCH_DEG = 20.0  # detections made under a wind this close to the current one still count
FRESH_S = 1.0  # a reading older than this says nothing about now
CAST_STEP_M = 4.0  # the cast widens by this much on each crossing
MAX_DETECTIONS = 2000


@dataclass(frozen=True, slots=True)
class Detection:
    x: float
    y: float
    t: float  # wall, s
    wind_deg: float  # the direction the air carried the pollutant to, degrees counter-clockwise from east


def _unit(deg: float) -> Vec2:
    r = math.radians(deg)
    return (math.cos(r), math.sin(r))


def _angle_between(a_deg: float, b_deg: float) -> float:
    return abs(math.remainder(a_deg - b_deg, 360.0))


class SourceEstimate:
    """The source as the swarm's detections place it: the mean of the most upwind ones."""

    def __init__(self, memory_s: float, k: int = 3):
        self.memory_s = memory_s
        self.k = k
        self.detections: list[Detection] = []

    def add(self, d: Detection) -> None:
        self.detections.append(d)
        if len(self.detections) > MAX_DETECTIONS:
            del self.detections[: len(self.detections) - MAX_DETECTIONS]

    def estimate(self, now: float, wind_deg: float) -> Vec2 | None:
        self.detections = [d for d in self.detections if now - d.t <= self.memory_s]
        usable = [d for d in self.detections if _angle_between(d.wind_deg, wind_deg) <= WIND_MATCH_DEG]
        if not usable:
            return None
        ux, uy = _unit(wind_deg)
        usable.sort(key=lambda d: d.x * ux + d.y * uy)
        best = usable[: self.k]
        return (sum(d.x for d in best) / len(best), sum(d.y for d in best) / len(best))


class PlumeSearch:
    """A :class:`~uav_stack.behaviours.base.Behaviour` and :class:`~uav_stack.behaviours.base.Cooperative`
    for plume missions (module docstring)."""

    topics = (DETECTION_TOPIC,)

    def __init__(self, cfg: PlumeSeeking, area: Rect, speed: float, payload: Payload, rng: random.Random):
        self.cfg = cfg
        self.speed = speed
        self.sensor = payload.sensor(cfg.sensor)
        self.wind = payload.sensor(cfg.wind_sensor)
        self.rng = rng
        self.search = RandomDirectionCoverage(area, speed, rng)
        self.area = area
        self.sources = SourceEstimate(cfg.memory_s)
        self.state = "search"
        self.stopped = False
        self.last_in: Vec2 | None = None  # where the plume was last sensed
        self.cast_since = 0.0
        self.cast_k = 0
        self.cast_target: Vec2 | None = None
        self.estimate: Vec2 | None = None
        self._best: Detection | None = None  # own most upwind detection since the last share
        self._next_share = 0.0
        self._next_estimate = 0.0
        self._out: list[tuple[str, Any]] = []
        self._last_reading_t = -math.inf

    @property
    def done(self) -> bool:
        return False

    @property
    def status(self) -> str:
        return self.state

    # -- sensing ------------------------------------------------------------------------------
    def _fresh(self, r: SensorReading | None, now: float) -> SensorReading | None:
        return r if r is not None and r.age(now) <= FRESH_S else None

    def _wind_deg(self, now: float) -> float | None:
        w = self._fresh(self.wind.latest(), now)
        return w.value if w is not None and math.isfinite(w.value) else None

    def _sense(self, me: SelfState, now: float, wind: float | None) -> bool | None:
        """In the plume (True), out of it (False), or no fresh reading (None). Records a detection."""
        r = self._fresh(self.sensor.latest(), now)
        if r is None:
            return None
        inside = r.value >= self.cfg.threshold
        if inside and wind is not None and r.t > self._last_reading_t:
            d = Detection(me.pos[0], me.pos[1], r.t, wind)
            self.sources.add(d)
            ux, uy = _unit(wind)
            if self._best is None or d.x * ux + d.y * uy < self._best.x * ux + self._best.y * uy:
                self._best = d
        self._last_reading_t = r.t
        return inside

    # -- the swarm ------------------------------------------------------------------------------
    def receive(self, src: int, topic: str, body: Any, now: float) -> None:
        if topic != DETECTION_TOPIC or not isinstance(body, list) or len(body) != 4:
            return
        try:
            x, y, t, wind = (float(v) for v in body)
        except (TypeError, ValueError):
            return
        if all(math.isfinite(v) for v in (x, y, t, wind)) and 0.0 <= now - t <= self.cfg.memory_s:
            self.sources.add(Detection(x, y, t, wind))

    def outbox(self) -> list[tuple[str, Any]]:
        out, self._out = self._out, []
        return out

    def _share(self, now: float, wind: float | None) -> None:
        if now >= self._next_share and self._best is not None:
            b = self._best
            self._out.append((DETECTION_TOPIC, [round(b.x, 2), round(b.y, 2), b.t, round(b.wind_deg, 2)]))
            self._best = None
            self._next_share = now + SHARE_PERIOD
        if wind is not None:
            self.estimate = self.sources.estimate(now, wind)
        if now >= self._next_estimate:
            self._next_estimate = now + ESTIMATE_PERIOD
            if self.estimate is not None:
                self._out.append((ESTIMATE_TOPIC, [round(self.estimate[0], 2), round(self.estimate[1], 2), now]))

    # -- motion ---------------------------------------------------------------------------------
    def velocity(self, me: SelfState, members: Sequence[int] = ()) -> Vec2:
        if not is_finite(me.pos):
            return (0.0, 0.0)
        now = me.t
        wind = self._wind_deg(now)
        inside = self._sense(me, now, wind)
        self._share(now, wind)
        if self.cfg.strategy == "stop":
            return self._stop_rule(me, inside)
        return self._seek(me, now, inside, wind)

    def _stop_rule(self, me: SelfState, inside: bool | None) -> Vec2:
        if inside:
            if not self.stopped and self.rng.random() < self.cfg.stop_probability:
                self.stopped = True
        elif inside is False:
            self.stopped = False
        self.state = "stopped" if self.stopped else "search"
        return (0.0, 0.0) if self.stopped else self.search.velocity(me)

    def _seek(self, me: SelfState, now: float, inside: bool | None, wind: float | None) -> Vec2:
        if inside and wind is not None:
            self.state = "surge"
            self.last_in = me.pos
            self.cast_k = 0
            self.cast_target = None
            ux, uy = _unit(wind)
            return self._clamp(me.pos, (-ux * self.speed, -uy * self.speed))
        if self.state in ("surge", "cast") and self.last_in is not None and wind is not None:
            if self.state == "surge":
                self.state, self.cast_since = "cast", now
            if now - self.cast_since <= self.cfg.cast_s:
                return self._cast(me, wind)
        self.state = "search"
        return self.search.velocity(me)

    def _cast(self, me: SelfState, wind: float) -> Vec2:
        """Across the wind around the last point in the plume, alternating sides, wider each time."""
        assert self.last_in is not None
        if self.cast_target is None or math.dist(me.pos, self.cast_target) < 1.5:
            self.cast_k += 1
            side = 1.0 if self.cast_k % 2 else -1.0
            cx, cy = -math.sin(math.radians(wind)), math.cos(math.radians(wind))
            amp = CAST_STEP_M * self.cast_k * side
            self.cast_target = self.area.clamp((self.last_in[0] + cx * amp, self.last_in[1] + cy * amp))
        dx, dy = self.cast_target[0] - me.pos[0], self.cast_target[1] - me.pos[1]
        d = math.hypot(dx, dy)
        k = min(self.speed, d) / d if d > 1e-9 else 0.0
        return (dx * k, dy * k)

    def _clamp(self, p: Vec2, v: Vec2) -> Vec2:
        """Never leave the search area: a velocity that would is cut at its edge."""
        nx, ny = p[0] + v[0], p[1] + v[1]
        if self.area.contains((nx, ny)):
            return v
        cx, cy = self.area.clamp((nx, ny))
        return (cx - p[0], cy - p[1])
