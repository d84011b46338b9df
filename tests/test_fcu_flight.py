"""Flights over real UDP against the virtual FCU (PX4 and ArduPilot flavours).

Flights are kept short (low altitudes, short legs, faster landing speed) so the suite stays
fast at RTF 1; every wait is bounded. PX4 answers as PX4 1.16 does on its onboard link: no
STATUSTEXT, events (EVENT) instead, refusals TEMPORARILY_REJECTED, the mode in its next regular
heartbeat; an ArduPilot is asked for its streams first, as a ground station does.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable, Iterator

import pytest

from tests.fcu_helpers import FcuThread, MavClient
from uav_stack.fcu import FcuConfig, VehicleConfig
from uav_stack.fcu import px4 as px4fw
from uav_stack.fcu.modes import px4_custom_mode
from uav_stack.geo import GeoPoint, LocalFrame
from uav_stack.mav import mavlink as M

NAN = math.nan
HOME = GeoPoint(47.397742, 8.545594, 488.0)
FAST = {"MIS_TAKEOFF_ALT": 1.5, "MPC_LAND_SPEED": 1.2, "COM_DISARM_LAND": 0.5, "MPC_TKO_SPEED": 2.0}
ACC = M.MAV_RESULT_ACCEPTED
REJECTED = M.MAV_RESULT_TEMPORARILY_REJECTED


def fly(flavour: str = "px4", **params: float) -> tuple[FcuThread, MavClient]:
    p = dict(FAST) if flavour == "px4" else {}
    p.update(params)
    ft = FcuThread(FcuConfig([VehicleConfig(sysid=1, home=HOME, flavour=flavour, params=p)]))
    c = MavClient(ft.addrs[0], sysid=255)  # (ArduPilot's GCS failsafe hears MAV_GCS_SYSID, 255)
    return ft, c


@pytest.fixture
def px4() -> Iterator[tuple[FcuThread, MavClient]]:
    ft, c = fly()
    with ft, c:
        c.heartbeat()
        assert c.recv_match("HEARTBEAT", 3.0) is not None
        yield ft, c


def rel_alt(c: MavClient) -> float:
    m = c.latest.get("GLOBAL_POSITION_INT")
    return m.relative_alt / 1000.0 if m is not None else NAN


def ned(c: MavClient) -> tuple[float, float, float]:
    m = c.latest.get("LOCAL_POSITION_NED")
    return (m.x, m.y, m.z) if m is not None else (NAN, NAN, NAN)


def field(c: MavClient, msg: str, name: str) -> object:
    m = c.latest.get(msg)
    return getattr(m, name) if m is not None else None


def wait_mode(c: MavClient, mode: str, timeout: float) -> bool:
    return c.wait(lambda: c.px4_mode() == mode, timeout)


def takeoff(c: MavClient, alt: float = 1.5) -> None:
    assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
    assert c.command_long(M.MAV_CMD_NAV_TAKEOFF, *[NAN] * 7) == ACC  # MAVSDK: all params NaN -> MIS_TAKEOFF_ALT
    assert wait_mode(c, "HOLD", 6.0), c.px4_mode()
    assert c.wait(lambda: abs(rel_alt(c) - alt) < 0.1, 3.0), rel_alt(c)


def stream(c: MavClient, seconds: float, send: Callable[[], None], hz: float = 20.0,
           until: Callable[[], bool] | None = None) -> bool:  # fmt: skip
    """Send setpoints at ``hz`` for up to ``seconds`` (receiving in between)."""
    end = time.monotonic() + seconds
    nxt = time.monotonic()
    while time.monotonic() < end:
        if time.monotonic() >= nxt:
            send()
            nxt += 1.0 / hz
        c.pump(max(0.0, min(nxt, end) - time.monotonic()))
        if until is not None and until():
            return True
    return until is None


def test_arm_takeoff_reaches_mis_takeoff_alt_then_hold(px4) -> None:
    ft, c = px4
    assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, NAN) == ACC
    assert c.wait(lambda: px4fw.ARMED_BY.id in c.events, 0.5)  # PX4 says so with an event
    # the next regular heartbeat shows it (PX4 sends none extra)
    hb = c.recv_match("HEARTBEAT", 1.5)
    assert hb is not None and hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and hb.system_status == M.MAV_STATE_ACTIVE
    assert c.command_long(M.MAV_CMD_NAV_TAKEOFF, *[NAN] * 7) == ACC
    hb = c.recv_match("HEARTBEAT", 1.5)
    assert hb is not None and hb.custom_mode == px4_custom_mode(4, 2)
    assert c.wait(lambda: field(c, "EXTENDED_SYS_STATE", "landed_state") == M.MAV_LANDED_STATE_TAKEOFF, 2.0)
    assert wait_mode(c, "HOLD", 6.0)
    assert c.wait(lambda: abs(rel_alt(c) - 1.5) < 0.05, 3.0)
    c.drain(1.0)
    assert max(m.relative_alt for m in c.received if m.get_type() == "GLOBAL_POSITION_INT") < 1600  # no overshoot
    assert c.latest["EXTENDED_SYS_STATE"].landed_state == M.MAV_LANDED_STATE_IN_AIR
    assert c.command_long(M.MAV_CMD_NAV_TAKEOFF, *[NAN] * 7) == ACC  # idempotent: a retry keeps flying
    t = ft.fcu.truth()
    assert t.armed and not t.landed and abs(t.pos_ned[0]) < 0.01 and t.battery_remaining < 1.0


def test_takeoff_before_arm_then_land_and_auto_disarm(px4) -> None:
    ft, c = px4
    # QGC order: takeoff (p7 AMSL) is accepted while disarmed, arming then takes off
    assert c.command_long(M.MAV_CMD_NAV_TAKEOFF, NAN, NAN, NAN, NAN, NAN, NAN, HOME.alt + 1.0) == ACC
    assert wait_mode(c, "TAKEOFF", 1.5)
    c.drain(0.3)
    assert ft.fcu.truth().landed  # waits for arming
    assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
    assert wait_mode(c, "HOLD", 5.0)
    assert c.wait(lambda: abs(rel_alt(c) - 1.0) < 0.1, 3.0)
    assert c.command_long(M.MAV_CMD_NAV_LAND, NAN, NAN, NAN, NAN) == ACC
    assert wait_mode(c, "LAND", 1.0)
    assert c.wait(lambda: c.latest["EXTENDED_SYS_STATE"].landed_state == M.MAV_LANDED_STATE_LANDING, 2.0)
    assert c.wait(lambda: c.latest["EXTENDED_SYS_STATE"].landed_state == M.MAV_LANDED_STATE_ON_GROUND, 4.0)
    assert c.wait(lambda: not c.armed(), 3.0)  # COM_DISARM_LAND 0.5 s after touchdown
    assert px4fw.LANDING_DETECTED.id in c.events and px4fw.DISARMED_BY_LANDING.id in c.events
    assert not c.statustexts
    t = ft.fcu.truth()
    assert t.landed and not t.armed and t.pos_ned[2] == 0.0


def test_disarm_in_air_denied_unless_forced(px4) -> None:
    ft, c = px4
    takeoff(c)
    assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == REJECTED
    assert ft.fcu.truth().armed
    assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196) == ACC
    assert c.wait(lambda: ft.fcu.truth().landed, 3.0)  # motors cut: it falls
    assert not ft.fcu.truth().armed


def test_offboard_entry_rule_setpoints_and_loss_failsafe(px4) -> None:
    ft, c = px4
    # refused without a setpoint stream, also on the ground
    assert c.set_mode_px4(6) == REJECTED
    takeoff(c)
    hover = ned(c)
    hold_here = lambda: c.setpoint_local(hover[0], hover[1], -1.5, yaw=0.0)  # noqa: E731
    stream(c, 0.3, hold_here)
    assert c.set_mode_px4(6) == ACC  # PX4's code rule: a setpoint younger than COM_OF_LOSS_T is enough
    assert wait_mode(c, "OFFBOARD", 1.0)
    # position setpoint 6 m east: reached, no overshoot worth the name
    goal = (hover[0], hover[1] + 6.0, -2.0)
    assert stream(c, 8.0, lambda: c.setpoint_local(*goal, yaw=0.0),
                  until=lambda: math.dist(ned(c), goal) < 0.1 and abs(c.latest["LOCAL_POSITION_NED"].vy) < 0.05)  # fmt: skip
    ys = [m.y for m in c.received if m.get_type() == "LOCAL_POSITION_NED"]
    assert max(ys) < goal[1] + 0.2
    # velocity setpoint (altitude held by position on z)
    assert stream(c, 4.0, lambda: c.setpoint_local(z=-2.0, vx=2.0, vy=0.0),
                  until=lambda: abs(c.latest["LOCAL_POSITION_NED"].vx - 2.0) < 0.05)  # fmt: skip
    assert abs(ned(c)[2] + 2.0) < 0.1
    assert c.px4_mode() == "OFFBOARD"
    # the stream stops: COM_OF_LOSS_T (1 s) later the failsafe (an event), POSCTL (COM_OBL_RC_ACT 0), CRITICAL,
    # OFFBOARD still the intended mode
    t_stop = time.monotonic()
    assert c.wait(lambda: px4fw.FAILSAFE_ENTER.id in c.events, 3.0)
    assert 0.9 < time.monotonic() - t_stop < 3.0  # COM_OF_LOSS_T = 1 s (+ supervisor tick, slack for a busy host)
    assert wait_mode(c, "POSCTL", 1.5)
    assert c.latest["HEARTBEAT"].system_status == M.MAV_STATE_CRITICAL
    assert c.wait(lambda: c.latest["CURRENT_MODE"].custom_mode == px4_custom_mode(3), 2.5)
    assert c.latest["CURRENT_MODE"].intended_custom_mode == px4_custom_mode(6)
    x_hold = ned(c)[0]
    c.drain(3.0)
    assert abs(ned(c)[0] - x_hold) < 2.5 and abs(c.latest["LOCAL_POSITION_NED"].vx) < 0.1  # braked and holds


def test_offboard_strict_stream_rule_when_configured() -> None:
    """SIM_OFB_STREAM_T > 0 (the emulator's own setting, not a PX4 parameter): PX4's documented rule, a
    > 2 Hz stream for that long."""
    ft, c = fly(SIM_OFB_STREAM_T=1.0)
    with ft, c:
        c.heartbeat()
        assert c.param_read("SIM_OFB_STREAM_T", timeout=0.5) is None  # not on PX4's parameter list
        takeoff(c)
        hover = ned(c)
        hold_here = lambda: c.setpoint_local(hover[0], hover[1], -1.5, yaw=0.0)  # noqa: E731
        stream(c, 0.5, hold_here)
        assert c.set_mode_px4(6) == REJECTED  # < 1 s of stream
        stream(c, 0.7, hold_here)
        assert c.set_mode_px4(6) == ACC


def test_set_mode_message_qgc_style(px4) -> None:
    ft, c = px4
    # PX4 refuses MISSION without a mission (an empty plan is no mission)
    c.send(c.mav.set_mode_encode(1, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, px4_custom_mode(4, 4)))
    c.drain(1.2)
    assert ft.fcu.truth().mode == "HOLD" and c.px4_mode() == "HOLD"
    for main, sub, name in ((3, 0, "POSCTL"), (4, 3, "HOLD")):
        want = px4_custom_mode(main, sub)
        c.send(c.mav.set_mode_encode(1, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, want))
        hb = c.recv_match("HEARTBEAT", 1.5, lambda m, cm=want: m.custom_mode == cm)
        assert hb is not None, name
        assert ft.fcu.truth().mode == name
    assert c.recv_match("COMMAND_ACK", 0.3) is None  # SET_MODE is never ACKed
    c.send(c.mav.set_mode_encode(1, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, px4_custom_mode(6)))
    c.drain(1.2)  # refused (no setpoints): the heartbeat stays HOLD
    assert c.px4_mode() == "HOLD" and not c.statustexts


def test_reposition_then_rtl_returns_home_and_disarms(px4) -> None:
    ft, c = px4
    c.param_set("RTL_RETURN_ALT", 2.5)
    takeoff(c)
    frame = LocalFrame(HOME)
    lat, lon, _ = frame.to_geodetic(2.0, 6.0, 0.0)  # 6 m north, 2 m east
    # MAVSDK goto_location: COMMAND_INT DO_REPOSITION, GLOBAL_INT (AMSL), p2=1 change mode, p4=yaw rad
    r = c.command_int(M.MAV_CMD_DO_REPOSITION, M.MAV_FRAME_GLOBAL_INT, -1, 1, 0, 0.5,
                      round(lat * 1e7), round(lon * 1e7), HOME.alt + 2.0)  # fmt: skip
    assert r == ACC
    assert c.wait(lambda: math.dist(ned(c), (6.0, 2.0, -2.0)) < 0.15, 8.0), ned(c)
    assert c.px4_mode() == "HOLD"
    assert abs(ft.fcu.truth().yaw - 0.5) < 0.05
    # MAVSDK return_to_launch(): DO_SET_MODE (4, 5)
    assert c.set_mode_px4(4, 5) == ACC
    assert wait_mode(c, "RTL", 1.0)
    assert c.wait(lambda: rel_alt(c) > 2.3, 3.0)  # climbs to RTL_RETURN_ALT first
    assert c.wait(lambda: not c.armed(), 15.0), ned(c)
    x, y, z = ned(c)
    assert math.hypot(x, y) < 0.7 and z == pytest.approx(0.0, abs=0.01)
    assert ft.fcu.truth().landed


def test_param_set_changes_takeoff_altitude_and_geofence_holds(px4) -> None:
    ft, c = px4
    assert c.param_set("MIS_TAKEOFF_ALT", 1.0).param_value == pytest.approx(1.0)
    hor = struct.unpack("<f", struct.pack("<f", 3.0))[0]
    assert c.param_set("GF_MAX_HOR_DIST", hor).param_value == pytest.approx(3.0)
    takeoff(c, alt=1.0)
    assert c.latest["SYS_STATUS"].onboard_control_sensors_enabled & M.MAV_SYS_STATUS_GEOFENCE or c.wait(
        lambda: c.latest["SYS_STATUS"].onboard_control_sensors_enabled & M.MAV_SYS_STATUS_GEOFENCE, 1.5
    )
    frame = LocalFrame(HOME)
    lat, lon, _ = frame.to_geodetic(0.0, 10.0, 0.0)
    assert c.command_int(M.MAV_CMD_DO_REPOSITION, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 2.0, 0, 0, NAN,
                         round(lat * 1e7), round(lon * 1e7), 1.0) == ACC  # fmt: skip
    assert c.wait(lambda: px4fw.FAILSAFE_ENTER.id in c.events, 6.0)  # the fence breached
    c.drain(2.5)
    x = ned(c)[0]
    assert 3.0 < x < 5.5 and abs(c.latest["LOCAL_POSITION_NED"].vx) < 0.1  # stopped (GF_ACTION 2 = Hold)
    assert c.px4_mode() == "HOLD"
    assert not c.latest["SYS_STATUS"].onboard_control_sensors_health & M.MAV_SYS_STATUS_GEOFENCE


def test_an_injected_battery_failure_goes_below_the_simulated_floor(px4: tuple[FcuThread, MavClient]) -> None:
    """SIM_BAT_MIN_PCT (50 % by default) keeps PX4's simulated drain from emptying the battery; a chaos run's
    battery_drop is a failing battery instead: it goes below the floor, stays there, and PX4's failsafe lands."""
    from swarmnet.messages import FaultInjection
    from uav_stack.sim_faults import SimFaults

    ft, c = px4
    takeoff(c)
    ok, msg = SimFaults(ft.fcu).apply(FaultInjection("chaos", 1, 1, "battery_drop", {"level": 0.06}), time.time())
    assert ok and msg.endswith("-> 6 %"), msg
    assert stream(c, 3.0, c.heartbeat, hz=2.0, until=lambda: field(c, "SYS_STATUS", "battery_remaining") == 6)
    c.drain(1.5)
    assert field(c, "SYS_STATUS", "battery_remaining") <= 6  # not back at the 50 % floor
    # PX4 1.16 default COM_LOW_BAT_ACT 3: Return at critical (BAT_CRIT_THR 7 %), then down and disarmed
    assert c.wait(lambda: c.px4_mode() in ("RTL", "LAND"), 3.0), c.px4_mode()
    assert c.wait(lambda: not c.armed(), 10.0)


def test_datalink_loss_and_low_battery_failsafes() -> None:
    # PX4's simulated battery drains over SIM_BAT_DRAIN while armed, never below SIM_BAT_MIN_PCT (50 % by default)
    ft, c = fly(NAV_DLL_ACT=3, COM_DL_LOSS_T=1, SIM_BAT_DRAIN=40.0, SIM_BAT_MIN_PCT=0, BAT_LOW_THR=0.92, BAT_CRIT_THR=0.05,
                BAT_EMERGEN_THR=0.01, COM_LOW_BAT_ACT=2)  # fmt: skip
    with ft, c:
        c.heartbeat()
        assert c.recv_match("HEARTBEAT", 3.0) is not None
        assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
        assert c.command_long(M.MAV_CMD_NAV_TAKEOFF, *[NAN] * 7) == ACC
        last_hb = [0.0]

        def gcs_heartbeat() -> None:
            c.heartbeat()
            last_hb[0] = time.monotonic()

        # the GCS keeps its 2 Hz heartbeat going while flying
        assert stream(c, 6.0, gcs_heartbeat, hz=2.0, until=lambda: c.px4_mode() == "HOLD" and rel_alt(c) > 1.4)
        # battery: 40 s endurance -> "low" (92 %) after ~3 s of flight: a warning only
        low = M.MAV_BATTERY_CHARGE_STATE_LOW
        assert stream(c, 8.0, gcs_heartbeat, hz=2.0, until=lambda: field(c, "BATTERY_STATUS", "charge_state") == low)
        assert c.px4_mode() == "HOLD"
        # the GCS falls silent: NAV_DLL_ACT 3 = Land after COM_DL_LOSS_T (the failsafe's event first)
        assert c.wait(lambda: px4fw.FAILSAFE_ENTER.id in c.events, 3.0)
        assert 0.9 < time.monotonic() - last_hb[0] < 3.0
        assert wait_mode(c, "LAND", 1.5)
        assert c.wait(lambda: field(c, "HEARTBEAT", "system_status") == M.MAV_STATE_CRITICAL, 1.5)
        assert not c.statustexts


def test_ardupilot_guided_takeoff_velocity_timeout_and_land() -> None:
    ft, c = fly("ardupilot", GUID_TIMEOUT=1.0, LAND_SPEED=120, DISARM_DELAY=5)
    with ft, c:
        c.heartbeat()
        c.request_streams()  # ArduPilot streams nothing until asked
        hb = c.recv_match("HEARTBEAT", 3.0)
        assert hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA and hb.custom_mode == 0  # STABILIZE
        # C-cast parameter encoding
        v = c.param_read("DISARM_DELAY")
        assert v.param_type == M.MAV_PARAM_TYPE_INT8 and v.param_value == 5.0
        assert c.command_long(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 2.0) == M.MAV_RESULT_FAILED  # not GUIDED
        # MAVProxy "mode GUIDED": DO_SET_MODE p1=1, p2=4
        assert c.command_long(M.MAV_CMD_DO_SET_MODE, 1, 4) == ACC
        assert c.wait(lambda: field(c, "HEARTBEAT", "custom_mode") == 4, 1.0)
        assert c.command_long(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 2.0) == M.MAV_RESULT_FAILED  # not armed
        assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
        assert c.command_long(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 2.0) == ACC  # p7 relative
        assert c.wait(lambda: abs(rel_alt(c) - 2.0) < 0.1, 10.0)  # after the throttle ramp
        assert ft.fcu.truth().mode == "GUIDED"
        # guided velocity target, then silence: stops after GUID_TIMEOUT (no failsafe mode change)
        assert stream(c, 4.0, lambda: c.setpoint_local(vx=2.0, vy=0.0, vz=0.0),
                      until=lambda: abs(c.latest["LOCAL_POSITION_NED"].vx - 2.0) < 0.05)  # fmt: skip
        assert c.wait(lambda: abs(c.latest["LOCAL_POSITION_NED"].vx) < 0.05, 4.0)
        assert ft.fcu.truth().mode == "GUIDED"
        # MAVProxy "mode LAND" (9): lands and disarms ("Disarming motors" about 2 s after touching down)
        assert c.command_long(M.MAV_CMD_DO_SET_MODE, 1, 9) == ACC
        assert c.wait(lambda: not c.armed(), 8.0)
        assert ft.fcu.truth().landed
        assert "Arming motors" in c.statustexts and "Disarming motors" in c.statustexts
