"""COMMAND_LONG / COMMAND_INT handling: one function per MAV_CMD, one ACK per command.

Handlers return ``(MAV_RESULT, reason)``; on ArduPilot a refusal's reason also goes out as STATUSTEXT (PX4
sends none on its onboard link). Everything a handler sends goes out after its ACK, as both firmwares do,
except what it sends with ``v.send_now`` (PX4's replies to REQUEST_MESSAGE come first). PX4 ACKs DO_SET_MODE
twice. NaN (and INT32_MAX for COMMAND_INT x/y) mean "unset". Unknown commands get UNSUPPORTED.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from uav_stack.fcu import ardupilot, px4
from uav_stack.fcu.offboard import GLOBAL_FRAMES
from uav_stack.fcu.streams import REQUESTABLE, STREAM_BY_ID
from uav_stack.fcu.vehicle import ACCEPTED, DENIED, FAILED, Vehicle
from uav_stack.geo import GeoPoint
from uav_stack.mav import mavlink

M = mavlink
NAN = math.nan
INT32_MAX = 2**31 - 1
FORCE_MAGIC = 21196
ALT_MIN, ALT_MAX = -1000.0, 20000.0  # m AMSL accepted in commands
MAX_REL_ALT = 10000.0  # m, ArduPilot takeoff
UNSUPPORTED = M.MAV_RESULT_UNSUPPORTED

Result = tuple[int, str]


@dataclass
class MavCommand:
    """A received COMMAND_LONG or COMMAND_INT, in one shape (params 1-7, plus the frame for COMMAND_INT)."""

    command: int
    p1: float
    p2: float
    p3: float
    p4: float
    p5: float  # COMMAND_LONG: float; COMMAND_INT: x (int) as float
    p6: float
    p7: float
    frame: int | None  # COMMAND_INT frame; None for COMMAND_LONG
    src_sys: int
    src_comp: int

    @property
    def is_int(self) -> bool:
        return self.frame is not None

    @classmethod
    def from_long(cls, m: mavlink.MAVLink_message) -> MavCommand:
        return cls(m.command, m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7, None,
                   m.get_srcSystem(), m.get_srcComponent())  # fmt: skip

    @classmethod
    def from_int(cls, m: mavlink.MAVLink_message) -> MavCommand:
        return cls(m.command, m.param1, m.param2, m.param3, m.param4, float(m.x), float(m.y), m.z, m.frame,
                   m.get_srcSystem(), m.get_srcComponent())  # fmt: skip

    def latlon(self) -> tuple[float, float] | None:
        """Target latitude/longitude in degrees from p5/p6; None if unset.

        Raises ValueError for a set but impossible location.
        """
        if self.is_int:
            x, y = int(self.p5), int(self.p6)
            if x == INT32_MAX or y == INT32_MAX or (x == 0 and y == 0):
                return None
            lat, lon = x * 1e-7, y * 1e-7
        else:
            if not (math.isfinite(self.p5) and math.isfinite(self.p6)):
                return None
            lat, lon = self.p5, self.p6
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise ValueError("latitude/longitude out of range")
        return lat, lon

    def alt_amsl(self, home_alt: float) -> float | None:
        """Target altitude AMSL from p7 (COMMAND_INT frames may make it relative); None if unset.

        Raises ValueError for an altitude no multirotor flies at.
        """
        if not math.isfinite(self.p7):
            return None
        alt = self.p7 + home_alt if self.is_int and GLOBAL_FRAMES.get(self.frame, False) else self.p7
        if not ALT_MIN <= alt <= ALT_MAX:
            raise ValueError("altitude out of range")
        return alt


def _finite(x: float) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


# ------------------------------------------------------------------ handlers
def cmd_arm_disarm(v: Vehicle, c: MavCommand) -> Result:
    force = _finite(c.p2) and int(c.p2) == FORCE_MAGIC
    if not _finite(c.p1):
        return DENIED, "ARM_DISARM: param1 unset"
    if c.p1 >= 0.5:
        return v.arm(force)
    return v.disarm(force, why="forced" if force else "command")


def cmd_takeoff(v: Vehicle, c: MavCommand) -> Result:
    if v.flavour.is_px4:
        # PX4: p7 is AMSL; NaN (MAVSDK) or not above home -> MIS_TAKEOFF_ALT above home
        try:
            alt = c.alt_amsl(v.home.alt)
        except ValueError as e:
            return DENIED, f"Takeoff: {e}"
        if alt is not None and alt <= v.home.alt:
            v.statustext(M.MAV_SEVERITY_WARNING, f"Takeoff alt {alt:.1f} below home: MIS_TAKEOFF_ALT")
            alt = None
        alt = alt if alt is not None else NAN
        yaw = c.p4 if _finite(c.p4) else NAN
        same = (alt == v.takeoff_alt_amsl or alt != alt and v.takeoff_alt_amsl != v.takeoff_alt_amsl) and (
            yaw == v.takeoff_yaw or yaw != yaw and v.takeoff_yaw != v.takeoff_yaw
        )
        if v.mode.name == "TAKEOFF" and v.phase == "takeoff" and same:
            return ACCEPTED, ""  # a retry of the takeoff in progress
        v.takeoff_alt_amsl = alt
        v.takeoff_yaw = yaw
        v.enter_mode(v.flavour.mode("TAKEOFF"))
        return ACCEPTED, ""
    # ArduPilot: GUIDED and armed, on the ground; p7 = altitude above the current position
    if v.mode.name != "GUIDED":
        return FAILED, "Takeoff requires GUIDED mode"
    if not v.armed:
        return FAILED, "Takeoff: not armed"
    if v.phase == "takeoff" or v.pending_takeoff is not None:
        return ACCEPTED, ""  # a retry of the takeoff in progress
    if not v.landed:
        return FAILED, "Takeoff: already flying"
    if not _finite(c.p7) or not 0 < c.p7 <= MAX_REL_ALT:
        return FAILED, "Takeoff: altitude must be > 0"
    z = float(v.ctx.dyn.pos[v.i, 2]) - c.p7
    # ArduCopter ramps its throttle up first: it leaves the ground a few seconds after the ACK
    v.pending_takeoff = (v.now + ardupilot.TAKEOFF_SPOOL_S, z, c.p4 if _finite(c.p4) else NAN)
    return ACCEPTED, ""


def cmd_land(v: Vehicle, c: MavCommand) -> Result:
    result, why = v.request_mode(v.flavour.mode("LAND"))
    if result == ACCEPTED:
        v.event(px4.LANDING_CURRENT_POS)
    return result, why


def cmd_rtl(v: Vehicle, c: MavCommand) -> Result:
    return v.request_mode(v.flavour.mode("RTL"))


def cmd_loiter_unlim(v: Vehicle, c: MavCommand) -> Result:
    return v.request_mode(v.flavour.mode(v.flavour.hold_mode))


def cmd_set_mode(v: Vehicle, c: MavCommand) -> Result:
    base = int(c.p1) if _finite(c.p1) else M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if not base & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return DENIED, "DO_SET_MODE: only custom modes supported"
    spec = v.flavour.from_command(c.p2, c.p3)
    if spec is None:
        return DENIED, "DO_SET_MODE: unknown mode"
    return v.request_mode(spec)


def cmd_reposition(v: Vehicle, c: MavCommand) -> Result:
    if c.is_int and c.frame not in GLOBAL_FRAMES:
        return DENIED, "Reposition: frame not supported"
    if not v.armed:
        return DENIED, "Reposition: not armed"
    try:
        ll = c.latlon()
        alt = c.alt_amsl(v.home.alt)
    except ValueError as e:
        return DENIED, f"Reposition: {e}"
    if not v.flavour.is_px4:
        change_mode = _finite(c.p2) and int(c.p2) & 1
        if v.landed:
            return FAILED, "Reposition: not flying"
        if v.mode.name != "GUIDED" and not change_mode:
            return FAILED, "Reposition: not in GUIDED"
        if v.mode.name != "GUIDED":
            v.enter_mode(v.flavour.mode("GUIDED"))
    d, i = v.ctx.dyn, v.i
    # unset axes keep the current hold target, or where the vehicle would stop now
    target = d.pos_sp[i].copy() if v.phase == "hold" and np.isfinite(d.pos_sp[i]).all() else d.stop_point(i)
    if ll is not None:
        t = v.ned_of(ll[0], ll[1], alt if alt is not None else v.frame.origin.alt)
        target[0], target[1] = t[0], t[1]
    if alt is not None:
        target[2] = min(v.alt_to_z(alt), float(d.ground_z[i]))
    speed = c.p1 if _finite(c.p1) and c.p1 > 0 else NAN
    yaw = c.p4 if _finite(c.p4) else NAN
    v.goto(target, speed, yaw)
    return ACCEPTED, ""


def cmd_change_speed(v: Vehicle, c: MavCommand) -> Result:
    kind = int(c.p1) if _finite(c.p1) else 1
    speed = c.p2
    if speed != speed or speed == -1:
        return ACCEPTED, ""  # no change
    if not math.isfinite(speed) or speed > 100.0:
        return DENIED, "DO_CHANGE_SPEED: speed out of range"
    value = NAN if speed == -2 or speed <= 0 else float(speed)
    if kind in (0, 1):
        v.speed_xy = value if value != value else min(value, v.settings.xy_vel_max)
    elif kind == 2:
        v.speed_up = value
    elif kind == 3:
        v.speed_dn = value
    else:
        return DENIED, "DO_CHANGE_SPEED: unknown speed type"
    v._apply_limits()
    return ACCEPTED, ""


def cmd_set_home(v: Vehicle, c: MavCommand) -> Result:
    if _finite(c.p1) and int(c.p1) == 1:
        lat, lon, alt = v.geodetic()
    else:
        try:
            ll = c.latlon()
            alt_v = c.alt_amsl(v.home.alt)
        except ValueError as e:
            return DENIED, f"DO_SET_HOME: {e}"
        if ll is None:
            return DENIED, "DO_SET_HOME: no position"
        lat, lon = ll
        alt = alt_v if alt_v is not None else v.home.alt
    v.set_home(GeoPoint(lat, lon, alt))
    return ACCEPTED, ""


def _reply(v: Vehicle, msg: mavlink.MAVLink_message | None) -> Result:
    """Send a requested message. PX4 sends it just before its ACK, and DENIES when it has nothing to send
    (no home yet); ArduPilot sends it after the ACK, and ACCEPTS even then (the message just does not come)."""
    if v.flavour.is_px4:
        if msg is None:
            return DENIED, ""
        v.send_now(msg)
        return ACCEPTED, ""
    if msg is not None:
        v.send(msg)
    return ACCEPTED, ""


def _unknown(v: Vehicle) -> Result:
    """A message this firmware cannot send (ArduPilot: FAILED, as for PROTOCOL_VERSION; PX4: DENIED)."""
    return (DENIED if v.flavour.is_px4 else FAILED), ""


def _msg_id(x: float) -> int | None:
    return int(x) if _finite(x) and 0 <= x < 1 << 24 else None


def cmd_request_message(v: Vehicle, c: MavCommand) -> Result:
    if _msg_id(c.p1) is None:
        return _unknown(v)
    fn = REQUESTABLE[v.flavour.name].get(int(c.p1))
    if fn is None:
        return _unknown(v)
    return _reply(v, fn(v))


def cmd_autopilot_caps(v: Vehicle, c: MavCommand) -> Result:
    return _reply(v, REQUESTABLE[v.flavour.name][M.MAVLINK_MSG_ID_AUTOPILOT_VERSION](v))


def cmd_get_home(v: Vehicle, c: MavCommand) -> Result:
    return _reply(v, v.encoders["HOME_POSITION"](v))


def cmd_mission_start(v: Vehicle, c: MavCommand) -> Result:
    """MISSION_START: the mission mode, from item p1 if given (p2, the last item, is not supported)."""
    if _finite(c.p1) and c.p1 > 0 and not v.mission.set_current(int(c.p1)):
        return DENIED, f"Mission: no item {int(c.p1)}"
    result, why = v.request_mode(v.flavour.mode(v.flavour.mission_mode))
    if result == ACCEPTED and not v.flavour.is_px4:
        v.mission.say_item()  # ArduCopter names the item again when the mission (re)starts
    return result, why


def cmd_set_mission_current(v: Vehicle, c: MavCommand) -> Result:
    """DO_SET_MISSION_CURRENT: fly item p1 next (p2 = 1, reset the mission: from its start)."""
    seq = int(c.p1) if _finite(c.p1) else -1
    if _finite(c.p2) and int(c.p2) == 1:
        seq = v.mission.first
    if not v.mission.set_current(seq):
        return DENIED, f"Mission: no item {seq}"
    return ACCEPTED, ""


def cmd_set_message_interval(v: Vehicle, c: MavCommand) -> Result:
    if _msg_id(c.p1) is None or not _finite(c.p2) or not -1 <= c.p2 <= 2e9:
        return DENIED, ""
    name = STREAM_BY_ID.get(int(c.p1))
    if name is None or name not in v.encoders:
        return _unknown(v)
    if name == "HEARTBEAT":
        if c.p2 == -1 or c.p2 < 0:
            return DENIED, "HEARTBEAT cannot be disabled"
        v.hb_period = max(c.p2 * 1e-6, 0.1) if c.p2 > 0 else 1.0
        v.hb_interval_wall = v.hb_period / max(1.0, v.ctx.clock.target_rtf)
        return ACCEPTED, ""
    v.streams.set_interval_us(name, c.p2, v.now, v.default_rate(name))
    return ACCEPTED, ""


def cmd_get_message_interval(v: Vehicle, c: MavCommand) -> Result:
    """MESSAGE_INTERVAL, just before the ACK (both firmwares): -1 for a message not streamed."""
    mid = _msg_id(c.p1)
    if mid is None or mid > 0xFFFF:  # MESSAGE_INTERVAL.message_id is 16 bit
        return DENIED, ""
    name = STREAM_BY_ID.get(mid)
    if name is None or name not in v.encoders:
        v.send_now(v.mav.message_interval_encode(mid, 0))
        return (ACCEPTED if v.flavour.is_px4 else FAILED), ""
    if name == "HEARTBEAT":
        v.send_now(v.mav.message_interval_encode(mid, int(v.hb_period * 1e6)))
    else:
        v.send_now(v.mav.message_interval_encode(mid, v.streams.interval_us(name)))
    return ACCEPTED, ""


HANDLERS: dict[int, Callable[[Vehicle, MavCommand], Result]] = {
    M.MAV_CMD_COMPONENT_ARM_DISARM: cmd_arm_disarm,
    M.MAV_CMD_NAV_TAKEOFF: cmd_takeoff,
    M.MAV_CMD_NAV_LAND: cmd_land,
    M.MAV_CMD_NAV_RETURN_TO_LAUNCH: cmd_rtl,
    M.MAV_CMD_NAV_LOITER_UNLIM: cmd_loiter_unlim,
    M.MAV_CMD_DO_SET_MODE: cmd_set_mode,
    M.MAV_CMD_DO_REPOSITION: cmd_reposition,
    M.MAV_CMD_DO_CHANGE_SPEED: cmd_change_speed,
    M.MAV_CMD_DO_SET_HOME: cmd_set_home,
    M.MAV_CMD_REQUEST_MESSAGE: cmd_request_message,
    M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: cmd_autopilot_caps,
    M.MAV_CMD_GET_HOME_POSITION: cmd_get_home,
    M.MAV_CMD_SET_MESSAGE_INTERVAL: cmd_set_message_interval,
    M.MAV_CMD_MISSION_START: cmd_mission_start,
    M.MAV_CMD_DO_SET_MISSION_CURRENT: cmd_set_mission_current,
    M.MAV_CMD_GET_MESSAGE_INTERVAL: cmd_get_message_interval,
}

_RESULT_NAMES = {
    getattr(M, n): n[len("MAV_RESULT_") :] for n in dir(M) if n.startswith("MAV_RESULT_") and n != "MAV_RESULT_ENUM_END"
}


def handle_command(v: Vehicle, c: MavCommand) -> None:
    """Run one command and ACK it (always exactly one ACK, two for PX4's DO_SET_MODE, even if the handler
    raises); what the handler sent follows the ACK."""
    stats = v.ctx.stats
    stats.commands_by_id[c.command] += 1
    fn = HANDLERS.get(c.command)
    held: list[mavlink.MAVLink_message] = []
    v._deferred = held
    try:
        result, reason = fn(v, c) if fn is not None else (UNSUPPORTED, "")
    except Exception:
        stats.handler_errors += 1
        stats.handler_errors_by_type[f"COMMAND_{c.command}"] += 1
        v.ctx.log.exception("sysid %d: command %d failed", v.sysid, c.command)
        result, reason = FAILED, ""
    finally:
        v._deferred = None
    stats.commands[_RESULT_NAMES.get(result, str(result))] += 1
    px = v.flavour.is_px4
    ack = v.mav.command_ack_encode(c.command, result, 0, 0, c.src_sys, c.src_comp)
    v.send(ack)
    if px and c.command == M.MAV_CMD_DO_SET_MODE:
        v.send(v.mav.command_ack_encode(c.command, result, 0, 0, c.src_sys, c.src_comp))
    for m in held:
        v.send(m)
    if reason and result != ACCEPTED and not px:
        v.statustext(M.MAV_SEVERITY_WARNING if result == DENIED else M.MAV_SEVERITY_ERROR, reason)
