"""The virtual FCU's position first (`VirtualFcu.poll_position`, aligned ticks) against the whole step at once.

What a user relies on: with aligned ticks the UAV's pose leaves before the rest of its FCU's
step is done, yet the vehicle flies exactly as before (the same state, step for step) and a
ground station receives the same telemetry; only the order within the instant changes, the
position first and alone. Two FCUs over real UDP, with one injected wall clock, are driven tick
by tick: one the way the aligned loop drives it now, one the way it did before.
"""

from __future__ import annotations

import math
import select
from collections import Counter
from typing import Any

import numpy as np

from tests.fcu_helpers import MavClient
from uav_stack.fcu import FcuConfig, VehicleConfig, VirtualFcu
from uav_stack.geo import GeoPoint
from uav_stack.mav import mavlink as M

NAN = math.nan
HOME = GeoPoint(47.397742, 8.545594, 488.0)
PARAMS = {"SIM_GPS_FIX_T": 0.0, "MIS_TAKEOFF_ALT": 1.5, "MPC_TKO_SPEED": 2.0}
PERIOD = 0.1  # s, the agent's tick
ACT_AT = 0.03  # s after the instant: when the act half runs


def _open(wall: list[float]) -> tuple[VirtualFcu, MavClient]:
    fcu = VirtualFcu(FcuConfig([VehicleConfig(sysid=1, home=HOME, params=dict(PARAMS))]), clock=lambda: wall[0])
    (addr,) = fcu.open(start=wall[0] - 0.001)  # the steps a hair before the instants, as runtime.FCU_LEAD_S
    return fcu, MavClient(addr)


def _drain(c: MavClient) -> list[Any]:
    out: list[Any] = []
    while batch := c.pump(0.0):
        out += batch
    return out


def _to_fcu(fcu: VirtualFcu) -> None:
    """Whatever the client sent is in the FCU's socket (loopback; bounded wait)."""
    select.select(fcu.fds(), [], [], 0.5)


def _script(c: MavClient, k: int) -> bool:
    """The companion's messages at the act half of tick ``k``: arm, take off, a setpoint stream,
    OFFBOARD, a velocity. True if it sent something."""
    if k == 1:
        c.send(c.mav.command_long_encode(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
    elif k == 3:
        c.send(c.mav.command_long_encode(1, 1, M.MAV_CMD_NAV_TAKEOFF, 0, NAN, NAN, NAN, NAN, NAN, NAN, NAN))
    elif 25 <= k < 35:
        c.setpoint_local(0.0, 0.0, -1.5, yaw=0.0)
        if k == 30:
            c.send(c.mav.command_long_encode(1, 1, M.MAV_CMD_DO_SET_MODE, 0, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0,
                                             0, 0, 0, 0))
    elif k >= 35:
        c.setpoint_local(z=-1.5, vx=2.0, vy=-1.0)
    else:
        return False
    return True


def _content(m: Any) -> tuple[str, tuple[Any, ...]]:
    return m.get_type(), tuple(str(getattr(m, f)) for f in m.get_fieldnames())


def test_the_position_leaves_first_and_the_flight_is_the_same() -> None:
    wall = [1000.0]
    new, c_new = _open(wall)
    old, c_old = _open(wall)
    got_new: list[Any] = []
    got_old: list[Any] = []
    try:
        for c in (c_new, c_old):
            c.heartbeat()  # the FCU streams to the first peer it hears
        _to_fcu(new)
        _to_fcu(old)
        for f in (new, old):
            f.poll_io()
        _drain(c_new)  # (the answer to the heartbeat: the same in both)
        _drain(c_old)
        for k in range(1, 70):
            instant = 1000.0 + k * PERIOD
            # the sense half: now the instant's position alone, before, the whole step
            wall[0] = instant
            new.poll_position()
            first = _drain(c_new)
            old.poll_io()
            old.service()
            old.poll_io()
            assert [m.get_type() for m in first] == ["GLOBAL_POSITION_INT"], f"tick {k}: {[m.get_type() for m in first]}"
            got_new += first
            # the act half: the rest of the held step, physics up to now, the companion's messages
            wall[0] = instant + ACT_AT
            new.poll_io()
            new.service()
            old.poll_io()
            sent = [_script(c, k) for c in (c_new, c_old)]
            if any(sent):
                _to_fcu(new)
                _to_fcu(old)
            new.poll_io()
            old.poll_io()
            got_new += _drain(c_new)
            got_old += _drain(c_old)
            for name in ("pos", "vel", "pos_sp", "vel_ff", "yaw"):
                assert np.array_equal(getattr(new.dyn, name), getattr(old.dyn, name), equal_nan=True), f"tick {k}: {name}"
            assert (new.vehicles[0].mode, new.vehicles[0].phase) == (old.vehicles[0].mode, old.vehicles[0].phase)
        # the scenario flew what it meant to: airborne in OFFBOARD, moving north-west at 2 and 1 m/s
        v = new.vehicles[0]
        assert v.armed and v.mode.name == "OFFBOARD", (v.armed, v.mode.name)
        assert new.truth().pos_ned[0] > 3.0 and new.truth().pos_ned[1] < -1.0 and new.truth().pos_ned[2] < -1.0
        # the same telemetry, message for message (the heartbeats, paced on wall time, too); the
        # two whose content is the wall clock (SYSTEM_TIME, and the RTF, measured on it) by count
        wall_clock = {"SYSTEM_TIME", "NAMED_VALUE_FLOAT"}
        assert Counter(m.get_type() for m in got_new) == Counter(m.get_type() for m in got_old)
        a = Counter(_content(m) for m in got_new if m.get_type() not in wall_clock)
        b = Counter(_content(m) for m in got_old if m.get_type() not in wall_clock)
        assert a == b, (sorted((a - b).items())[:6], sorted((b - a).items())[:6])
        assert sum(m.get_type() == "ATTITUDE" for m in got_new) >= 30  # the held telemetry did leave
    finally:
        for f, c in ((new, c_new), (old, c_old)):
            c.close()
            f.close()
