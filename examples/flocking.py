"""Reynolds flocking (separation, alignment, cohesion) from the neighbours' shared poses only.

Each UAV keeps a heading and flies it at a constant speed; each step turns it towards the mean
velocity of the neighbours within ``radius`` (alignment), towards their centroid (cohesion) and
away from those closer than ``separation`` (separation). No message is sent: the poses every
UAV shares are all it uses (Reynolds 1987; Olfati-Saber 2006 for the analysis).
"""

from __future__ import annotations

import math
import random

import msgspec

from mrswarm.api import Behaviour, Context, Velocity


class FlockParams(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    speed: float = 3.0  # m/s, cruise speed of the flock
    radius: float = 40.0  # m, neighbours closer than this count
    separation: float = 8.0  # m, neighbours closer than this push away
    alignment_gain: float = 1.5  # 1/s
    cohesion_gain: float = 0.05  # 1/(m s)
    separation_gain: float = 2.0  # 1/s


class Flocking(Behaviour[FlockParams]):
    """Reynolds' three rules on the neighbours' poses; the heading starts at random per UAV."""

    Params = FlockParams
    rate_hz = 10.0

    def setup(self, ctx: Context) -> None:
        a = random.Random(ctx.uav).uniform(-math.pi, math.pi)
        self.hx, self.hy = math.cos(a), math.sin(a)

    def step(self, ctx: Context) -> Velocity:
        p = self.params
        near = [n for n in ctx.neighbours_within(p.radius) if n.age < 1.0]
        ax = ay = cx = cy = sx = sy = 0.0
        for n in near:
            ax += n.vx
            ay += n.vy
            cx += n.x - ctx.x
            cy += n.y - ctx.y
            d = math.hypot(n.x - ctx.x, n.y - ctx.y)
            if 1e-3 < d < p.separation:
                k = (p.separation - d) / (p.separation * d)
                sx -= (n.x - ctx.x) * k
                sy -= (n.y - ctx.y) * k
        if near:
            k = len(near)
            s = math.hypot(ax, ay)
            if s > 0.3 * p.speed * k:  # the neighbours' mean heading (when they move)
                ax, ay = ax / s - self.hx, ay / s - self.hy
            else:
                ax = ay = 0.0
            cx, cy = cx / k, cy / k
        dt = min(ctx.dt, 0.5) or 0.1
        hx = self.hx + dt * (p.alignment_gain * ax + p.cohesion_gain * cx + p.separation_gain * sx)
        hy = self.hy + dt * (p.alignment_gain * ay + p.cohesion_gain * cy + p.separation_gain * sy)
        h = math.hypot(hx, hy) or 1.0
        self.hx, self.hy = hx / h, hy / h
        return Velocity(p.speed * self.hx, p.speed * self.hy)
