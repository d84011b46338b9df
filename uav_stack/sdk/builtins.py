"""Our own missions written on the SDK: go to a goal, lawnmower and random-direction coverage.

Registered by name (``mission.behaviour: goto``, ``lawnmower``, ``random``; :data:`~uav_stack.sdk.loader.BUILTINS`),
they fly the same algorithms as ``mission.type: goto`` and ``coverage``
(:mod:`uav_stack.behaviours.coverage`, pure algorithms without I/O), through the public API:
they double as examples of a behaviour that keeps state between steps and finishes (``done``).
The missions that read sensors (``plume``, ``wildfire``) are in :mod:`uav_stack.sdk.sensing`;
:func:`builtin_mission` makes every built-in mission type.
"""

from __future__ import annotations

import random
from typing import TYPE_CHECKING, Annotated

import msgspec
from msgspec import Meta

from uav_stack.behaviours.base import Rect, SelfState
from uav_stack.behaviours.coverage import GoTo as GoToAlgorithm
from uav_stack.behaviours.coverage import LawnmowerCoverage, RandomDirectionCoverage
from uav_stack.sdk.behaviour import Behaviour
from uav_stack.sdk.context import Context
from uav_stack.sdk.intents import Velocity

if TYPE_CHECKING:
    from uav_stack.behaviours.zones import ZoneField
    from uav_stack.config import AgentConfig
    from uav_stack.sdk.adapter import BehaviourMission
    from uav_stack.sensors import Payload

Metres = Annotated[float, Meta(gt=0.0, le=10000.0, description="m")]
Area = tuple[float, float, float, float]  # x_min, x_max, y_min, y_max (m, ENU)


def _me(ctx: Context) -> SelfState:
    return SelfState(uav=ctx.uav, pos=(ctx.x, ctx.y), vel=(ctx.vx, ctx.vy), t=ctx.t)


def _area(given: Area | None, ctx: Context) -> Rect:
    a = given if given is not None else ctx.area
    if a is None:
        raise ValueError("no area: give params.area or the scenario's mission.area")
    return Rect(*a)


class GoToParams(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    goal: tuple[float, float] | None = None  # x, y (m, ENU); None: this UAV's uavs[].goal
    tolerance: Metres = 1.5  # m: done once this close


class GoToGoal(Behaviour[GoToParams]):
    """Fly to the goal and stay there; ``done`` once within ``tolerance`` (the head-on benchmark's mission)."""

    Params = GoToParams

    def setup(self, ctx: Context) -> None:
        goal = self.params.goal if self.params.goal is not None else ctx.goal
        if goal is None:
            raise ValueError("no goal: give params.goal or the UAV's goal in the scenario (uavs[].goal)")
        self.algorithm = GoToAlgorithm(goal, ctx.speed, self.params.tolerance)

    def step(self, ctx: Context) -> Velocity:
        return Velocity(*self.algorithm.velocity(_me(ctx)))

    @property
    def done(self) -> bool:
        return hasattr(self, "algorithm") and self.algorithm.done

    @property
    def status(self) -> str:
        return "goto"


class LawnmowerParams(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    area: Area | None = None  # None: the scenario's mission.area
    lane_spacing: Metres = 16.0  # m between lanes (the sensor's swath less the overlap)


class Lawnmower(Behaviour[LawnmowerParams]):
    """Systematic coverage: one strip of the area per member, swept back and forth; re-split when members change."""

    Params = LawnmowerParams

    def setup(self, ctx: Context) -> None:
        self.algorithm = LawnmowerCoverage(_area(self.params.area, ctx), ctx.speed, self.params.lane_spacing)

    def step(self, ctx: Context) -> Velocity:
        return Velocity(*self.algorithm.velocity(_me(ctx), ctx.members))

    @property
    def done(self) -> bool:
        return hasattr(self, "algorithm") and self.algorithm.done

    @property
    def status(self) -> str:
        return "coverage/lawnmower"


class RandomParams(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    area: Area | None = None  # None: the scenario's mission.area
    seed: int = 0  # the draws of UAV u: random.Random(seed * 1_000_003 + u)


class RandomDirection(Behaviour[RandomParams]):
    """CPSwarm random coverage: straight to the area's edge, then a random turn. Never done."""

    Params = RandomParams

    def setup(self, ctx: Context) -> None:
        rng = random.Random(self.params.seed * 1_000_003 + ctx.uav)
        self.algorithm = RandomDirectionCoverage(_area(self.params.area, ctx), ctx.speed, rng)

    def step(self, ctx: Context) -> Velocity:
        return Velocity(*self.algorithm.velocity(_me(ctx)))

    @property
    def status(self) -> str:
        return "coverage/random"


def builtin_mission(cfg: AgentConfig, payload: Payload | None = None, zones: ZoneField | None = None) -> BehaviourMission:
    """``mission.type`` goto, coverage (lawnmower, random), plume or wildfire flown as the built-in behaviour
    of the SDK, with the mission's settings as its parameters (``uav_stack.agent.make_mission``); the plume
    and wildfire read the ``payload``'s sensors (the wildfire drives its spray) and the ``zones``
    (None: the agent's)."""
    from uav_stack.sdk import sensing
    from uav_stack.sdk.adapter import BehaviourMission

    m = cfg.mission
    if m.type == "goto":
        return BehaviourMission(cfg, GoToGoal(GoToParams(goal=m.goal, tolerance=m.goal_tolerance)), "goto")
    if m.type == "coverage" and m.strategy == "lawnmower":
        return BehaviourMission(cfg, Lawnmower(LawnmowerParams(area=m.area, lane_spacing=m.lane_spacing)), "lawnmower")
    if m.type == "coverage" and m.strategy == "random":
        return BehaviourMission(cfg, RandomDirection(RandomParams(area=m.area, seed=cfg.seed)), "random")
    if m.type == "plume":
        plume = msgspec.structs.asdict(m.plume) if m.plume is not None else {}
        params = sensing.PlumeParams(**plume, area=m.area, seed=cfg.seed)
        return BehaviourMission(cfg, sensing.PlumeSource(params), "plume", payload, zones)
    if m.type == "wildfire":
        w = m.wildfire
        if w is None:
            raise ValueError("a wildfire mission needs its section (hub, fire_hint)")
        spray = cfg.actuator(w.spray)
        wparams = sensing.WildfireParams(**msgspec.structs.asdict(w), capacity_l=spray.capacity_l,
                                         spray_radius_m=spray.radius_m, seed=cfg.seed)
        return BehaviourMission(cfg, sensing.Wildfire(wparams), "wildfire", payload, zones)
    raise ValueError(f"no built-in behaviour for mission type {m.type!r} ({m.strategy})")
