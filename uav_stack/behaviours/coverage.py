"""Mission behaviours: preferred velocities for coverage (random direction, lawnmower) and go-to-goal.

Each is a :class:`~uav_stack.behaviours.base.Behaviour`: a small state machine driven by
:meth:`velocity` at the agent's control rate. They produce the *preferred* velocity only; collision avoidance adjusts it
afterwards (:class:`uav_stack.behaviours.avoidance.CollisionAvoidance`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from uav_stack.behaviours.base import Rect, SelfState, Vec2, dist, is_finite

_ZERO: Vec2 = (0.0, 0.0)


class UniformSource(Protocol):
    """Anything that draws a uniform float in [low, high): ``random.Random`` or a numpy Generator."""

    def uniform(self, low: float, high: float) -> float: ...


def _check_positive(**vals: float) -> None:
    for name, v in vals.items():
        if not (math.isfinite(v) and v > 0.0):
            raise ValueError(f"{name} must be a positive finite number, got {v!r}")


def _towards(p: Vec2, target: Vec2, speed: float) -> Vec2:
    dx, dy = target[0] - p[0], target[1] - p[1]
    d = math.hypot(dx, dy)
    if d <= 1e-9:
        return _ZERO
    k = speed / d
    return (dx * k, dy * k)


def _members(me: SelfState, members: Sequence[int]) -> tuple[int, ...]:
    return tuple(sorted(set(members) | {me.uav}))


# --- go to a goal ---------------------------------------------------------------------------
class GoTo:
    """Fly to ``goal`` and stop there (the head-on benchmark).

    Speed is ``min(speed, approach_gain * distance)``: a proportional approach, so the UAV slows
    down over the last ``speed / approach_gain`` metres instead of overshooting.  ``done`` latches
    once the UAV has been within ``tolerance``; it keeps holding the goal afterwards (if avoidance
    pushes it away it comes back).
    """

    def __init__(
        self, goal: Vec2, speed: float, tolerance: float = 1.0, approach_gain: float = 1.0
    ) -> None:
        _check_positive(speed=speed, tolerance=tolerance, approach_gain=approach_gain)
        if not (math.isfinite(goal[0]) and math.isfinite(goal[1])):
            raise ValueError(f"goal must be finite, got {goal!r}")
        self.goal: Vec2 = (float(goal[0]), float(goal[1]))
        self.speed = float(speed)
        self.tolerance = float(tolerance)
        self.approach_gain = float(approach_gain)
        self._done = False

    @property
    def done(self) -> bool:
        return self._done

    def velocity(self, me: SelfState, members: Sequence[int] = ()) -> Vec2:
        if not is_finite(me.pos):
            return _ZERO  # no position fix: hold (and keep the state untouched)
        d = dist(me.pos, self.goal)
        if d <= self.tolerance:
            self._done = True
        return _towards(me.pos, self.goal, min(self.speed, self.approach_gain * d))


# --- CPSwarm random direction ---------------------------------------------------------------
def _exit_distance(p: Vec2, d: Vec2, box: Rect) -> float:
    """Distance along unit ``d`` from ``p`` (inside ``box``) to the box boundary."""
    t = math.inf
    if d[0] > 1e-12:
        t = min(t, (box.x_max - p[0]) / d[0])
    elif d[0] < -1e-12:
        t = min(t, (box.x_min - p[0]) / d[0])
    if d[1] > 1e-12:
        t = min(t, (box.y_max - p[1]) / d[1])
    elif d[1] < -1e-12:
        t = min(t, (box.y_min - p[1]) / d[1])
    return max(t, 0.0)


class RandomDirectionCoverage:
    """CPSwarm "random" coverage: fly straight to the area boundary, then turn randomly.

    The boundary is the area shrunk by ``margin``.  At the boundary a new heading is drawn
    uniformly among the directions that lead at least ``2 * reach_tolerance`` into the area
    (rejection sampling, i.e. uniform over the clear sector), and the leg's goal is where that
    ray meets the boundary.  A leg that takes more than twice its nominal time plus 5 s (blocked
    by traffic) is abandoned and a new heading drawn.  Never ``done``.
    """

    def __init__(
        self,
        area: Rect,
        speed: float,
        rng: UniformSource,
        margin: float = 2.0,
        reach_tolerance: float = 1.0,
        max_tries: int = 20,
    ) -> None:
        _check_positive(speed=speed, reach_tolerance=reach_tolerance)
        if not (math.isfinite(margin) and margin >= 0.0):
            raise ValueError(f"margin must be finite and >= 0, got {margin!r}")
        self.area = area
        self.inner = area.shrunk(margin)
        self.speed = float(speed)
        self.rng = rng
        self.margin = float(margin)
        self.reach_tolerance = float(reach_tolerance)
        self.max_tries = int(max_tries)
        self.target: Vec2 | None = None
        self._deadline = -math.inf
        self.legs = 0  # headings drawn so far

    @property
    def done(self) -> bool:
        return False

    def _new_leg(self, me: SelfState) -> None:
        box = self.inner
        p = box.clamp(me.pos)
        if dist(p, me.pos) > self.reach_tolerance:
            # outside the area: enter it at the nearest point first
            self.target = p
        else:
            min_leg = min(2.0 * self.reach_tolerance, 0.5 * min(box.width, box.height))
            choice: tuple[Vec2, float] | None = None
            for _ in range(self.max_tries):
                theta = float(self.rng.uniform(0.0, 2.0 * math.pi))
                d = (math.cos(theta), math.sin(theta))
                length = _exit_distance(p, d, box)
                if length >= min_leg:
                    choice = (d, length)
                    break
            if choice is None:  # hemmed in (tiny area): head for the far side through the centre
                c = box.centre
                dc = math.hypot(c[0] - p[0], c[1] - p[1]) or 1.0
                d = ((c[0] - p[0]) / dc, (c[1] - p[1]) / dc)
                choice = (d, _exit_distance(p, d, box))
            d, length = choice
            self.target = (p[0] + d[0] * length, p[1] + d[1] * length)
            self.legs += 1
        self._deadline = me.t + 2.0 * dist(me.pos, self.target) / self.speed + 5.0

    def velocity(self, me: SelfState, members: Sequence[int] = ()) -> Vec2:
        if not is_finite(me.pos):
            return _ZERO
        if self.target is None or dist(me.pos, self.target) <= self.reach_tolerance or me.t > self._deadline:
            self._new_leg(me)
        assert self.target is not None
        return _towards(me.pos, self.target, self.speed)


# --- systematic: strips + boustrophedon -----------------------------------------------------
@dataclass(frozen=True, slots=True)
class _Segment:
    """A piece of a lane to sweep from ``a`` to ``b``; ``width`` is the band it covers."""

    a: Vec2
    b: Vec2
    width: float


@dataclass(frozen=True, slots=True)
class _Band:
    """Rectangle this UAV has swept itself."""

    x0: float
    x1: float
    y0: float
    y1: float


class LawnmowerCoverage:
    """Systematic coverage: equal strips per alive member, each swept boustrophedon.

    The area is cut into ``len(members)`` equal strips along x (east); sorted ids give my strip
    index.  In my strip, lanes run along y (north) at ``ceil(strip_width / lane_spacing)`` evenly
    spaced x positions (spacing <= ``lane_spacing``), from ``lane_spacing/2`` inside the south
    edge to ``lane_spacing/2`` inside the north edge, so a sensor swath of at least
    ``lane_spacing`` covers the strip.  Pass ``lane_spacing = swath * (1 - overlap)``.

    Lanes are flown in greedy nearest-end order from where the UAV is, which from a corner is
    the usual back-and-forth pattern.  When membership changes, the strips are recomputed and
    the new strip is planned again from the UAV's current position (it continues at the nearest
    unswept point), leaving out every part of the new lanes that this UAV has already swept
    itself.  It cannot know what others swept, so it may re-sweep some of that.  ``done`` once
    every lane piece of the current strip has been flown; the UAV then hovers (velocity 0), and
    a later membership change can make it busy again.
    """

    def __init__(self, area: Rect, speed: float, lane_spacing: float, waypoint_tolerance: float = 2.0) -> None:
        _check_positive(speed=speed, lane_spacing=lane_spacing, waypoint_tolerance=waypoint_tolerance)
        self.area = area
        self.speed = float(speed)
        self.lane_spacing = float(lane_spacing)
        self.waypoint_tolerance = float(waypoint_tolerance)
        self.members: tuple[int, ...] | None = None
        self.strip: Rect | None = None
        self.plan: list[_Segment] = []
        self.replans = 0
        self._swept: list[_Band] = []
        self._sweeping = False  # False: transit to plan[0].a; True: flying plan[0].a -> plan[0].b
        self._min_piece = min(0.5, 0.5 * self.lane_spacing)  # shorter unswept pieces are dropped

    @property
    def done(self) -> bool:
        return self.members is not None and not self.plan

    # geometry -------------------------------------------------------------------------------
    def strip_for(self, uav: int, members: Sequence[int]) -> Rect:
        ids = sorted(set(members) | {uav})
        n, i = len(ids), ids.index(uav)
        w = self.area.width / n
        x0 = self.area.x_min + i * w
        x1 = self.area.x_max if i == n - 1 else x0 + w
        return Rect(x0, x1, self.area.y_min, self.area.y_max)

    def _lane_ends(self) -> tuple[float, float]:
        inset = min(0.5 * self.lane_spacing, 0.5 * self.area.height)
        return self.area.y_min + inset, self.area.y_max - inset

    def _band_swept(self, xl: float, xr: float, y: float) -> bool:
        """Is the cross-section ``[xl, xr]`` at height ``y`` inside what this UAV swept?"""
        spans = sorted((b.x0, b.x1) for b in self._swept if b.y0 <= y <= b.y1)
        reach = xl
        for x0, x1 in spans:
            if x0 > reach + 1e-6:
                break
            reach = max(reach, x1)
            if reach >= xr - 1e-6:
                return True
        return reach >= xr - 1e-6

    def _unswept_segments(self, strip: Rect) -> list[_Segment]:
        n_lanes = max(1, math.ceil(strip.width / self.lane_spacing - 1e-9))
        s = strip.width / n_lanes
        ya, yb = self._lane_ends()
        # coverage can only change at the y edges of swept bands: test each piece in between
        cuts = sorted({ya, yb, *(y for b in self._swept for y in (b.y0, b.y1) if ya < y < yb)})
        segs: list[_Segment] = []
        for li in range(n_lanes):
            x = strip.x_min + (li + 0.5) * s
            xl, xr = x - 0.5 * s, x + 0.5 * s
            run: float | None = None  # y where the current unswept run started
            for y0, y1 in zip(cuts, cuts[1:], strict=False):
                if self._band_swept(xl, xr, 0.5 * (y0 + y1)):
                    if run is not None and y0 - run >= self._min_piece:
                        segs.append(_Segment((x, run), (x, y0), s))
                    run = None
                elif run is None:
                    run = y0
            if run is not None and yb - run >= self._min_piece:
                segs.append(_Segment((x, run), (x, yb), s))
        return segs

    @staticmethod
    def _order(segs: list[_Segment], start: Vec2) -> list[_Segment]:
        """Greedy: repeatedly take the segment with the nearest end, entering at that end."""
        left = list(segs)
        out: list[_Segment] = []
        p = start
        while left:
            best, best_d, flip = 0, math.inf, False
            for i, sg in enumerate(left):
                da, db = dist(p, sg.a), dist(p, sg.b)
                if da < best_d - 1e-9:
                    best, best_d, flip = i, da, False
                if db < best_d - 1e-9:
                    best, best_d, flip = i, db, True
            sg = left.pop(best)
            if flip:
                sg = _Segment(sg.b, sg.a, sg.width)
            out.append(sg)
            p = sg.b
        return out

    def _record(self, seg: _Segment, upto: Vec2) -> None:
        """Remember that ``seg`` was swept from its start to the projection of ``upto``."""
        ax, ay = seg.a
        bx, by = seg.b
        lx, ly = bx - ax, by - ay
        l2 = lx * lx + ly * ly
        t = 1.0 if l2 <= 1e-12 else min(max(((upto[0] - ax) * lx + (upto[1] - ay) * ly) / l2, 0.0), 1.0)
        ey = ay + t * ly
        half = 0.5 * seg.width
        self._swept.append(_Band(ax - half, ax + half, min(ay, ey), max(ay, ey)))

    def _replan(self, me: SelfState, members: tuple[int, ...]) -> None:
        if self._sweeping and self.plan:
            self._record(self.plan[0], me.pos)  # keep the part of the current lane already flown
        self.members = members
        self.strip = self.strip_for(me.uav, members)
        self.plan = self._order(self._unswept_segments(self.strip), me.pos)
        self._sweeping = False
        self.replans += 1

    # control --------------------------------------------------------------------------------
    def velocity(self, me: SelfState, members: Sequence[int]) -> Vec2:
        if not is_finite(me.pos):
            return _ZERO
        ids = _members(me, members)
        if ids != self.members:
            self._replan(me, ids)
        tol = self.waypoint_tolerance
        while self.plan:
            seg = self.plan[0]
            if not self._sweeping:
                if dist(me.pos, seg.a) > tol:
                    return _towards(me.pos, seg.a, self.speed)
                self._sweeping = True
            if dist(me.pos, seg.b) > tol:
                return _towards(me.pos, seg.b, self.speed)
            self._record(seg, seg.b)
            self.plan.pop(0)
            self._sweeping = False
        return _ZERO
