"""Sticks and health over real UDP against the virtual FCU: MANUAL_CONTROL in PX4 POSCTL,
RC_CHANNELS_OVERRIDE in ArduCopter LOITER, the stick-loss failsafe, and SYS_STATUS from boot to ready."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from tests.fcu_helpers import FcuThread, MavClient
from uav_stack.fcu import FcuConfig, VehicleConfig, px4
from uav_stack.geo import GeoPoint
from uav_stack.mav import mavlink as M

NAN = math.nan
HOME = GeoPoint(47.397742, 8.545594, 488.0)
ACC = M.MAV_RESULT_ACCEPTED
GPS, PREARM, RC = M.MAV_SYS_STATUS_SENSOR_GPS, M.MAV_SYS_STATUS_PREARM_CHECK, M.MAV_SYS_STATUS_SENSOR_RC_RECEIVER


def vehicle(flavour: str, ready: bool = True, boot: str = "short", **params: float) -> tuple[FcuThread, MavClient]:
    cfg = FcuConfig([VehicleConfig(sysid=1, home=HOME, flavour=flavour, params=params, boot=boot)])
    ft = FcuThread(cfg, ready=ready)
    c = MavClient(ft.addrs[0])
    if flavour == "ardupilot":
        c.request_streams()  # ArduPilot streams nothing until asked
    return ft, c


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
    """PX4 on its own boot timeline: sensors reported once up, no position nor home until the estimate is
    valid, arming refused (TEMPORARILY_REJECTED and an event) until its checks pass."""
    ft, c = vehicle("px4", ready=False, boot="firmware")
    b = ft.fcu.vehicles[0].boot
    with ft, c:
        c.heartbeat()
        assert c.wait(lambda: "SYS_STATUS" in c.latest, 1.5) and ft.fcu.sim_time < b.at["home"]
        st = c.latest["SYS_STATUS"]
        assert st.onboard_control_sensors_present == 0  # (PX4: nothing reported before its sensors are up)
        assert c.latest["GPS_RAW_INT"].fix_type == M.GPS_FIX_TYPE_3D_FIX  # SIH's GPS has a fix from the start
        assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_TEMPORARILY_REJECTED
        assert c.wait(lambda: px4.ARM_DENIED.id in c.events, 0.5) and not c.statustexts
        assert c.command_long(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION) == M.MAV_RESULT_DENIED
        assert "GLOBAL_POSITION_INT" not in c.latest and "HOME_POSITION" not in c.latest
        # sensors up: reported, calibrated ones healthy, not armable yet
        assert c.wait(lambda: c.latest["SYS_STATUS"].onboard_control_sensors_present & GPS, 3.0)
        st = c.latest["SYS_STATUS"]
        assert st.onboard_control_sensors_health & M.MAV_SYS_STATUS_SENSOR_3D_GYRO
        assert not st.onboard_control_sensors_health & PREARM
        # the estimate: GLOBAL_POSITION_INT starts (never before with zeros), then the checks pass
        assert c.wait(lambda: "GLOBAL_POSITION_INT" in c.latest, 3.0) and ft.fcu.sim_time >= b.at["position"]
        assert c.latest["GLOBAL_POSITION_INT"].lat != 0
        assert c.wait(lambda: c.latest["SYS_STATUS"].onboard_control_sensors_health & (GPS | PREARM) == GPS | PREARM, 3.0)
        assert c.wait(lambda: c.latest["HEARTBEAT"].system_status == M.MAV_STATE_STANDBY, 2.5)
        assert "HOME_POSITION" in c.latest
        assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC


def test_px4_posctl_sticks_fly_and_a_lost_stick_stream_fails_safe() -> None:
    ft, c = vehicle("px4", MIS_TAKEOFF_ALT=2.0, MPC_TKO_SPEED=2.0, MPC_VEL_MANUAL=4.0)
    with ft, c:
        c.heartbeat()
        assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
        assert c.command_long(M.MAV_CMD_NAV_TAKEOFF) == ACC
        assert c.wait(lambda: px4_mode(c) == "HOLD" and -ned(c)[2] > 1.8, 6.0), (px4_mode(c), ned(c))
        assert c.set_mode_px4(3) == M.MAV_RESULT_TEMPORARILY_REJECTED  # POSCTL in the air needs a stick stream
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
        assert px4.FAILSAFE_ENTER.id in c.events
        assert ft.fcu.stats.failsafes["manual control lost"] == 1


def test_ardupilot_rc_override_climbs_in_loiter_and_its_loss_runs_fs_thr_enable() -> None:
    ft, c = vehicle("ardupilot", RC_OVERRIDE_TIME=1.0, FS_THR_ENABLE=3)
    with ft, c:
        c.heartbeat()
        assert c.command_long(M.MAV_CMD_DO_SET_MODE, 1, 9) == ACC  # LAND, on the ground
        assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_FAILED
        assert c.wait(lambda: "Arm: LAND mode not armable" in c.statustexts, 0.5)  # ArduCopter's words
        assert c.command_long(M.MAV_CMD_DO_SET_MODE, 1, 4) == ACC  # GUIDED
        assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
        assert c.command_long(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 0, 0, 2.0) == ACC
        assert c.wait(lambda: -ned(c)[2] > 1.8, 10.0), ned(c)  # after the throttle ramp
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
        assert ft.fcu.stats.failsafes["manual control lost"] == 1
