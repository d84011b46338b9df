"""The MAVLink mission protocol: upload, download, clear and the current item (mavlink.io, Mission Protocol).

Upload: MISSION_COUNT, then each item requested and answered with MISSION_ITEM_INT (or the float
MISSION_ITEM), then MISSION_ACK. The requests are the firmwares': ArduCopter asks with the legacy
MISSION_REQUEST (id 40) for every item; PX4 with MISSION_REQUEST until the ground station has shown that it
speaks the INT protocol (a MISSION_ITEM_INT or MISSION_REQUEST_INT, or a NACK UNSUPPORTED of a legacy
request, as MAVSDK sends: then it asks again with MISSION_REQUEST_INT), and remembers it. ArduCopter then
says "Flight plan received". On download,
ArduCopter's item 0 is its current home (frame GLOBAL, AMSL) and an RTL item comes back in frame GLOBAL.
Download: MISSION_REQUEST_LIST, MISSION_COUNT, MISSION_REQUEST(_INT) per item. MISSION_CLEAR_ALL clears; MISSION_SET_CURRENT picks
the item flown next. Mission types 0/1/2 (mission, fence, rally) are stored; only the mission is
flown (mission.py). An ArduPilot MISSION_ITEM_INT with ``current=2`` outside a transfer is a
"guided goto", as ArduCopter reads it.
"""

from __future__ import annotations

import math

from uav_stack.fcu.mission import MissionItem, is_nav
from uav_stack.fcu.offboard import GLOBAL_FRAMES
from uav_stack.fcu.vehicle import Vehicle
from uav_stack.mav import mavlink

M = mavlink
UPLOAD_STALE_S = 5.0  # wall seconds without progress before a mission upload is abandoned
MAX_ITEMS = 1000


def _ack(v: Vehicle, m: mavlink.MAVLink_message, result: int, mission_type: int) -> None:
    v.send(v.mav.mission_ack_encode(m.get_srcSystem(), m.get_srcComponent(), result, mission_type))


def on_mission_request_list(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    items = v.missions.get(m.mission_type)
    if items is None:
        _ack(v, m, M.MAV_MISSION_UNSUPPORTED, m.mission_type)
        return
    v.send(v.mav.mission_count_encode(m.get_srcSystem(), m.get_srcComponent(), len(items), m.mission_type))


def on_mission_count(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    if m.mission_type not in v.missions:
        _ack(v, m, M.MAV_MISSION_UNSUPPORTED, m.mission_type)
        return
    if m.count == 0:
        _store(v, m.mission_type, [])
        v.upload = None
        _ack(v, m, M.MAV_MISSION_ACCEPTED, m.mission_type)
        return
    if m.count > MAX_ITEMS:
        _ack(v, m, M.MAV_MISSION_NO_SPACE, m.mission_type)
        return
    v.upload = {"type": m.mission_type, "count": m.count, "items": [], "t": v.ctx.wall()}
    _request_item(v, m, 0, m.mission_type)


def _request_item(v: Vehicle, m: mavlink.MAVLink_message, seq: int, mission_type: int) -> None:
    if v.mission_int_protocol:
        v.send(v.mav.mission_request_int_encode(m.get_srcSystem(), m.get_srcComponent(), seq, mission_type))
    else:
        v.send(v.mav.mission_request_encode(m.get_srcSystem(), m.get_srcComponent(), seq, mission_type))


def _item(m: mavlink.MAVLink_message, seq: int) -> MissionItem | None:
    """The item in MISSION_ITEM_INT terms; None if a float item's x/y cannot be one."""
    if m.get_type() == "MISSION_ITEM_INT":
        x, y = m.x, m.y
    else:
        if not (math.isfinite(m.x) and math.isfinite(m.y) and abs(m.x) <= 180.0 and abs(m.y) <= 180.0):
            return None
        x, y = int(round(m.x * 1e7)), int(round(m.y * 1e7))
    return MissionItem(seq, m.frame, m.command, m.current, m.autocontinue, (m.param1, m.param2, m.param3, m.param4),
                       x, y, m.z, m.mission_type)  # fmt: skip


def _check(item: MissionItem) -> int:
    """MAV_MISSION_RESULT for one uploaded item (ACCEPTED if it can be stored)."""
    if is_nav(item.command) and item.frame not in GLOBAL_FRAMES and item.frame != M.MAV_FRAME_MISSION:
        return M.MAV_MISSION_UNSUPPORTED_FRAME  # local frames: missions here are geodetic
    if item.frame in GLOBAL_FRAMES and not (-90e7 <= item.x <= 90e7 and -180e7 <= item.y <= 180e7):
        return M.MAV_MISSION_INVALID_PARAM5_X
    return M.MAV_MISSION_ACCEPTED


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
    if m.get_type() == "MISSION_ITEM_INT" and v.flavour.is_px4:
        v.mission_int_protocol = True
    items: list[MissionItem] = up["items"]  # type: ignore[assignment]
    if m.seq != len(items):
        _request_item(v, m, len(items), m.mission_type)
        return
    item = _item(m, m.seq)
    result = M.MAV_MISSION_INVALID_PARAM5_X if item is None else _check(item)
    if item is None or result != M.MAV_MISSION_ACCEPTED:
        v.upload = None
        _ack(v, m, result, m.mission_type)
        return
    items.append(item)
    up["t"] = v.ctx.wall()
    if len(items) >= up["count"]:  # type: ignore[operator]
        _store(v, m.mission_type, items)
        v.upload = None
        _ack(v, m, M.MAV_MISSION_ACCEPTED, m.mission_type)
        if not v.flavour.is_px4 and m.mission_type == M.MAV_MISSION_TYPE_MISSION:
            v.statustext(M.MAV_SEVERITY_INFO, "Flight plan received")
    else:
        _request_item(v, m, len(items), m.mission_type)


def _store(v: Vehicle, mission_type: int, items: list[MissionItem]) -> None:
    v.missions[mission_type] = items
    if mission_type == M.MAV_MISSION_TYPE_MISSION:
        v.mission.load()


def _guided_item(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    item = _item(m, m.seq)
    lat, lon = (item.x * 1e-7, item.y * 1e-7) if item is not None else (999.0, 999.0)
    ok_alt = math.isfinite(m.z) and abs(m.z) < 20000.0
    if v.mode.name != "GUIDED" or not v.armed or v.landed or abs(lat) > 90 or abs(lon) > 180 or not ok_alt:
        _ack(v, m, M.MAV_MISSION_ERROR, m.mission_type)
        return
    rel = m.frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
    alt = float(m.z) + (v.home.alt if rel else 0.0)
    target = v.ned_of(lat, lon, alt)
    target[2] = min(target[2], float(v.ctx.dyn.ground_z[v.i]))
    v.goto(target)
    _ack(v, m, M.MAV_MISSION_ACCEPTED, m.mission_type)


def on_mission_ack(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    """During an upload, a NACK UNSUPPORTED answers a legacy MISSION_REQUEST (MAVSDK speaks only the INT
    protocol): ask again for the item with MISSION_REQUEST_INT."""
    up = v.upload
    if up is None or m.type != M.MAV_MISSION_UNSUPPORTED or m.mission_type != up["type"] or v.mission_int_protocol:
        return
    v.mission_int_protocol = True
    up["t"] = v.ctx.wall()
    items: list[MissionItem] = up["items"]  # type: ignore[assignment]
    _request_item(v, m, len(items), m.mission_type)


def on_mission_request(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    if m.get_type() == "MISSION_REQUEST_INT" and v.flavour.is_px4:
        v.mission_int_protocol = True
    items = v.missions.get(m.mission_type)
    if items is None or not 0 <= m.seq < len(items):
        _ack(v, m, M.MAV_MISSION_INVALID_SEQUENCE, m.mission_type)
        return
    f = items[m.seq]
    p1, p2, p3, p4 = f.params
    frame, x, y, z = f.frame, f.x, f.y, f.z
    mission = m.mission_type == M.MAV_MISSION_TYPE_MISSION
    if v.flavour.is_px4:
        current = int(mission and m.seq == v.mission.current)
    else:  # ArduCopter: item 0 is home, RTL has no position; "current" is never set
        current = 0
        if mission and m.seq == 0:
            h = v.home
            frame, x, y, z = M.MAV_FRAME_GLOBAL, round(h.lat * 1e7), round(h.lon * 1e7), float(h.alt)
        elif mission and f.command == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            frame = M.MAV_FRAME_GLOBAL
    v.send(
        v.mav.mission_item_int_encode(
            m.get_srcSystem(), m.get_srcComponent(), m.seq, frame, f.command, current, f.autocontinue,
            p1, p2, p3, p4, x, y, z, m.mission_type,
        )  # fmt: skip
    )


def on_mission_clear_all(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    if m.mission_type == M.MAV_MISSION_TYPE_ALL:
        for k in list(v.missions):
            _store(v, k, [])
    elif m.mission_type in v.missions:
        _store(v, m.mission_type, [])
    else:
        _ack(v, m, M.MAV_MISSION_UNSUPPORTED, m.mission_type)
        return
    v.upload = None
    _ack(v, m, M.MAV_MISSION_ACCEPTED, m.mission_type)


def on_mission_set_current(v: Vehicle, m: mavlink.MAVLink_message) -> None:
    """MISSION_SET_CURRENT (MAVSDK's set_current_mission_item): answered by MISSION_CURRENT."""
    if not v.mission.set_current(m.seq):
        v.statustext(M.MAV_SEVERITY_WARNING, f"Mission: no item {m.seq}")
        v.mission.announce(force=True)


HANDLERS = {
    "MISSION_REQUEST_LIST": on_mission_request_list,
    "MISSION_COUNT": on_mission_count,
    "MISSION_ITEM_INT": on_mission_item,
    "MISSION_ITEM": on_mission_item,
    "MISSION_REQUEST_INT": on_mission_request,
    "MISSION_REQUEST": on_mission_request,
    "MISSION_CLEAR_ALL": on_mission_clear_all,
    "MISSION_SET_CURRENT": on_mission_set_current,
    "MISSION_ACK": on_mission_ack,
}
