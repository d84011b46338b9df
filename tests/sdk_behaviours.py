"""Behaviours of the SDK's tests (imported by the UAV processes as tests.sdk_behaviours:<Class>)."""

from __future__ import annotations

import math
import time

import msgspec

from mrswarm.api import Behaviour, Context, GoTo, Hold, Intent, Velocity


class FaultyParams(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    raise_on: list[int] = []  # UAVs whose step raises after `after_s`
    slow_on: list[int] = []  # UAVs whose step overruns its budget after `after_s`
    after_s: float = 3.0  # s of mission
    slow_s: float = 0.06  # s of CPU a slow step takes


class Faulty(Behaviour[FaultyParams]):
    """Hovers; on the UAVs named, raises or sleeps past its budget after a while."""

    Params = FaultyParams

    def step(self, ctx: Context) -> Intent | None:
        p = self.params
        if ctx.mission_t >= p.after_s:
            if ctx.uav in p.raise_on:
                raise RuntimeError(f"UAV {ctx.uav} fails on purpose")
            if ctx.uav in p.slow_on:  # a slow computation: CPU time over the budget
                end = time.thread_time() + p.slow_s
                while time.thread_time() < end:
                    pass
        return Hold() if ctx.mission_t < 1.0 else None


class Ping(msgspec.Struct, frozen=True):
    n: int


class Chatty(Behaviour):  # type: ignore[type-arg]
    """Broadcasts a counter and hovers: the message counters' test."""

    messages = {"test/ping": Ping}
    rate_hz = 5.0

    def setup(self, ctx: Context) -> None:
        self.n = 0

    def step(self, ctx: Context) -> Velocity:
        self.n += 1
        ctx.send("test/ping", Ping(self.n))
        ctx.record("heard", float(len(ctx.inbox("test/ping"))))
        return Velocity(0.0, 0.0)


class StraightParams(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    altitude: float | None = None  # m above the origin; None: the flight's


class Straight(Behaviour[StraightParams]):
    """Straight to the UAV's goal at its own altitude, without collision avoidance (it opts out)."""

    Params = StraightParams
    avoidance = False

    def step(self, ctx: Context) -> Intent:
        assert ctx.goal is not None
        return GoTo(ctx.goal[0], ctx.goal[1], self.params.altitude)


class Note(msgspec.Struct, frozen=True):
    n: int


class Recording(Behaviour):  # type: ignore[type-arg]
    """Hovers, broadcasts a counter and records values every step: good ones, a NaN, and two it may not record."""

    messages = {"test/note": Note}
    rate_hz = 5.0

    def setup(self, ctx: Context) -> None:
        self.n = 0

    def step(self, ctx: Context) -> Velocity:
        self.n += 1
        ctx.send("test/note", Note(self.n))
        ctx.record("step", self.n)
        ctx.record("heard", len(ctx.inbox("test/note")))
        ctx.record("nothing.yet", math.nan)
        ctx.record("bad name!", 1.0)  # refused: not a name
        ctx.record("text", "1.5")  # type: ignore[arg-type] # refused: not a number
        return Velocity(0.0, 0.0)
