"""What the agent must know about each autopilot it flies, chosen from the FCU's heartbeat.

PX4 and ArduPilot speak the same MAVLink, yet differ in how a companion computer flies them:
the mode in which they follow external setpoints (PX4 OFFBOARD, ArduPilot GUIDED), the modes
they pass through while taking off, whether NAV_TAKEOFF needs a mode first (ArduPilot takes off
only in GUIDED), how NAV_TAKEOFF gives its altitude, and how DO_SET_MODE encodes a mode. Each
difference is one field of :class:`AutopilotProfile`; :func:`profile_for` picks the profile
from ``HEARTBEAT.autopilot``. To fly a third autopilot, add a profile to ``PROFILES``.

Mode names are each autopilot's own, the names :class:`FcuState.mode
<uav_stack.fcu_link.FcuState>` holds (:func:`mode_name`): PX4's AUTO.LOITER is ``HOLD``, as
PX4, QGroundControl and MAVSDK call it (pymavlink says ``LOITER``), and ArduCopter's modes are
its mode numbers' names (``LOITER`` there is ArduCopter's own position-hold mode).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from uav_stack.mav import mavlink, mavutil


@dataclass(frozen=True)
class AutopilotProfile:
    """The differences between autopilots that the agent's state machine depends on."""

    name: str  # "px4" | "ardupilot", as in the scenario's ``flavour``
    label: str  # for error messages: "PX4", "ArduCopter"
    autopilot: int  # HEARTBEAT.autopilot (MAV_AUTOPILOT_*)
    offboard_mode: str  # the mode in which the FCU follows SET_POSITION_TARGET_* setpoints
    # modes the FCU passes through while the agent takes off and enters ``offboard_mode``;
    # any other new mode in that time means someone took the FCU over
    climb_modes: frozenset[str]
    takeoff_mode: str | None  # mode NAV_TAKEOFF needs (ArduPilot: GUIDED); None: any mode
    takeoff_alt_relative: bool  # NAV_TAKEOFF param 7: metres above home (ArduPilot), not AMSL (PX4)
    mode_params: Mapping[str, tuple[float, ...]]  # DO_SET_MODE params 2.. (custom mode) per mode name
    # modes a companion leaves before arming (``arming_mode``): the autopilot refuses to arm in them
    # (a landed UAV is often left in RTL or LAND), or arming would start something (PX4 MISSION)
    leave_before_arming: frozenset[str] = frozenset()
    arming_mode: str = ""

    def set_mode_params(self, name: str) -> tuple[float, ...]:
        """DO_SET_MODE params 1.. for a mode name (case-insensitive); ValueError if unknown."""
        params = self.mode_params.get(name.upper())
        if params is None:
            raise ValueError(f"unknown {self.label} mode {name!r}; known: {', '.join(self.mode_params)}")
        return (float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), *params)

    def takeoff_params(self, alt_amsl: float, relative_alt: float) -> tuple[float, ...]:
        """NAV_TAKEOFF params 1-7 for a climb to ``alt_amsl`` (m AMSL), ``relative_alt`` m above home."""
        if self.takeoff_alt_relative:
            return (0, 0, 0, math.nan, 0, 0, relative_alt)
        return (math.nan, 0, 0, math.nan, math.nan, math.nan, alt_amsl)


# PX4's modes by (main mode, sub mode) of HEARTBEAT.custom_mode (px4_custom_mode.h), named as
# PX4's own commander and QGroundControl name them
PX4_MODE_NAMES: dict[tuple[int, int], str] = {
    (1, 0): "MANUAL", (2, 0): "ALTCTL", (3, 0): "POSCTL", (3, 1): "ORBIT", (4, 1): "READY", (4, 2): "TAKEOFF",
    (4, 3): "HOLD", (4, 4): "MISSION", (4, 5): "RTL", (4, 6): "LAND", (4, 8): "FOLLOWME", (4, 9): "PRECLAND",
    (5, 0): "ACRO", (6, 0): "OFFBOARD", (7, 0): "STABILIZED",
}  # fmt: skip


def mode_name(msg: Any) -> str:
    """The flight mode a HEARTBEAT announces, in its autopilot's own words (PX4 ``HOLD``)."""
    if msg.autopilot == mavlink.MAV_AUTOPILOT_PX4 and msg.get_type() == "HEARTBEAT":
        main, sub = (msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF
        return PX4_MODE_NAMES.get((main, sub)) or PX4_MODE_NAMES.get((main, 0)) or f"Mode({msg.custom_mode})"
    return str(mavutil.mode_string_v10(msg))


PX4_PROFILE = AutopilotProfile(
    name="px4",
    label="PX4",
    autopilot=mavlink.MAV_AUTOPILOT_PX4,
    offboard_mode="OFFBOARD",
    climb_modes=frozenset({"TAKEOFF", "HOLD", "OFFBOARD", "READY"}),
    takeoff_mode=None,  # PX4 switches to its TAKEOFF mode by itself
    takeoff_alt_relative=False,
    # PX4 reads main/sub from params 2/3; LOITER is pymavlink's name for HOLD, kept as an alias
    mode_params={**{name: (float(main), float(sub)) for (main, sub), name in PX4_MODE_NAMES.items()},
                 "LOITER": (4.0, 3.0)},
    leave_before_arming=frozenset({"RTL", "MISSION"}),
    arming_mode="HOLD",
)

ARDUPILOT_PROFILE = AutopilotProfile(
    name="ardupilot",
    label="ArduCopter",
    autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
    offboard_mode="GUIDED",
    climb_modes=frozenset({"GUIDED"}),
    takeoff_mode="GUIDED",
    takeoff_alt_relative=True,
    mode_params={name: (float(number),) for number, name in mavutil.mode_mapping_acm.items()},
    leave_before_arming=frozenset({"RTL", "LAND", "AUTO", "SMART_RTL", "AUTO_RTL"}),
    arming_mode="GUIDED",
)

PROFILES: dict[int, AutopilotProfile] = {p.autopilot: p for p in (PX4_PROFILE, ARDUPILOT_PROFILE)}


def profile_for(autopilot: int) -> AutopilotProfile:
    """The profile for a ``HEARTBEAT.autopilot`` value.

    An autopilot without a profile (or 0, before the first heartbeat) is flown as PX4, whose
    OFFBOARD handling follows the MAVLink offboard-control description most closely.
    """
    return PROFILES.get(autopilot, PX4_PROFILE)
