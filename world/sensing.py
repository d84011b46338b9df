"""Virtual sensor readings: each UAV's sensors, computed from its tracked pose at their rate, released after their latency.

Like the tracking-system-fed simulator of Reina et al., the world computes what each UAV's
sensor would read where the UAV is, and sends it to that UAV. The tracking system here is the
swarm itself: every UAV already shares its pose at 10 Hz, and the world extrapolates the
latest one to the measurement instant (at most :data:`MAX_EXTRAPOLATION_S`). A UAV whose pose
is older than :data:`TRACK_TIMEOUT_S` gets no readings: the world does not know where it is.

Each ``(UAV, sensor)`` pair is due every ``1 / rate_hz`` seconds (late: skipped, never a
burst); a reading describes the world at its due instant (``t_meas``) and is released
``latency_s`` later (``t_sent``). All the UAVs due for one sensor in a tick are computed in one
numpy call.
"""

from __future__ import annotations

import heapq
import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from swarmnet.messages import MAX_READING_POINTS, READING_LIMIT, Pose, Reading
from uav_stack.config import SensorSpec
from world.model import UavKey, World

MAX_EXTRAPOLATION_S = 0.5
TRACK_TIMEOUT_S = 2.0


@dataclass
class Track:
    """A UAV as the world tracks it: its latest shared pose."""

    swarm: str
    pose: Pose

    def at(self, now: float) -> tuple[float, float, float]:
        """Where the UAV is at ``now``: its pose moved on by its velocity (for at most half a second)."""
        p = self.pose
        dt = min(max(now - p.t_wall, 0.0), MAX_EXTRAPOLATION_S)
        return (p.x + p.vx * dt, p.y + p.vy * dt, p.z + p.vz * dt)

    def fresh(self, now: float) -> bool:
        return now - self.pose.t_wall <= TRACK_TIMEOUT_S


class SensorServer:
    """Schedules, computes and holds back (latency) every UAV's virtual sensor readings."""

    def __init__(self, world: World, sensors: tuple[SensorSpec, ...], seed: int = 0):
        self.world = world
        self.sensors = sensors
        self.rng = np.random.default_rng(seed)
        self.due: dict[tuple[UavKey, str], float] = {}
        self.seq: dict[tuple[UavKey, str], int] = {}
        self._queue: list[tuple[float, int, str, Reading]] = []
        self._n = 0
        self.computed: Counter[str] = Counter()  # readings per sensor type

    def tick(self, now: float, tracks: dict[UavKey, Track]) -> None:
        """Compute every reading due at ``now`` and queue it for release."""
        t = self.world.time(now)
        for spec in self.sensors:
            period = 1.0 / spec.rate_hz
            keys = [k for k, tr in tracks.items() if tr.fresh(now) and self.due.get((k, spec.name), 0.0) <= now]
            if not keys:
                continue
            for k in keys:
                d = self.due.get((k, spec.name), now)
                self.due[(k, spec.name)] = max(d + period, now)
            pos = np.array([tracks[k].at(now) for k in keys], dtype=float).reshape(-1, 3)
            yaws = np.array([tracks[k].pose.yaw for k in keys], dtype=float)
            values, points = self._compute(spec, keys, pos, yaws, t)
            release = now + spec.latency_s
            for i, k in enumerate(keys):
                seq = self.seq.get((k, spec.name), 0)
                self.seq[(k, spec.name)] = (seq + 1) & 0xFFFFFFFF
                r = Reading(k[1], spec.name, seq, now, now, float(values[i]), points[i])
                self._n += 1
                heapq.heappush(self._queue, (release, self._n, k[0], r))
            self.computed[spec.type] += len(keys)

    def release(self, now: float) -> list[tuple[str, Reading]]:
        """The readings whose latency has passed, as ``(swarm, reading)`` with ``t_sent = now``."""
        out = []
        q = self._queue
        while q and q[0][0] <= now:
            _, _, swarm, r = heapq.heappop(q)
            out.append((swarm, Reading(r.uav, r.sensor, r.seq, r.t_meas, now, r.value, r.points)))
        return out

    def next_release(self) -> float:
        return self._queue[0][0] if self._queue else math.inf

    # -- the sensor types ---------------------------------------------------------------------------
    def _compute(self, spec: SensorSpec, keys: list[UavKey], pos: np.ndarray, yaws: np.ndarray,
                 t: float) -> tuple[np.ndarray, list[tuple[tuple[float, float, float], ...]]]:
        n = len(keys)
        w = self.world
        points: list[tuple[tuple[float, float, float], ...]] = [()] * n
        if spec.type == "pollutant":
            values = w.plume.read(pos, t) if w.plume is not None else np.zeros(n)
        elif spec.type == "wind":
            values = np.full(n, w.wind.direction_at(t))
        elif spec.type == "tank":
            values = np.array([w.tank_level(k) for k in keys], dtype=float)
        elif spec.type == "alarm":
            values = np.full(n, float(w.fire.counts()["burning"]) if w.fire is not None else 0.0)
        elif spec.type == "fire":
            values, points = self._fire(spec, pos)
        elif spec.type == "target":
            values, points = self._targets(spec, pos, yaws, t)
        else:  # a type this world does not model: nothing to read
            values = np.zeros(n)
        if spec.noise > 0.0:
            if spec.type in ("fire", "target"):
                points = [tuple((x + self.rng.normal(0.0, spec.noise), y + self.rng.normal(0.0, spec.noise), v)
                                for x, y, v in pts) for pts in points]
            else:
                values = values + self.rng.normal(0.0, spec.noise, n)
        if spec.threshold is not None:
            values = (values >= spec.threshold).astype(float)
        return np.clip(values, -READING_LIMIT, READING_LIMIT), points

    def _fire(self, spec: SensorSpec, pos: np.ndarray) -> tuple[np.ndarray, list[tuple[tuple[float, float, float], ...]]]:
        """A downward camera: its footprint's radius (``z tan(fov/2)``, at most ``range_m``), every burning cell in it."""
        n = len(pos)
        if spec.fov_deg < 180.0:
            radius = np.minimum(spec.range_m, np.maximum(pos[:, 2], 0.0) * math.tan(math.radians(spec.fov_deg) / 2.0))
        else:
            radius = np.full(n, spec.range_m)
        fire = self.world.fire
        if fire is None:
            return radius, [()] * n
        xs, ys, heat = fire.burning_cells()
        if len(xs) == 0:
            return radius, [()] * n
        d2 = (pos[:, 0:1] - xs[None, :]) ** 2 + (pos[:, 1:2] - ys[None, :]) ** 2
        out = []
        for i in range(n):
            idx = np.nonzero(d2[i] <= radius[i] ** 2)[0]
            if len(idx) > MAX_READING_POINTS:
                idx = idx[np.argsort(-heat[idx])[:MAX_READING_POINTS]]
            out.append(tuple((float(xs[j]), float(ys[j]), float(heat[j])) for j in idx))
        return radius, out

    def _targets(self, spec: SensorSpec, pos: np.ndarray, yaws: np.ndarray,
                 t: float) -> tuple[np.ndarray, list[tuple[tuple[float, float, float], ...]]]:
        """Targets within ``range_m`` and within ``fov_deg`` around the heading: ``(x, y, id)``; the value is how many."""
        where = [(tg.id, *tg.position(t)) for tg in self.world.targets]
        out = []
        half = math.radians(spec.fov_deg) / 2.0
        for i in range(len(pos)):
            seen = []
            for tid, x, y in where:
                dx, dy = x - pos[i, 0], y - pos[i, 1]
                if math.hypot(dx, dy) > spec.range_m:
                    continue
                if spec.fov_deg < 360.0 and abs(math.remainder(math.atan2(dy, dx) - yaws[i], math.tau)) > half:
                    continue
                seen.append((x, y, float(tid)))
            out.append(tuple(seen[:MAX_READING_POINTS]))
        return np.array([len(s) for s in out], dtype=float), out
