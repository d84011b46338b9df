"""Handlers for every MAVLink message the FCU understands (commands live in commands.py, the
mission protocol in mission_transfer.py).

VirtualFcu looks a message's handler up in ``HANDLERS`` (copied per instance), skips
messages ``addressed_to`` another system/component, and wraps the call so an exception is
logged and counted and the vehicle keeps flying.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable

from uav_stack.fcu import ardupilot, mission_transfer
from uav_stack.fcu.commands import MavCommand, handle_command
from uav_stack.fcu.dynamics import POS, YAW
from uav_stack.fcu.firmware import firmware
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
    """A ground station's heartbeat feeds the datalink-loss failsafe (ArduPilot: only MAV_GCS_SYSID's)."""
    if m.type != M.MAV_TYPE_GCS:
        return
    if not v.flavour.is_px4 and m.get_srcSystem() != int(v.settings.gcs_sysid):
        return
    v.gcs_last = v.now


def on_command_long(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    if not v.flavour.is_px4 and (m.param5 != m.param5 or m.param6 != m.param6):
        # ArduPilot turns COMMAND_LONG into COMMAND_INT, params 5 and 6 into integers: NaN there is undefined,
        # and a real ArduCopter SITL stops on the floating-point trap. Never answered here, always counted.
        v.ctx.stats.nan_integer_params += 1
        v.ctx.log.error("COMMAND_LONG %d with NaN in param 5 or 6: ArduPilot makes them integers (undefined; "
                    "its SITL stops), ignored", m.command)
        return
    handle_command(v, MavCommand.from_long(m))


def on_command_int(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    handle_command(v, MavCommand.from_int(m))


def on_set_mode(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    """SET_MODE (#11): QGC's way to change PX4 modes. No ACK; the heartbeat tells the result (ArduPilot sends
    one at once when the mode changes)."""
    px = v.flavour.is_px4
    if not m.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        if not px:
            v.statustext(M.MAV_SEVERITY_WARNING, "SET_MODE: only custom modes supported")
        return
    spec = v.flavour.by_custom_mode(m.custom_mode)
    if spec is None:
        if not px:
            v.statustext(M.MAV_SEVERITY_WARNING, f"SET_MODE: unknown mode {m.custom_mode}")
        return
    result, reason = v.request_mode(spec)
    if result != ACCEPTED and not px:
        v.statustext(M.MAV_SEVERITY_WARNING, reason)


# ------------------------------------------------------------------ parameters
UNINDEXED = 65535  # ArduPilot's param_index in a PARAM_VALUE that answers a name (a read, a set) or comes unasked


def _param_value(v: Vehicle, k: int, index: int | None = None) -> mavlink.MAVLink_message:
    name, value, ptype = v.params.encode(k)
    return v.mav.param_value_encode(name.encode(), value, ptype, len(v.params), k if index is None else index)


def hash_check(v: Vehicle) -> int:
    """PX4's _HASH_CHECK: the firmware's for its defaults, another value for every other set of values."""
    fw = firmware("px4").hash_check or 0
    changed = v.params.changed()
    if not changed:
        return fw
    blob = ";".join(f"{n}={changed[n]!r}" for n in sorted(changed)).encode()
    return (fw ^ zlib.crc32(blob)) & 0xFFFFFFFF or 1


def on_param_request_list(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    """The whole list, paced as the firmware sends it (Vehicle._param_tick): PX4 starts with _HASH_CHECK
    (index 65535), ArduPilot with its banner (firmware, board, frame) as STATUSTEXT."""
    if v.flavour.is_px4:
        h = v.params.wire(hash_check(v), M.MAV_PARAM_TYPE_UINT32)
        v.send(v.mav.param_value_encode(b"_HASH_CHECK", h, M.MAV_PARAM_TYPE_UINT32, len(v.params), UNINDEXED))
    else:
        for text in (firmware("ardupilot").name, ardupilot.board_uid(v.sysid), ardupilot.FRAME_TEXT):
            v.statustext(M.MAV_SEVERITY_INFO, text)
    v.param_queue.clear()
    v.param_queue.extend(range(len(v.params)))


def _param_name(raw: str | bytes) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return raw.split("\x00", 1)[0].strip()


def on_param_request_read(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    """By index, or by name (ArduPilot answers a name with index 65535); an unknown one gets no answer."""
    if m.param_index >= 0:
        if m.param_index < len(v.params):
            v.send(_param_value(v, m.param_index))
        return
    k = v.params.on_mavlink(_param_name(m.param_id))
    if k is not None:
        v.send(_param_value(v, k, None if v.flavour.is_px4 else UNINDEXED))


def on_param_set(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    """Set and echo with the parameter's own type (a value it refuses: the old one). An unknown name gets no
    answer. PX4 echoes twice; ArduPilot's echo has index 65535."""
    name = _param_name(m.param_id)
    k = v.params.on_mavlink(name)
    if k is None:
        return
    v.set_param(name, v.params.decode(name, m.param_value, m.param_type))
    if v.flavour.is_px4:
        echo = _param_value(v, k)
        v.send(echo)
        v.param_echo_again.append(echo)
    else:
        v.send(_param_value(v, k, UNINDEXED))


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


def on_request_data_stream(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    """ArduPilot sets a stream group's rate (never ACKed); PX4 ignores REQUEST_DATA_STREAM."""
    if not v.flavour.is_px4:
        v.request_data_stream(m.req_stream_id, m.req_message_rate, m.start_stop)


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
    "REQUEST_DATA_STREAM": on_request_data_stream,
}


def addressed_to(v: Vehicle, m: mavlink.MAVLink_message) -> bool:
    """False if the message names another system or component as its target."""
    ts = getattr(m, "target_system", 0)
    if ts not in (0, v.sysid):
        return False
    tc = getattr(m, "target_component", 0)
    return tc in (0, v.compid) or m.get_type() in ("SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT")
