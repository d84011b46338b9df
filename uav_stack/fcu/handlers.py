"""Handlers for every MAVLink message the FCU understands (commands live in commands.py, the
mission protocol in mission_transfer.py).

VirtualFcu looks a message's handler up in ``HANDLERS`` (copied per instance), skips
messages ``addressed_to`` another system/component, and wraps the call so an exception is
logged and counted and the vehicle keeps flying.
"""

from __future__ import annotations

from collections.abc import Callable

from uav_stack.fcu import mission_transfer
from uav_stack.fcu.commands import MavCommand, handle_command
from uav_stack.fcu.dynamics import POS, YAW
from uav_stack.fcu.manual import from_manual_control
from uav_stack.fcu.offboard import decode_global, decode_local
from uav_stack.fcu.vehicle import ACCEPTED, Vehicle
from uav_stack.mav import mavlink

M = mavlink
FTP_ACK, FTP_NAK = 128, 129
FTP_TERMINATE, FTP_RESET = 1, 2
FTP_ERR_FILE_NOT_FOUND = 10

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


# ------------------------------------------------------------------- setpoints
def on_set_position_target_local_ned(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    d = v.ctx.dyn
    sp = decode_local(m, d.get(POS, v.i), d.get(YAW, v.i))
    if sp is not None:
        v.on_setpoint(sp)


def on_set_position_target_global_int(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    sp = decode_global(m, v.frame, v.home.alt)
    if sp is not None:
        v.on_setpoint(sp)


# ---------------------------------------------------------------------- sticks
def on_manual_control(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    """MANUAL_CONTROL (PX4's joystick input; its ``target`` is our sysid)."""
    if m.target in (0, v.sysid):
        v.on_sticks(from_manual_control(m))


def on_rc_channels_override(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    """RC_CHANNELS_OVERRIDE (ArduPilot's stick input from a GCS, e.g. MAVProxy's ``rc``)."""
    v.on_sticks(v.sticks.rc.update(m))


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
    **mission_transfer.HANDLERS,
    "MANUAL_CONTROL": on_manual_control,
    "RC_CHANNELS_OVERRIDE": on_rc_channels_override,
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
