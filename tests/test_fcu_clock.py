"""Sim clock and RTF: pacing, graceful slow-down of a starved loop, timers on sim time."""

from __future__ import annotations

import math
import select
import time

import pytest

from tests.fcu_helpers import FcuThread, MavClient
from uav_stack.fcu import FcuConfig, VehicleConfig, VirtualFcu, px4
from uav_stack.fcu.clock import SimClock
from uav_stack.mav import mavlink as M
from uav_stack.rtf import RtfMeter


def test_sim_clock_paces_and_drops_backlog() -> None:
    c = SimClock(physics_hz=50.0, target_rtf=0.5, max_catchup_s=0.1)
    c.start(100.0)
    assert c.wall_per_step == pytest.approx(0.04)
    assert c.due_steps(100.039) == 0
    assert c.due_steps(100.04) == 1
    c.advance()
    c.plan_wake(100.08)
    assert c.due_steps(100.15) == 2  # 0.07 s after the planned wake-up: caught up in a batch
    c.advance(2)
    assert c.dropped_wall_s == 0.0
    c.plan_wake(c.next_step_wall)
    # starved for 5 s: only max_catchup_s worth of steps (within a step), the rest of the wall
    # time is dropped, in whole steps, so that the steps keep their phase to the wall clock
    n = c.due_steps(105.2)
    assert int(0.1 / 0.04) + 1 <= n <= int(0.1 / 0.04) + 2
    late = 5.2 - 100.16 + 100
    assert late - 0.1 - 0.04 < c.dropped_wall_s <= late - 0.1
    assert c.dropped_wall_s / 0.04 == pytest.approx(round(c.dropped_wall_s / 0.04), abs=1e-6)
    c.advance(n)
    assert c.sim_time == pytest.approx((3 + n) * 0.02)
    assert c.rtf_total(105.2) < 0.1  # RTF fell instead of the sim bursting


def test_a_dropped_backlog_keeps_the_phase_of_the_10_hz_grid() -> None:
    """Aligned ticks rely on the virtual FCU's 10 Hz telemetry staying on the wall clock's grid:
    a late host drops whole 0.1 s, and the steps on the grid stay on it."""
    c = SimClock(physics_hz=50.0, target_rtf=1.0, max_catchup_s=0.2, phase_steps=5)
    c.start(100.0)
    for late_by in (0.537, 1.013, 3.333):
        c.plan_wake(c.next_step_wall)
        now = c.next_step_wall + late_by
        n = c.due_steps(now)
        c.advance(n)
        on_grid = c.wall_of_step((c.steps // 5 + 1) * 5)  # the next step on the 10 Hz grid (telemetry)
        assert (on_grid - 100.0) / 0.1 == pytest.approx(round((on_grid - 100.0) / 0.1), abs=1e-6)
        assert c.dropped_wall_s / 0.1 == pytest.approx(round(c.dropped_wall_s / 0.1), abs=1e-6)
        assert now - c.next_step_wall < 0.2 + 0.1  # the backlog left: max_catchup_s, and less than 0.1 s more
    assert c.dropped_wall_s > 4.0


def test_rtf_meter_window() -> None:
    m = RtfMeter(window_s=5.0)
    m.add(0.0, 0.0)
    for k in range(1, 41):  # 10 s at RTF 1, sampled every 0.25 s
        m.add(k * 0.25, k * 0.25)
    assert m.value == pytest.approx(1.0)
    for k in range(41, 81):  # then 10 s at RTF 0.4
        m.add(k * 0.25, 10.0 + (k - 40) * 0.25 * 0.4)
    assert m.value == pytest.approx(0.4, abs=0.02)  # the window forgot the first phase
    assert m.total() == pytest.approx(14.0 / 20.0)


def test_rtf_meter_is_nan_until_measured_and_restarts_on_reboot() -> None:
    m = RtfMeter(min_span_s=0.5)
    assert math.isnan(m.value) and math.isnan(m.total())  # unknown, not "stopped"
    m.add(100.0, 0.0)
    m.add(100.3, 0.3)
    assert math.isnan(m.value)  # 0.3 s of wall time is too short to tell
    m.add(101.0, 0.0)  # a paused simulator is a real measurement: 0.0
    assert m.value == 0.0
    for k in range(1, 11):
        m.add(101.0 + k * 0.2, 60.0 + k * 0.2)
    m.add(104.0, 2.0)  # sim time went back by a minute: the FCU rebooted
    assert math.isnan(m.value)
    m.add(105.0, 2.5)
    assert m.value == pytest.approx(0.5) and m.total() == pytest.approx(0.5)


def _cfg(**kw) -> FcuConfig:
    return FcuConfig([VehicleConfig(sysid=1, params=kw.pop("params", {}))], **kw)


def test_target_rtf_half_is_measured_and_published() -> None:
    with FcuThread(_cfg(target_rtf=0.5), ready=False) as ft, MavClient(ft.addrs[0]) as c:  # timed from boot
        c.heartbeat()
        # the emulator's NAMED_VALUE_FLOAT "RTF" is sent when asked for (neither firmware has it)
        c.send(c.mav.command_long_encode(1, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0, M.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT, 1e6,
                                         0, 0, 0, 0, 0))  # fmt: skip
        t0 = time.monotonic()
        rtf_msgs = []
        while time.monotonic() - t0 < 3.5:
            m = c.recv_match("NAMED_VALUE_FLOAT", timeout=1.5, cond=lambda m: m.name == "RTF")
            if m is not None:
                rtf_msgs.append(m.value)
        wall = time.monotonic() - t0
        fcu = ft.fcu
        assert fcu.rtf_total == pytest.approx(0.5, abs=0.06)
        assert fcu.rtf == pytest.approx(0.5, abs=0.06)
        assert fcu.sim_time == pytest.approx(0.5 * (wall + 0.0), abs=0.4)
        # NAMED_VALUE_FLOAT RTF at 1 Hz of sim time = every ~2 s of wall time here
        assert 1 <= len(rtf_msgs) <= 3
        assert rtf_msgs[-1] == pytest.approx(0.5, abs=0.1)


def test_starved_loop_slows_the_sim_instead_of_jumping() -> None:
    fcu = VirtualFcu(_cfg())
    fcu.open()
    try:
        t_end = time.monotonic() + 0.5
        while time.monotonic() < t_end:
            nxt = fcu.service()
            time.sleep(max(0.0, min(0.05, nxt - time.monotonic())))
        sim_before = fcu.sim_time
        time.sleep(1.0)  # the host loop stalls
        fcu.service()
        jump = fcu.sim_time - sim_before
        assert jump <= 0.1 + 0.02 + 0.05  # max_catchup_s (+ the batch in flight), not 1 s
        assert fcu.stats.dropped_wall_s > 0.8
        assert fcu.rtf_total < 0.75  # 1.5 s of wall, < 0.75 s of sim
        assert fcu.truth().landed and fcu.truth().pos_ned == (0.0, 0.0, 0.0)
    finally:
        fcu.close()


def test_fcu_timers_run_on_sim_time() -> None:
    """Preflight auto-disarm after COM_DISARM_PRFLT (+ PX4's landing detector's delay) of *sim* time, with an
    injected wall clock."""
    wall = [1000.0]
    fcu = VirtualFcu(_cfg(target_rtf=0.5, params={"COM_DISARM_PRFLT": 1.0}), clock=lambda: wall[0])
    (addr,) = fcu.open()
    fcu.vehicles[0].finish_boot()  # armable at once: the test times the preflight disarm from boot
    limit = 1.0 + px4.DISARM_PRFLT_GRACE_S
    try:
        with MavClient(addr) as c:
            c.send(c.mav.command_long_encode(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
            select.select(fcu.fds(), [], [], 1.0)
            fcu.poll_io()
            ack = c.recv_match("COMMAND_ACK", 1.0)
            assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
            assert fcu.truth().armed
            # 0.3 s of sim short of the limit: still armed (at RTF 0.5, twice that of wall time)
            while fcu.sim_time < limit - 0.3:
                wall[0] += 0.02
                fcu.service()
            assert fcu.truth().armed
            while fcu.sim_time < limit + 0.2:
                wall[0] += 0.02
                fcu.service()
            assert not fcu.truth().armed
            assert c.wait(lambda: px4.DISARMED_PREFLIGHT.id in c.events, 1.0)
            # time_boot_ms follows sim time too
            m = c.latest.get("LOCAL_POSITION_NED")
            assert m is not None and abs(m.time_boot_ms / 1000.0 - fcu.sim_time) < 0.2
    finally:
        fcu.close()
