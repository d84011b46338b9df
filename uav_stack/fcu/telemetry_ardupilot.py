"""The messages only the ArduPilot flavour sends (ArduPilot's own and the ones of its stream groups):
AHRS, AHRS2, SIMSTATE, MEMINFO, EKF_STATUS_REPORT, POWER_STATUS, RAW_IMU, SCALED_IMU2/3, SCALED_PRESSURE2,
RC_CHANNELS, NAV_CONTROLLER_OUTPUT, TERRAIN_REPORT, TERRAIN_REQUEST, WIND, POSITION_TARGET_GLOBAL_INT.

Their values are the vehicle's state where it has one (attitude, position, velocity, targets) and a
healthy sensor's quiet readings elsewhere; what a ground station or a companion decides on (the EKF's
flags, whether a message is sent at all) follows the firmware (ardupilot.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from uav_stack.fcu import ardupilot
from uav_stack.fcu.dynamics import PITCH, PITCH_RATE, POS, ROLL, ROLL_RATE, YAW, YAW_RATE, G
from uav_stack.fcu.telemetry import _i16, _i32, _ms, _u16, pressure_hpa
from uav_stack.mav import mavlink

if TYPE_CHECKING:
    from uav_stack.fcu.vehicle import Vehicle

M = mavlink


def _accel_body(v: Vehicle) -> tuple[float, float, float]:
    """Specific force in body axes (m/s²), from the attitude: what an accelerometer at rest-like flight reads."""
    d, i = v.ctx.dyn, v.i
    r, p = d.get(ROLL, i), d.get(PITCH, i)
    return G * math.sin(p), -G * math.sin(r) * math.cos(p), -G * math.cos(r) * math.cos(p)


def ahrs(v: Vehicle) -> mavlink.MAVLink_message:
    return v.mav.ahrs_encode(0.0, 0.0, 0.0, 0.0, 0.0, 0.002, 0.001)


def ahrs2(v: Vehicle) -> mavlink.MAVLink_message | None:
    if not v.booted and not v.boot.passed("ekf_init", v.now):
        return None  # the EKF's own attitude: once it is initialised
    d, i = v.ctx.dyn, v.i
    lat, lon, alt = v.reported_geodetic() if v.gps_fix else (0.0, 0.0, 0.0)
    return v.mav.ahrs2_encode(d.get(ROLL, i), d.get(PITCH, i), d.get(YAW, i), alt, _i32(lat * 1e7), _i32(lon * 1e7))


def simstate(v: Vehicle) -> mavlink.MAVLink_message:
    d, i = v.ctx.dyn, v.i
    lat, lon, _ = v.geodetic()
    ax, ay, az = _accel_body(v)
    return v.mav.simstate_encode(d.get(ROLL, i), d.get(PITCH, i), d.get(YAW, i), ax, ay, az, d.get(ROLL_RATE, i),
                                 d.get(PITCH_RATE, i), d.get(YAW_RATE, i), _i32(lat * 1e7), _i32(lon * 1e7))  # fmt: skip


def meminfo(v: Vehicle) -> mavlink.MAVLink_message:
    return v.mav.meminfo_encode(0, 65535, 131072)


def ekf_status_report(v: Vehicle) -> mavlink.MAVLink_message | None:
    flags = ardupilot.ekf_flags(v)
    if flags is None:
        return None
    return v.mav.ekf_status_report_encode(flags, 0.02, 0.01, 0.01, 0.01, 0.0, 0.0)


def power_status(v: Vehicle) -> mavlink.MAVLink_message:
    return v.mav.power_status_encode(5000, 0, 0)


def raw_imu(v: Vehicle) -> mavlink.MAVLink_message:
    ax, ay, az = _accel_body(v)
    d, i = v.ctx.dyn, v.i
    k = 1000.0 / G  # milli-g
    return v.mav.raw_imu_encode(int(v.now * 1e6), _i16(ax * k), _i16(ay * k), _i16(az * k),
                                _i16(d.get(ROLL_RATE, i) * 1000), _i16(d.get(PITCH_RATE, i) * 1000),
                                _i16(d.get(YAW_RATE, i) * 1000), 210, 0, 400, 0, 4500)  # fmt: skip


def _scaled_imu(v: Vehicle, encode: Callable[..., mavlink.MAVLink_message]) -> mavlink.MAVLink_message:
    ax, ay, az = _accel_body(v)
    d, i = v.ctx.dyn, v.i
    k = 1000.0 / G
    return encode(_ms(v), _i16(ax * k), _i16(ay * k), _i16(az * k), _i16(d.get(ROLL_RATE, i) * 1000),
                  _i16(d.get(PITCH_RATE, i) * 1000), _i16(d.get(YAW_RATE, i) * 1000), 210, 0, 400, 4500)  # fmt: skip


def scaled_imu2(v: Vehicle) -> mavlink.MAVLink_message:
    return _scaled_imu(v, v.mav.scaled_imu2_encode)


def scaled_imu3(v: Vehicle) -> mavlink.MAVLink_message:
    return _scaled_imu(v, v.mav.scaled_imu3_encode)


def scaled_pressure2(v: Vehicle) -> mavlink.MAVLink_message:
    _, _, alt = v.geodetic()
    return v.mav.scaled_pressure2_encode(_ms(v), pressure_hpa(alt), 0.0, 2500, 0)


def rc_channels(v: Vehicle) -> mavlink.MAVLink_message:
    """SITL's RC input: sticks centred, throttle low (ArduCopter SITL's RC7 is "SaveWaypoint LOW")."""
    ch = [1500, 1500, 1000, 1500, 1800, 1000, 1000, 1800] + [0] * 10
    return v.mav.rc_channels_encode(_ms(v), 16, *ch, 255)


def nav_controller_output(v: Vehicle) -> mavlink.MAVLink_message:
    d, i = v.ctx.dyn, v.i
    pos, sp = d.get(POS, i), d.pos_sp[i]
    dn = float(sp[0]) - pos[0] if sp[0] == sp[0] else 0.0
    de = float(sp[1]) - pos[1] if sp[1] == sp[1] else 0.0
    dz = float(sp[2]) - pos[2] if sp[2] == sp[2] else 0.0
    bearing = _i16(math.degrees(math.atan2(de, dn))) if math.hypot(dn, de) > 0.1 else _i16(math.degrees(d.get(YAW, i)))
    return v.mav.nav_controller_output_encode(math.degrees(d.get(ROLL, i)), math.degrees(d.get(PITCH, i)), bearing,
                                              bearing, _u16(math.hypot(dn, de)), -dz, 0.0, 0.0)  # fmt: skip


def terrain_report(v: Vehicle) -> mavlink.MAVLink_message:
    lat, lon, alt = v.geodetic()
    ground = v.frame.origin.alt  # the ground is flat at the origin's height
    return v.mav.terrain_report_encode(_i32(lat * 1e7), _i32(lon * 1e7), 0, 0.0, alt - ground, 0, 0)


def terrain_request(v: Vehicle) -> mavlink.MAVLink_message | None:
    if not v.gps_fix:
        return None
    lat, lon, _ = v.geodetic()
    return v.mav.terrain_request_encode(_i32(lat * 1e7), _i32(lon * 1e7), 100, (1 << 56) - 1)


def wind(v: Vehicle) -> mavlink.MAVLink_message | None:
    if not v.booted and not v.boot.passed("ekf_gps", v.now):
        return None  # the wind estimate needs the EKF's horizontal position
    w = v.ctx.dyn.wind
    wn, we = float(w[v.i, 0]), float(w[v.i, 1])
    return v.mav.wind_encode(math.degrees(math.atan2(-we, -wn)) % 360.0, math.hypot(wn, we), 0.0)


def position_target_global_int(v: Vehicle) -> mavlink.MAVLink_message | None:
    """Only while GUIDED flies to a position target (ArduCopter's EXT_STAT stream)."""
    if not v.guided_position_target():
        return None
    d, i = v.ctx.dyn, v.i
    n, e, dn = (float(x) for x in d.pos_sp[i])
    lat, lon, alt = v.frame.to_geodetic(e, n, -dn)
    return v.mav.position_target_global_int_encode(_ms(v), M.MAV_FRAME_GLOBAL_INT, 0xFF8, _i32(lat * 1e7), _i32(lon * 1e7),
                                                   alt, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # fmt: skip


ENCODERS: dict[str, Callable[[Vehicle], mavlink.MAVLink_message | None]] = {
    "AHRS": ahrs,
    "AHRS2": ahrs2,
    "SIMSTATE": simstate,
    "MEMINFO": meminfo,
    "EKF_STATUS_REPORT": ekf_status_report,
    "POWER_STATUS": power_status,
    "RAW_IMU": raw_imu,
    "SCALED_IMU2": scaled_imu2,
    "SCALED_IMU3": scaled_imu3,
    "SCALED_PRESSURE2": scaled_pressure2,
    "RC_CHANNELS": rc_channels,
    "NAV_CONTROLLER_OUTPUT": nav_controller_output,
    "TERRAIN_REPORT": terrain_report,
    "TERRAIN_REQUEST": terrain_request,
    "WIND": wind,
    "POSITION_TARGET_GLOBAL_INT": position_target_global_int,
}
