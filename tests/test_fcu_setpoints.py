"""Setpoint decoding (frames, type_mask), the stream rule, and the commands that move targets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.fcu_helpers import FcuThread, MavClient
from uav_stack.fcu import FcuConfig, VehicleConfig
from uav_stack.fcu.offboard import SetpointStream, decode_global, decode_local
from uav_stack.geo import GeoPoint, LocalFrame
from uav_stack.mav import mavlink as M

NAN = math.nan
HOME = GeoPoint(47.397742, 8.545594, 488.0)
MAV = M.MAVLink(None, 245, 190)
POS_YAW = 0b0000_1001_1111_1000  # 2552: MAVSDK set_position_ned (position + yaw)
VEL_YAW = 0b0000_1001_1100_0111  # 2503: velocity + yaw


def local(frame: int, mask: int, x=0.0, y=0.0, z=0.0, vx=0.0, vy=0.0, vz=0.0, yaw=0.0):
    return MAV.set_position_target_local_ned_encode(0, 1, 1, frame, mask, x, y, z, vx, vy, vz, 0, 0, 0, yaw, 0)


def test_local_frames_and_masks() -> None:
    here = np.array([10.0, 20.0, -5.0])
    sp = decode_local(local(M.MAV_FRAME_LOCAL_NED, POS_YAW, 1, 2, -3, yaw=0.5), here, 0.0)
    assert list(sp.pos) == [1, 2, -3] and np.isnan(sp.vel).all() and sp.yaw == 0.5 and math.isnan(sp.yaw_rate)
    sp = decode_local(local(M.MAV_FRAME_LOCAL_NED, VEL_YAW, vx=1, vy=-1, vz=0.5), here, 0.0)
    assert np.isnan(sp.pos).all() and list(sp.vel) == [1, -1, 0.5] and sp.has_velocity
    sp = decode_local(local(M.MAV_FRAME_LOCAL_OFFSET_NED, POS_YAW, 1, 2, -3), here, 0.0)
    assert list(sp.pos) == [11, 22, -8]
    # body frames: facing east (yaw 90 deg), forward = east
    sp = decode_local(local(M.MAV_FRAME_BODY_NED, VEL_YAW, vx=2.0), here, math.pi / 2)
    assert np.allclose(sp.vel, [0, 2, 0], atol=1e-9)
    sp = decode_local(local(M.MAV_FRAME_BODY_OFFSET_NED, POS_YAW, 3.0, 1.0, 0.0), here, math.pi / 2)
    assert np.allclose(sp.pos, [10 - 1, 20 + 3, -5], atol=1e-9)
    # per-axis: xy position, z velocity
    sp = decode_local(local(M.MAV_FRAME_LOCAL_NED, 0b1101_1101_1100, 4, 5, vz=-1), here, 0.0)
    assert list(sp.pos[:2]) == [4, 5] and math.isnan(sp.pos[2]) and sp.vel[2] == -1
    assert decode_local(local(M.MAV_FRAME_GLOBAL_INT, POS_YAW), here, 0.0) is None  # not a local frame


def test_global_int_setpoint() -> None:
    frame = LocalFrame(HOME)
    lat, lon, _ = frame.to_geodetic(-4.0, 6.0, 0.0)  # 6 m north, 4 m west
    m = MAV.set_position_target_global_int_encode(0, 1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, POS_YAW,
                                                  round(lat * 1e7), round(lon * 1e7), 3.0, 0, 0, 0, 0, 0, 0, 1.0, 0)  # fmt: skip
    sp = decode_global(m, frame, HOME.alt)
    assert np.allclose(sp.pos, [6.0, -4.0, -3.0], atol=0.02) and sp.yaw == 1.0
    m = MAV.set_position_target_global_int_encode(0, 1, 1, M.MAV_FRAME_GLOBAL_INT, POS_YAW,
                                                  round(lat * 1e7), round(lon * 1e7), HOME.alt + 3.0,
                                                  0, 0, 0, 0, 0, 0, 0, 0)
    assert np.allclose(decode_global(m, frame, HOME.alt).pos, [6.0, -4.0, -3.0], atol=0.02)


def test_stream_rule_needs_more_than_2hz_for_a_second() -> None:
    s = SetpointStream()
    sp = decode_local(local(M.MAV_FRAME_LOCAL_NED, POS_YAW), np.zeros(3), 0.0)
    for k in range(10):  # 1 Hz: never a stream
        s.note(sp, k * 1.0)
        assert not s.active(k * 1.0)
    t = 20.0
    for k in range(25):  # 20 Hz
        s.note(sp, t + k * 0.05)
    assert not s.active(t + 0.9)
    for k in range(25, 40):
        s.note(sp, t + k * 0.05)
    assert s.active(t + 39 * 0.05)
    assert not s.active(t + 39 * 0.05 + 0.6)  # stopped
    # SIM_OFB_STREAM_T = 0: PX4's code rule, one setpoint younger than COM_OF_LOSS_T
    s2 = SetpointStream()
    s2.note(sp, 100.0)
    assert not s2.active(100.0) and s2.active(100.0, 0.0, 1.0) and not s2.active(101.1, 0.0, 1.0)


def test_global_setpoints_home_speed_and_data_stream_over_udp() -> None:
    cfg = FcuConfig([VehicleConfig(sysid=1, home=HOME)])
    with FcuThread(cfg) as ft, MavClient(ft.addrs[0]) as c:
        c.heartbeat()
        assert c.recv_match("HEARTBEAT", 3.0) is not None
        v = ft.fcu.vehicles[0]
        frame = LocalFrame(HOME)
        lat, lon, _ = frame.to_geodetic(5.0, 0.0, 0.0)
        c.send(MAV.set_position_target_global_int_encode(0, 1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, POS_YAW,
                                                         round(lat * 1e7), round(lon * 1e7), 2.0,
                                                         0, 0, 0, 0, 0, 0, 0, 0))
        assert c.wait(lambda: v.setpoints.latest is not None, 2.0)
        assert np.allclose(v.setpoints.latest.pos, [0.0, 5.0, -2.0], atol=0.02)
        # DO_SET_HOME with a location (COMMAND_INT, relative altitude), answered by HOME_POSITION
        lat2, lon2, _ = frame.to_geodetic(0.0, 10.0, 0.0)
        r = c.command_int(M.MAV_CMD_DO_SET_HOME, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0, x=round(lat2 * 1e7),
                          y=round(lon2 * 1e7), z=0.0)  # fmt: skip
        assert r == M.MAV_RESULT_ACCEPTED
        h = c.recv_match("HOME_POSITION", 2.0)
        assert h is not None and h.latitude == round(lat2 * 1e7) and h.x == pytest.approx(10.0, abs=0.02)
        assert c.command_long(M.MAV_CMD_DO_SET_HOME, 1) == M.MAV_RESULT_ACCEPTED  # here
        h = c.recv_match("HOME_POSITION", 2.0)
        assert h is not None and abs(h.x) < 0.01
        # DO_CHANGE_SPEED: ground speed for auto modes, -2 = back to the default
        assert c.command_long(M.MAV_CMD_DO_CHANGE_SPEED, 1, 2.5) == M.MAV_RESULT_ACCEPTED
        assert ft.fcu.dyn.vxy_max[0] == pytest.approx(2.5)
        assert c.command_long(M.MAV_CMD_DO_CHANGE_SPEED, 1, -2) == M.MAV_RESULT_ACCEPTED
        assert ft.fcu.dyn.vxy_max[0] == pytest.approx(5.0)
        # REQUEST_DATA_STREAM (MAVProxy/QGC for ArduPilot) is accepted quietly
        c.send(MAV.request_data_stream_encode(1, 1, 0, 4, 1))
        assert c.command_long(M.MAV_CMD_REQUEST_MESSAGE, 242) == M.MAV_RESULT_ACCEPTED
        assert ft.fcu.stats.handler_errors == 0
