"""The messages only the PX4 flavour sends (its onboard link's streams, px4.STREAMS): HIGHRES_IMU, ALTITUDE,
ATTITUDE_TARGET, POSITION_TARGET_LOCAL_NED, DISTANCE_SENSOR, ODOMETRY, ESTIMATOR_STATUS, LINK_NODE_STATUS,
OPEN_DRONE_ID_LOCATION/SYSTEM, CURRENT_MODE, TIME_ESTIMATE_TO_TARGET, PING and CURRENT_EVENT_SEQUENCE.

Values come from the vehicle's state (attitude, position, velocity, targets, mode) where it has one; the
rest reads as a healthy vehicle's would.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from uav_stack.fcu import px4
from uav_stack.fcu.dynamics import PITCH, PITCH_RATE, POS, ROLL, ROLL_RATE, VEL, YAW, YAW_RATE, G
from uav_stack.fcu.telemetry import _i32, _ms, _reuse, pressure_hpa
from uav_stack.mav import mavlink

if TYPE_CHECKING:
    from uav_stack.fcu.vehicle import Vehicle

M = mavlink
NAN = math.nan


def _quaternion(roll: float, pitch: float, yaw: float) -> list[float]:
    r, p, y = roll / 2, pitch / 2, yaw / 2
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy]


def highres_imu(v: Vehicle) -> mavlink.MAVLink_message:
    d, i = v.ctx.dyn, v.i
    get = d.get
    r, p = get(ROLL, i), get(PITCH, i)
    _, _, alt = v.geodetic()
    m = _reuse(v, "HIGHRES_IMU", lambda: v.mav.highres_imu_encode(0, 0, 0, 0, 0, 0, 0, 0.21, 0.0, 0.42, 0, 0, 0, 25.0,
                                                                   0x1FFF, 0))  # fmt: skip
    m.time_usec = int(v.now * 1e6)
    m.xacc, m.yacc, m.zacc = G * math.sin(p), -G * math.sin(r) * math.cos(p), -G * math.cos(r) * math.cos(p)
    m.xgyro, m.ygyro, m.zgyro = get(ROLL_RATE, i), get(PITCH_RATE, i), get(YAW_RATE, i)
    m.abs_pressure = pressure_hpa(alt)
    m.pressure_alt = alt
    return m


def altitude(v: Vehicle) -> mavlink.MAVLink_message:
    _, _, alt = v.geodetic()
    local = -v.ctx.dyn.get(POS, v.i)[2]
    rel = alt - v.home.alt
    ground = v.frame.origin.alt
    return v.mav.altitude_encode(int(v.now * 1e6), alt, alt, local, rel, NAN, alt - ground)


def attitude_target(v: Vehicle) -> mavlink.MAVLink_message:
    d, i = v.ctx.dyn, v.i
    q = _quaternion(d.get(ROLL, i), d.get(PITCH, i), d.get(YAW, i))
    thrust = 0.0 if not v.armed else (0.1 if v.landed else 0.5)
    return v.mav.attitude_target_encode(_ms(v), 0, q, 0.0, 0.0, 0.0, thrust)


def position_target_local_ned(v: Vehicle) -> mavlink.MAVLink_message:
    d, i = v.ctx.dyn, v.i
    x, y, z = (float(c) for c in d.pos_sp[i])
    vx, vy, vz = (float(c) for c in d.vel_ff[i])
    return v.mav.position_target_local_ned_encode(_ms(v), M.MAV_FRAME_LOCAL_NED, 0, x, y, z, vx, vy, vz, NAN, NAN, NAN,
                                                  d.get(YAW, i), NAN)  # fmt: skip


def distance_sensor(v: Vehicle) -> mavlink.MAVLink_message:
    """SIH's downward range finder: height above the (flat) ground, 0.1..100 m."""
    h = max(0.0, v.ctx.dyn.height(v.i))
    cm = int(min(max(h * 100.0, 10.0), 10000.0))
    return v.mav.distance_sensor_encode(_ms(v), 10, 10000, cm, M.MAV_DISTANCE_SENSOR_LASER, 0,
                                        M.MAV_SENSOR_ROTATION_PITCH_270, 0, 0.0, 0.0, [0.0] * 4, 0)  # fmt: skip


def odometry(v: Vehicle) -> mavlink.MAVLink_message:
    d, i = v.ctx.dyn, v.i
    get = d.get
    m = _reuse(v, "ODOMETRY", lambda: v.mav.odometry_encode(0, M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_BODY_FRD, 0, 0, 0,
                                                            [1.0, 0.0, 0.0, 0.0], 0, 0, 0, 0, 0, 0, [NAN] * 21,
                                                            [NAN] * 21, 0, M.MAV_ESTIMATOR_TYPE_AUTOPILOT, 100))  # fmt: skip
    m.time_usec = int(v.now * 1e6)
    m.x, m.y, m.z = get(POS, i)
    m.vx, m.vy, m.vz = get(VEL, i)
    m.q = _quaternion(get(ROLL, i), get(PITCH, i), get(YAW, i))
    m.rollspeed, m.pitchspeed, m.yawspeed = get(ROLL_RATE, i), get(PITCH_RATE, i), get(YAW_RATE, i)
    return m


def estimator_status(v: Vehicle) -> mavlink.MAVLink_message:
    flags = 1023 if v.booted else px4.estimator_flags(v.boot, v.now)
    return v.mav.estimator_status_encode(int(v.now * 1e6), flags, 0.01, 0.01, 0.01, 0.01, 0.0, 0.0, 0.5, 0.8)


def link_node_status(v: Vehicle) -> mavlink.MAVLink_message:
    st = v.ctx.stats
    return v.mav.link_node_status_encode(int(v.now * 1e3), 0, 0, 0, 0, st.bad_datagrams & 0xFFFF, 0, 0,
                                         st.messages_out & 0xFFFFFFFF, sum(st.messages_in.values()) & 0xFFFFFFFF, 0)  # fmt: skip


def _uas_id(v: Vehicle) -> bytes:
    return f"MRSWARM{v.sysid:03d}".encode().ljust(20, b"\0")


def open_drone_id_location(v: Vehicle) -> mavlink.MAVLink_message:
    lat, lon, alt = v.geodetic()
    d, i = v.ctx.dyn, v.i
    vn, ve, vd = d.get(VEL, i)
    gs = math.hypot(vn, ve)
    direction = int(math.degrees(math.atan2(ve, vn)) % 360 * 100) if gs > 0.1 else 36100
    status = M.MAV_ODID_STATUS_AIRBORNE if v.armed and not v.landed else M.MAV_ODID_STATUS_GROUND
    return v.mav.open_drone_id_location_encode(0, 0, list(_uas_id(v)), status, direction, int(min(gs, 254.25) * 100),
                                               int(-vd * 100), _i32(lat * 1e7), _i32(lon * 1e7), alt, alt,
                                               M.MAV_ODID_HEIGHT_REF_OVER_TAKEOFF, alt - v.home.alt,
                                               M.MAV_ODID_HOR_ACC_3_METER, M.MAV_ODID_VER_ACC_3_METER,
                                               M.MAV_ODID_VER_ACC_3_METER, M.MAV_ODID_SPEED_ACC_1_METERS_PER_SECOND,
                                               (v.now % 3600.0), M.MAV_ODID_TIME_ACC_1_0_SECOND)  # fmt: skip


def open_drone_id_system(v: Vehicle) -> mavlink.MAVLink_message:
    h = v.home
    return v.mav.open_drone_id_system_encode(0, 0, list(_uas_id(v)), M.MAV_ODID_OPERATOR_LOCATION_TYPE_TAKEOFF,
                                             M.MAV_ODID_CLASSIFICATION_TYPE_EU, _i32(h.lat * 1e7), _i32(h.lon * 1e7), 1, 0,
                                             -1000.0, -1000.0, M.MAV_ODID_CATEGORY_EU_UNDECLARED,
                                             M.MAV_ODID_CLASS_EU_UNDECLARED, h.alt, int(v.now))  # fmt: skip


def current_mode(v: Vehicle) -> mavlink.MAVLink_message:
    return v.mav.current_mode_encode(0, v.mode.custom_mode, v.intended_mode.custom_mode)


def time_estimate_to_target(v: Vehicle) -> mavlink.MAVLink_message:
    return v.mav.time_estimate_to_target_encode(-1, -1, -1, -1, -1)


def ping(v: Vehicle) -> mavlink.MAVLink_message:
    v.ping_seq = (v.ping_seq + 1) & 0xFFFFFFFF
    return v.mav.ping_encode(int(v.now * 1e6), v.ping_seq, 0, 0)


def current_event_sequence(v: Vehicle) -> mavlink.MAVLink_message | None:
    ev = v.events
    if ev is None:
        return None
    return ev.current_sequence(v)


ENCODERS: dict[str, Callable[[Vehicle], mavlink.MAVLink_message | None]] = {
    "HIGHRES_IMU": highres_imu,
    "ALTITUDE": altitude,
    "ATTITUDE_TARGET": attitude_target,
    "POSITION_TARGET_LOCAL_NED": position_target_local_ned,
    "DISTANCE_SENSOR": distance_sensor,
    "ODOMETRY": odometry,
    "ESTIMATOR_STATUS": estimator_status,
    "LINK_NODE_STATUS": link_node_status,
    "OPEN_DRONE_ID_LOCATION": open_drone_id_location,
    "OPEN_DRONE_ID_SYSTEM": open_drone_id_system,
    "CURRENT_MODE": current_mode,
    "TIME_ESTIMATE_TO_TARGET": time_estimate_to_target,
    "PING": ping,
    "CURRENT_EVENT_SEQUENCE": current_event_sequence,
}
