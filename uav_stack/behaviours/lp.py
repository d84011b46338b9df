"""Small linear programs over 2-D velocities for ORCA.

Problem: find the velocity closest to ``v_pref`` inside a disk of radius ``radius`` (the speed
limit) and inside every half-plane.  A half-plane is ``(p, n)`` with unit normal ``n`` pointing
into the permitted side: it allows ``v`` with ``n . (v - p) >= 0``; its *violation* at ``v`` is
``n . (p - v)``.

* :func:`solve_2d` is the randomised-incremental LP of Seidel / de Berg et al. in its
  deterministic form: keep the optimum; when a constraint is violated, the new optimum lies on
  that constraint's boundary line, which is a 1-D problem (:func:`_solve_on_line`) over the
  earlier constraints and the disk.  Expected O(n) and here n <= ~10.
* If the half-planes and the disk have no common point (too many neighbours, or already too
  close), :func:`solve` falls back to the 3-D program "minimise the largest violation": each
  time the current point violates some constraint ``i`` by more than the best level so far, it
  solves a 2-D LP over the loci "as violated as ``i``" of the earlier constraints, pushing along
  ``n_i``.  This is the fallback described by van den Berg et al. (ORCA, ISRR 2009).

Pure functions on floats; no numpy (a 2-D problem of this size is faster on scalars).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from uav_stack.behaviours.base import Vec2

EPS = 1e-9


@dataclass(slots=True)
class HalfPlane:
    """Treat as immutable. Not ``frozen``: avoidance makes one per neighbour in range every tick,
    and the solver more, and a frozen dataclass's ``__init__`` costs 2.5 times as much."""

    point: Vec2
    normal: Vec2  # unit, into the permitted side

    def violation(self, v: Vec2) -> float:
        """How far ``v`` lies outside (positive) or inside (negative) the half-plane."""
        n = self.normal
        return n[0] * (self.point[0] - v[0]) + n[1] * (self.point[1] - v[1])


def _solve_on_line(
    planes: Sequence[HalfPlane], i: int, radius: float, target: Vec2, maximise_direction: bool
) -> Vec2 | None:
    """Optimum on the boundary line of ``planes[i]`` subject to ``planes[:i]`` and the disk."""
    p, n = planes[i].point, planes[i].normal
    d = (-n[1], n[0])  # along the boundary line
    # |p + t d|^2 <= r^2  ->  t^2 + 2 t (p.d) + |p|^2 - r^2 <= 0
    pd = p[0] * d[0] + p[1] * d[1]
    disc = pd * pd + radius * radius - (p[0] * p[0] + p[1] * p[1])
    if disc < 0.0:
        return None  # the line misses the speed disk
    root = math.sqrt(disc)
    t_lo, t_hi = -pd - root, -pd + root
    for j in range(i):
        q, m = planes[j].point, planes[j].normal
        # m . (p + t d - q) >= 0  ->  t (m.d) >= m . (q - p)
        md = m[0] * d[0] + m[1] * d[1]
        rhs = m[0] * (q[0] - p[0]) + m[1] * (q[1] - p[1])
        if abs(md) <= EPS:
            if rhs > EPS:
                return None  # parallel and the whole line is outside plane j
            continue
        t = rhs / md
        if md > 0.0:
            if t > t_lo:
                t_lo = t
        elif t < t_hi:
            t_hi = t
        if t_lo > t_hi:
            return None
    if maximise_direction:
        t = t_hi if (target[0] * d[0] + target[1] * d[1]) > 0.0 else t_lo
    else:
        t = d[0] * (target[0] - p[0]) + d[1] * (target[1] - p[1])
        t = min(max(t, t_lo), t_hi)
    return (p[0] + t * d[0], p[1] + t * d[1])


def solve_2d(
    planes: Sequence[HalfPlane], radius: float, target: Vec2, maximise_direction: bool = False
) -> tuple[int, Vec2]:
    """Incremental 2-D LP.

    Minimises ``|v - target|`` (or, with ``maximise_direction``, maximises ``v . target`` for a
    unit ``target``) over the disk and the half-planes.  Returns ``(k, v)``: ``k == len(planes)``
    on success, else the index of the first constraint that made the problem infeasible, with
    ``v`` the optimum of ``planes[:k]``.
    """
    if maximise_direction:
        v = (target[0] * radius, target[1] * radius)
    else:
        tn = math.hypot(target[0], target[1])
        v = target if tn <= radius else (target[0] * radius / tn, target[1] * radius / tn)
    for i, h in enumerate(planes):
        if h.violation(v) > EPS:
            w = _solve_on_line(planes, i, radius, target, maximise_direction)
            if w is None:
                return i, v
            v = w
    return len(planes), v


def _least_violation(planes: Sequence[HalfPlane], start: int, radius: float, v: Vec2, hard: int = 0) -> Vec2:
    """Minimise the largest violation over ``planes[hard:]`` within the disk and ``planes[:hard]``
    (3-D LP by projection; the hard planes enter every projected LP as they are, as RVO2 does
    with obstacles)."""
    level = 0.0
    for i in range(max(start, hard), len(planes)):
        hi = planes[i]
        if hi.violation(v) <= level + EPS:
            continue
        ni, pi = hi.normal, hi.point
        proj: list[HalfPlane] = list(planes[:hard])
        for j in range(hard, i):
            nj, pj = planes[j].normal, planes[j].point
            # points where plane j is violated no more than plane i:
            #   nj.(pj - v) <= ni.(pi - v)   <=>   (nj - ni) . v >= nj.pj - ni.pi
            mx, my = nj[0] - ni[0], nj[1] - ni[1]
            mlen = math.hypot(mx, my)
            if mlen <= EPS:
                continue  # same direction: j is uniformly less violated than i here
            c = (nj[0] * pj[0] + nj[1] * pj[1] - ni[0] * pi[0] - ni[1] * pi[1]) / mlen
            m = (mx / mlen, my / mlen)
            proj.append(HalfPlane((m[0] * c, m[1] * c), m))
        k, w = solve_2d(proj, radius, ni, maximise_direction=True)
        if k == len(proj):  # numerically it can fail; keep the previous point then
            v = w
        level = hi.violation(v)
    return v


def solve(planes: Sequence[HalfPlane], radius: float, target: Vec2, hard: int = 0) -> tuple[Vec2, bool]:
    """Closest velocity to ``target`` meeting every half-plane within the speed disk.

    Returns ``(v, feasible)``; if infeasible, ``v`` minimises the largest violation instead,
    never relaxing the first ``hard`` planes (static obstacles) unless they alone leave no room.
    """
    k, v = solve_2d(planes, radius, target)
    if k == len(planes):
        return v, True
    if k < hard:  # the hard planes alone have no common point (a corner): least violation of all
        return _least_violation(planes, k, radius, v), False
    return _least_violation(planes, k, radius, v, hard), False
