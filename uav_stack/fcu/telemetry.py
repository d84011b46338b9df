"""Telemetry: the encoders of the messages both flavours send (the flavours' own are in
telemetry_ardupilot.py and telemetry_px4.py; streams.py schedules them all).

An encoder returns None when the firmware would send nothing yet (no position before the
estimate is valid, no home before it is set): the stream skips that slot.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from uav_stack.fcu import ardupilot, px4
from uav_stack.fcu.dynamics import BATTERY, LANDED, PITCH, PITCH_RATE, POS, ROLL, ROLL_RATE, VEL, YAW, YAW_RATE
from uav_stack.mav import mavlink

if TYPE_CHECKING:
    from uav_stack.fcu.vehicle import Vehicle

M = mavlink
SENSORS = (
    M.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | M.MAV_SYS_STATUS_SENSOR_3D_MAG
    | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | M.MAV_SYS_STATUS_SENSOR_GPS
    | M.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | M.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | M.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | M.MAV_SYS_STATUS_AHRS
    | M.MAV_SYS_STATUS_SENSOR_BATTERY
)
PREARM = M.MAV_SYS_STATUS_PREARM_CHECK
FENCE = M.MAV_SYS_STATUS_GEOFENCE
GPS = M.MAV_SYS_STATUS_SENSOR_GPS
RC = M.MAV_SYS_STATUS_SENSOR_RC_RECEIVER  # stick input (MANUAL_CONTROL / RC_CHANNELS_OVERRIDE)
ARDUPILOT_GPS_FIX = ardupilot.GPS_FIX


def _ms(v: Vehicle) -> int:
    return int(v.ctx.clock.sim_time * 1000.0) & 0xFFFFFFFF


def _cdeg_heading(yaw: float) -> int:
    return int(round(math.degrees(yaw) % 360.0 * 100.0)) % 36000 if math.isfinite(yaw) else 65535


# Field values rounded and held in range (non-finite: 0). The in-range case, every one at run time,
# costs one call (round); several telemetry fields each tick in every virtual UAV go through these.
def _i16(x: float) -> int:
    if -32767.0 <= x <= 32767.0:  # (False for NaN)
        return round(x)
    return 0 if not math.isfinite(x) else (32767 if x > 0.0 else -32767)


def _i32(x: float) -> int:
    if -2147483647.0 <= x <= 2147483647.0:
        return round(x)
    return 0 if not math.isfinite(x) else (2147483647 if x > 0.0 else -2147483647)


def _u16(x: float) -> int:
    if 0.0 <= x <= 65534.0:
        return round(x)
    return 0 if not math.isfinite(x) else (65534 if x > 0.0 else 0)


def heartbeat(v: Vehicle) -> mavlink.MAVLink_message:
    """HEARTBEAT as each firmware fills it.

    PX4: system_status UNINIT while the arming checks fail (at boot; in OFFBOARD without setpoints),
    STANDBY when they pass, ACTIVE armed, CRITICAL in a failsafe. ArduPilot: BOOT until it has
    started, STANDBY (also armed on the ground), ACTIVE flying, CRITICAL in a failsafe; its base_mode
    carries GUIDED_ENABLED while booting and in the modes that have it (ModeSpec)."""
    mode = v.mode
    base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mode.base_flags
    now = v.now
    first = v.heartbeats_sent == 0  # the first one shows the boot state, however short the boot
    v.heartbeats_sent += 1
    if v.flavour.is_px4:
        if v.armed:
            base |= M.MAV_MODE_FLAG_SAFETY_ARMED
            status = M.MAV_STATE_CRITICAL if v.failsafe_active else M.MAV_STATE_ACTIVE
        else:
            status = M.MAV_STATE_STANDBY if v.arming_checks_pass() and not first else M.MAV_STATE_UNINIT
    else:
        if v.armed:
            base |= M.MAV_MODE_FLAG_SAFETY_ARMED | mode.armed_flags
        if first or not v.boot.passed("standby", now):
            base |= M.MAV_MODE_FLAG_GUIDED_ENABLED
            status = M.MAV_STATE_BOOT
        elif v.failsafe_active:
            status = M.MAV_STATE_CRITICAL
        else:
            status = M.MAV_STATE_ACTIVE if v.armed and v.has_flown_since_arming() else M.MAV_STATE_STANDBY
    return v.mav.heartbeat_encode(M.MAV_TYPE_QUADROTOR, v.flavour.autopilot, base, mode.custom_mode, status)


def _reuse(v: Vehicle, name: str, make: Callable[[], mavlink.MAVLink_message]) -> mavlink.MAVLink_message:
    """The vehicle's instance of a high-rate message, refilled in place (skips re-construction)."""
    m = v.msg_cache.get(name)
    if m is None:
        m = v.msg_cache[name] = make()
    return m


def global_position_int(v: Vehicle) -> mavlink.MAVLink_message | None:
    """PX4: none until the position estimate is valid. ArduPilot: zeros (but a heading) until its GPS has a
    fix, then the position; relative_alt 0 until home is set."""
    d = v.ctx.dyn
    m = _reuse(v, "GLOBAL_POSITION_INT", lambda: v.mav.global_position_int_encode(0, 0, 0, 0, 0, 0, 0, 0, 0))
    m.time_boot_ms = _ms(v)
    m.hdg = _cdeg_heading(d.get(YAW, v.i))
    if not v.booted:
        if v.flavour.is_px4:
            if not v.boot.passed("position", v.now):
                return None
        elif not v.boot.passed("gps_fix", v.now):
            m.lat = m.lon = m.alt = m.relative_alt = m.vx = m.vy = m.vz = 0
            return m
    lat, lon, alt = v.reported_geodetic()
    vn, ve, vd = d.get(VEL, v.i)
    m.lat = _i32(lat * 1e7)
    m.lon = _i32(lon * 1e7)
    m.alt = _i32(alt * 1000.0)
    m.relative_alt = _i32((alt - v.home.alt) * 1000.0) if v.home_set else 0
    m.vx, m.vy, m.vz = _i16(vn * 100.0), _i16(ve * 100.0), _i16(vd * 100.0)
    return m


def local_position_ned(v: Vehicle) -> mavlink.MAVLink_message | None:
    if not v.booted and not v.flavour.is_px4 and not v.boot.passed("ekf_gps", v.now):
        return None  # ArduPilot: only once the EKF has a horizontal position
    d = v.ctx.dyn
    m = _reuse(v, "LOCAL_POSITION_NED", lambda: v.mav.local_position_ned_encode(0, 0, 0, 0, 0, 0, 0))
    m.time_boot_ms = _ms(v)
    x, y, z = d.get(POS, v.i)
    ex, ey, ez = v.position_error
    m.x, m.y, m.z = x + ex, y + ey, z + ez
    m.vx, m.vy, m.vz = d.get(VEL, v.i)
    return m


def attitude(v: Vehicle) -> mavlink.MAVLink_message:
    d, i = v.ctx.dyn, v.i
    m = _reuse(v, "ATTITUDE", lambda: v.mav.attitude_encode(0, 0, 0, 0, 0, 0, 0))
    m.time_boot_ms = _ms(v)
    get = d.get
    m.roll, m.pitch, m.yaw = get(ROLL, i), get(PITCH, i), get(YAW, i)
    m.rollspeed, m.pitchspeed, m.yawspeed = get(ROLL_RATE, i), get(PITCH_RATE, i), get(YAW_RATE, i)
    return m


def attitude_quaternion(v: Vehicle) -> mavlink.MAVLink_message:
    d, i = v.ctx.dyn, v.i
    get = d.get
    r, p, y = get(ROLL, i) / 2, get(PITCH, i) / 2, get(YAW, i) / 2
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    m = _reuse(v, "ATTITUDE_QUATERNION", lambda: v.mav.attitude_quaternion_encode(0, 1, 0, 0, 0, 0, 0, 0))
    m.time_boot_ms = _ms(v)
    m.q1, m.q2 = cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy
    m.q3, m.q4 = cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy
    m.rollspeed, m.pitchspeed, m.yawspeed = get(ROLL_RATE, i), get(PITCH_RATE, i), get(YAW_RATE, i)
    return m


def sys_status(v: Vehicle) -> mavlink.MAVLink_message:
    """Sensors present/enabled/healthy as MAVSDK's health() and QGC read them: GPS healthy from the
    first fix, PREARM_CHECK while arming would pass, RC_RECEIVER while stick input arrives."""
    if not v.booted and v.flavour.is_px4 and not v.boot.passed("home", v.now):
        volts, amps, pct = v.battery_readings()  # PX4 reports its sensors once they are up
        return v.mav.sys_status_encode(0, 0, 0, 0, _u16(volts * 1000), _i16(amps * 100), pct, 0, 0, 0, 0, 0, 0)
    sticks = RC if v.settings.stick_input else 0
    present = SENSORS | PREARM | FENCE | sticks
    enabled = SENSORS | PREARM | (FENCE if v.fence_enabled else 0) | sticks
    health = SENSORS | FENCE
    if not v.gps_fix:
        health &= ~GPS
    # PX4's checks include the mode's (OFFBOARD without setpoints fails them); ArduPilot's pre-arm checks do not
    if v.arming_checks_pass() if v.flavour.is_px4 else v.prearm_ok():
        health |= PREARM
    if v.sticks_fresh:
        health |= RC
    if v.fence_breached:
        health &= ~FENCE
    volts, amps, pct = v.battery_readings()
    return v.mav.sys_status_encode(
        present, enabled, health, 0, _u16(volts * 1000), _i16(amps * 100), pct, 0, 0, 0, 0, 0, 0
    )


def extended_sys_state(v: Vehicle) -> mavlink.MAVLink_message:
    vtol = M.MAV_VTOL_STATE_UNDEFINED if v.flavour.is_px4 else M.MAV_VTOL_STATE_MC
    return v.mav.extended_sys_state_encode(vtol, v.landed_state())


def home_position(v: Vehicle) -> mavlink.MAVLink_message | None:
    if not v.home_set:
        return None  # nothing to say before home is set
    h = v.home
    x, y, z = (float(c) for c in v.home_ned)
    return v.mav.home_position_encode(
        _i32(h.lat * 1e7),
        _i32(h.lon * 1e7),
        _i32(h.alt * 1000.0),
        x,
        y,
        z,
        [1.0, 0.0, 0.0, 0.0],
        0.0,
        0.0,
        0.0,
        int(v.ctx.clock.sim_time * 1e6),
    )


def battery_status(v: Vehicle) -> mavlink.MAVLink_message:
    volts, amps, pct = v.battery_readings()
    cells = v.ctx.dyn.params.battery_cells
    cell_mv = int(volts * 1000 / cells)
    voltages = [cell_mv] * min(cells, 10) + [65535] * (10 - min(cells, 10))
    soc = v.ctx.dyn.get(BATTERY, v.i)
    cap = v.ctx.dyn.params.battery_capacity_mah
    s = v.settings
    if soc <= s.bat_emerg:
        charge = M.MAV_BATTERY_CHARGE_STATE_EMERGENCY
    elif soc <= s.bat_crit:
        charge = M.MAV_BATTERY_CHARGE_STATE_CRITICAL
    elif soc <= s.bat_low:
        charge = M.MAV_BATTERY_CHARGE_STATE_LOW
    else:
        charge = M.MAV_BATTERY_CHARGE_STATE_OK
    remaining_s = soc * s.endurance_s
    return v.mav.battery_status_encode(
        0,
        M.MAV_BATTERY_FUNCTION_ALL,
        M.MAV_BATTERY_TYPE_LIPO,
        32767,
        voltages,
        _i16(amps * 100),
        _i32((1.0 - soc) * cap),
        -1,
        pct,
        _i32(remaining_s),
        charge,
    )


def gps_raw_int(v: Vehicle) -> mavlink.MAVLink_message:
    if not v.gps_fix:  # searching: no fix, no satellites
        no_fix = M.GPS_FIX_TYPE_NO_FIX if v.flavour.is_px4 else M.GPS_FIX_TYPE_NO_GPS  # (ArduCopter: 0 until detected)
        return v.mav.gps_raw_int_encode(int(v.ctx.clock.sim_time * 1e6), no_fix, 0, 0, 0,
                                        65535, 65535, 0, 65535, 0)  # fmt: skip
    lat, lon, alt = v.reported_geodetic()
    vn, ve, _ = v.ctx.dyn.get(VEL, v.i)
    gs = math.hypot(vn, ve)
    cog = _cdeg_heading(math.atan2(ve, vn)) if gs > 0.1 else 65535
    return v.mav.gps_raw_int_encode(
        int(v.ctx.clock.sim_time * 1e6),
        M.GPS_FIX_TYPE_3D_FIX if v.flavour.is_px4 else ARDUPILOT_GPS_FIX,
        _i32(lat * 1e7),
        _i32(lon * 1e7),
        _i32(alt * 1000.0),
        70,
        110,
        _u16(gs * 100),
        cog,
        14,
        _i32(alt * 1000.0),
        500,
        800,
        200,
        0,
        0,
    )


def vfr_hud(v: Vehicle) -> mavlink.MAVLink_message:
    _, _, alt = v.geodetic()
    d, i = v.ctx.dyn, v.i
    vn, ve, vd = d.get(VEL, i)
    gs = math.hypot(vn, ve)
    throttle = 0 if not v.armed else (15 if d.get(LANDED, i) else 50)
    yaw = d.get(YAW, i)
    heading = int(math.degrees(yaw) % 360) if math.isfinite(yaw) else 0
    return v.mav.vfr_hud_encode(gs, gs, heading, throttle, alt, -vd)


def system_time(v: Vehicle) -> mavlink.MAVLink_message:
    unix_us = int((v.ctx.unix_at_start + v.ctx.clock.sim_time) * 1e6)
    return v.mav.system_time_encode(unix_us, _ms(v))


def named_value_rtf(v: Vehicle) -> mavlink.MAVLink_message:
    rtf = float(v.ctx.rtf())
    return v.mav.named_value_float_encode(_ms(v), b"RTF", rtf if math.isfinite(rtf) else 0.0)  # 0.0: not measured yet


def mission_current(v: Vehicle) -> mavlink.MAVLink_message:
    return v.mission.current_message()


def autopilot_version(v: Vehicle) -> mavlink.MAVLink_message:
    """The version and capabilities the firmware reports (PX4 1.16.0, ArduCopter 4.7.0-dev)."""
    if v.flavour.is_px4:
        cap, sw, custom = px4.CAPABILITIES, px4.FLIGHT_SW_VERSION, list(px4.FLIGHT_CUSTOM_VERSION)
        uid2 = [0] * 18
    else:
        cap, sw, custom = ardupilot.CAPABILITIES, ardupilot.FLIGHT_SW_VERSION, list(ardupilot.FLIGHT_CUSTOM_VERSION)
        uid2 = list(ardupilot.board_uid(v.sysid).encode()[:17]) + [0]
    return v.mav.autopilot_version_encode(
        cap,
        sw,
        sw if v.flavour.is_px4 else 0,
        0,
        1 if v.flavour.is_px4 else 0,
        custom,
        [0] * 8,
        [0] * 8,
        0,
        0,
        0x4D52_0000_0000_0000 | v.sysid if v.flavour.is_px4 else 0,  # "MR" + sysid: stable per vehicle
        uid2,
    )


def gps_global_origin(v: Vehicle) -> mavlink.MAVLink_message | None:
    if not v.origin_set:
        return None
    o = v.frame.origin
    return v.mav.gps_global_origin_encode(_i32(o.lat * 1e7), _i32(o.lon * 1e7), _i32(o.alt * 1000.0), int(v.now * 1e6))


def scaled_pressure(v: Vehicle) -> mavlink.MAVLink_message:
    _, _, alt = v.geodetic()
    return v.mav.scaled_pressure_encode(_ms(v), pressure_hpa(alt), 0.0, 2500, 0)


def servo_output_raw(v: Vehicle) -> mavlink.MAVLink_message:
    pwm = motor_pwm(v)
    return v.mav.servo_output_raw_encode(int(v.now * 1e6) & 0xFFFFFFFF, 0, pwm, pwm, pwm, pwm, 0, 0, 0, 0,
                                         0, 0, 0, 0, 0, 0, 0, 0)  # fmt: skip


def vibration(v: Vehicle) -> mavlink.MAVLink_message:
    return v.mav.vibration_encode(int(v.now * 1e6), 0.0, 0.0, 0.0, 0, 0, 0)


def timesync_request(v: Vehicle) -> mavlink.MAVLink_message:
    """A TIMESYNC request of the vehicle's own (tc1 = 0, ts1 = its time in ns)."""
    return v.mav.timesync_encode(0, max(1, int(v.now * 1e9)))


def pressure_hpa(alt_amsl: float) -> float:
    """ISA static pressure at an altitude (hPa)."""
    return 1013.25 * (1.0 - 2.25577e-5 * alt_amsl) ** 5.25588


def motor_pwm(v: Vehicle) -> int:
    """A motor output in µs: 1000 disarmed, about 1100 armed on the ground, about 1500 hovering."""
    if not v.armed:
        return 1000
    return 1100 if v.landed else 1500


