"""Missions over real UDP against the virtual FCU: the mission protocol, PX4 MISSION and ArduCopter AUTO flights.

Legs are short and low so each flight takes seconds at RTF 1; every wait is bounded. PX4 reports no
mission_state (0) and repeats MISSION_ITEM_REACHED for the last item reached; ArduCopter reports both.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest

from tests.fcu_helpers import FcuThread, MavClient
from uav_stack.fcu import FcuConfig, VehicleConfig
from uav_stack.fcu.modes import px4_custom_mode
from uav_stack.geo import GeoPoint, LocalFrame
from uav_stack.mav import mavlink as M

NAN = math.nan
HOME = GeoPoint(47.397742, 8.545594, 488.0)
FRAME = LocalFrame(HOME)
ACC = M.MAV_RESULT_ACCEPTED
REL = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
WP, TAKEOFF, LAND, RTL = M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_RETURN_TO_LAUNCH
SPEED = M.MAV_CMD_DO_CHANGE_SPEED
PX4_FAST = {"MIS_TAKEOFF_ALT": 2.0, "MPC_TKO_SPEED": 2.0, "MPC_LAND_SPEED": 1.2, "COM_DISARM_LAND": 0.5}


def geo(north: float, east: float) -> tuple[float, float]:
    lat, lon, _ = FRAME.to_geodetic(east, north, 0.0)
    return lat, lon


def wp(north: float, east: float, alt: float, radius: float = 0.0, hold: float = 0.0) -> tuple:
    return (REL, WP, *geo(north, east), alt, (hold, radius, 0.0, NAN))


@pytest.fixture
def vehicle(request: pytest.FixtureRequest) -> Iterator[tuple[FcuThread, MavClient]]:
    flavour, params = request.param
    ft = FcuThread(FcuConfig([VehicleConfig(sysid=1, home=HOME, flavour=flavour, params=params)]))
    with ft, MavClient(ft.addrs[0]) as c:
        c.heartbeat()
        if flavour == "ardupilot":
            c.request_streams()  # ArduPilot streams nothing until asked
        assert c.recv_match("HEARTBEAT", 3.0) is not None
        yield ft, c


def ned(c: MavClient) -> tuple[float, float, float]:
    m = c.latest.get("LOCAL_POSITION_NED")
    return (m.x, m.y, m.z) if m is not None else (NAN, NAN, NAN)


def mission_current(c: MavClient) -> tuple[int, int, int, int] | None:
    m = c.latest.get("MISSION_CURRENT")
    return None if m is None else (m.seq, m.total, m.mission_state, m.mission_mode)


def reached_items(c: MavClient, since: int) -> list[int]:
    """The items reached, in order (PX4 repeats MISSION_ITEM_REACHED for the last one every second)."""
    out: list[int] = []
    for m in c.received[since:]:
        if m.get_type() == "MISSION_ITEM_REACHED" and (not out or out[-1] != m.seq):
            out.append(m.seq)
    return out


def closest_approach(c: MavClient, since: int, targets: dict[int, tuple[float, float, float]],
                     horizontal: bool = False) -> dict[int, float]:  # fmt: skip
    """Per mission item: the closest distance (3D, or horizontal) of the vehicle to it while it was current.

    The FCU announces the next item in the same step as the position sample that reached the last
    one, so the first sample after a change counts for the item just left too."""
    current, left = -1, -1
    out: dict[int, float] = {}
    for m in c.received[since:]:
        t = m.get_type()
        if t == "MISSION_CURRENT" and m.seq != current:
            current, left = m.seq, current
        elif t == "LOCAL_POSITION_NED":
            for k in {current, left} & set(targets):
                x, y, z = targets[k]
                d = math.hypot(m.x - x, m.y - y) if horizontal else math.dist((m.x, m.y, m.z), (x, y, z))
                out[k] = min(out.get(k, math.inf), d)
            left = -1
    return out


@pytest.mark.parametrize("vehicle", [("px4", PX4_FAST)], indirect=True)
def test_px4_mission_takes_off_flies_every_waypoint_pauses_resumes_and_completes(vehicle) -> None:
    ft, c = vehicle
    legs = [(7.0, 0.0), (7.0, 7.0), (0.0, 7.0), (0.0, 0.0)]
    items = [(M.MAV_FRAME_MISSION, SPEED, 0.0, 0.0, 0.0, (1.0, 3.0, -1.0, 0.0))]  # 3 m/s ground speed
    items += [wp(n, e, 3.0, radius=1.0) for n, e in legs]
    assert c.upload_mission(items) == M.MAV_MISSION_ACCEPTED
    assert c.wait(lambda: mission_current(c) == (0, 5, 0, 2), 2.0), mission_current(c)  # (no mission_state)
    assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
    since = len(c.received)
    assert c.set_mode_px4(4, 4) == ACC  # MAVSDK's start_mission: DO_SET_MODE MISSION
    # no takeoff item: PX4 climbs to MIS_TAKEOFF_ALT first, then flies the items
    assert c.wait(lambda: -ned(c)[2] > 1.8, 4.0), ned(c)
    assert mission_current(c) == (1, 5, 0, 1)  # the speed item passed at once
    reached = lambda: reached_items(c, since)  # noqa: E731
    assert c.wait(lambda: reached() == [0, 1, 2], 15.0), (reached(), mission_current(c), ned(c))  # (PX4: DO items too)
    # pause (MAVSDK's pause_mission: HOLD), then continue with the item that was current
    assert c.set_mode_px4(4, 3) == ACC
    assert c.wait(lambda: mission_current(c) == (3, 5, 0, 2), 1.5), mission_current(c)
    c.drain(1.5)
    assert reached() == [0, 1, 2] and c.wait(lambda: c.px4_mode() == "HOLD", 1.5)
    assert c.set_mode_px4(4, 4) == ACC
    assert c.wait(lambda: reached() == [0, 1, 2, 3, 4], 15.0), (reached(), mission_current(c))
    # every item in order, the last one reported again every second
    c.drain(2.5)
    again = [m for m in c.received[since:] if m.get_type() == "MISSION_ITEM_REACHED" and m.seq == 4]
    assert len(again) >= 2
    targets = {k + 1: (n, e, -3.0) for k, (n, e) in enumerate(legs)}
    near = closest_approach(c, since, targets, horizontal=True)
    assert all(near[k] <= 1.0 for k in targets), near  # each reached inside its 1 m acceptance radius
    speeds = [math.hypot(m.vx, m.vy) for m in c.received[since:] if m.get_type() == "LOCAL_POSITION_NED"]
    assert 2.5 < max(speeds) < 3.2  # DO_CHANGE_SPEED: 3 m/s instead of the 5 m/s cruise
    # the mission is over: still in MISSION, holding at the last waypoint
    assert c.px4_mode() == "MISSION" and math.dist(ned(c), (0.0, 0.0, -3.0)) < 1.0
    assert c.command_long(M.MAV_CMD_NAV_LAND) == ACC
    assert c.wait(lambda: not c.armed(), 10.0)


@pytest.mark.parametrize("vehicle", [("ardupilot", {"RTL_ALT": 400, "LAND_SPEED": 120, "WPNAV_SPEED": 400})], indirect=True)
def test_ardupilot_auto_needs_a_takeoff_skips_home_and_ends_with_rtl(vehicle) -> None:
    ft, c = vehicle
    home = (M.MAV_FRAME_GLOBAL, WP, HOME.lat, HOME.lon, HOME.alt, ())  # item 0: ArduCopter's home slot
    assert c.upload_mission([home, wp(6.0, 0.0, 3.0)]) == M.MAV_MISSION_ACCEPTED
    assert c.command_long(M.MAV_CMD_DO_SET_MODE, 1, 4) == ACC  # GUIDED
    assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
    assert c.command_long(M.MAV_CMD_DO_SET_MODE, 1, 3) == M.MAV_RESULT_FAILED  # armed on the ground, no takeoff item
    assert c.wait(lambda: any(t == "Auto: Missing Takeoff Cmd" for t in c.statustexts), 0.5)
    rtl = (M.MAV_FRAME_MISSION, RTL, 0, 0, 0, ())
    items = [home, (REL, TAKEOFF, 0.0, 0.0, 3.0, ()), wp(6.0, 0.0, 3.0), wp(6.0, 6.0, 4.0), rtl]
    assert c.upload_mission(items) == M.MAV_MISSION_ACCEPTED
    since = len(c.received)
    assert c.command_long(M.MAV_CMD_DO_SET_MODE, 1, 3) == ACC  # MAVProxy's "mode AUTO"
    assert c.wait(lambda: not c.armed(), 40.0), (mission_current(c), ned(c))  # RTL landed and disarmed
    reached = [m.seq for m in c.received[since:] if m.get_type() == "MISSION_ITEM_REACHED"]
    assert reached == [1, 2, 3, 4]  # the home slot is never flown (and ArduCopter reports each once)
    texts = [t for t in c.statustexts if t.startswith(("Mission:", "Reached"))]
    assert texts[:4] == ["Mission: 1 Takeoff", "Mission: 2 WP", "Reached command #2", "Mission: 3 WP"]
    currents = [m for m in c.received[since:] if m.get_type() == "MISSION_CURRENT"]
    assert {m.total for m in currents} == {4} and currents[-1].mission_state == M.MISSION_STATE_COMPLETE
    near = closest_approach(c, since, {2: (6.0, 0.0, -3.0), 3: (6.0, 6.0, -4.0)})
    assert near[2] <= 2.0 and near[3] <= 2.0, near  # WPNAV_RADIUS 2 m (a sphere, for ArduCopter)
    alts = [-m.z for m in c.received[since:] if m.get_type() == "LOCAL_POSITION_NED"]
    assert 3.8 < max(alts) < 4.3  # RTL_ALT 4 m: it returned at the last waypoint's height
    assert ft.fcu.truth().landed and math.hypot(*ft.fcu.truth().pos_ned[:2]) < 0.8  # at home


@pytest.mark.parametrize("vehicle", [("px4", {})], indirect=True)
def test_mission_protocol_download_current_clear_and_refusals(vehicle) -> None:
    ft, c = vehicle
    items = [wp(5.0, 0.0, 3.0, radius=1.5, hold=2.0), wp(5.0, 5.0, 3.0), (REL, LAND, 0.0, 0.0, 0.0, ())]
    assert c.upload_mission(items) == M.MAV_MISSION_ACCEPTED
    # download: what was uploaded, item by item
    c.send(c.mav.mission_request_list_encode(1, 1, 0))
    count = c.recv_match("MISSION_COUNT", 1.0)
    assert count is not None and count.count == 3
    c.send(c.mav.mission_request_int_encode(1, 1, 0, 0))
    item = c.recv_match("MISSION_ITEM_INT", 1.0)
    lat, lon = geo(5.0, 0.0)
    assert item is not None and (item.command, item.x, item.y, item.z, item.param1, item.param2) == (
        WP, round(lat * 1e7), round(lon * 1e7), 3.0, 2.0, 1.5)
    # the current item: MISSION_SET_CURRENT (MAVSDK) and DO_SET_MISSION_CURRENT (QGC, MAVProxy)
    c.send(c.mav.mission_set_current_encode(1, 1, 2))
    assert c.recv_match("MISSION_CURRENT", 1.0, lambda m: m.seq == 2) is not None
    assert c.command_long(M.MAV_CMD_DO_SET_MISSION_CURRENT, 7) == M.MAV_RESULT_DENIED
    assert c.command_long(M.MAV_CMD_DO_SET_MISSION_CURRENT, 1) == ACC
    assert c.recv_match("MISSION_CURRENT", 1.0, lambda m: m.seq == 1) is not None
    # MISSION_START switches to the mission mode (from p1)
    assert c.command_long(M.MAV_CMD_MISSION_START, 0, 0) == ACC
    hb = c.recv_match("HEARTBEAT", 1.5, lambda m: m.custom_mode == px4_custom_mode(4, 4))
    assert hb is not None
    assert c.set_mode_px4(4, 3) == ACC
    # a NAV item in a local frame cannot be flown here: refused at upload, the old mission stays
    local = (M.MAV_FRAME_LOCAL_NED, WP, 0.0, 0.0, -3.0, ())
    assert c.upload_mission([local]) == M.MAV_MISSION_UNSUPPORTED_FRAME
    assert len(ft.fcu.vehicles[0].missions[0]) == 3
    # clear: no mission, and MISSION is refused again
    c.send(c.mav.mission_clear_all_encode(1, 1, 0))
    ack = c.recv_match("MISSION_ACK", 1.0)
    assert ack is not None and ack.type == M.MAV_MISSION_ACCEPTED
    assert c.wait(lambda: mission_current(c) is not None and mission_current(c)[1] == 65535, 1.5)  # PX4: no mission
    assert c.set_mode_px4(4, 4) == M.MAV_RESULT_TEMPORARILY_REJECTED
    assert ft.alive and ft.fcu.stats.handler_errors == 0
