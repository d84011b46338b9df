"""Flight modes of the two autopilot flavours and their MAVLink ``custom_mode`` encodings.

PX4: ``custom_mode = main << 16 | sub << 24`` (px4_custom_mode.h). ArduCopter: the mode
number itself. Each mode maps to one of a few kinds of :class:`Guidance` that the vehicle
implements (docs/fcu.md lists the modes and what each does).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from uav_stack.autopilot import ARDUPILOT_PROFILE, PX4_PROFILE, AutopilotProfile
from uav_stack.mav import mavlink


class Guidance(str, Enum):
    """What the vehicle does in a mode; several modes of an autopilot share one."""

    HOLD = "hold"  # hold position (or fly to a reposition target), brake to a stop on entry
    TAKEOFF = "takeoff"  # climb to the takeoff altitude, then HOLD (PX4) / guided hold (ArduPilot)
    LAND = "land"  # descend at the landing speed, auto-disarm on the ground
    RTL = "rtl"  # climb, return at cruise speed, land at home
    OFFBOARD = "offboard"  # follow external setpoints (PX4 OFFBOARD, ArduPilot GUIDED)
    MISSION = "mission"  # fly the uploaded mission (PX4 MISSION, ArduPilot AUTO): mission.py
    STICKS = "sticks"  # position/velocity under stick input, hold when centred (PX4 POSCTL, ArduPilot LOITER): manual.py
    MANUAL = "manual"  # attitude/thrust under sticks: not emulated, refused in the air; acts like HOLD


# What the vehicle is doing right now within its mode (Vehicle.phase): a mode's guidance goes
# through these (RTL: climb, return, land); the mission uses them for its items.
P_HOLD = "hold"
P_TAKEOFF = "takeoff"
P_LAND = "land"
P_RTL_CLIMB = "rtl_climb"
P_RTL_RETURN = "rtl_return"
P_OFFBOARD = "offboard"
P_MISSION = "mission"  # flying to a mission item, or holding at it
P_STICKS = "sticks"  # under stick input (or holding with centred sticks)

TAKEOFF_DONE_M = 0.3  # altitude error at which a takeoff counts as complete


@dataclass(frozen=True)
class ModeSpec:
    name: str
    custom_mode: int
    guidance: Guidance  # what the vehicle does in this mode
    base_flags: int  # MAV_MODE_FLAG bits besides CUSTOM_MODE_ENABLED and SAFETY_ARMED
    can_arm: bool = True
    armed_flags: int = 0  # bits the firmware adds while armed (ArduCopter's RTL: GUIDED_ENABLED)


def px4_custom_mode(main: int, sub: int = 0) -> int:
    """PX4's HEARTBEAT.custom_mode for a main and sub mode (px4_custom_mode.h)."""
    return (main & 0xFF) << 16 | (sub & 0xFF) << 24


_AUTO = mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
_OFFBOARD = mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED  # PX4 1.16: OFFBOARD's base_mode is 0x11 (0x91 armed)
_MANUAL = mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
_ASSIST = mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED

B = Guidance
PX4_MODES: tuple[ModeSpec, ...] = (
    ModeSpec("MANUAL", px4_custom_mode(1), B.MANUAL, _MANUAL),
    ModeSpec("ALTCTL", px4_custom_mode(2), B.STICKS, _ASSIST),
    ModeSpec("POSCTL", px4_custom_mode(3), B.STICKS, _ASSIST),
    ModeSpec("READY", px4_custom_mode(4, 1), B.HOLD, _AUTO),
    ModeSpec("TAKEOFF", px4_custom_mode(4, 2), B.TAKEOFF, _AUTO),
    ModeSpec("HOLD", px4_custom_mode(4, 3), B.HOLD, _AUTO),
    ModeSpec("MISSION", px4_custom_mode(4, 4), B.MISSION, _AUTO),
    ModeSpec("RTL", px4_custom_mode(4, 5), B.RTL, _AUTO, can_arm=False),
    ModeSpec("LAND", px4_custom_mode(4, 6), B.LAND, _AUTO, can_arm=False),
    ModeSpec("ACRO", px4_custom_mode(5), B.MANUAL, _MANUAL),
    ModeSpec("OFFBOARD", px4_custom_mode(6), B.OFFBOARD, _OFFBOARD),
    ModeSpec("STABILIZED", px4_custom_mode(7), B.MANUAL, _ASSIST),
)

# ArduCopter 4.7's base_mode (HEARTBEAT): 81 (STABILIZE | MANUAL_INPUT | CUSTOM) plus GUIDED_ENABLED in the
# guided modes: GUIDED, AUTO and LAND read 89 disarmed and 217 armed, STABILIZE 81, RTL 81 disarmed and 217 armed
_APM_BASE = mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED | mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
_APM_GUIDED = _APM_BASE | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
ARDUPILOT_MODES: tuple[ModeSpec, ...] = (
    ModeSpec("STABILIZE", 0, B.MANUAL, _APM_BASE),
    ModeSpec("ACRO", 1, B.MANUAL, _APM_BASE),
    ModeSpec("ALT_HOLD", 2, B.STICKS, _APM_BASE),
    ModeSpec("AUTO", 3, B.MISSION, _APM_GUIDED, can_arm=False),
    ModeSpec("GUIDED", 4, B.OFFBOARD, _APM_GUIDED),
    ModeSpec("LOITER", 5, B.STICKS, _APM_BASE),
    ModeSpec("RTL", 6, B.RTL, _APM_BASE, can_arm=False, armed_flags=mavlink.MAV_MODE_FLAG_GUIDED_ENABLED),
    ModeSpec("LAND", 9, B.LAND, _APM_GUIDED, can_arm=False),
    ModeSpec("POSHOLD", 16, B.STICKS, _APM_BASE),
    ModeSpec("BRAKE", 17, B.HOLD, _APM_GUIDED),
    ModeSpec("SMART_RTL", 21, B.RTL, _APM_GUIDED, can_arm=False),
)


@dataclass(frozen=True)
class Flavour:
    """What differs between the emulated autopilots.

    ``profile`` is what a companion computer expects of the autopilot this flavour emulates
    (the agent picks it from our heartbeat's ``autopilot``); the rest is the emulation's own.
    Mode names here are the autopilot's own (PX4 ``HOLD``, which pymavlink calls ``LOITER``).
    """

    name: str  # "px4" | "ardupilot"
    profile: AutopilotProfile
    modes: tuple[ModeSpec, ...]
    initial_mode: str
    hold_mode: str  # target of "hold"-type failsafes
    mission_mode: str  # the mode that flies the uploaded mission
    bytewise_params: bool  # PX4 PARAM_ENCODE_BYTEWISE; ArduPilot C cast

    def __post_init__(self) -> None:
        object.__setattr__(self, "_by_name", {m.name: m for m in self.modes})
        object.__setattr__(self, "_by_custom", {m.custom_mode: m for m in self.modes})

    @property
    def autopilot(self) -> int:
        """HEARTBEAT.autopilot (MAV_AUTOPILOT_*)."""
        return self.profile.autopilot

    @property
    def is_px4(self) -> bool:
        return self.name == "px4"

    def mode(self, name: str) -> ModeSpec:
        return self._by_name[name]  # type: ignore[attr-defined]

    def by_custom_mode(self, custom_mode: int) -> ModeSpec | None:
        return self._by_custom.get(custom_mode)  # type: ignore[attr-defined]

    def from_command(self, p2: float, p3: float) -> ModeSpec | None:
        """Decode DO_SET_MODE params: PX4 main/sub in p2/p3, ArduPilot number in p2."""
        if not (math.isfinite(p2) and 0 <= p2 < 256):
            return None
        if self.is_px4:
            if p3 != p3:
                p3 = 0.0
            if not (math.isfinite(p3) and 0 <= p3 < 256):
                return None
            return self.by_custom_mode(px4_custom_mode(int(p2), int(p3)))
        return self.by_custom_mode(int(p2))


PX4 = Flavour(
    name="px4",
    profile=PX4_PROFILE,
    modes=PX4_MODES,
    initial_mode="HOLD",
    hold_mode="HOLD",
    mission_mode="MISSION",
    bytewise_params=True,
)

ARDUPILOT = Flavour(
    name="ardupilot",
    profile=ARDUPILOT_PROFILE,
    modes=ARDUPILOT_MODES,
    initial_mode="STABILIZE",
    hold_mode="LOITER",
    mission_mode="AUTO",
    bytewise_params=False,
)

FLAVOURS: dict[str, Flavour] = {"px4": PX4, "ardupilot": ARDUPILOT}


def get_flavour(name: str) -> Flavour:
    try:
        return FLAVOURS[name.lower()]
    except KeyError:
        raise ValueError(f"unknown flavour {name!r}; expected one of {sorted(FLAVOURS)}") from None
