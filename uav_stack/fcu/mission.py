"""Flying the uploaded mission: PX4 MISSION and ArduCopter AUTO.

The mission protocol (mission_transfer.py) stores the items; :class:`MissionRun` flies them
while the vehicle is in its flavour's mission mode, one item after the other, and reports
like the autopilots do: MISSION_CURRENT (the item flown, the mission's state) on every change
and at 1 Hz, MISSION_ITEM_REACHED when a navigation item is done.

Items (MAV_CMD): NAV_WAYPOINT (hold time p1 s, acceptance radius p2 m, yaw p4 deg),
NAV_SPLINE_WAYPOINT / NAV_LOITER_TURNS / NAV_LOITER_TO_ALT (flown as waypoints),
NAV_LOITER_TIME (p1 s), NAV_LOITER_UNLIM, NAV_DELAY (p1 s), NAV_TAKEOFF, NAV_LAND,
NAV_RETURN_TO_LAUNCH, DO_CHANGE_SPEED (p2 m/s), DO_JUMP (p1 item, p2 repeats); any other
DO/condition item (camera, gimbal, ...) passes at once. A waypoint counts as reached inside
its acceptance radius (NAV_ACC_RAD / WPNAV_RADIUS when the item gives none) and within
NAV_MC_ALT_RAD vertically (PX4), or inside a sphere of that radius (ArduCopter). Positions:
latitude/longitude in degE7 (both 0: where the vehicle is), altitude per the item's frame
(relative to home, or AMSL).

Reporting differs as the firmwares do: PX4's MISSION_CURRENT has mission_state 0 (unknown), it sends
MISSION_ITEM_REACHED for every item done (a DO item as it passes: MAVSDK's is_mission_finished counts on the
last one) and repeats it for the last item reached about once a second; ArduCopter names each item as it starts
("Mission: 2 WP") and each waypoint reached ("Reached command #2"), and reports mission_mode 0 outside AUTO.

Flavour differences: ArduCopter's item 0 is its home and is never flown, and from the ground
(armed) AUTO needs a NAV_TAKEOFF as the next item ("Auto: Missing Takeoff Cmd"); PX4 takes
off to MIS_TAKEOFF_ALT by itself when a mission starts on the ground without one. Leaving the
mission mode pauses the mission; coming back continues with the current item, or starts over
once the mission is complete. After its last item the vehicle holds there, still in the
mission mode (a NAV_LAND or NAV_RETURN_TO_LAUNCH item ends it on the ground).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from uav_stack.fcu import px4
from uav_stack.fcu.modes import P_LAND, P_MISSION, P_TAKEOFF, TAKEOFF_DONE_M, Guidance
from uav_stack.fcu.offboard import GLOBAL_FRAMES
from uav_stack.mav import mavlink

if TYPE_CHECKING:
    from uav_stack.fcu.vehicle import Vehicle

M = mavlink
NAN = math.nan
UINT16_MAX = 65535
WAYPOINTS = frozenset({
    M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_SPLINE_WAYPOINT, M.MAV_CMD_NAV_LOITER_TURNS, M.MAV_CMD_NAV_LOITER_TO_ALT,
    M.MAV_CMD_NAV_LOITER_TIME, M.MAV_CMD_NAV_LOITER_UNLIM,
})  # fmt: skip
ENDS_ON_GROUND = frozenset({M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_RETURN_TO_LAUNCH})
ITEM_WORDS = {M.MAV_CMD_NAV_TAKEOFF: "Takeoff", M.MAV_CMD_NAV_WAYPOINT: "WP", M.MAV_CMD_NAV_RETURN_TO_LAUNCH: "RTL",
              M.MAV_CMD_NAV_LAND: "Land", M.MAV_CMD_NAV_LOITER_TIME: "LoitTime", M.MAV_CMD_NAV_LOITER_UNLIM: "LoitUnlim",
              M.MAV_CMD_NAV_LOITER_TURNS: "LoitTurns", M.MAV_CMD_NAV_SPLINE_WAYPOINT: "SplineWP",
              M.MAV_CMD_NAV_DELAY: "Delay"}  # ArduCopter's words for its items ("Mission: 2 WP")  # fmt: skip
MAX_STEPS_PER_ITEM = 4  # bounds a chain of DO_JUMPs: at most this many passes over the mission per advance


def is_nav(command: int) -> bool:
    """NAV commands (16..94) take time and move the vehicle; DO and condition commands pass at once."""
    return command < M.MAV_CMD_NAV_LAST


@dataclass(frozen=True)
class MissionItem:
    """One stored item, in MISSION_ITEM_INT terms."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    params: tuple[float, float, float, float]
    x: int  # latitude, degE7 (global frames)
    y: int  # longitude, degE7
    z: float  # altitude, m (relative to home or AMSL, per frame)
    mission_type: int = 0


class MissionRun:
    """The mission of one vehicle: which item is flown, and the state MISSION_CURRENT reports."""

    def __init__(self, v: Vehicle):
        self.v = v
        self.current = 0
        self.state = M.MISSION_STATE_NO_MISSION
        self.stage = ""  # takeoff | auto_takeoff | goto | hold | loiter | land | rtl | done
        self.hold_s = 0.0  # hold time at the waypoint being flown to
        self.hold_until = math.inf
        self.target = np.zeros(3)
        self.radius = 2.0
        self.jumps: dict[int, int] = {}  # DO_JUMP seq -> jumps left
        self.speed = NAN  # the mission's DO_CHANGE_SPEED, m/s (kept over a pause)
        self._announced: tuple[int, int, int] | None = None
        self.last_reached: int | None = None  # PX4 repeats MISSION_ITEM_REACHED for it
        self._reached_again = math.inf

    # ---- what is stored ---------------------------------------------------------------
    @property
    def items(self) -> list[MissionItem]:
        return self.v.missions[M.MAV_MISSION_TYPE_MISSION]

    @property
    def first(self) -> int:
        """The first item flown: ArduCopter keeps its home as item 0."""
        return 0 if self.v.flavour.is_px4 else 1

    def flyable(self) -> bool:
        return len(self.items) > self.first

    def load(self) -> None:
        """A new mission was stored (or cleared): start from its first item next time."""
        self.current = self.first if self.flyable() else 0
        self.state = M.MISSION_STATE_NOT_STARTED if self.flyable() else M.MISSION_STATE_NO_MISSION
        self.stage = ""
        self.jumps = {}
        self.speed = NAN
        self.last_reached = None
        if self.v.mode.guidance is Guidance.MISSION:
            self.v._start_hold()  # a new plan while flying one: hold until the mission mode is entered again
        self.announce()

    # ---- mode changes -----------------------------------------------------------------
    def can_start(self) -> tuple[bool, str]:
        v = self.v
        if not self.flyable():
            return False, "Mission: no mission uploaded" if v.flavour.is_px4 else "Auto: no mission"
        if not v.flavour.is_px4 and v.armed and v.landed and self.state != M.MISSION_STATE_ACTIVE:
            nxt = self._next_nav(self.first if self.state == M.MISSION_STATE_COMPLETE else self.current)
            if nxt is None or nxt.command != M.MAV_CMD_NAV_TAKEOFF:
                return False, "Auto: Missing Takeoff Cmd"
        return True, ""

    def start(self) -> None:
        """Entering the mission mode, or arming in it: fly from the current item."""
        v = self.v
        if self.state == M.MISSION_STATE_COMPLETE:
            self.current, self.jumps, self.speed = self.first, {}, NAN
        if not self.flyable():
            v._start_hold()
            return
        if not v.armed:  # the mission begins when the vehicle is armed
            v._start_hold()
            self.announce()
            self.say_item()
            return
        self.state = M.MISSION_STATE_ACTIVE
        if self.speed == self.speed:
            v.speed_xy = self.speed  # a paused mission resumes at its own speed
        nxt = self._next_nav(self.current)
        if v.flavour.is_px4:
            v.event(px4.MISSION_EXECUTE)
            if v.landed:  # "climbing to ... before starting the mission" (its takeoff item's altitude, or the default)
                alt = self._z_above_home(nxt) if nxt is not None and nxt.command == M.MAV_CMD_NAV_TAKEOFF else NAN
                climb = alt if alt == alt and alt > 0 else v.settings.takeoff_alt
                v.event(px4.Event(px4.MISSION_CLIMB.name, px4.MISSION_CLIMB.id, px4.MISSION_CLIMB.log_levels,
                                  struct.pack("<f", climb)))  # fmt: skip
        if v.flavour.is_px4 and v.landed and (nxt is None or nxt.command != M.MAV_CMD_NAV_TAKEOFF):
            z = v.alt_to_z(v.home.alt + v.settings.takeoff_alt)  # PX4 takes off by itself first
            v._start_takeoff(z)
            self.stage = "auto_takeoff"
            self.target = v.takeoff_target.copy()
            self.announce()
            return
        self._begin()

    def pause(self) -> None:
        """Leaving the mission mode: the current item is kept for later."""
        if self.state == M.MISSION_STATE_ACTIVE:
            self.state = M.MISSION_STATE_PAUSED
        self.stage = ""
        self.announce()

    def set_current(self, seq: int) -> bool:
        """MISSION_SET_CURRENT / DO_SET_MISSION_CURRENT: fly ``seq`` next (at once, if flying the mission)."""
        if not 0 <= seq < len(self.items):
            return False
        self.current = max(seq, self.first)
        self.jumps = {}
        if self.state == M.MISSION_STATE_ACTIVE and self.v.mode.guidance is Guidance.MISSION and self.v.armed:
            self._begin()
        elif self.state == M.MISSION_STATE_COMPLETE:
            self.state = M.MISSION_STATE_NOT_STARTED
        self.announce(force=True)
        return True

    # ---- flying -----------------------------------------------------------------------
    def tick(self, now: float) -> None:
        """Supervisor tick (10 Hz of sim time) while in the mission mode."""
        v = self.v
        if self.state != M.MISSION_STATE_ACTIVE or not v.armed:
            return
        st = self.stage
        d, i = v.ctx.dyn, v.i
        if st in ("takeoff", "auto_takeoff"):
            if v.phase == P_TAKEOFF and not v.landed and abs(d.pos[i, 2] - v.takeoff_target[2]) < TAKEOFF_DONE_M:
                if st == "takeoff":
                    self._reached()
                else:
                    self._begin()
        elif st == "goto":
            if self._arrived():
                if self.hold_s > 0:
                    self.stage, self.hold_until = "hold", now + self.hold_s
                elif self.items[self.current].command == M.MAV_CMD_NAV_LOITER_UNLIM:
                    self.stage = "loiter"
                else:
                    self._reached()
        elif st == "hold":
            if now >= self.hold_until:
                self._reached()
        elif st in ("land", "rtl") and v.phase == P_LAND and v.landed:
            self._reached()

    def _arrived(self) -> bool:
        """Inside the acceptance radius: PX4 a cylinder (radius, NAV_MC_ALT_RAD), ArduCopter a sphere."""
        v = self.v
        p, t = v.ctx.dyn.pos[v.i], self.target
        if not v.flavour.is_px4:
            return math.dist(p, t) <= self.radius
        return math.hypot(p[0] - t[0], p[1] - t[1]) <= self.radius and abs(p[2] - t[2]) <= v.settings.alt_rad

    def _reached(self) -> None:
        item = self.items[self.current]
        v = self.v
        v.send(v.mav.mission_item_reached_encode(item.seq))
        self.last_reached = item.seq
        self._reached_again = v.now + px4.ITEM_REACHED_REPEAT_S
        if not v.flavour.is_px4 and item.command in WAYPOINTS:
            v.statustext(M.MAV_SEVERITY_INFO, f"Reached command #{item.seq}")
        if item.command in ENDS_ON_GROUND:
            self._complete()
            return
        self.current += 1
        self._begin()

    def _next_nav(self, seq: int) -> MissionItem | None:
        for item in self.items[seq:]:
            if is_nav(item.command):
                return item
        return None

    def _begin(self) -> None:
        """Pass the DO items from ``current`` on, then start the next NAV item (or complete)."""
        items = self.items
        for _ in range(MAX_STEPS_PER_ITEM * len(items) + 1):
            if self.current >= len(items):
                break
            item = items[self.current]
            if not is_nav(item.command):
                self._do(item)
                continue
            if self._fly(item):
                self.announce()
                self.say_item()
                return
            self.v.statustext(M.MAV_SEVERITY_WARNING, f"Mission: item {item.seq} (cmd {item.command}) skipped")
            self.current += 1
        self._complete()

    def _do(self, item: MissionItem) -> None:
        v = self.v
        p1, p2 = item.params[0], item.params[1]
        if item.command == M.MAV_CMD_DO_JUMP and math.isfinite(p1) and math.isfinite(p2):
            left = self.jumps.setdefault(item.seq, int(p2))
            if left != 0 and self.first <= int(p1) < len(self.items):
                self.jumps[item.seq] = left - 1 if left > 0 else left  # < 0: jump forever
                self.current = int(p1)
                return
        elif item.command == M.MAV_CMD_DO_CHANGE_SPEED and math.isfinite(p2) and p2 > 0:
            v.speed_xy = self.speed = min(p2, v.settings.xy_vel_max)
            v._apply_limits()
        if v.flavour.is_px4:  # PX4 reports every item done, a DO item as it passes (ArduCopter: NAV items only)
            v.send(v.mav.mission_item_reached_encode(item.seq))
            self.last_reached = item.seq
            self._reached_again = v.now + px4.ITEM_REACHED_REPEAT_S
        self.current += 1  # camera, gimbal and other payload items: nothing to fly

    def _fly(self, item: MissionItem) -> bool:
        """Start flying one NAV item; False if it is not supported."""
        v = self.v
        cmd = item.command
        d, i = v.ctx.dyn, v.i
        self.hold_s = 0.0
        if cmd == M.MAV_CMD_NAV_TAKEOFF:
            z = self._z(item)
            if not math.isfinite(z) or z >= d.ground_z[i] - 0.5:
                z = v.alt_to_z(v.home.alt + v.settings.takeoff_alt)
            if not v.landed:
                z = min(z, float(d.pos[i, 2]))  # already higher: keep the altitude
            v._start_takeoff(z, self._yaw(item))
            self.stage = "takeoff"
            return True
        if cmd == M.MAV_CMD_NAV_LAND:
            xy = self._xy(item)
            v._start_land(xy)
            self.stage = "land"
            return True
        if cmd == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            v._start_rtl()
            self.stage = "rtl"
            return True
        if cmd == M.MAV_CMD_NAV_DELAY:
            v._start_hold()
            v.phase = P_MISSION
            delay = item.params[0] if math.isfinite(item.params[0]) else 0.0  # -1 (time of day) is not supported
            self.stage, self.hold_until = "hold", v.now + max(delay, 0.0)
            return True
        if cmd not in WAYPOINTS:
            return False
        target = d.stop_point(i) if v.landed else d.pos_sp[i].copy()
        if not np.isfinite(target).all():
            target = d.stop_point(i)
        xy = self._xy(item)
        if xy is not None:
            target[0], target[1] = xy
        z = self._z(item)
        if math.isfinite(z):
            target[2] = min(z, float(d.ground_z[i]))
        p1, p2 = item.params[0], item.params[1]
        if cmd in (M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_TIME) and math.isfinite(p1) and p1 > 0:
            self.hold_s = float(p1)
        self.radius = float(p2) if cmd == M.MAV_CMD_NAV_WAYPOINT and math.isfinite(p2) and p2 > 0 else v.settings.acc_rad
        self.target = target
        yaw = self._yaw(item)
        if yaw != yaw:
            dn, de = target[0] - d.pos[i, 0], target[1] - d.pos[i, 1]
            yaw = math.atan2(de, dn) if math.hypot(dn, de) > 2.0 else NAN  # face the waypoint (MIS_YAWMODE 0)
        v.phase = P_MISSION
        v._targets(target, yaw=yaw)
        v._apply_limits()
        self.stage = "goto"
        return True

    def _xy(self, item: MissionItem) -> np.ndarray | None:
        """The item's north/east in the vehicle's local frame; None for "here" (lat = lon = 0)."""
        if item.frame not in GLOBAL_FRAMES or (item.x == 0 and item.y == 0):
            return None
        lat, lon = item.x * 1e-7, item.y * 1e-7
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return None
        return self.v.ned_of(lat, lon, self.v.frame.origin.alt)[:2]

    def _z(self, item: MissionItem) -> float:
        """The item's altitude as local NED down; NaN when the frame gives none."""
        rel = GLOBAL_FRAMES.get(item.frame)
        if rel is None or not math.isfinite(item.z):
            return NAN
        return self.v.alt_to_z(item.z + (self.v.home.alt if rel else 0.0))

    def _z_above_home(self, item: MissionItem) -> float:
        z = self._z(item)
        return self.v.home_ned[2] - z if math.isfinite(z) else NAN

    def _yaw(self, item: MissionItem) -> float:
        yaw_deg = item.params[3]
        if item.command in (M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_TAKEOFF) and math.isfinite(yaw_deg) and self.v.flavour.is_px4:
            return math.radians(yaw_deg)
        return NAN

    def _complete(self) -> None:
        v = self.v
        self.state = M.MISSION_STATE_COMPLETE
        self.stage = "done"
        self.current = max(min(self.current, len(self.items) - 1), 0)
        if not v.landed:
            v._start_hold()  # hold after the last item, still in the mission mode
        v.statustext(M.MAV_SEVERITY_INFO, "Mission finished")
        self.announce()

    # ---- reporting --------------------------------------------------------------------
    def current_message(self) -> mavlink.MAVLink_message:
        """MISSION_CURRENT: the item flown, the item count, the state. PX4: mission_state 0 (it reports none),
        mission_mode 1 in MISSION else 2. ArduCopter: the count without its home (0 with none), the mission
        ACTIVE as soon as AUTO is on, mission_mode 1 in AUTO else 0."""
        v = self.v
        in_mode = v.mode.guidance is Guidance.MISSION
        if v.flavour.is_px4:
            total = len(self.items) if self.flyable() else UINT16_MAX
            return v.mav.mission_current_encode(self.current, total, 0, 1 if in_mode else 2)
        total = len(self.items) - self.first if self.flyable() else 0
        state = M.MISSION_STATE_ACTIVE if in_mode and self.state == M.MISSION_STATE_NOT_STARTED else self.state
        return v.mav.mission_current_encode(self.current, total, state, 1 if in_mode else 0)

    def say_item(self) -> None:
        """ArduCopter names the item it starts ("Mission: 1 Takeoff")."""
        v = self.v
        if v.flavour.is_px4 or not self.flyable():
            return
        item = self._next_nav(self.current)
        if item is not None:
            v.statustext(M.MAV_SEVERITY_INFO, f"Mission: {item.seq} {ITEM_WORDS.get(item.command, 'WP')}")

    def repeat_reached(self, now: float) -> None:
        """PX4 repeats MISSION_ITEM_REACHED for the last item reached about once a second."""
        if self.last_reached is None or now < self._reached_again or self.v.mode.guidance is not Guidance.MISSION:
            return
        self._reached_again = now + px4.ITEM_REACHED_REPEAT_S
        self.v.send(self.v.mav.mission_item_reached_encode(self.last_reached))

    def announce(self, force: bool = False) -> None:
        """MISSION_CURRENT now, if what it says has changed (also streamed at 1 Hz)."""
        in_mode = 1 if self.v.mode.guidance is Guidance.MISSION else 2
        key = (self.current, self.state, in_mode)
        if force or key != self._announced:
            self._announced = key
            self.v.send(self.current_message())
