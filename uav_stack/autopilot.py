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
    # the modes the agent arms in; in any other it first switches to ``arming_mode``. The autopilot
    # refuses to arm in many (PX4 OFFBOARD without a setpoint stream, where PX4 returns after a
    # landing; RTL, LAND, ArduPilot AUTO), or arming would start something (PX4 MISSION)
    arm_modes: frozenset[str] = frozenset()
    arming_mode: str = ""
    # the message whose flags say whether the autopilot's estimator has a usable position (ArduPilot
    # EKF_STATUS_REPORT, PX4 ESTIMATOR_STATUS), asked for at start-up; "" when it has none
    estimator: str = ""
    # its GLOBAL_POSITION_INT is no position until the estimator's flags say so (ArduCopter sends a
    # real latitude and longitude from its GPS while the EKF still ignores them); PX4 sends none before
    estimator_first: bool = False
    # COMMAND_LONG params 5 and 6 become integers (ArduPilot): never NaN there
    integer_xy: bool = False
    # honours REQUEST_DATA_STREAM (ArduPilot does; PX4 ignores it): the start-up contract's fallback
    data_streams: bool = True

    def set_mode_params(self, name: str) -> tuple[float, ...]:
        """DO_SET_MODE params 1.. for a mode name (case-insensitive); ValueError if unknown."""
        params = self.mode_params.get(name.upper())
        if params is None:
            raise ValueError(f"unknown {self.label} mode {name!r}; known: {', '.join(self.mode_params)}")
        return (float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), *params)

    def land_params(self) -> tuple[float, ...]:
        """NAV_LAND params 1-7 for a landing where the UAV is, yaw unchanged. PX4 takes NaN as "here"; ArduPilot
        turns params 5 and 6 into integers (COMMAND_LONG to COMMAND_INT), where a NaN is undefined and stops its
        SITL on the floating-point trap: it takes 0, 0 as "here"."""
        if self.integer_xy:
            return (0, 0, 0, math.nan, 0, 0, 0)
        return (0, 0, 0, math.nan, math.nan, math.nan, math.nan)

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
    arm_modes=frozenset({"HOLD", "READY", "TAKEOFF"}),  # PX4 arms in Hold; NAV_TAKEOFF may have come first
    arming_mode="HOLD",
    estimator="ESTIMATOR_STATUS",
    data_streams=False,
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
    arm_modes=frozenset({"GUIDED"}),  # ArduCopter takes off only in GUIDED: it arms there
    arming_mode="GUIDED",
    estimator="EKF_STATUS_REPORT",
    estimator_first=True,
    integer_xy=True,
)

PROFILES: dict[int, AutopilotProfile] = {p.autopilot: p for p in (PX4_PROFILE, ARDUPILOT_PROFILE)}


def firmware_version(flight_sw_version: int) -> str:
    """AUTOPILOT_VERSION.flight_sw_version as PX4 and ArduPilot encode it: major, minor, patch and
    the release type in its four bytes (``0x04070000`` is 4.7.0-dev, ``0x011000FF`` 1.16.0)."""
    v = flight_sw_version
    kind = {0: "-dev", 64: "-alpha", 128: "-beta", 192: "-rc"}.get(v & 0xFF, "")
    return f"{(v >> 24) & 0xFF}.{(v >> 16) & 0xFF}.{(v >> 8) & 0xFF}{kind}"


# PX4's EVENTs (message 410) carry no text: an id, whose name and message come from the
# firmware's event metadata. These are the ones PX4 1.16 sends on its onboard link around arming,
# take-off, landing and failsafes, as recorded from a real PX4 SITL. Unknown ids are shown by number.
PX4_EVENTS: dict[int, tuple[str, str]] = {
    0x0102089D: ("commander_arm_denied_resolve_failures", "Arming denied: Resolve system health failures first"),
    0x0105C2D9: ("check_modes_mission", "No valid mission available"),
    0x0106ED29: ("check_modes_manual_control", "No manual control input"),
    0x011D3727: ("commander_health_summary", "Health report summary event"),
    0x012F1DC7: ("check_modes_offboard_signal", "No offboard signal"),
    0x0132B2DE: ("commander_landing_current_pos", "Landing at current position"),
    0x01414569: ("commander_takeoff_detected", "Takeoff detected"),
    0x0167C97B: ("check_rc_dl_no_dllink", "No connection to the ground control station"),
    0x0190CAF3: ("commander_armed_by", "Armed by {1}"),
    0x019638AC: ("commander_landing_detected", "Landing detected"),
    0x0198C273: ("check_modes_global_pos", "Navigation error: No valid global position estimate"),
    0x01A893E0: ("commander_arming_check_summary", "Arming check summary event"),
    0x01D31BB9: ("check_modes_local_pos", "Navigation error: No valid position estimate"),
    0x01DEDBD0: ("commander_failsafe_enter_generic", "Failsafe activated: switching to {2}"),
    0x01F46777: ("commander_disarmed_by", "Disarmed by {1}"),
}  # fmt: skip
PX4_ARMING_SUMMARY = 0x01A893E0  # starts a new arming-check report: the check events that follow belong to it
PX4_HEALTH_SUMMARY = 0x011D3727  # ends it


def px4_event_text(event_id: int) -> str:
    """An EVENT's id as a person reads it: ``commander_arm_denied_resolve_failures (Arming denied:
    Resolve system health failures first)``, or ``PX4 event 0x01234567`` for an id not in the table."""
    known = PX4_EVENTS.get(event_id)
    return f"{known[0]} ({known[1]})" if known else f"PX4 event 0x{event_id:08x}"


def profile_for(autopilot: int) -> AutopilotProfile:
    """The profile for a ``HEARTBEAT.autopilot`` value.

    An autopilot without a profile (or 0, before the first heartbeat) is flown as PX4, whose
    OFFBOARD handling follows the MAVLink offboard-control description most closely.
    """
    return PROFILES.get(autopilot, PX4_PROFILE)
