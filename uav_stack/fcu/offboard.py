"""External setpoints: SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT decoding and stream rules.

PX4 rules (PX4's offboardCheck.cpp; docs/fcu.md, Offboard): OFFBOARD can be entered (or armed
in) only while a setpoint younger than COM_OF_LOSS_T exists; this is what PX4's code checks
and what MAVSDK's "set a setpoint, then start()" relies on. The emulator parameter
SIM_OFB_STREAM_T > 0 enforces the stricter rule of PX4's documentation instead (a > 2 Hz
stream for that many seconds). In OFFBOARD, no setpoint for COM_OF_LOSS_T triggers the
COM_OBL_RC_ACT failsafe. ArduPilot GUIDED has no entry rule;
velocity targets time out after GUID_TIMEOUT (the vehicle stops and holds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uav_stack.geo import LocalFrame
from uav_stack.mav import mavlink

M = mavlink
IGNORE_PX, IGNORE_PY, IGNORE_PZ = 1, 2, 4
IGNORE_VX, IGNORE_VY, IGNORE_VZ = 8, 16, 32
IGNORE_YAW, IGNORE_YAW_RATE = 1024, 2048
STREAM_GAP_S = 0.5  # > 2 Hz
MAX_OFFSET_M = 1e6  # setpoints farther than this from the origin are refused
MAX_SPEED = 100.0  # m/s, velocity setpoints above this are refused
STREAM_MIN_S = 1.0  # for at least one second

LOCAL_FRAMES = {
    M.MAV_FRAME_LOCAL_NED,
    M.MAV_FRAME_LOCAL_OFFSET_NED,
    M.MAV_FRAME_BODY_NED,
    M.MAV_FRAME_BODY_OFFSET_NED,
    M.MAV_FRAME_BODY_FRD,
}
# global frames -> altitude reference: True = relative to home, False = AMSL
GLOBAL_FRAMES = {
    M.MAV_FRAME_GLOBAL: False,
    M.MAV_FRAME_GLOBAL_INT: False,
    M.MAV_FRAME_GLOBAL_RELATIVE_ALT: True,
    M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: True,
    M.MAV_FRAME_GLOBAL_TERRAIN_ALT: True,  # flat terrain at home height
    M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT: True,
}


Vec3 = tuple[float, float, float]


@dataclass
class Setpoint:
    """One external setpoint, NED. Plain float tuples: this runs for every setpoint (10-20 Hz per
    vehicle), and numpy's per-call overhead on 3-element arrays dominated its cost."""

    pos: Vec3  # NaN per axis = not position-controlled
    vel: Vec3  # NaN per axis = none
    yaw: float = math.nan
    yaw_rate: float = math.nan

    @property
    def has_velocity(self) -> bool:
        """Some axis is velocity-controlled (a velocity and no position)."""
        (p0, p1, p2), (v0, v1, v2) = self.pos, self.vel
        return (v0 == v0 and p0 != p0) or (v1 == v1 and p1 != p1) or (v2 == v2 and p2 != p2)


# (written out per axis, not as generators: a setpoint arrives every tick in every virtual UAV)
def _masked(vals: Vec3, mask: int, bits: tuple[int, int, int]) -> Vec3:
    """The axes ``mask`` does not ignore and that are finite; NaN for the others."""
    (a, b, c), (ba, bb, bc) = vals, bits
    isfinite, nan = math.isfinite, math.nan
    return (a if not (mask & ba) and isfinite(a) else nan, b if not (mask & bb) and isfinite(b) else nan,
            c if not (mask & bc) and isfinite(c) else nan)


def _sane(sp: Setpoint) -> Setpoint | None:
    """Refuse setpoints no vehicle could follow (they would only overflow telemetry later)."""
    (p0, p1, p2), (v0, v1, v2) = sp.pos, sp.vel
    far = abs(p0) > MAX_OFFSET_M or abs(p1) > MAX_OFFSET_M or abs(p2) > MAX_OFFSET_M  # NaN compares False
    fast = abs(v0) > MAX_SPEED or abs(v1) > MAX_SPEED or abs(v2) > MAX_SPEED
    odd_yaw = abs(sp.yaw) > 100.0 or abs(sp.yaw_rate) > 100.0
    return None if far or fast or odd_yaw else sp


def _rot(yaw: float, v: Vec3) -> Vec3:
    """Body (forward, right, down) -> NED for a vehicle at heading yaw."""
    c, s = math.cos(yaw), math.sin(yaw)
    return (c * v[0] - s * v[1], s * v[0] + c * v[1], v[2])


def _add(a: Vec3 | np.ndarray, b: Vec3) -> Vec3:
    return (float(a[0]) + b[0], float(a[1]) + b[1], float(a[2]) + b[2])


def decode_local(msg: mavlink.MAVLink_message, pos_now: Vec3 | np.ndarray, yaw_now: float) -> Setpoint | None:
    """SET_POSITION_TARGET_LOCAL_NED -> LOCAL_NED setpoint; None for unsupported frames."""
    frame = msg.coordinate_frame
    if frame not in LOCAL_FRAMES:
        return None
    m = msg.type_mask
    pos = _masked((msg.x, msg.y, msg.z), m, (IGNORE_PX, IGNORE_PY, IGNORE_PZ))
    vel = _masked((msg.vx, msg.vy, msg.vz), m, (IGNORE_VX, IGNORE_VY, IGNORE_VZ))
    if frame == M.MAV_FRAME_LOCAL_OFFSET_NED:
        pos = _add(pos_now, pos)
    elif frame == M.MAV_FRAME_BODY_NED:
        vel = _rot(yaw_now, vel)
    elif frame in (M.MAV_FRAME_BODY_OFFSET_NED, M.MAV_FRAME_BODY_FRD):
        pos = _add(pos_now, _rot(yaw_now, pos))
        vel = _rot(yaw_now, vel)
    yaw = msg.yaw if not (m & IGNORE_YAW) and math.isfinite(msg.yaw) else math.nan
    yaw_rate = msg.yaw_rate if not (m & IGNORE_YAW_RATE) and math.isfinite(msg.yaw_rate) else math.nan
    return _sane(Setpoint(pos, vel, yaw, yaw_rate))


def decode_global(msg: mavlink.MAVLink_message, frame_geo: LocalFrame, home_alt: float) -> Setpoint | None:
    """SET_POSITION_TARGET_GLOBAL_INT -> LOCAL_NED setpoint; None for unsupported frames."""
    rel = GLOBAL_FRAMES.get(msg.coordinate_frame)
    if rel is None:
        return None
    m = msg.type_mask
    lat, lon = msg.lat_int * 1e-7, msg.lon_int * 1e-7
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        return None
    alt = msg.alt + (home_alt if rel else 0.0)
    z_ok = not (m & IGNORE_PZ) and math.isfinite(msg.alt)
    e, n, u = frame_geo.to_enu(lat, lon, alt if z_ok else frame_geo.origin.alt)
    pos = (
        n if not (m & IGNORE_PX) else math.nan,
        e if not (m & IGNORE_PY) else math.nan,
        -u if z_ok else math.nan,
    )
    vel = _masked((msg.vx, msg.vy, msg.vz), m, (IGNORE_VX, IGNORE_VY, IGNORE_VZ))
    yaw = msg.yaw if not (m & IGNORE_YAW) and math.isfinite(msg.yaw) else math.nan
    yaw_rate = msg.yaw_rate if not (m & IGNORE_YAW_RATE) and math.isfinite(msg.yaw_rate) else math.nan
    return _sane(Setpoint(pos, vel, yaw, yaw_rate))


@dataclass
class SetpointStream:
    """Tracks the setpoint stream on sim time (PX4's offboard entry/loss rules)."""

    last: float = -math.inf
    start: float = -math.inf
    latest: Setpoint | None = None
    count: int = 0

    def note(self, sp: Setpoint, now: float) -> None:
        if now - self.last > STREAM_GAP_S:
            self.start = now
        self.last = now
        self.latest = sp
        self.count += 1

    def active(self, now: float, min_stream_s: float = STREAM_MIN_S, loss_t: float = STREAM_GAP_S) -> bool:
        """A > 2 Hz stream has been arriving for >= ``min_stream_s`` (and still is).

        ``min_stream_s <= 0`` is what PX4's code checks (offboardCheck.cpp): any setpoint
        younger than COM_OF_LOSS_T (``loss_t``) is enough.
        """
        if self.latest is None:
            return False
        if min_stream_s <= 0:
            return now - self.last <= loss_t
        return now - self.last <= STREAM_GAP_S and now - self.start >= min_stream_s - 1e-9

    def age(self, now: float) -> float:
        return now - self.last
