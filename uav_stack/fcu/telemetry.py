"""Telemetry: message encoders per stream name and the per-vehicle stream scheduler.

Streams are scheduled on *sim* time, checked after every physics step, so they slow down
with the simulation and never burst. Vehicles of one fleet get different phase offsets so
a process hosting many vehicles spreads its sends over the period.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from swarmnet.compiled import compiled_module
from uav_stack import geo
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
    base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | v.mode.base_flags
    if v.armed:
        base |= M.MAV_MODE_FLAG_SAFETY_ARMED
    status = M.MAV_STATE_ACTIVE if v.armed else M.MAV_STATE_STANDBY
    if v.failsafe_active:
        status = M.MAV_STATE_CRITICAL
    return v.mav.heartbeat_encode(M.MAV_TYPE_QUADROTOR, v.flavour.autopilot, base, v.mode.custom_mode, status)


def _reuse(v: Vehicle, name: str, make: Callable[[], mavlink.MAVLink_message]) -> mavlink.MAVLink_message:
    """The vehicle's instance of a high-rate message, refilled in place (skips re-construction)."""
    m = v.msg_cache.get(name)
    if m is None:
        m = v.msg_cache[name] = make()
    return m


def global_position_int(v: Vehicle) -> mavlink.MAVLink_message | None:
    if not v.gps_ok:
        return None  # no global position before the first fix (PX4 sends none either)
    lat, lon, alt = v.reported_geodetic()
    d = v.ctx.dyn
    vn, ve, vd = d.get(VEL, v.i)
    m = _reuse(v, "GLOBAL_POSITION_INT", lambda: v.mav.global_position_int_encode(0, 0, 0, 0, 0, 0, 0, 0, 0))
    m.time_boot_ms = _ms(v)
    m.lat = _i32(lat * 1e7)
    m.lon = _i32(lon * 1e7)
    m.alt = _i32(alt * 1000.0)
    m.relative_alt = _i32((alt - v.home.alt) * 1000.0)
    m.vx, m.vy, m.vz = _i16(vn * 100.0), _i16(ve * 100.0), _i16(vd * 100.0)
    m.hdg = _cdeg_heading(d.get(YAW, v.i))
    return m


def local_position_ned(v: Vehicle) -> mavlink.MAVLink_message | None:
    if not v.gps_ok:
        return None  # the local position comes from GPS here
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
    r, p, y = float(d.roll[i]) / 2, float(d.pitch[i]) / 2, float(d.yaw[i]) / 2
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return v.mav.attitude_quaternion_encode(
        _ms(v),
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        float(d.roll_rate[i]),
        float(d.pitch_rate[i]),
        float(d.yaw_rate[i]),
    )


def sys_status(v: Vehicle) -> mavlink.MAVLink_message:
    """Sensors present/enabled/healthy as MAVSDK's health() and QGC read them: GPS healthy from the
    first fix, PREARM_CHECK while arming would pass, RC_RECEIVER while stick input arrives."""
    sticks = RC if v.settings.stick_input else 0
    present = SENSORS | PREARM | FENCE | sticks
    enabled = SENSORS | PREARM | (FENCE if v.fence_enabled else 0) | sticks
    health = SENSORS | FENCE
    if not v.gps_ok:
        health &= ~GPS
    if v.prearm_ok():
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
    return v.mav.extended_sys_state_encode(M.MAV_VTOL_STATE_MC, v.landed_state())


def home_position(v: Vehicle) -> mavlink.MAVLink_message | None:
    if not v.gps_ok:
        return None  # home is set at the first fix
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
    if not v.gps_ok:  # searching: no fix, no satellites
        return v.mav.gps_raw_int_encode(int(v.ctx.clock.sim_time * 1e6), M.GPS_FIX_TYPE_NO_FIX, 0, 0, 0,
                                        65535, 65535, 0, 65535, 0)  # fmt: skip
    lat, lon, alt = v.reported_geodetic()
    vn, ve, _ = v.ctx.dyn.get(VEL, v.i)
    gs = math.hypot(vn, ve)
    cog = _cdeg_heading(math.atan2(ve, vn)) if gs > 0.1 else 65535
    return v.mav.gps_raw_int_encode(
        int(v.ctx.clock.sim_time * 1e6),
        M.GPS_FIX_TYPE_3D_FIX,
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
    cap = (
        M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
        | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
        | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
        | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
        | M.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
        | M.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
    )
    cap |= (
        M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        if v.flavour.bytewise_params
        else M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
    )
    return v.mav.autopilot_version_encode(
        cap,
        v.flavour.flight_sw_version,
        0,
        0,
        0,
        [0] * 8,
        [0] * 8,
        [0] * 8,
        0,
        0,
        0x4D52_0000_0000_0000 | v.sysid,  # "MR" + sysid: stable per vehicle
    )


# None: nothing to send yet (no position before the first GPS fix)
ENCODERS: dict[str, Callable[[Vehicle], mavlink.MAVLink_message | None]] = {
    "HEARTBEAT": heartbeat,
    "GLOBAL_POSITION_INT": global_position_int,
    "LOCAL_POSITION_NED": local_position_ned,
    "ATTITUDE": attitude,
    "ATTITUDE_QUATERNION": attitude_quaternion,
    "SYS_STATUS": sys_status,
    "EXTENDED_SYS_STATE": extended_sys_state,
    "HOME_POSITION": home_position,
    "BATTERY_STATUS": battery_status,
    "GPS_RAW_INT": gps_raw_int,
    "VFR_HUD": vfr_hud,
    "SYSTEM_TIME": system_time,
    "NAMED_VALUE_FLOAT": named_value_rtf,
    "MISSION_CURRENT": mission_current,
}



def _framer() -> Any:
    """The compiled GLOBAL_POSITION_INT framer (uav_stack/fcu/_telemetry.c), configured; None
    without it, or with a pymavlink whose message it would not frame alike (another layout,
    CRC extra or id, or MAVLink 1 on the wire)."""
    compiled = compiled_module("uav_stack.fcu._telemetry")
    cls = mavlink.MAVLink_global_position_int_message
    if compiled is None or float(mavlink.WIRE_PROTOCOL_VERSION) != 2.0 or (cls.id, cls.crc_extra, cls.unpacker.format) != (
            33, 104, "<IiiiihhhH"):
        return None
    compiled.configure(math.hypot, geo.WGS84_A, geo.WGS84_B, geo.WGS84_F, geo.WGS84_E2, geo._EP2, math.radians(80))
    return compiled


_FRAMER = _framer()
TELEMETRY = "compiled" if _FRAMER is not None else "python"
"""Who builds the FCU's GLOBAL_POSITION_INT stream: ``"compiled"`` or ``"python"`` (a UAV's status file)."""


def global_position_int_frame(v: Vehicle) -> bytes | None:
    """GLOBAL_POSITION_INT as the frame :func:`global_position_int` and ``mavcodec.pack`` make,
    built in one compiled call (it is sent every tick, with the interpreter's caches cold: 131
    against 4.8 µs warm, docs/benchmarks.md); None: nothing to send, or the Python path must
    (no fix yet, a signing link, no compiled framer), so :func:`global_position_int` decides."""
    mav = v.mav
    if not v.gps_ok or mav.signing.sign_outgoing:
        return None
    d = v.ctx.dyn
    frame: bytes = _FRAMER.global_position_int(
        d.pos, d.vel, d.yaw, v.i, v.frame.constants, v.position_error, v.home.alt, v.ctx.clock.sim_time,
        mav.seq, mav.srcSystem, mav.srcComponent)
    return frame


# Streams some of whose messages a compiled call frames whole: name -> frame or None (then the encoder)
FRAMERS: dict[str, Callable[[Vehicle], bytes | None]] = (
    {"GLOBAL_POSITION_INT": global_position_int_frame} if _FRAMER is not None else {})

# Messages REQUEST_MESSAGE can produce, by id (streams plus one-shot ones).
REQUESTABLE: dict[int, Callable[[Vehicle], mavlink.MAVLink_message | None]] = {
    M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: autopilot_version,
    **{getattr(M, f"MAVLINK_MSG_ID_{name}"): fn for name, fn in ENCODERS.items()},
}
STREAM_BY_ID: dict[int, str] = {getattr(M, f"MAVLINK_MSG_ID_{name}"): name for name in ENCODERS}


class StreamSet:
    """Per-vehicle stream intervals (sim seconds) and next due times.

    All of a vehicle's streams are phase-aligned on the physics step grid (offset
    ``phase`` steps), so one wake-up sends everything due and a lone vehicle wakes its
    host loop about 10 times a second, not once per stream; vehicles of a fleet get
    different phases, which spreads their sends.
    """

    def __init__(self, rates: dict[str, float], defaults: dict[str, float], dt: float, phase: int = 0):
        self.dt = dt
        self.defaults = dict(defaults)
        self.interval: dict[str, float] = {}
        self.next_due: dict[str, float] = {}
        self.next_any = math.inf
        self._phase = phase
        self._grid = max(1, round(0.1 / dt))  # first sends on the 10 Hz grid: everything within 0.1 s
        for name in ENCODERS:
            self.set_rate(name, rates.get(name, 0.0), now=0.0, first=True)

    def _aligned(self, now: float, iv: float, first: bool = False) -> float:
        steps = max(1, round(iv / self.dt))
        if first:
            steps = min(steps, self._grid)
        k_now = round(now / self.dt)
        return (k_now + 1 + (self._phase - k_now - 1) % steps) * self.dt

    def set_rate(self, name: str, hz: float, now: float, first: bool = False) -> None:
        if not hz > 0 or not math.isfinite(hz):
            self.interval[name] = 0.0
            self.next_due[name] = math.inf
        else:
            iv = max(1.0 / hz, self.dt)
            self.interval[name] = iv
            self.next_due[name] = self._aligned(now, iv, first)
        self.next_any = min(self.next_due.values())

    def set_interval_us(self, name: str, interval_us: float, now: float) -> None:
        """SET_MESSAGE_INTERVAL semantics: -1 off, 0 default, else microseconds."""
        if interval_us == -1:
            self.set_rate(name, 0.0, now)
        elif interval_us == 0:
            self.set_rate(name, self.defaults.get(name, 0.0), now)
        else:
            self.set_rate(name, 1e6 / interval_us, now)

    def interval_us(self, name: str) -> int:
        iv = self.interval.get(name, 0.0)
        return int(round(iv * 1e6)) if iv > 0 else -1

    def due(self, now: float) -> list[str]:
        if now + 1e-9 < self.next_any:
            return []
        out = []
        for name, t in self.next_due.items():
            if now + 1e-9 >= t:
                out.append(name)
                iv = self.interval[name]
                nt = t + iv
                self.next_due[name] = nt if nt > now else now + iv
        self.next_any = min(self.next_due.values())
        return out
