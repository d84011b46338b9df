"""The missions that read sensors (plume, wildfire), built from a UAV's configuration and payload."""

from __future__ import annotations

import random

from uav_stack.behaviours.base import Behaviour, Rect
from uav_stack.behaviours.firefighting import FireFighter
from uav_stack.behaviours.plume import PlumeSearch
from uav_stack.behaviours.zones import ZoneField
from uav_stack.config import AgentConfig, PlumeSeeking
from uav_stack.sensors import Payload


def make_sensing_mission(cfg: AgentConfig, payload: Payload, zones: ZoneField | None, rng: random.Random) -> Behaviour:
    """A :class:`PlumeSearch` or a :class:`FireFighter` (the configuration names their sensors;
    ``AgentConfig`` has checked that the payload has them)."""
    m = cfg.mission
    if m.type == "plume":
        return PlumeSearch(m.plume or PlumeSeeking(), Rect(*m.area), cfg.speed, payload, rng)
    if m.type == "wildfire":
        w = m.wildfire
        if w is None:
            raise ValueError("a wildfire mission needs its section (hub, fire_hint)")
        spray = cfg.actuator(w.spray)

        def reachable(p: tuple[float, float]) -> bool:
            return zones is None or not zones.blocked(p, cfg.altitude)

        return FireFighter(w, cfg.speed, payload, spray.capacity_l, spray.radius_m, rng, reachable)
    raise ValueError(f"{m.type!r} is not a sensing mission")
