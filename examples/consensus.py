"""Average consensus over swarm messages, driving a rendezvous.

Each UAV starts with its own position as its estimate of the meeting point and broadcasts the
estimate; at every step it moves it towards its neighbours' latest ones,
``x_i += epsilon * sum_j (x_j - x_i)`` (Olfati-Saber, Fax and Murray 2007), which converges to
the average of the starting positions. Every UAV flies to its slot on a ring around its current
estimate (the slots keep the UAVs apart: collision avoidance would not let them share a point).
"""

from __future__ import annotations

import math

import msgspec

from mrswarm.api import Behaviour, Context, GoTo


class ConsensusParams(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    epsilon: float = 0.1  # step size, < 1 / (number of UAVs)
    ring: float = 7.0  # m, radius of the ring of slots around the agreed point
    forget_s: float = 3.0  # s: an estimate older than this no longer counts


class Estimate(msgspec.Struct, frozen=True):
    x: float  # m, ENU
    y: float


class Consensus(Behaviour[ConsensusParams]):
    """Agree on the mean of the starting positions, then meet around it."""

    Params = ConsensusParams
    messages = {"consensus/estimate": Estimate}
    rate_hz = 5.0

    def setup(self, ctx: Context) -> None:
        self.x, self.y = ctx.x, ctx.y
        self.heard: dict[int, tuple[float, float, float]] = {}  # uav -> its estimate and when it came

    def step(self, ctx: Context) -> GoTo:
        p = self.params
        for m in ctx.inbox("consensus/estimate"):
            self.heard[m.src] = (m.body.x, m.body.y, ctx.t - m.age)
        fresh = [(x, y) for x, y, t in self.heard.values() if ctx.t - t <= p.forget_s]
        self.x += p.epsilon * sum(x - self.x for x, _ in fresh)
        self.y += p.epsilon * sum(y - self.y for _, y in fresh)
        ctx.send("consensus/estimate", Estimate(self.x, self.y))
        ctx.record("estimate_x", self.x)
        ctx.record("estimate_y", self.y)
        members = ctx.members or (ctx.uav,)
        a = 2.0 * math.pi * members.index(ctx.uav) / len(members) if ctx.uav in members else 0.0
        return GoTo(self.x + p.ring * math.cos(a), self.y + p.ring * math.sin(a))
