"""Age-aware ORCA collision avoidance (van den Berg, Guy, Lin, Manocha, ISRR 2009), in 2-D.

For me (A) and a neighbour (B) the agent gives B's pose as last received and its age ``a``.

1. Extrapolate B to now: ``p_B = p + v * a``.
2. Combined radius ``r = safety_distance + e`` with the age term
   ``e = min(cap, |v_A - v_B| * (a + response_time))`` while ``a <= stale_after`` (the response
   time covers our own actuation lag, 0.4 s by default); beyond that the uncertainty keeps
   growing at ``max(|v_rel|, max_speed)`` per second up to the same cap, and B is ignored once
   ``a > forget_after``.  Stale neighbours are also treated as non-reciprocal (they may not be
   hearing us either).
3. Velocity obstacle for horizon ``tau``: with ``x = p_B - p_A``, ``v = v_A - v_B``,
   ``w = v - x / tau``: if ``v`` is nearest to the cut-off disk (centre ``x/tau``, radius
   ``r/tau``) the smallest change that leaves the VO is ``u = (r/tau - |w|) w/|w|`` with outward
   normal ``w/|w|``; otherwise ``u`` is the projection of ``v`` onto the nearer leg of the cone
   (the leg on the side of ``w``), normal perpendicular to that leg.  Already inside ``r``: the
   same disk construction with ``tau`` replaced by ``time_step``, i.e. "be out within one step".
4. ORCA half-plane: through ``v_A + s * u`` with that normal, ``s = 1/2`` for a reciprocal
   neighbour and ``s = 1`` for one that will not do its share (physical UAV, stale link).
5. New velocity: closest to the preferred one inside all half-planes and the speed disk
   (:mod:`uav_stack.behaviours.lp`); if that is empty, the velocity minimising the largest
   violation, which moves the UAV apart from whoever it is too close to.

Symmetry: the leg is chosen by the sign of ``det(x, w)`` with ties going to the right leg; for
the neighbour ``x`` and ``w`` are exactly negated, so both pick the same side and an exactly
symmetric head-on resolves (see the tests).  Coincident positions are split by UAV id.
"""

from __future__ import annotations

import heapq
import math
import operator
from collections.abc import Sequence
from dataclasses import dataclass

from uav_stack.behaviours.base import NeighbourView, SelfState, Vec2, clip_norm, is_finite
from uav_stack.behaviours.lp import HalfPlane, solve
from uav_stack.behaviours.zones import ZoneField


@dataclass(frozen=True, slots=True)
class AvoidanceResult:
    velocity: Vec2
    active: bool  # some constraint changed the (speed-clipped) preferred velocity
    closest: float  # predicted (extrapolated) distance to the closest neighbour, inf if none
    inflation: float  # extra radius used for the closest neighbour (age term)
    feasible: bool = True  # False if ORCA had no solution and the least-violation fallback ran
    considered: int = 0  # neighbours that produced a constraint


@dataclass(slots=True)
class _Constraint:
    """One neighbour's half-plane, made for each neighbour in range every tick (about 15 a tick
    in a UAV of 50): not ``frozen``, whose ``__init__`` costs 2.5 times as much. Treat as immutable."""

    dist: float
    plane: HalfPlane
    oncoming: float  # 0..1: how fast this neighbour itself comes towards us (keep-right weight)


_FIRST = operator.itemgetter(0)
YIELD_MARGIN = 0.3  # of a zone's margin still kept when the full margin leaves no way to give way to a neighbour


class CollisionAvoidance:
    """ORCA with message-age compensation.  Stateless: ``adjust`` depends only on its arguments."""

    def __init__(
        self,
        safety_distance: float,
        max_speed: float,
        time_horizon: float = 4.0,
        stale_after: float = 1.0,
        max_neighbours: int = 10,
        neighbour_range: float = 50.0,
        forget_after: float = 5.0,
        max_inflation: float | None = None,
        time_step: float = 0.1,
        bias_angle: float = 0.5 * math.pi,
        response_time: float = 0.4,
        zones: ZoneField | None = None,
    ) -> None:
        """
        safety_distance: minimum centre-to-centre distance between two UAVs (body + position
            error), metres.  This is the *combined* radius, not a per-UAV one.
        max_speed: output speed limit, m/s.
        time_horizon: ORCA tau, s: avoid collisions predicted within this time.
        stale_after: age after which a neighbour's pose is "stale" (uncertainty grows faster,
            full responsibility).
        max_neighbours / neighbour_range: only the nearest ``max_neighbours`` within
            ``neighbour_range`` metres (predicted distance) produce constraints.
        forget_after: neighbours older than this are ignored altogether.
        max_inflation: cap of the age term, metres (default: ``safety_distance``).
        time_step: control period, s; an existing overlap is to be resolved within it.
        response_time: the vehicle's own velocity response time, s (first-order lag of the
            flight controller + airframe).  ORCA assumes a new velocity takes effect at once;
            until it does the pair keeps closing at up to ``|v_rel|``, so this is added to the
            message age in the inflation term.  0 gives the bare ``|v_rel| * age``.
        bias_angle: keep-right rule, radians: when avoidance blocks progress along the preferred
            velocity, that velocity is turned clockwise by up to this angle (in proportion to how
            much progress is lost) and ORCA solved again.  Breaks the symmetric deadlock of ORCA's
            cut-off disk; 0 disables it.
        zones: no-fly zones and obstacles (:mod:`uav_stack.behaviours.zones`): hard constraints,
            never relaxed for a neighbour, and the way around a zone that blocks the path.
        """
        for name, val in (
            ("safety_distance", safety_distance),
            ("max_speed", max_speed),
            ("time_horizon", time_horizon),
            ("stale_after", stale_after),
            ("neighbour_range", neighbour_range),
            ("forget_after", forget_after),
            ("time_step", time_step),
        ):
            if not (math.isfinite(val) and val > 0.0):
                raise ValueError(f"{name} must be a positive finite number, got {val!r}")
        if not (math.isfinite(response_time) and response_time >= 0.0):
            raise ValueError(f"response_time must be finite and >= 0, got {response_time!r}")
        if forget_after < stale_after:
            raise ValueError("need stale_after <= forget_after")
        if not (math.isfinite(bias_angle) and 0.0 <= bias_angle <= 0.5 * math.pi):
            raise ValueError(f"bias_angle must be in [0, pi/2], got {bias_angle!r}")
        if max_neighbours < 1:
            raise ValueError("max_neighbours must be >= 1")
        if max_inflation is None:
            max_inflation = safety_distance
        if not (math.isfinite(max_inflation) and max_inflation >= 0.0):
            raise ValueError(f"max_inflation must be finite and >= 0, got {max_inflation!r}")
        self.safety_distance = float(safety_distance)
        self.max_speed = float(max_speed)
        self.time_horizon = float(time_horizon)
        self.stale_after = float(stale_after)
        self.max_neighbours = int(max_neighbours)
        self.neighbour_range = float(neighbour_range)
        self.forget_after = float(forget_after)
        self.max_inflation = float(max_inflation)
        self.time_step = float(time_step)
        self.bias_angle = float(bias_angle)
        self.response_time = float(response_time)
        self.zones = zones

    # -- the age term ------------------------------------------------------------------------
    def inflation(self, age: float, rel_speed: float) -> float:
        """Extra combined radius for a pose ``age`` seconds old at relative speed ``rel_speed``.

        ``rel_speed * (age + response_time)`` while fresh; past ``stale_after`` it grows at
        ``max(rel_speed, max_speed)``; never more than ``max_inflation``.
        """
        a = max(age, 0.0)
        e = rel_speed * (min(a, self.stale_after) + self.response_time)
        if a > self.stale_after:
            e += max(rel_speed, self.max_speed) * (a - self.stale_after)
        return min(e, self.max_inflation)

    # -- one ORCA half-plane -----------------------------------------------------------------
    def _half_plane(
        self, me_uav: int, v_a: Vec2, x: Vec2, v: Vec2, r: float, share: float, other_uav: int
    ) -> HalfPlane:
        """ORCA half-plane for relative position ``x`` (B - A), relative velocity ``v`` (A - B)."""
        xx, xy = x
        vx, vy = v
        d2 = xx * xx + xy * xy
        r2 = r * r
        if d2 > r2:
            inv_tau = 1.0 / self.time_horizon
            wx, wy = vx - xx * inv_tau, vy - xy * inv_tau
            w2 = wx * wx + wy * wy
            wdotx = wx * xx + wy * xy
            if wdotx < 0.0 and wdotx * wdotx > r2 * w2:
                # nearest to the cut-off disk
                wl = math.sqrt(w2)
                nx, ny = wx / wl, wy / wl
                k = r * inv_tau - wl
                ux, uy = nx * k, ny * k
            else:
                # nearest to a leg of the cone; legs are x rotated by +-asin(r/|x|)
                leg = math.sqrt(d2 - r2)
                if xx * wy - xy * wx > 0.0:  # w counter-clockwise of x: left leg
                    dx, dy = (xx * leg - xy * r) / d2, (xx * r + xy * leg) / d2
                    nx, ny = -dy, dx  # outward = leg direction turned left
                else:
                    dx, dy = (xx * leg + xy * r) / d2, (-xx * r + xy * leg) / d2
                    nx, ny = dy, -dx  # outward = leg direction turned right
                s = vx * dx + vy * dy
                ux, uy = s * dx - vx, s * dy - vy
        else:
            # already closer than r: leave the disk of radius r/dt around x/dt within one step
            inv_dt = 1.0 / self.time_step
            wx, wy = vx - xx * inv_dt, vy - xy * inv_dt
            wl = math.hypot(wx, wy)
            if wl <= 1e-9:
                # no relative motion information to go on: move straight away from B
                dl = math.sqrt(d2)
                if dl > 1e-9:
                    wx, wy, wl = -xx / dl, -xy / dl, 1.0
                else:  # coincident: split deterministically by id
                    wx, wy, wl = (-1.0, 0.0, 1.0) if me_uav < other_uav else (1.0, 0.0, 1.0)
            nx, ny = wx / wl, wy / wl
            k = r * inv_dt - wl
            ux, uy = nx * k, ny * k
        return HalfPlane((v_a[0] + share * ux, v_a[1] + share * uy), (nx, ny))

    # -- the public call ---------------------------------------------------------------------
    def adjust(self, me: SelfState, preferred: Vec2, neighbours: Sequence[NeighbourView],
               altitude: float = math.nan) -> AvoidanceResult:
        """Safe velocity closest to ``preferred``; never faster than ``max_speed``.

        ``altitude`` (m above the origin) decides which zones apply; NaN: all of them.
        """
        pref = preferred if is_finite(preferred) else (0.0, 0.0)
        pref = clipped = clip_norm(pref, self.max_speed)
        if not is_finite(me.pos):
            # we do not know where we are: hovering is the only defensible answer
            return AvoidanceResult((0.0, 0.0), True, math.inf, 0.0)
        hard: list[HalfPlane] = []
        if self.zones:
            zone_planes = self.zones.planes(me.pos, altitude)
            hard = [h for _, h in zone_planes]
            pref = self.zones.steer(pref, zone_planes, me.pos)
        v_a = me.vel if is_finite(me.vel) else (0.0, 0.0)
        px, py = me.pos
        vax, vay = v_a

        # Every neighbour passes through this loop each tick (up to 99 at N = 100), most of them
        # out of range or beyond the nearest max_neighbours: names bound once, and the half-plane
        # worked out only for the nearest in range (after the loop), the inflation for them and the closest.
        me_uav, forget, in_range, stale = me.uav, self.forget_after, self.neighbour_range, self.stale_after
        isfinite, hypot = math.isfinite, math.hypot
        closest, closest_age, closest_rv = math.inf, 0.0, 0.0
        near: list[tuple[float, float, float, float, float, float, NeighbourView]] = []
        for nb in neighbours:
            if nb.uav == me_uav:
                continue
            age = nb.age
            if not -math.inf < age <= forget:  # too old, or NaN
                continue
            if age < 0.0:
                age = 0.0  # clock skew: treat as fresh
            bx, by = nb.pos
            bvx, bvy = nb.vel
            if not (isfinite(bx) and isfinite(by) and isfinite(bvx) and isfinite(bvy)):
                continue
            xx = bx + bvx * age - px
            xy = by + bvy * age - py
            d = hypot(xx, xy)
            if d < closest:
                closest, closest_age, closest_rv = d, age, hypot(vax - bvx, vay - bvy)
            if d <= in_range:
                near.append((d, xx, xy, bvx, bvy, age, nb))

        closest_infl = self.inflation(closest_age, closest_rv) if closest < math.inf else 0.0
        if not near and not hard:
            return AvoidanceResult(pref, pref != clipped, closest, closest_infl)
        # the nearest max_neighbours, nearest first (ties in the order given, as a stable sort keeps them)
        near = heapq.nsmallest(self.max_neighbours, near, key=_FIRST)
        cons: list[_Constraint] = []
        for d, xx, xy, bvx, bvy, age, nb in near:
            rvx, rvy = vax - bvx, vay - bvy
            infl = self.inflation(age, hypot(rvx, rvy))
            share = 0.5 if (nb.reciprocal and age <= stale) else 1.0
            plane = self._half_plane(
                me_uav, v_a, (xx, xy), (rvx, rvy), self.safety_distance + infl, share, nb.uav
            )
            # the neighbour's own speed towards us, relative to a fifth of our top speed
            closing = -(bvx * xx + bvy * xy) / d if d > 1e-9 else 0.0
            oncoming = min(max(closing / (0.2 * self.max_speed), 0.0), 1.0)
            cons.append(_Constraint(d, plane, oncoming))
        planes = hard + [c.plane for c in cons]
        v, feasible = solve(planes, self.max_speed, pref, hard=len(hard))
        if not feasible and hard and self.zones is not None and cons:
            # boxed in between a zone's margin and a neighbour: give way into the margin (never into the zone)
            # rather than towards the neighbour
            hard = [h for _, h in self.zones.planes(me.pos, altitude, margin=self.zones.margin * YIELD_MARGIN)]
            planes = hard + [c.plane for c in cons]
            v, feasible = solve(planes, self.max_speed, pref, hard=len(hard))
        sp = math.hypot(pref[0], pref[1])
        if self.bias_angle > 0.0 and sp > 1e-9 and cons:
            # keep-right: the more progress is blocked by traffic coming our way, the more the
            # wish turns clockwise (a parked neighbour is just waited for, not circled)
            blocked = 1.0 - (v[0] * pref[0] + v[1] * pref[1]) / (sp * sp)
            oncoming = max(c.oncoming for c in cons)
            if blocked > 1e-6 and oncoming > 0.0:
                phi = self.bias_angle * min(blocked, 1.0) * oncoming
                c, s = math.cos(phi), math.sin(phi)
                biased = (c * pref[0] + s * pref[1], -s * pref[0] + c * pref[1])
                v, feasible = solve(planes, self.max_speed, biased, hard=len(hard))
        v = clip_norm(v, self.max_speed)
        active = math.hypot(v[0] - clipped[0], v[1] - clipped[1]) > 1e-6
        return AvoidanceResult(v, active, closest, closest_infl, feasible, len(cons))
