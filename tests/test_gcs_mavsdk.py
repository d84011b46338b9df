"""MAVSDK-Python 4.x, a real external client, flies a running virtual UAV through the agent's MAVLink router.

One MAVSDK session runs the flows of MAVSDK-Python's examples one after the other, with the same
calls in the same order (only the connection URL differs, and a few sleeps are shorter):
``takeoff_and_land`` (plus ``goto_location``), ``mission`` (upload, arm, start, pause at item 2,
continue, wait until finished, RTL), the offboard velocity example, and the manual control example.
The agent, never started by the swarm, shows each of these flights as a takeover and is ready again
after each landing. MAVSDK cannot sign MAVLink (no signing API in MAVSDK-Python 4.1), so this UAV's
router asks for unsigned commands by name (``gcs.allow_unsigned``), as docs/gcs.md says to.
"""

from __future__ import annotations

import asyncio
import csv
import math
import socket
from pathlib import Path

import pytest

# MAVSDK-Python 4.x is in the test extra (pip install -e '.[test]'); a missing one is a failure, not a skip
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk  # noqa: E402
from mavsdk.asyncio.plugins.action import ActionAsync  # noqa: E402
from mavsdk.asyncio.plugins.manual_control import ManualControlAsync  # noqa: E402
from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan  # noqa: E402
from mavsdk.asyncio.plugins.offboard import OffboardAsync, VelocityNedYaw  # noqa: E402
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync  # noqa: E402

from tests.conftest import free_port, wait_for
from tests.gcs_helpers import agent_stats, start_virtual_uav, stop_process
from uav_stack.fcu.firmware import firmware

pytestmark = pytest.mark.e2e
M_PER_DEG = 111_320.0


async def _until(get, pred, timeout: float, what: str):  # noqa: ANN001, ANN202
    deadline = asyncio.get_running_loop().time() + timeout
    last = None
    while asyncio.get_running_loop().time() < deadline:
        last = await get()
        if pred(last):
            return last
        await asyncio.sleep(0.2)
    raise AssertionError(f"{what}: not reached within {timeout} s (last: {last})")


def _dist(lat: float, lon: float, lat0: float, lon0: float) -> float:
    """Horizontal distance in m (flat earth, fine over a few hundred metres)."""
    return math.hypot((lat - lat0) * M_PER_DEG, (lon - lon0) * M_PER_DEG * math.cos(math.radians(lat0)))


def make_mission_item(latitude_deg, longitude_deg, relative_altitude_m, speed_m_s,  # noqa: ANN001, ANN201
                      is_fly_through, gimbal_pitch_deg, gimbal_yaw_deg, camera_action):  # noqa: ANN001
    """MAVSDK-Python's examples/mission.py, as it is."""
    item = MissionItem()
    item.latitude_deg = latitude_deg
    item.longitude_deg = longitude_deg
    item.relative_altitude_m = relative_altitude_m
    item.speed_m_s = speed_m_s
    item.is_fly_through = is_fly_through
    item.gimbal_pitch_deg = gimbal_pitch_deg
    item.gimbal_yaw_deg = gimbal_yaw_deg
    item.camera_action = camera_action
    item.loiter_time_s = 0.0
    item.camera_photo_interval_s = 1.0
    item.acceptance_radius_m = 1.0
    item.yaw_deg = 0.0
    item.camera_photo_distance_m = 0.0
    item.vehicle_action = MissionItem.VehicleAction.NONE
    return item


# the example's first four waypoints, 40-60 m north of PX4 SITL's home (the virtual UAV's home here)
WAYPOINTS = [
    (47.398170327054473, 8.5456490218639658, 10.0, 5.0, False, 20.0, 60.0, MissionItem.CameraAction.NONE),
    (47.398241338125118, 8.5455360114574432, 10.0, 2.0, True, 0.0, -60.0, MissionItem.CameraAction.TAKE_PHOTO),
    (47.398139363821485, 8.5453846156597137, 10.0, 5.0, True, -45.0, 0.0, MissionItem.CameraAction.START_VIDEO),
    (47.398058617228855, 8.5454618036746979, 10.0, 2.0, False, -90.0, 30.0, MissionItem.CameraAction.STOP_VIDEO),
]


async def _takeoff_and_land(system, log: dict) -> None:  # noqa: ANN001
    """examples/takeoff_and_land.py, plus a goto_location before landing."""
    action, tel = ActionAsync(system), TelemetryAsync(system)
    log["takeoff_alt"] = await action.get_takeoff_altitude()
    log["rtl_alt"] = await action.get_return_to_launch_altitude()
    await action.arm()
    await _until(tel.armed, lambda a: a, 3, "armed")  # (PX4 shows it in its next regular heartbeat)
    await action.takeoff()
    await _until(tel.position, lambda p: p.relative_altitude_m > 2.0, 20, "takeoff")
    log["in_air"] = await tel.in_air()
    home = log["home"]
    north = 15.0 / M_PER_DEG  # 15 m north, 5 m above home
    target = (home[0] + north, home[1], home[2] + 5.0)
    await action.goto_location(*target, 0.0)
    p = await _until(tel.position, lambda p: _dist(p.latitude_deg, p.longitude_deg, *target[:2]) < 1.5
                     and abs(p.absolute_altitude_m - target[2]) < 1.0, 30, "goto")
    log["goto"] = (p.latitude_deg, p.longitude_deg, p.absolute_altitude_m)
    log["mode_after_goto"] = await tel.flight_mode()
    await action.land()
    await _until(tel.armed, lambda a: not a, 40, "land and auto-disarm")
    log["landed_alt"] = (await tel.position()).relative_altitude_m


async def _mission(system, log: dict) -> None:  # noqa: ANN001
    """examples/mission.py with four waypoints; the pause lasts 2 s instead of 5."""
    action, mission, tel = ActionAsync(system), MissionAsync(system), TelemetryAsync(system)
    await action.set_return_to_launch_altitude(10.0)  # RTL at the mission's height, not PX4's default 60 m
    await mission.upload_mission(MissionPlan([make_mission_item(*w) for w in WAYPOINTS]))
    await action.arm()
    progress: list[tuple[int, int]] = []
    samples: list[tuple[int, float, float, float]] = []  # (current item, lat, lon, relative alt)
    want_to_pause = asyncio.Event()

    async def watch_progress() -> None:
        async for p in mission.subscribe_mission_progress():
            progress.append((p.current, p.total))
            if p.current >= 2:
                want_to_pause.set()

    async def watch_position() -> None:
        async for p in tel.subscribe_position():
            samples.append((progress[-1][0] if progress else -1, p.latitude_deg, p.longitude_deg, p.relative_altitude_m))

    tasks = [asyncio.create_task(watch_progress()), asyncio.create_task(watch_position())]
    await mission.start_mission()
    await asyncio.wait_for(want_to_pause.wait(), 60)
    await mission.pause_mission()
    log["paused_mode"] = await _until(tel.flight_mode, lambda m: m == FlightMode.HOLD, 5, "pause")
    pause_at = await tel.position()
    await asyncio.sleep(2.0)
    resumed_at = await tel.position()
    log["drift_while_paused"] = _dist(resumed_at.latitude_deg, resumed_at.longitude_deg,
                                      pause_at.latitude_deg, pause_at.longitude_deg)
    await mission.start_mission()
    deadline = asyncio.get_running_loop().time() + 90
    while not await mission.is_mission_finished():
        assert asyncio.get_running_loop().time() < deadline, f"mission not finished: {progress}"
        await asyncio.sleep(0.5)
    await action.return_to_launch()
    await asyncio.sleep(2)
    await _until(tel.armed, lambda a: not a, 60, "RTL landed and disarmed")
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    log["progress"] = progress
    # the closest approach to each waypoint while it was the current item (and the sample right after)
    closest = [math.inf] * len(WAYPOINTS)
    prev = -1
    for cur, lat, lon, alt in samples:
        for k in {cur, prev} & set(range(len(WAYPOINTS))):
            wlat, wlon, walt = WAYPOINTS[k][:3]
            closest[k] = min(closest[k], math.hypot(_dist(lat, lon, wlat, wlon), alt - walt))
        prev = cur
    log["closest"] = closest
    end = await tel.position()
    log["mission_end"] = _dist(end.latitude_deg, end.longitude_deg, *log["home"][:2])


async def _offboard_velocity(system, log: dict) -> None:  # noqa: ANN001
    """The offboard velocity (NED) example: arm, initial setpoint, start, climb, north facing east, stop."""
    action, offboard, tel = ActionAsync(system), OffboardAsync(system), TelemetryAsync(system)
    await action.arm()
    await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
    await offboard.start()
    await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, -2.0, 0.0))  # up at 2 m/s
    await asyncio.sleep(3)
    log["offboard_climb"] = (await tel.position()).relative_altitude_m
    await offboard.set_velocity_ned(VelocityNedYaw(2.0, 0.0, 0.0, 90.0))  # north at 2 m/s, facing east
    await asyncio.sleep(3)
    pv = await tel.position_velocity_ned()
    log["offboard_velocity"] = (pv.velocity.north_m_s, pv.velocity.east_m_s, pv.velocity.down_m_s)
    log["offboard_heading"] = (await tel.heading()).heading_deg
    log["offboard_mode"] = await tel.flight_mode()
    await offboard.stop()
    log["after_offboard"] = await _until(tel.flight_mode, lambda m: m == FlightMode.HOLD, 5, "offboard stop")


async def _manual_control(system, log: dict) -> None:  # noqa: ANN001
    """The manual control example: input, arm, takeoff, input, start_position_control, then stick inputs."""
    action, manual, tel = ActionAsync(system), ManualControlAsync(system), TelemetryAsync(system)
    await manual.set_manual_control_input(0.0, 0.0, 0.5, 0.0)
    await action.arm()
    await action.takeoff()
    await asyncio.sleep(1)
    await manual.set_manual_control_input(0.0, 0.0, 0.5, 0.0)
    await manual.start_position_control()
    for _ in range(50):  # the stick input goes on while PX4's next heartbeat shows the mode (a pause is a lost stick)
        await manual.set_manual_control_input(0.0, 0.0, 0.5, 0.0)
        if await tel.flight_mode() == FlightMode.POSCTL:
            break
        await asyncio.sleep(0.1)
    log["manual_mode"] = await tel.flight_mode()
    start = await tel.position()
    for _ in range(25):  # full forward stick for 2.5 s (the vehicle faces east after the offboard flow)
        await manual.set_manual_control_input(1.0, 0.0, 0.5, 0.0)
        await asyncio.sleep(0.1)
    moved = await tel.position()
    for _ in range(15):  # full throttle for 1.5 s
        await manual.set_manual_control_input(0.0, 0.0, 1.0, 0.0)
        await asyncio.sleep(0.1)
    climbed = await tel.position()
    log["manual_moved_m"] = _dist(moved.latitude_deg, moved.longitude_deg, start.latitude_deg, start.longitude_deg)
    east = (moved.longitude_deg - start.longitude_deg) * M_PER_DEG * math.cos(math.radians(start.latitude_deg))
    log["manual_moved_east_m"] = east
    log["manual_climbed_m"] = climbed.relative_altitude_m - moved.relative_altitude_m
    await action.land()
    await _until(tel.armed, lambda a: not a, 40, "land after manual control")


async def _session(port: int) -> dict:
    log: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as drone:
        await drone.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = await drone.first_autopilot(timeout_s=20.0)
        assert system is not None, "MAVSDK found no autopilot behind the router"
        log["sysid"] = await system.get_system_id()
        tel = TelemetryAsync(system)
        # the mission example's readiness check (a just-booted FCU has no position yet)
        await _until(tel.health, lambda h: h.is_gyrometer_calibration_ok and h.is_accelerometer_calibration_ok
                     and h.is_magnetometer_calibration_ok and h.is_local_position_ok and h.is_global_position_ok
                     and h.is_home_position_ok and h.is_armable, 20, "health")
        home = await tel.position()
        log["home"] = (home.latitude_deg, home.longitude_deg, home.absolute_altitude_m)
        await _takeoff_and_land(system, log)
        await _mission(system, log)
        await _offboard_velocity(system, log)
        await _manual_control(system, log)
    return log


def test_mavsdk_example_flows_fly_a_virtual_uav_through_the_agents_router(tmp_path: Path, router: str) -> None:
    port = free_port(socket.SOCK_DGRAM)
    proc = start_virtual_uav(tmp_path, router, uav=7, endpoints=(f"udpout:127.0.0.1:{port}",), allow_unsigned=True)
    try:
        log = asyncio.run(asyncio.wait_for(_session(port), timeout=360))
        assert wait_for(lambda: (tmp_path / "uav7.json").exists(), 10)
        assert wait_for(lambda: agent_stats(tmp_path, 7)["phase"] == "ready", 10), agent_stats(tmp_path, 7)["phase"]
        stats = agent_stats(tmp_path, 7)
    finally:
        stop_process(proc)
    assert log["sysid"] == 7  # the allocation scheme: UAV 7 -> sysid 7
    # takeoff and land (MIS_TAKEOFF_ALT and RTL_RETURN_ALT read as parameters), goto
    defaults = {p.name: p.default for p in firmware("px4").params}  # PX4 1.16's factory values
    assert log["takeoff_alt"] == pytest.approx(defaults["MIS_TAKEOFF_ALT"]) and log["rtl_alt"] == pytest.approx(
        defaults["RTL_RETURN_ALT"])
    assert log["in_air"] is True
    assert log["mode_after_goto"] == FlightMode.HOLD  # PX4: DO_REPOSITION ends in HOLD at the target
    assert log["landed_alt"] < 0.5
    # the mission: progress reported item by item up to 4/4, every waypoint within its 1 m acceptance radius
    currents = [c for c, _ in log["progress"]]
    assert {t for _, t in log["progress"]} == {4} and currents == sorted(currents) and currents[-1] == 4, log["progress"]
    assert {1, 2, 3} <= set(currents)
    assert all(d <= 1.0 for d in log["closest"]), log["closest"]
    assert log["paused_mode"] == FlightMode.HOLD and log["drift_while_paused"] < 1.5
    assert log["mission_end"] < 1.0  # RTL brought it home
    # offboard velocity: climbed at 2 m/s, then 2 m/s north facing east
    assert log["offboard_climb"] > 4.0
    vn, ve, vd = log["offboard_velocity"]
    assert vn == pytest.approx(2.0, abs=0.15) and abs(ve) < 0.15 and abs(vd) < 0.15
    assert log["offboard_heading"] == pytest.approx(90.0, abs=3.0) and log["offboard_mode"] == FlightMode.OFFBOARD
    # manual control: the forward stick flew it forward (east: its heading), full throttle climbed
    assert log["manual_mode"] == FlightMode.POSCTL
    # (accelerating at MPC_ACC_HOR 3 m/s^2 towards MPC_VEL_MANUAL: about 8 m in 2.5 s)
    assert log["manual_moved_east_m"] > 5.0 and log["manual_moved_m"] < log["manual_moved_east_m"] + 1.0
    assert log["manual_climbed_m"] > 2.0
    # every byte went through the agent's router, and the agent never fought MAVSDK
    r = stats["mavlink_router"]
    assert r["to_fcu"] > 100 and r["to_gcs"] > 1000 and r["bad_datagrams"] == 0
    assert r["signing"] == "unsigned-allowed" and r["unsigned_accepted"] >= r["to_fcu"]
    assert stats["fcu_link"]["tx_setpoints"] == 0
    with open(tmp_path / "uav7.csv") as f:
        phases = [row["phase"] for row in csv.DictReader(f)]
    assert "yielded" in phases  # each flight showed as a ground station's takeover ...
    assert phases[-1] == "ready" and stats["phase"] == "ready"  # ... and the UAV is ready for the swarm again
