"""PX4 1.16 as it behaves on its onboard (API) link, for the PX4 flavour: boot milestones, the streams it
sends unasked and their rates, and the events (MAVLink EVENT, id 410) it reports instead of STATUSTEXT.

Times are PX4 SITL's (SIH quadrotor), seconds after launch; rates are those of PX4's "onboard" link mode,
the one its SITL opens for the API port. Both were recorded from the real firmware (docs/fcu.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from uav_stack.fcu.boot import BootTimeline
from uav_stack.fcu.firmware import firmware
from uav_stack.mav import mavlink

if TYPE_CHECKING:
    from uav_stack.fcu.vehicle import Vehicle

# Milestones of a boot, s after launch. READY: the arming checks pass (system_status STANDBY).
MILESTONES: dict[str, float] = {
    "sensors": 0.50,  # GPS_RAW_INT (a 3D fix from the start), HIGHRES_IMU, LOCAL_POSITION_NED, ODOMETRY
    "events": 0.55,  # the first EVENT and CURRENT_EVENT_SEQUENCE
    "control": 0.60,  # ALTITUDE, ATTITUDE_TARGET, POSITION_TARGET_LOCAL_NED, SERVO_OUTPUT_RAW, TIMESYNC, VFR_HUD, ...
    "status": 0.70,  # SYS_STATUS (nothing present yet), EXTENDED_SYS_STATE
    "params": 1.29,  # MISSION_CURRENT; the airframe's parameter changes (PARAM_VALUE)
    "heartbeat": 1.51,  # first HEARTBEAT: HOLD, system_status UNINIT; ESTIMATOR_STATUS, PING, SYSTEM_TIME, ...
    "origin": 1.57,  # GPS_GLOBAL_ORIGIN
    "attitude": 1.66,  # ATTITUDE, ATTITUDE_QUATERNION
    "estimate": 2.29,  # TIME_ESTIMATE_TO_TARGET; the first health report (no position estimate)
    "home": 2.52,  # HOME_POSITION, BATTERY_STATUS, CURRENT_MODE, VIBRATION; SYS_STATUS shows the sensors
    "position": 2.78,  # GLOBAL_POSITION_INT (never before: no zeros)
    "estimator_ok": 3.53,  # ESTIMATOR_STATUS flags 1023
    "ready": 4.45,  # the health report passes: arming accepted, STANDBY; home set again
}
READY = "ready"

# The onboard link's streams (Hz) and the milestone each starts at. A stream is never faster than the physics.
STREAMS: dict[str, tuple[float, str]] = {
    "ATTITUDE": (100.0, "attitude"),
    "GLOBAL_POSITION_INT": (50.0, "position"),
    "HIGHRES_IMU": (50.0, "sensors"),
    "ATTITUDE_QUATERNION": (50.0, "attitude"),
    "LOCAL_POSITION_NED": (30.0, "sensors"),
    "ODOMETRY": (30.0, "sensors"),
    "ALTITUDE": (10.0, "control"),
    "ATTITUDE_TARGET": (10.0, "control"),
    "POSITION_TARGET_LOCAL_NED": (10.0, "control"),
    "SERVO_OUTPUT_RAW": (10.0, "control"),
    "TIMESYNC": (10.0, "control"),
    "VFR_HUD": (10.0, "control"),
    "DISTANCE_SENSOR": (10.0, "control"),
    "GPS_RAW_INT": (8.0, "sensors"),
    "SYS_STATUS": (5.0, "status"),
    "EXTENDED_SYS_STATE": (5.0, "status"),
    "ESTIMATOR_STATUS": (1.0, "heartbeat"),
    "MISSION_CURRENT": (1.0, "params"),
    "PING": (1.0, "heartbeat"),
    "SYSTEM_TIME": (1.0, "heartbeat"),
    "SCALED_PRESSURE": (1.0, "heartbeat"),
    "LINK_NODE_STATUS": (1.0, "heartbeat"),
    "OPEN_DRONE_ID_LOCATION": (1.0, "heartbeat"),
    "OPEN_DRONE_ID_SYSTEM": (1.0, "heartbeat"),
    "HOME_POSITION": (0.5, "home"),
    "BATTERY_STATUS": (0.5, "home"),
    "VIBRATION": (0.5, "home"),
    "CURRENT_MODE": (0.5, "home"),
    "TIME_ESTIMATE_TO_TARGET": (0.5, "estimate"),
    "CURRENT_EVENT_SEQUENCE": (1.0 / 3.0, "events"),
}

FLIGHT_SW_VERSION = (1 << 24) | (16 << 16) | (0 << 8) | 0xFF  # 1.16.0, FIRMWARE_VERSION_TYPE_OFFICIAL
CAPABILITIES = 59647
FLIGHT_CUSTOM_VERSION = bytes([0, 0, 0, 87, 145, 83, 163, 110])

ESTIMATOR_FLAGS = ((0.0, 1152), (2.52, 229), (3.53, 1023))  # ESTIMATOR_STATUS.flags from these times after launch
DISARM_PRFLT_GRACE_S = 1.2  # PX4 disarms a vehicle armed without takeoff about COM_DISARM_PRFLT + 1.2 s later
EVENT_SEQUENCE_START = 65526  # the events before the link opened took the first numbers
ITEM_REACHED_REPEAT_S = 1.0  # MISSION_ITEM_REACHED is repeated this often for the last item reached


@dataclass(frozen=True)
class Event:
    """A PX4 event: its id (the event's hash in PX4's metadata), log levels and arguments."""

    name: str  # PX4's event name (for logs and tests)
    id: int
    log_levels: int
    args: bytes = b""


def _e(name: str, id_: int, levels: int, args_hex: str = "") -> Event:
    return Event(name, id_, levels, bytes.fromhex(args_hex))


ARM_DENIED = _e("commander_arm_denied_resolve_failures", 0x0102089D, 98)
ARMED_BY = _e("commander_armed_by", 0x0190CAF3, 102, "04")  # 4: by a MAVLink command
DISARMED_BY_COMMAND = _e("commander_disarmed_by", 0x01F46777, 102, "04")
DISARMED_BY_LANDING = _e("commander_disarmed_by", 0x01F46777, 102, "06")
DISARMED_PREFLIGHT = _e("commander_disarmed_by", 0x01F46777, 102, "07")  # auto-disarm: no takeoff
TAKEOFF_DETECTED = _e("commander_takeoff_detected", 0x01414569, 102)
LANDING_CURRENT_POS = _e("commander_landing_current_pos", 0x0132B2DE, 102)
LANDING_DETECTED = _e("commander_landing_detected", 0x019638AC, 102)
FAILSAFE_ENTER = _e("commander_failsafe_enter_generic", 0x01DEDBD0, 66, "0000060002")
MISSION_EXECUTE = _e("mission_execute", 0x01EE01B1, 102)
MISSION_CLIMB = _e("mission_climb_before_start", 0x017D425C, 102, "00002041")
LOGGER_OPEN = _e("logger_open_file_time", 0x01125BEF, 102, "ea070c02013611")

_CHECKS = "commander_arming_check_summary", 0x01A893E0, 136
_MISSION = _e("check_modes_mission", 0x0105C2D9, 102, "0800000014")
_OFFBOARD = _e("check_modes_offboard_signal", 0x012F1DC7, 51, "0040000014")
_MANUAL = _e("check_modes_manual_control", 0x0106ED29, 68, "ffffffff07")
_DLLINK = _e("check_rc_dl_no_dllink", 0x0167C97B, 102, "ffffffff0c")
# The health report PX4 sends whenever its arming checks change, by state (the reports it sent at boot,
# once ready, and while an offboard setpoint stream was there).
HEALTH_REPORTS: dict[str, tuple[Event, ...]] = {
    "no_estimate": (
        _e(*_CHECKS, "000000120180000000803b0180803b0180"),
        _e("check_modes_local_pos", 0x01D31BB9, 51, "7c007e0011"),
        _e("check_modes_global_pos", 0x0198C273, 51, "3800000018"),
        _MISSION, _OFFBOARD, _MANUAL, _DLLINK,
        _e("commander_health_summary", 0x011D3727, 136, "00020c0238"),
    ),
    "ready": (
        _e(*_CHECKS, "000000100080000000b03b7f80b03b7f80"),
        _MISSION, _OFFBOARD, _MANUAL, _DLLINK,
        _e("commander_health_summary", 0x011D3727, 136, "000a0c0238"),
    ),
    "ready_offboard": (
        _e(*_CHECKS, "000000000080000000b07b7f80b07b7f80"),
        _MISSION, _MANUAL, _DLLINK,
        _e("commander_health_summary", 0x011D3727, 136, "000a0c0238"),
    ),
}  # fmt: skip


def timeline(profile: str) -> BootTimeline:
    fw = firmware("px4")
    events: list[tuple[float, str, object]] = [(MILESTONES["events"], "event", LOGGER_OPEN)]
    events += [(t, "param_value", (name, None, None, None)) for t, name, _v, _ty, _n in fw.boot_param_values]
    events += [(MILESTONES["origin"], "gps_origin", None), (MILESTONES["ready"], "home", None)]
    return BootTimeline(MILESTONES, READY, profile, events)


def estimator_flags(boot: BootTimeline, now: float) -> int:
    """ESTIMATOR_STATUS.flags now (1023 once the estimator is good)."""
    if now >= boot.ready_at:
        return ESTIMATOR_FLAGS[-1][1]
    flags = ESTIMATOR_FLAGS[0][1]
    for t, f in ESTIMATOR_FLAGS:
        if now + 1e-9 >= boot.scaled(t):
            flags = f
    return flags


class EventLog:
    """PX4's events on one vehicle's link: a sequence number per event, and CURRENT_EVENT_SEQUENCE."""

    def __init__(self) -> None:
        self.seq = (EVENT_SEQUENCE_START - 1) & 0xFFFF
        self._reset_sent = False
        self.sent: list[str] = []  # names of the events sent (bounded), for logs and tests

    def emit(self, v: Vehicle, ev: Event) -> None:
        self.seq = (self.seq + 1) & 0xFFFF
        args = list(ev.args[:40].ljust(40, b"\0"))
        v.send(v.mav.event_encode(0, 0, ev.id, int(v.now * 1000.0) & 0xFFFFFFFF, self.seq, ev.log_levels, args))
        if len(self.sent) < 1000:
            self.sent.append(ev.name)

    def report(self, v: Vehicle, state: str) -> None:
        """The health report PX4 sends when its arming checks change (HEALTH_REPORTS)."""
        for ev in HEALTH_REPORTS[state]:
            self.emit(v, ev)

    def current_sequence(self, v: Vehicle) -> mavlink.MAVLink_message:
        flags = 0 if self._reset_sent else 1  # the first one says the sequence (re)started
        self._reset_sent = True
        return v.mav.current_event_sequence_encode(self.seq, flags)
