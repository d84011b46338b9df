"""Handlers for every MAVLink message the FCU understands (commands live in commands.py).

VirtualFcu looks a message's handler up in ``HANDLERS`` (copied per instance), skips
messages ``addressed_to`` another system/component, and wraps the call so an exception is
logged and counted and the vehicle keeps flying.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from uav_stack.fcu.commands import MavCommand, handle_command
from uav_stack.fcu.offboard import decode_global, decode_local
from uav_stack.fcu.vehicle import ACCEPTED, Vehicle
from uav_stack.mav import mavlink

M = mavlink
FTP_ACK, FTP_NAK = 128, 129
FTP_TERMINATE, FTP_RESET = 1, 2
FTP_ERR_FILE_NOT_FOUND = 10
UPLOAD_STALE_S = 5.0  # wall seconds without progress before a mission upload is abandoned

Handler = Callable[[Vehicle, mavlink.MAVLink_message], None]


def on_heartbeat(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    if m.type == M.MAV_TYPE_GCS:
        v.gcs_last = v.now


def on_command_long(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    handle_command(v, MavCommand.from_long(m))


def on_command_int(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    handle_command(v, MavCommand.from_int(m))


def on_set_mode(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    """SET_MODE (#11): QGC's way to change PX4 modes. No ACK; the heartbeat tells the result."""
    if not m.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        v.statustext(M.MAV_SEVERITY_WARNING, "SET_MODE: only custom modes supported")
        return
    spec = v.flavour.by_custom_mode(m.custom_mode)
    if spec is None:
        v.statustext(M.MAV_SEVERITY_WARNING, f"SET_MODE: unknown mode {m.custom_mode}")
        return
    result, reason = v.request_mode(spec)
    if result != ACCEPTED:
        v.statustext(M.MAV_SEVERITY_WARNING, reason)
    else:
        v.send_heartbeat()  # confirm at once, also when the mode did not change


# ------------------------------------------------------------------ parameters
def _param_value(v: Vehicle, k: int) -> mavlink.MAVLink_message:
    name, value, ptype = v.params.encode(k)
    return v.mav.param_value_encode(name.encode(), value, ptype, len(v.params), k)


def on_param_request_list(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    for k in range(len(v.params)):
        v.send(_param_value(v, k))


def _param_name(raw: str | bytes) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return raw.split("\x00", 1)[0].strip()


def on_param_request_read(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    if m.param_index >= 0:
        if m.param_index < len(v.params):
            v.send(_param_value(v, m.param_index))
        return
    name = _param_name(m.param_id)
    if name in v.params:
        v.send(_param_value(v, v.params.index(name)))


def on_param_set(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    name = _param_name(m.param_id)
    if name not in v.params:
        v.statustext(M.MAV_SEVERITY_WARNING, f"Unknown parameter {name}"[:50])
        return
    value = v.params.decode(name, m.param_value, m.param_type)
    if not v.set_param(name, value):
        v.statustext(M.MAV_SEVERITY_WARNING, f"Param {name}: invalid value"[:50])
    v.send(_param_value(v, v.params.index(name)))


# --------------------------------------------------------------------- mission
def _mission_ack(v: Vehicle, m: mavlink.MAVLink_message, result: int, mission_type: int) -> None:
    v.send(v.mav.mission_ack_encode(m.get_srcSystem(), m.get_srcComponent(), result, mission_type))


def on_mission_request_list(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    items = v.missions.get(m.mission_type)
    if items is None:
        _mission_ack(v, m, M.MAV_MISSION_UNSUPPORTED, m.mission_type)
        return
    v.send(v.mav.mission_count_encode(m.get_srcSystem(), m.get_srcComponent(), len(items), m.mission_type))


def on_mission_count(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    if m.mission_type not in v.missions:
        _mission_ack(v, m, M.MAV_MISSION_UNSUPPORTED, m.mission_type)
        return
    if m.count == 0:
        v.missions[m.mission_type] = []
        v.upload = None
        _mission_ack(v, m, M.MAV_MISSION_ACCEPTED, m.mission_type)
        return
    if m.count > 1000:
        _mission_ack(v, m, M.MAV_MISSION_NO_SPACE, m.mission_type)
        return
    v.upload = {"type": m.mission_type, "count": m.count, "items": [], "t": v.ctx.wall()}
    _request_item(v, m, 0, m.mission_type)


def _request_item(v: Vehicle, m: mavlink.MAVLink_message, seq: int, mission_type: int) -> None:
    v.send(v.mav.mission_request_int_encode(m.get_srcSystem(), m.get_srcComponent(), seq, mission_type))


def _item_fields(m: mavlink.MAVLink_message) -> dict[str, object] | None:
    """The item as MISSION_ITEM_INT fields; None if a float item's x/y cannot be one."""
    is_int = m.get_type() == "MISSION_ITEM_INT"
    if is_int:
        x, y = m.x, m.y
    else:
        if not (math.isfinite(m.x) and math.isfinite(m.y) and abs(m.x) <= 180.0 and abs(m.y) <= 180.0):
            return None
        x, y = int(round(m.x * 1e7)), int(round(m.y * 1e7))
    return {
        "frame": m.frame,
        "command": m.command,
        "current": m.current,
        "autocontinue": m.autocontinue,
        "params": (m.param1, m.param2, m.param3, m.param4),
        "x": x,
        "y": y,
        "z": m.z,
    }


def on_mission_item(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    up = v.upload
    if up is not None and v.ctx.wall() - float(up["t"]) > UPLOAD_STALE_S:  # type: ignore[arg-type]
        v.upload = up = None
    if up is None:
        if m.current == 2 and not v.flavour.is_px4:  # ArduPilot "guided goto" item
            _guided_item(v, m)
        return
    if m.mission_type != up["type"]:
        return
    items: list = up["items"]  # type: ignore[assignment]
    if m.seq != len(items):
        _request_item(v, m, len(items), m.mission_type)
        return
    f = _item_fields(m)
    if f is None:
        v.upload = None
        _mission_ack(v, m, M.MAV_MISSION_INVALID_PARAM5_X, m.mission_type)
        return
    items.append(f)
    up["t"] = v.ctx.wall()
    if len(items) >= up["count"]:  # type: ignore[operator]
        v.missions[m.mission_type] = items
        v.upload = None
        _mission_ack(v, m, M.MAV_MISSION_ACCEPTED, m.mission_type)
    else:
        _request_item(v, m, len(items), m.mission_type)


def _guided_item(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    f = _item_fields(m)
    lat, lon = (int(f["x"]) * 1e-7, int(f["y"]) * 1e-7) if f is not None else (999.0, 999.0)  # type: ignore[call-overload]
    ok_alt = math.isfinite(m.z) and abs(m.z) < 20000.0
    if v.mode.name != "GUIDED" or not v.armed or v.landed or abs(lat) > 90 or abs(lon) > 180 or not ok_alt:
        _mission_ack(v, m, M.MAV_MISSION_ERROR, m.mission_type)
        return
    rel = m.frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
    alt = float(m.z) + (v.home.alt if rel else 0.0)
    target = v.ned_of(lat, lon, alt)
    target[2] = min(target[2], float(v.ctx.dyn.ground_z[v.i]))
    v.goto(target)
    _mission_ack(v, m, M.MAV_MISSION_ACCEPTED, m.mission_type)


def on_mission_request(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    items = v.missions.get(m.mission_type)
    if items is None or not 0 <= m.seq < len(items):
        _mission_ack(v, m, M.MAV_MISSION_INVALID_SEQUENCE, m.mission_type)
        return
    f = items[m.seq]
    p1, p2, p3, p4 = f["params"]
    v.send(
        v.mav.mission_item_int_encode(
            m.get_srcSystem(), m.get_srcComponent(), m.seq, f["frame"], f["command"], f["current"],
            f["autocontinue"], p1, p2, p3, p4, f["x"], f["y"], f["z"], m.mission_type,
        )  # fmt: skip
    )


def on_mission_clear_all(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    if m.mission_type == M.MAV_MISSION_TYPE_ALL:
        for k in v.missions:
            v.missions[k] = []
    elif m.mission_type in v.missions:
        v.missions[m.mission_type] = []
    else:
        _mission_ack(v, m, M.MAV_MISSION_UNSUPPORTED, m.mission_type)
        return
    v.upload = None
    _mission_ack(v, m, M.MAV_MISSION_ACCEPTED, m.mission_type)


# ------------------------------------------------------------------- setpoints
def on_set_position_target_local_ned(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    d = v.ctx.dyn
    sp = decode_local(m, d.pos[v.i].copy(), float(d.yaw[v.i]))
    if sp is not None:
        v.on_setpoint(sp)


def on_set_position_target_global_int(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    sp = decode_global(m, v.frame, v.home.alt)
    if sp is not None:
        v.on_setpoint(sp)


# ------------------------------------------------------------------ small stuff
def on_timesync(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    if m.tc1 == 0:
        v.send(v.mav.timesync_encode(max(1, int(v.now * 1e9)), m.ts1))  # tc1 = 0 would be a request


def on_ping(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    if m.target_system == 0:
        v.send(v.mav.ping_encode(m.time_usec, m.seq, m.get_srcSystem(), m.get_srcComponent()))


def on_ftp(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    """No MAVLink-FTP here: NAK (FileNotFound) so MAVProxy/QGC fall back to PARAM_REQUEST_LIST."""
    p = bytes(m.payload)
    if len(p) < 12:
        return
    seq, session, opcode = p[0] | p[1] << 8, p[2], p[3]
    if opcode in (FTP_ACK, FTP_NAK):
        return
    out = bytearray(251)
    rseq = (seq + 1) & 0xFFFF
    out[0], out[1], out[2], out[5] = rseq & 0xFF, rseq >> 8, session, opcode
    if opcode in (FTP_TERMINATE, FTP_RESET):
        out[3] = FTP_ACK
    else:
        out[3], out[4], out[12] = FTP_NAK, 1, FTP_ERR_FILE_NOT_FOUND
    v.send(v.mav.file_transfer_protocol_encode(0, m.get_srcSystem(), m.get_srcComponent(), out))


def on_ignore(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    return None


HANDLERS: dict[str, Handler] = {
    "HEARTBEAT": on_heartbeat,
    "COMMAND_LONG": on_command_long,
    "COMMAND_INT": on_command_int,
    "SET_MODE": on_set_mode,
    "PARAM_REQUEST_LIST": on_param_request_list,
    "PARAM_REQUEST_READ": on_param_request_read,
    "PARAM_SET": on_param_set,
    "MISSION_REQUEST_LIST": on_mission_request_list,
    "MISSION_COUNT": on_mission_count,
    "MISSION_ITEM_INT": on_mission_item,
    "MISSION_ITEM": on_mission_item,
    "MISSION_REQUEST_INT": on_mission_request,
    "MISSION_REQUEST": on_mission_request,
    "MISSION_CLEAR_ALL": on_mission_clear_all,
    "SET_POSITION_TARGET_LOCAL_NED": on_set_position_target_local_ned,
    "SET_POSITION_TARGET_GLOBAL_INT": on_set_position_target_global_int,
    "TIMESYNC": on_timesync,
    "PING": on_ping,
    "FILE_TRANSFER_PROTOCOL": on_ftp,
    "REQUEST_DATA_STREAM": on_ignore,  # accepted; streams are set by SET_MESSAGE_INTERVAL
}


def addressed_to(v: Vehicle, m: mavlink.MAVLink_message) -> bool:
    """False if the message names another system or component as its target."""
    ts = getattr(m, "target_system", 0)
    if ts not in (0, v.sysid):
        return False
    tc = getattr(m, "target_component", 0)
    return tc in (0, v.compid) or m.get_type() in ("SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT")
