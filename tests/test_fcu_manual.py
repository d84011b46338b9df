"""Sticks and health over real UDP against the virtual FCU: MANUAL_CONTROL in PX4 POSCTL,
RC_CHANNELS_OVERRIDE in ArduCopter LOITER, the stick-loss failsafe, and SYS_STATUS from boot to ready."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from tests.fcu_helpers import FcuThread, MavClient
from uav_stack.fcu import DEFAULT_STREAM_RATES, FcuConfig, VehicleConfig
from uav_stack.geo import GeoPoint
from uav_stack.mav import mavlink as M

NAN = math.nan
HOME = GeoPoint(47.397742, 8.545594, 488.0)
ACC = M.MAV_RESULT_ACCEPTED
GPS, PREARM, RC = M.MAV_SYS_STATUS_SENSOR_GPS, M.MAV_SYS_STATUS_PREARM_CHECK, M.MAV_SYS_STATUS_SENSOR_RC_RECEIVER


def vehicle(flavour: str, ready: bool = True, **params: float) -> tuple[FcuThread, MavClient]:
    rates = dict(DEFAULT_STREAM_RATES, LOCAL_POSITION_NED=10.0)
    cfg = FcuConfig([VehicleConfig(sysid=1, home=HOME, flavour=flavour, params=params)], stream_rates=rates)
    ft = FcuThread(cfg, ready=ready)
    return ft, MavClient(ft.addrs[0])


def ned(c: MavClient) -> tuple[float, float, float]:
    m = c.latest.get("LOCAL_POSITION_NED")
    return (m.x, m.y, m.z) if m is not None else (NAN, NAN, NAN)


def stream(c: MavClient, seconds: float, send: Callable[[], None], hz: float = 10.0) -> None:
    end = time.monotonic() + seconds
    nxt = time.monotonic()
    while time.monotonic() < end:
        if time.monotonic() >= nxt:
            send()
            nxt += 1.0 / hz
        c.pump(max(0.0, min(nxt, end) - time.monotonic()))


def sticks(c: MavClient, x: int = 0, y: int = 0, z: int = 500, r: int = 0) -> Callable[[], None]:
    """MANUAL_CONTROL as MAVSDK sends it (target = the vehicle's sysid; z 500 = mid throttle)."""
    return lambda: c.send(c.mav.manual_control_encode(1, x, y, z, r, 0))


def rc(c: MavClient, ch1: int = 0, ch2: int = 0, ch3: int = 0, ch4: int = 0) -> Callable[[], None]:
    """RC_CHANNELS_OVERRIDE as MAVProxy's ``rc`` sends it (0 = released)."""
    return lambda: c.send(c.mav.rc_channels_override_encode(1, 1, ch1, ch2, ch3, ch4, 0, 0, 0, 0))


def px4_mode(c: MavClient) -> str | None:
    return c.px4_mode()


def test_health_bits_from_boot_to_ready() -> None:
    ft, c = vehicle("px4", ready=False, SIM_GPS_FIX_T=1.5)
    with ft, c:
        c.heartbeat()
        st = c.recv_match("SYS_STATUS", 1.5)
        assert st is not None and ft.fcu.sim_time < 1.4
        # just booted: GPS present and enabled, not healthy; not armable; no position, no home
        assert st.onboard_control_sensors_present & GPS and st.onboard_control_sensors_enabled & GPS
        assert not st.onboard_control_sensors_health & GPS and not st.onboard_control_sensors_health & PREARM
        assert st.onboard_control_sensors_health & M.MAV_SYS_STATUS_SENSOR_3D_GYRO  # calibrated sensors are fine
        assert c.latest["GPS_RAW_INT"].fix_type < M.GPS_FIX_TYPE_3D_FIX if "GPS_RAW_INT" in c.latest else True
        assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_DENIED
        assert any("GPS fix" in t for t in c.statustexts), c.statustexts
        assert c.command_long(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION) == M.MAV_RESULT_TEMPORARILY_REJECTED
        assert "GLOBAL_POSITION_INT" not in c.latest and "HOME_POSITION" not in c.latest and "LOCAL_POSITION_NED" not in c.latest
        # the first fix: position, home and health, and arming works
        assert c.wait(lambda: "GLOBAL_POSITION_INT" in c.latest, 2.5)
        assert ft.fcu.sim_time >= 1.5
        assert c.wait(lambda: c.latest["SYS_STATUS"].onboard_control_sensors_health & (GPS | PREARM) == GPS | PREARM, 1.5)
        assert c.wait(lambda: "HOME_POSITION" in c.latest, 2.5)
        assert c.recv_match("GPS_RAW_INT", 1.5, lambda m: m.fix_type == M.GPS_FIX_TYPE_3D_FIX) is not None
        assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC


def test_px4_posctl_sticks_fly_and_a_lost_stick_stream_fails_safe() -> None:
    ft, c = vehicle("px4", MIS_TAKEOFF_ALT=2.0, MPC_TKO_SPEED=2.0, MPC_VEL_MANUAL=4.0)
    with ft, c:
        c.heartbeat()
        assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
        assert c.command_long(M.MAV_CMD_NAV_TAKEOFF) == ACC
        assert c.wait(lambda: px4_mode(c) == "HOLD" and -ned(c)[2] > 1.8, 6.0), (px4_mode(c), ned(c))
        assert c.set_mode_px4(3) == M.MAV_RESULT_DENIED  # POSCTL in the air needs a stick stream
        assert any("no manual control" in t for t in c.statustexts)
        stream(c, 0.5, sticks(c))  # MAVSDK: set an input before start_position_control()
        assert c.set_mode_px4(3) == ACC
        start = ned(c)
        stream(c, 2.0, sticks(c, x=1000))  # full forward: north at the heading 0
        moved = ned(c)
        assert moved[0] - start[0] > 3.0 and abs(moved[1] - start[1]) < 0.3, (start, moved)
        assert max(math.hypot(m.vx, m.vy) for m in c.received[-60:] if m.get_type() == "LOCAL_POSITION_NED") <= 4.1
        assert c.latest["SYS_STATUS"].onboard_control_sensors_health & RC  # the stick stream counts as RC
        stream(c, 1.0, sticks(c, z=1000))  # full throttle climbs
        assert -ned(c)[2] - -moved[2] > 1.0
        stream(c, 3.0, sticks(c))  # centred: brakes and holds
        held = ned(c)
        stream(c, 1.0, sticks(c))
        assert math.dist(held, ned(c)) < 0.2
        # the stream stops: COM_RC_LOSS_T later, NAV_RCL_ACT (default: Return)
        t_stop = time.monotonic()
        assert c.wait(lambda: px4_mode(c) == "RTL", 3.0), px4_mode(c)
        assert 0.4 < time.monotonic() - t_stop < 3.0
        assert any("manual control lost" in t for t in c.statustexts)
        assert ft.fcu.stats.failsafes["manual control lost"] == 1


def test_ardupilot_rc_override_climbs_in_loiter_and_its_loss_runs_fs_thr_enable() -> None:
    ft, c = vehicle("ardupilot", RC_OVERRIDE_TIME=1.0, FS_THR_ENABLE=3)
    with ft, c:
        c.heartbeat()
        assert c.command_long(M.MAV_CMD_DO_SET_MODE, 1, 9) == ACC  # LAND, on the ground
        assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_DENIED
        assert "Arm: Mode not armable" in c.statustexts  # ArduCopter's words (not "not in LAND")
        assert c.command_long(M.MAV_CMD_DO_SET_MODE, 1, 4) == ACC  # GUIDED
        assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
        assert c.command_long(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 0, 0, 2.0) == ACC
        assert c.wait(lambda: -ned(c)[2] > 1.8, 6.0), ned(c)
        assert c.command_long(M.MAV_CMD_DO_SET_MODE, 1, 5) == ACC  # LOITER: no overrides needed to hold
        c.drain(0.5)
        z0 = ned(c)[2]
        stream(c, 2.0, rc(c, ch3=1700))  # MAVProxy "rc 3 1700": above the throttle dead zone, climbs
        z1 = ned(c)[2]
        assert z0 - z1 > 1.2, (z0, z1)  # about 0.94 m/s at PILOT_SPEED_UP 2.5 m/s
        stream(c, 1.0, rc(c, ch3=1500))  # mid stick: holds the altitude
        z2 = ned(c)[2]
        stream(c, 1.0, rc(c, ch3=1500))
        assert abs(ned(c)[2] - z2) < 0.15
        x0 = ned(c)[0]
        stream(c, 1.5, rc(c, ch2=1300, ch3=1500))  # pitch forward (low PWM): north
        assert ned(c)[0] - x0 > 1.0
        assert c.latest["HEARTBEAT"].custom_mode == 5  # still LOITER
        # overrides stop: RC_OVERRIDE_TIME later the throttle failsafe (FS_THR_ENABLE 3: LAND)
        assert c.wait(lambda: c.latest["HEARTBEAT"].custom_mode == 9, 3.0), c.latest["HEARTBEAT"].custom_mode
        assert any("manual control lost" in t for t in c.statustexts)
