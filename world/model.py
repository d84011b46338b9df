"""The world's state in experiment time: wind, plume, fire, targets, and every UAV's virtual tank.

Experiment time ``t`` is 0 until the world starts (the swarm's mission starts, or at once), then
wall seconds since. The fire is set alight at ``t = 0``. A UAV is known by ``(swarm, uav)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from uav_stack.config import ActuatorSpec
from world.config import WorldConfig
from world.fire import FireGrid
from world.plume import PlumeModel
from world.targets import MovingTarget

UavKey = tuple[str, int]  # (swarm, uav)
MAX_BURST_S = 1.0  # an actuator releases at most this many seconds' worth of its rate at once


@dataclass
class Tank:
    """One UAV's virtual tank of one actuator."""

    level: float  # litres
    last_release: float = math.nan  # wall, s
    released: float = 0.0  # litres in total
    refused: int = 0  # requests that released nothing (empty tank)


class World:
    """Every virtual entity of the experiment, advanced by :meth:`advance`."""

    def __init__(self, cfg: WorldConfig):
        self.cfg = cfg
        self.wind = cfg.wind
        self.plume = PlumeModel(cfg.plume, cfg.wind) if cfg.plume is not None else None
        self.fire = FireGrid(cfg.fire, cfg.wind) if cfg.fire is not None else None
        self.targets = [MovingTarget(t) for t in cfg.targets]
        self.actuators = {a.name: a for a in cfg.actuators}
        self.tanks: dict[tuple[UavKey, str], Tank] = {}
        self.t0: float | None = None  # wall time of experiment time 0

    # -- time -----------------------------------------------------------------------------------------
    @property
    def started(self) -> bool:
        return self.t0 is not None

    def time(self, now: float) -> float:
        """Experiment time at wall time ``now`` (0 before the start)."""
        return 0.0 if self.t0 is None else max(0.0, now - self.t0)

    def start(self, t0: float) -> None:
        if self.t0 is not None:
            return
        self.t0 = t0
        if self.fire is not None:
            self.fire.ignite()

    def advance(self, now: float) -> None:
        if self.fire is not None and self.t0 is not None:
            self.fire.advance(self.time(now))

    # -- actuators --------------------------------------------------------------------------------------
    def tank(self, uav: UavKey, actuator: str) -> Tank:
        k = (uav, actuator)
        t = self.tanks.get(k)
        if t is None:
            t = self.tanks[k] = Tank(self.actuators[actuator].capacity_l)
        return t

    def actuate(self, uav: UavKey, actuator: str, amount: float, x: float, y: float, now: float) -> tuple[float, int]:
        """Apply a request of ``amount`` litres at ``(x, y)``: limited by the actuator's rate and
        the tank. Returns (litres released, cells extinguished)."""
        spec = self.actuators.get(actuator)
        if spec is None:
            return 0.0, 0
        tank = self.tank(uav, actuator)
        since = now - tank.last_release if tank.last_release == tank.last_release else MAX_BURST_S
        allowed = spec.rate_l_s * min(max(since, 0.0), MAX_BURST_S)
        litres = min(amount, allowed, tank.level)
        tank.last_release = now
        if litres <= 0.0:
            tank.refused += 1
            return 0.0, 0
        tank.level -= litres
        tank.released += litres
        out = 0
        if spec.type == "spray" and self.fire is not None:
            out = self.fire.spray(x, y, litres, spec.radius_m)
        return litres, out

    def refill(self, positions: dict[UavKey, tuple[float, float]], dt: float) -> None:
        """Top up the tanks of UAVs within their actuator's refill radius of its hub."""
        for spec in self.actuators.values():
            if spec.refill_at is None or spec.refill_rate_l_s <= 0.0:
                continue
            hx, hy = spec.refill_at
            for uav, (x, y) in positions.items():
                if math.hypot(x - hx, y - hy) <= spec.refill_radius_m:
                    tank = self.tank(uav, spec.name)
                    tank.level = min(spec.capacity_l, tank.level + spec.refill_rate_l_s * dt)

    def tank_level(self, uav: UavKey, spec: ActuatorSpec | None = None) -> float:
        """Litres in the UAV's tank of ``spec`` (default: its first actuator); 0 without actuators."""
        spec = spec or next(iter(self.actuators.values()), None)
        return self.tank(uav, spec.name).level if spec is not None else 0.0
