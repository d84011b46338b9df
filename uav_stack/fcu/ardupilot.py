"""ArduCopter 4.7 as it behaves on its MAVLink port, for the ArduPilot flavour: boot milestones, the
EKF's status flags, the pre-arm checks that fail while it boots, and the stream groups that
REQUEST_DATA_STREAM and the ``MAV1_*`` parameters set.

The times are ArduCopter SITL's, seconds after launch (recorded from the real firmware; docs/fcu.md).
The stream groups are ArduCopter's (GCS_MAVLink_Copter.cpp), limited to the messages this emulator has.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from uav_stack.fcu.boot import BootTimeline
from uav_stack.fcu.firmware import firmware
from uav_stack.mav import mavlink

if TYPE_CHECKING:
    from uav_stack.fcu.vehicle import Vehicle

M = mavlink

# Milestones of a boot, s after launch. READY: the EKF uses GPS, so the vehicle can arm.
MILESTONES: dict[str, float] = {
    "heartbeat": 1.02,  # first HEARTBEAT, system_status BOOT
    "streams": 2.46,  # "ArduPilot Ready": requested streams start
    "standby": 3.04,  # system_status STANDBY
    "ekf_report": 3.55,  # EKF_STATUS_REPORT exists: flags 1024 (not initialised)
    "ekf_init": 4.46,  # EKF3 initialised: AHRS2 is sent
    "ekf_zero": 5.55,  # flags 0
    "ekf_aligned": 6.05,  # tilt and yaw aligned: flags 167 (attitude, velocities, vertical position, const-pos mode)
    "gps_fix": 10.04,  # GPS detected with a 3D fix (GPS_RAW_INT fix 6): GLOBAL_POSITION_INT carries the position
    "accels_consistent": 14.0,  # pre-arm "Accels inconsistent" until here, then "Gyros inconsistent"
    "origin": 20.03,  # EKF origin and home set: GPS_GLOBAL_ORIGIN and HOME_POSITION pushed once
    "gyros_consistent": 24.0,
    "ekf_gps": 41.80,  # EKF uses GPS: flags 831, LOCAL_POSITION_NED and WIND join their streams, arming possible
}
READY = "ekf_gps"

EKF_UNINITIALISED = 1024  # EKF_UNINITIALIZED
EKF_ALIGNED = 167  # ATTITUDE | VELOCITY_HORIZ | VELOCITY_VERT | POS_VERT_ABS | CONST_POS_MODE
EKF_USING_GPS = 831  # ... | POS_HORIZ_REL | POS_HORIZ_ABS | PRED_POS_HORIZ_REL | PRED_POS_HORIZ_ABS, no CONST_POS_MODE
GPS_FIX = 6  # SITL's GPS reports GPS_FIX_TYPE_RTK_FIXED

PREARM_PERIOD_S = 30.0  # pre-arm failures are reported this often (once an arm was refused)
TIMESYNC_PERIOD_S = 10.0  # a TIMESYNC request (tc1 = 0, ts1 = sim ns) every 10 s, from 10 s on
STAT_RUNTIME_FIRST_S, STAT_RUNTIME_PERIOD_S = 30.46, 31.0  # STAT_RUNTIME saved (PARAM_VALUE) this often
TAKEOFF_SPOOL_S = 3.4  # GUIDED NAV_TAKEOFF: from the ACK to leaving the ground (throttle ramp)

FLIGHT_SW_VERSION = (4 << 24) | (7 << 16) | (0 << 8) | 0  # 4.7.0, FIRMWARE_VERSION_TYPE_DEV
FLIGHT_CUSTOM_VERSION = b"2598e9d4"  # the git hash ArduCopter reports
CAPABILITIES = 64495
FRAME_TEXT = "Frame: QUAD/PLUS"

# REQUEST_DATA_STREAM's stream id -> the MAV1_* parameter holding its rate (Hz); the messages of each group.
STREAM_PARAMS: dict[int, str] = {
    M.MAV_DATA_STREAM_RAW_SENSORS: "MAV1_RAW_SENS",
    M.MAV_DATA_STREAM_EXTENDED_STATUS: "MAV1_EXT_STAT",
    M.MAV_DATA_STREAM_RC_CHANNELS: "MAV1_RC_CHAN",
    M.MAV_DATA_STREAM_RAW_CONTROLLER: "MAV1_RAW_CTRL",
    M.MAV_DATA_STREAM_POSITION: "MAV1_POSITION",
    M.MAV_DATA_STREAM_EXTRA1: "MAV1_EXTRA1",
    M.MAV_DATA_STREAM_EXTRA2: "MAV1_EXTRA2",
    M.MAV_DATA_STREAM_EXTRA3: "MAV1_EXTRA3",
}
STREAM_GROUPS: dict[str, tuple[str, ...]] = {
    "MAV1_RAW_SENS": ("RAW_IMU", "SCALED_IMU2", "SCALED_IMU3", "SCALED_PRESSURE", "SCALED_PRESSURE2"),
    "MAV1_EXT_STAT": ("SYS_STATUS", "POWER_STATUS", "MEMINFO", "MISSION_CURRENT", "GPS_RAW_INT", "NAV_CONTROLLER_OUTPUT",
                      "POSITION_TARGET_GLOBAL_INT"),
    "MAV1_RC_CHAN": ("SERVO_OUTPUT_RAW", "RC_CHANNELS"),
    "MAV1_RAW_CTRL": (),
    "MAV1_POSITION": ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),
    "MAV1_EXTRA1": ("ATTITUDE", "SIMSTATE", "AHRS2"),
    "MAV1_EXTRA2": ("VFR_HUD",),
    "MAV1_EXTRA3": ("AHRS", "SYSTEM_TIME", "WIND", "TERRAIN_REPORT", "TERRAIN_REQUEST", "BATTERY_STATUS", "EKF_STATUS_REPORT",
                    "VIBRATION"),
    "MAV1_PARAMS": (),
    "MAV1_ADSB": (),
}  # fmt: skip
GROUP_OF: dict[str, str] = {name: group for group, names in STREAM_GROUPS.items() for name in names}
ALL_SKIPS = ("MAV1_PARAMS",)  # REQUEST_DATA_STREAM(ALL) leaves the parameter stream alone
TERRAIN_REQUEST_MAX_HZ = 0.5  # terrain data asked for about every 2 s while EXTRA3 streams


def timeline(profile: str) -> BootTimeline:
    fw = firmware("ardupilot")
    events: list[tuple[float, str, object]] = [(t, "statustext", (sev, text)) for t, sev, text in fw.boot_statustexts]
    events += [(t, "param_value", (name, value, ptype, count)) for t, name, value, ptype, count in fw.boot_param_values]
    events += [(MILESTONES["origin"], "gps_origin", None), (MILESTONES["origin"], "home", None)]
    return BootTimeline(MILESTONES, READY, profile, events)


def ekf_flags(v: Vehicle) -> int | None:
    """EKF_STATUS_REPORT.flags now; None before the EKF reports at all."""
    b, now = v.boot, v.now
    if now >= b.ready_at:
        return EKF_USING_GPS
    if not b.passed("ekf_report", now):
        return None
    if not b.passed("ekf_zero", now):
        return EKF_UNINITIALISED
    return 0 if not b.passed("ekf_aligned", now) else EKF_ALIGNED


def arm_failures(v: Vehicle) -> list[str]:
    """The pre-arm checks that fail now, in ArduCopter's order and words (without the "Arm: " prefix)."""
    b, now = v.boot, v.now
    if now >= b.ready_at:
        return []
    if not b.passed("ekf_aligned", now):
        return ["Need Alt Estimate", "Accels inconsistent", "EKF attitude is bad", "AHRS: waiting for home"]
    out = []
    if not b.passed("accels_consistent", now):
        out.append("Accels inconsistent")
    elif not b.passed("gyros_consistent", now):
        out.append("Gyros inconsistent")
    out.append("AHRS: waiting for home" if not b.passed("origin", now) else "Need Position Estimate")
    return out


def board_uid(sysid: int) -> str:
    """A 32-hex-digit board id, stable per vehicle (ArduPilot prints its board's after the banner)."""
    return f"4d52{sysid:04x}" + "0" * 24
