"""Autopilot profiles: the wire encodings the agent sends each autopilot, and the virtual
FCU's flavours announcing the autopilot whose profile they claim."""

from __future__ import annotations

import math

import pytest

from uav_stack.autopilot import ARDUPILOT_PROFILE, PX4_PROFILE, mode_name, profile_for
from uav_stack.fcu.modes import FLAVOURS, px4_custom_mode
from uav_stack.mav import mavlink as M


def test_profile_is_chosen_from_the_heartbeat_autopilot() -> None:
    assert profile_for(M.MAV_AUTOPILOT_PX4) is PX4_PROFILE
    assert profile_for(M.MAV_AUTOPILOT_ARDUPILOTMEGA) is ARDUPILOT_PROFILE
    assert profile_for(M.MAV_AUTOPILOT_GENERIC) is PX4_PROFILE  # unknown autopilots are flown as PX4
    for flavour in FLAVOURS.values():  # what the virtual FCU announces leads the agent to its profile
        assert profile_for(flavour.autopilot) is flavour.profile


def test_set_mode_encodings_match_what_the_virtual_fcu_decodes() -> None:
    flag = float(M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
    assert PX4_PROFILE.set_mode_params("offboard") == (flag, 6.0, 0.0)  # main mode in p2, sub mode in p3
    assert ARDUPILOT_PROFILE.set_mode_params("GUIDED") == (flag, 4.0)  # mode number in p2
    px4, apm = FLAVOURS["px4"], FLAVOURS["ardupilot"]
    for name in ("OFFBOARD", "TAKEOFF", "LAND", "RTL", "POSCTL"):
        _, p2, p3 = PX4_PROFILE.set_mode_params(name)
        spec = px4.from_command(p2, p3)
        assert spec is not None and spec.custom_mode == px4_custom_mode(int(p2), int(p3)) and spec.name == name
    _, p2 = ARDUPILOT_PROFILE.set_mode_params(ARDUPILOT_PROFILE.offboard_mode)
    assert apm.from_command(p2, math.nan).name == "GUIDED"  # type: ignore[union-attr]


def test_unknown_mode_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match="unknown PX4 mode 'GUIDED'"):
        PX4_PROFILE.set_mode_params("GUIDED")
    with pytest.raises(ValueError, match="unknown ArduCopter mode 'OFFBOARD'"):
        ARDUPILOT_PROFILE.set_mode_params("OFFBOARD")


def test_takeoff_altitude_is_amsl_for_px4_and_relative_for_ardupilot() -> None:
    assert PX4_PROFILE.takeoff_params(510.0, 10.0)[6] == 510.0
    assert ARDUPILOT_PROFILE.takeoff_params(510.0, 10.0)[6] == 10.0
    assert ARDUPILOT_PROFILE.takeoff_mode == ARDUPILOT_PROFILE.offboard_mode == "GUIDED"
    assert PX4_PROFILE.takeoff_mode is None


def test_mode_names_are_the_autopilots_own_px4_hold_is_hold() -> None:
    px4, apm = FLAVOURS["px4"], FLAVOURS["ardupilot"]
    mav = M.MAVLink(None, 1, 1)
    for spec in px4.modes:  # every mode the virtual FCU announces reads back under the FCU's own name
        hb = mav.heartbeat_encode(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 1, spec.custom_mode, 3)
        assert mode_name(hb) == spec.name
    hold = mav.heartbeat_encode(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 1, px4_custom_mode(4, 3), 3)
    assert mode_name(hold) == "HOLD"  # pymavlink says LOITER; PX4, QGC and MAVSDK say Hold
    for spec in apm.modes:
        hb = mav.heartbeat_encode(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 1, spec.custom_mode, 3)
        assert mode_name(hb) == spec.name
    assert PX4_PROFILE.set_mode_params("HOLD") == PX4_PROFILE.set_mode_params("LOITER") == (1.0, 4.0, 3.0)


def test_no_nan_where_ardupilot_makes_integers() -> None:
    """ArduPilot turns COMMAND_LONG into COMMAND_INT, params 5 and 6 into integers: a NaN there is undefined
    (a real ArduCopter 4.7 SITL stops on its floating-point trap). Every command the agent sends it has none."""
    from uav_stack.autopilot import ARDUPILOT_PROFILE

    for params in (ARDUPILOT_PROFILE.land_params(), ARDUPILOT_PROFILE.takeoff_params(600.0, 15.0),
                   ARDUPILOT_PROFILE.set_mode_params("GUIDED")):
        padded = list(params) + [0.0] * (7 - len(params))
        assert not any(math.isnan(p) for p in padded[4:6]), params
