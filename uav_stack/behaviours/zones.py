"""No-fly zones and obstacles as hard constraints of collision avoidance (2-D polygons with heights).

A zone is a polygon in the swarm's ENU frame between a floor and a ceiling. At the UAV's
altitude, each zone edge within reach becomes one ORCA half-plane for a *static* obstacle,
the way RVO2 treats obstacles (van den Berg et al.): with ``q`` the point of the edge
nearest to the UAV at ``p``, ``d = |q - p|`` and ``n = (q - p) / d``, the velocity must satisfy

    n . v <= (d - margin) / horizon

so the UAV cannot reach the margin around the zone within ``horizon`` seconds, and slides
along the edge rather than stopping (the velocity keeps its component along the edge). Inside
the margin the bound is negative: the UAV moves away. Should it ever be inside the polygon
(it started there, or a zone appeared under it), the one constraint of that zone points to the
nearest way out. These half-planes are *hard*: the least-violation fallback of the LP never
relaxes them to make room for a neighbour (:func:`uav_stack.behaviours.lp.solve`, ``hard``).

Pure geometry on floats, no numpy, like the rest of the avoidance.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

from uav_stack.behaviours.base import Vec2
from uav_stack.behaviours.lp import HalfPlane

SLIDE_FRACTION = 0.7  # of the preferred speed left along an edge: below it, go round the zone instead


def closest_on_segment(p: Vec2, a: Vec2, b: Vec2) -> Vec2:
    """The point of the segment ``a``-``b`` nearest to ``p``."""
    abx, aby = b[0] - a[0], b[1] - a[1]
    ab2 = abx * abx + aby * aby
    if ab2 <= 1e-18:
        return a
    t = ((p[0] - a[0]) * abx + (p[1] - a[1]) * aby) / ab2
    t = 0.0 if t < 0.0 else 1.0 if t > 1.0 else t
    return (a[0] + t * abx, a[1] + t * aby)


def convex_hull(points: Sequence[Vec2]) -> tuple[Vec2, ...]:
    """Counter-clockwise convex hull (Andrew's monotone chain); collinear points dropped."""
    pts = sorted(set(points))
    if len(pts) < 3:
        return tuple(pts)

    def cross(o: Vec2, a: Vec2, b: Vec2) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[Vec2] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0.0:
            lower.pop()
        lower.append(p)
    upper: list[Vec2] = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0.0:
            upper.pop()
        upper.append(p)
    return tuple(lower[:-1] + upper[:-1])


def inside_polygon(p: Vec2, polygon: Sequence[Vec2]) -> bool:
    """Even-odd rule (ray casting); a point on an edge may count either way."""
    x, y = p
    inside = False
    n = len(polygon)
    for i in range(n):
        ax, ay = polygon[i]
        bx, by = polygon[(i + 1) % n]
        if (ay > y) != (by > y) and x < ax + (y - ay) * (bx - ax) / (by - ay):
            inside = not inside
    return inside


@dataclass(frozen=True, slots=True)
class ZoneShape:
    """A zone's geometry: polygon vertices (ENU m) and the heights it spans (m above the origin)."""

    polygon: tuple[Vec2, ...]
    floor: float = -math.inf
    ceiling: float = math.inf
    name: str = ""

    def applies_at(self, altitude: float, margin: float) -> bool:
        """Whether the zone matters at ``altitude`` (unknown altitude, NaN: always)."""
        if altitude != altitude:
            return True
        return self.floor - margin <= altitude <= self.ceiling + margin

    def edges(self) -> Iterable[tuple[Vec2, Vec2]]:
        poly = self.polygon
        for i in range(len(poly)):
            yield poly[i], poly[(i + 1) % len(poly)]

    def contains(self, p: Vec2) -> bool:
        return inside_polygon(p, self.polygon)

    def distance(self, p: Vec2) -> float:
        """Distance from ``p`` to the polygon's boundary (also from inside)."""
        return min(math.dist(p, closest_on_segment(p, a, b)) for a, b in self.edges())

    def nearest_boundary(self, p: Vec2) -> Vec2:
        return min((closest_on_segment(p, a, b) for a, b in self.edges()), key=lambda q: math.dist(p, q))

    def hull(self) -> ZoneShape:
        """The same zone with its convex hull as polygon."""
        return ZoneShape(convex_hull(self.polygon), self.floor, self.ceiling, self.name)


class ZoneField:
    """The zones of a scenario, turned into the hard half-planes of one avoidance step.

    Each zone is avoided as its convex hull: a reactive method cannot get out of a pocket of a
    concave polygon (it slides into the pocket's corner and stays there), so the pocket is
    given up, which keeps the UAV out of the zone all the same.
    """

    def __init__(self, zones: Sequence[ZoneShape], margin: float = 3.0, horizon: float = 2.0, reach: float = 40.0):
        """
        margin: clearance kept from every zone, m.
        horizon: the UAV must not be able to reach the margin within this time, s (smaller:
            closer approach, harder braking).
        reach: edges farther than this produce no constraint, m (at least speed x horizon + margin).
        """
        if not (math.isfinite(margin) and margin >= 0.0):
            raise ValueError(f"margin must be finite and >= 0, got {margin!r}")
        if not (math.isfinite(horizon) and horizon > 0.0):
            raise ValueError(f"horizon must be a positive finite number, got {horizon!r}")
        self.zones = tuple(z.hull() for z in zones)
        self._side: dict[int, int] = {}  # zone index -> +1 (right) or -1 (left): the way around it
        self.margin = float(margin)
        self.horizon = float(horizon)
        self.reach = float(reach)

    def __bool__(self) -> bool:
        return bool(self.zones)

    def planes(self, pos: Vec2, altitude: float = math.nan, margin: float | None = None) -> list[tuple[int, HalfPlane]]:
        """The half-planes the velocity must satisfy at ``pos`` (ENU m) and ``altitude`` (m above
        the origin), each with the index of its zone; ``margin`` instead of the field's own."""
        out: list[tuple[int, HalfPlane]] = []
        inv = 1.0 / self.horizon
        margin = self.margin if margin is None else margin
        for zi, z in enumerate(self.zones):
            if not z.applies_at(altitude, margin):
                continue
            if z.contains(pos):  # the way out: towards the nearest boundary point, and beyond the margin
                q = z.nearest_boundary(pos)
                d = math.dist(pos, q)
                if d <= 1e-9:
                    continue  # on the boundary: the edge constraints of a step later will push out
                nx, ny = (q[0] - pos[0]) / d, (q[1] - pos[1]) / d
                s = (d + margin) * inv
                out.append((-1 - zi, HalfPlane((nx * s, ny * s), (nx, ny))))  # negative: an exit, never steered along
                continue
            for a, b in z.edges():
                q = closest_on_segment(pos, a, b)
                d = math.dist(pos, q)
                if d > self.reach:
                    continue
                if d <= 1e-9:  # exactly on the edge: out, across the edge, beyond the margin
                    ex, ey = b[0] - a[0], b[1] - a[1]
                    el = math.hypot(ex, ey)
                    if el <= 1e-9:
                        continue
                    ox, oy = ey / el, -ex / el
                    if z.contains((pos[0] + 1e-3 * ox, pos[1] + 1e-3 * oy)):
                        ox, oy = -ox, -oy
                    s = margin * inv
                    out.append((zi, HalfPlane((ox * s, oy * s), (ox, oy))))
                    continue
                nx, ny = (q[0] - pos[0]) / d, (q[1] - pos[1]) / d
                s = (d - margin) * inv
                out.append((zi, HalfPlane((nx * s, ny * s), (-nx, -ny))))
        return out

    def steer(self, preferred: Vec2, planes: Sequence[tuple[int, HalfPlane]], pos: Vec2 | None = None) -> Vec2:
        """The preferred velocity, turned along a zone's edge when the zone blocks it (wall following).

        Against an edge the avoidance slides the UAV along it, but straight at the edge there is
        nothing left to slide with, and the UAV would stop. Then the UAV goes around the zone,
        round its nearer end as seen from ``pos`` (:meth:`_shorter_side`; without ``pos``, on
        the side it was already sliding towards, to its right if square on), at the preferred
        speed, and keeps that side until the zone no longer lies in the preferred direction.
        This is the one state of the avoidance: which way it goes around each zone.
        """
        sp = math.hypot(preferred[0], preferred[1])
        if sp <= 1e-9 or not planes:
            self._side.clear()
            return preferred
        worst: tuple[float, int, HalfPlane] | None = None
        for zi, h in planes:
            if zi < 0:
                return preferred  # inside a zone: the exit constraint does the work
            viol = h.violation(preferred)
            if viol > 1e-9 and (worst is None or viol > worst[0]):
                worst = (viol, zi, h)
        if worst is None:
            self._side.clear()  # the way ahead is free
            return preferred
        _, zi, h = worst
        for k in [k for k in self._side if k != zi]:
            del self._side[k]
        rx, ry = -h.normal[1], h.normal[0]  # along the edge, to the right when facing the zone
        side = self._side.get(zi)
        if side is None:
            along = rx * preferred[0] + ry * preferred[1]
            if abs(along) >= SLIDE_FRACTION * sp:
                return preferred  # oblique: the avoidance slides along the edge by itself
            side = self._shorter_side(zi, pos, preferred) if pos is not None else (1 if along >= 0.0 else -1)
            self._side[zi] = side
        return (rx * side * sp, ry * side * sp)

    def _shorter_side(self, zi: int, pos: Vec2, preferred: Vec2) -> int:
        """+1 to go round zone ``zi`` to the right of ``preferred`` (clockwise), -1 to the left: the side whose
        silhouette (the hull's outermost corner as seen from ``pos``) is the smaller turn away from ``preferred``.

        Why not the side the UAV was sliding towards: aimed at a point behind a wide zone, UAVs north of its
        middle slide south along its edge and those south of it slide north, so they met head-on against the
        edge, where one of them cannot give way (the wildfire's village: two UAVs 3.3 m apart with a safety
        distance of 5 m). By the silhouette, each goes round the nearer end and the UAVs on the two sides of the
        middle part. Ties go to the right.
        """
        ux, uy = preferred
        right = left = 0.0  # the largest turn needed to clear the zone, clockwise and counter-clockwise, radians
        for vx, vy in self.zones[zi].polygon:
            wx, wy = vx - pos[0], vy - pos[1]
            a = math.atan2(ux * wy - uy * wx, ux * wx + uy * wy)  # counter-clockwise from preferred
            if a < 0.0:
                right = max(right, -a)
            else:
                left = max(left, a)
        return 1 if right <= left else -1

    def blocked(self, p: Vec2, altitude: float = math.nan, clearance: float | None = None) -> bool:
        """Whether ``p`` is inside a zone or within ``clearance`` (default: the margin) of one."""
        c = self.margin if clearance is None else clearance
        return any(z.applies_at(altitude, c) and (z.contains(p) or z.distance(p) < c) for z in self.zones)


class ZoneSpec(Protocol):
    """What a zone's configuration provides (``uav_stack.config.Zone``)."""

    @property
    def polygon(self) -> tuple[Vec2, ...]: ...

    @property
    def floor(self) -> float: ...

    @property
    def ceiling(self) -> float: ...

    @property
    def name(self) -> str: ...


def zone_field(zones: Sequence[ZoneSpec], margin: float = 3.0) -> ZoneField | None:
    """The avoidance's zone field for configured zones (None: there are none)."""
    if not zones:
        return None
    return ZoneField([ZoneShape(tuple(z.polygon), z.floor, z.ceiling, z.name) for z in zones], margin=margin)
