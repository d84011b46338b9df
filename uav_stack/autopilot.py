"""What the agent must know about each autopilot it flies, chosen from the FCU's heartbeat.

PX4 and ArduPilot speak the same MAVLink, yet differ in how a companion computer flies them:
the mode in which they follow external setpoints (PX4 OFFBOARD, ArduPilot GUIDED), the modes
they pass through while taking off, whether NAV_TAKEOFF needs a mode first (ArduPilot takes off
only in GUIDED), how NAV_TAKEOFF gives its altitude, and how DO_SET_MODE encodes a mode. Each
difference is one field of :class:`AutopilotProfile`; :func:`profile_for` picks the profile
from ``HEARTBEAT.autopilot``. To fly a third autopilot, add a profile to ``PROFILES``.

Mode names are pymavlink's (``mavutil.mode_string_v10``), the names :class:`FcuState.mode
<uav_stack.fcu_link.FcuState>` holds: PX4's AUTO.LOITER ("Hold" in QGroundControl) is
``LOITER`` here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

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


PX4_PROFILE = AutopilotProfile(
    name="px4",
    label="PX4",
    autopilot=mavlink.MAV_AUTOPILOT_PX4,
    offboard_mode="OFFBOARD",
    climb_modes=frozenset({"TAKEOFF", "LOITER", "OFFBOARD", "READY"}),
    takeoff_mode=None,  # PX4 switches to its TAKEOFF mode by itself
    takeoff_alt_relative=False,
    # px4_map: name -> (base_mode, main mode, sub mode); PX4 reads main/sub from params 2/3
    mode_params={name: (float(main), float(sub)) for name, (_base, main, sub) in mavutil.px4_map.items()},
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
)

PROFILES: dict[int, AutopilotProfile] = {p.autopilot: p for p in (PX4_PROFILE, ARDUPILOT_PROFILE)}


def profile_for(autopilot: int) -> AutopilotProfile:
    """The profile for a ``HEARTBEAT.autopilot`` value.

    An autopilot without a profile (or 0, before the first heartbeat) is flown as PX4, whose
    OFFBOARD handling follows the MAVLink offboard-control description most closely.
    """
    return PROFILES.get(autopilot, PX4_PROFILE)
