"""Moving virtual targets: points that follow a path at a constant speed, in experiment time."""

from __future__ import annotations

import math

from world.config import Target


class MovingTarget:
    """Where a :class:`~world.config.Target` is at time ``t``: ``speed * t`` metres along its path,
    round and round the closed path (``loop``) or back and forth along the open one."""

    def __init__(self, cfg: Target):
        self.cfg = cfg
        pts = list(cfg.path)
        if cfg.loop and len(pts) > 1:
            pts.append(pts[0])
        self.points = pts
        self.lengths = [math.dist(a, b) for a, b in zip(pts, pts[1:], strict=False)]
        self.total = sum(self.lengths)

    @property
    def id(self) -> int:
        return self.cfg.id

    def position(self, t: float) -> tuple[float, float]:
        if self.total <= 0.0:
            return self.points[0]
        s = self.cfg.speed * max(t, 0.0)
        if self.cfg.loop:
            s %= self.total
        else:
            s %= 2.0 * self.total
            if s > self.total:
                s = 2.0 * self.total - s
        for (a, b), seg in zip(zip(self.points, self.points[1:], strict=False), self.lengths, strict=True):
            if s <= seg:
                k = s / seg if seg > 0 else 0.0
                return (a[0] + k * (b[0] - a[0]), a[1] + k * (b[1] - a[1]))
            s -= seg
        return self.points[-1]
