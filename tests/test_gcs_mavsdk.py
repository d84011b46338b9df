"""MAVSDK-Python 4.x, a real external client, flies a running virtual UAV through the agent's MAVLink router."""

from __future__ import annotations

import asyncio
import math
import socket
from pathlib import Path

import pytest

# MAVSDK-Python 4.x is in the test extra (pip install -e '.[test]'); a missing one is a failure, not a skip
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk  # noqa: E402
from mavsdk.asyncio.plugins.action import ActionAsync  # noqa: E402
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync  # noqa: E402

from tests.conftest import free_port, wait_for
from tests.gcs_helpers import agent_stats, start_virtual_uav, stop_process

pytestmark = pytest.mark.e2e


async def _until(get, pred, timeout: float, what: str):  # noqa: ANN001, ANN202
    deadline = asyncio.get_running_loop().time() + timeout
    last = None
    while asyncio.get_running_loop().time() < deadline:
        last = await get()
        if pred(last):
            return last
        await asyncio.sleep(0.2)
    raise AssertionError(f"{what}: not reached within {timeout} s (last: {last})")


async def _fly(port: int) -> dict:
    log: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as drone:
        await drone.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = await drone.first_autopilot(timeout_s=20.0)
        assert system is not None, "MAVSDK found no autopilot behind the router"
        log["sysid"] = await system.get_system_id()
        tel, action = TelemetryAsync(system), ActionAsync(system)
        await _until(tel.health, lambda h: h.is_global_position_ok and h.is_home_position_ok and h.is_armable, 20, "health")
        home = await tel.position()
        log["home"] = (home.latitude_deg, home.longitude_deg, home.absolute_altitude_m)
        await action.arm()
        assert await tel.armed()
        await action.takeoff()
        await _until(tel.position, lambda p: p.relative_altitude_m > 2.0, 20, "takeoff")
        log["in_air"] = await tel.in_air()
        # 15 m north, 5 m above home
        north = 15.0 / 111_320.0
        target = (home.latitude_deg + north, home.longitude_deg, home.absolute_altitude_m + 5.0)
        await action.goto_location(*target, 0.0)

        def arrived(p) -> bool:  # noqa: ANN001
            dn = (p.latitude_deg - target[0]) * 111_320.0
            de = (p.longitude_deg - target[1]) * 111_320.0 * math.cos(math.radians(target[0]))
            return math.hypot(dn, de) < 1.5 and abs(p.absolute_altitude_m - target[2]) < 1.0

        p = await _until(tel.position, arrived, 30, "goto")
        log["goto"] = (p.latitude_deg, p.longitude_deg, p.absolute_altitude_m)
        log["mode_after_goto"] = await tel.flight_mode()
        await action.land()
        await _until(tel.armed, lambda a: not a, 40, "land and auto-disarm")
        log["landed_alt"] = (await tel.position()).relative_altitude_m
    return log


def test_mavsdk4_flies_a_virtual_uav_through_the_agents_router(tmp_path: Path, router: str) -> None:
    port = free_port(socket.SOCK_DGRAM)
    proc = start_virtual_uav(tmp_path, router, uav=7, endpoints=(f"udpout:127.0.0.1:{port}",))
    try:
        log = asyncio.run(asyncio.wait_for(_fly(port), timeout=150))
        assert wait_for(lambda: (tmp_path / "uav7.json").exists(), 10)
        stats = agent_stats(tmp_path, 7)
    finally:
        stop_process(proc)
    assert log["sysid"] == 7  # the allocation scheme: UAV 7 -> sysid 7
    assert log["in_air"] is True
    assert log["mode_after_goto"] == FlightMode.HOLD  # PX4: DO_REPOSITION ends in HOLD at the target
    assert log["landed_alt"] < 0.5
    r = stats["mavlink_router"]
    assert r["to_fcu"] > 10 and r["to_gcs"] > 100  # every byte went through the agent's router
    assert r["bad_datagrams"] == 0
    assert stats["phase"] == "ready"  # the agent never fought MAVSDK: it was not flying the UAV
