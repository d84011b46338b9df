"""Which messages each flavour streams, at what rate, and the per-vehicle scheduler that sends them.

* PX4 streams its onboard link's set from boot without being asked (px4.STREAMS), each from the boot
  milestone the firmware starts it at; SET_MESSAGE_INTERVAL changes one (-1 off, 0 back to its default).
* ArduPilot streams nothing periodic but HEARTBEAT (and a TIMESYNC every 10 s) until asked:
  REQUEST_DATA_STREAM sets a stream group's ``MAV1_*`` rate and every message of that group
  (ardupilot.STREAM_GROUPS), SET_MESSAGE_INTERVAL one message (0: back to its group's rate); messages in
  no group (HOME_POSITION, EXTENDED_SYS_STATE, ...) stream only by interval.

Streams are scheduled on *sim* time, checked after every physics step, so they slow down with the
simulation and never burst, and never faster than the physics (one message per step). Vehicles of one
fleet get different phase offsets so a process hosting many vehicles spreads its sends over the period.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from uav_stack.fcu import ardupilot, px4, telemetry, telemetry_ardupilot, telemetry_px4
from uav_stack.mav import mavlink

if TYPE_CHECKING:
    from uav_stack.fcu.vehicle import Vehicle

M = mavlink
Encoder = Callable[["Vehicle"], mavlink.MAVLink_message | None]

# Messages both flavours stream (None from an encoder: nothing to send yet)
COMMON: dict[str, Encoder] = {
    "HEARTBEAT": telemetry.heartbeat,
    "GLOBAL_POSITION_INT": telemetry.global_position_int,
    "LOCAL_POSITION_NED": telemetry.local_position_ned,
    "ATTITUDE": telemetry.attitude,
    "ATTITUDE_QUATERNION": telemetry.attitude_quaternion,
    "SYS_STATUS": telemetry.sys_status,
    "EXTENDED_SYS_STATE": telemetry.extended_sys_state,
    "HOME_POSITION": telemetry.home_position,
    "BATTERY_STATUS": telemetry.battery_status,
    "GPS_RAW_INT": telemetry.gps_raw_int,
    "VFR_HUD": telemetry.vfr_hud,
    "SYSTEM_TIME": telemetry.system_time,
    "NAMED_VALUE_FLOAT": telemetry.named_value_rtf,  # the emulator's measured RTF, on request only
    "MISSION_CURRENT": telemetry.mission_current,
    "GPS_GLOBAL_ORIGIN": telemetry.gps_global_origin,
    "SCALED_PRESSURE": telemetry.scaled_pressure,
    "SERVO_OUTPUT_RAW": telemetry.servo_output_raw,
    "VIBRATION": telemetry.vibration,
    "TIMESYNC": telemetry.timesync_request,
}
ENCODERS_BY_FLAVOUR: dict[str, dict[str, Encoder]] = {
    "px4": {**COMMON, **telemetry_px4.ENCODERS},
    "ardupilot": {**COMMON, **telemetry_ardupilot.ENCODERS},
}
ENCODERS: dict[str, Encoder] = {**COMMON, **telemetry_px4.ENCODERS, **telemetry_ardupilot.ENCODERS}
STREAM_NAMES = frozenset(ENCODERS)
STREAM_BY_ID: dict[int, str] = {getattr(M, f"MAVLINK_MSG_ID_{name}"): name for name in ENCODERS}
# Messages REQUEST_MESSAGE can produce, by id (every stream of the flavour, plus one-shot ones).
ONE_SHOT: dict[str, Encoder] = {"AUTOPILOT_VERSION": telemetry.autopilot_version}
REQUESTABLE: dict[str, dict[int, Encoder]] = {
    flavour: {getattr(M, f"MAVLINK_MSG_ID_{name}"): fn for name, fn in {**encs, **ONE_SHOT}.items()}
    for flavour, encs in ENCODERS_BY_FLAVOUR.items()
}

# The first TIMESYNC request of ArduPilot goes out 10 s after launch (a period, not a boot stage).
ARDUPILOT_DEFAULTS: dict[str, float] = {"HEARTBEAT": 1.0, "TIMESYNC": 1.0 / ardupilot.TIMESYNC_PERIOD_S}


def firmware_rates(flavour: str, param: Callable[[str], float] | None = None) -> dict[str, float]:
    """The rates (Hz) a flavour streams at from boot. ArduPilot's come from its ``MAV1_*`` parameters
    (``param(name)``; all 0 from factory), PX4's are its onboard link's."""
    if flavour == "px4":
        return {"HEARTBEAT": 1.0, **{name: hz for name, (hz, _) in px4.STREAMS.items()}}
    rates = dict(ARDUPILOT_DEFAULTS)
    if param is not None:
        for group, names in ardupilot.STREAM_GROUPS.items():
            hz = param(group)
            for name in names:
                rates[name] = ardupilot_group_hz(name, hz)
    return rates


def turned_down(flavour: str, wanted: dict[str, float]) -> dict[str, float]:
    """``FcuConfig.stream_rates`` for a link that carries only ``wanted`` (name -> Hz): every stream the
    flavour sends unasked off, the wanted ones at their rates. What a companion does to a real PX4 with
    SET_MESSAGE_INTERVAL −1 when it reads few of its onboard link's 400 messages a second; for an
    ArduPilot (silent until asked) it only sets the wanted ones."""
    unasked = firmware_rates(flavour).items() if flavour == "px4" else ()
    rates = {name: 0.0 for name, hz in unasked if hz > 0 and name != "HEARTBEAT"}
    rates.update({name: hz for name, hz in wanted.items() if name in ENCODERS_BY_FLAVOUR[flavour]})
    return rates


def ardupilot_group_hz(name: str, group_hz: float) -> float:
    """The rate of one message of a stream group set to ``group_hz``."""
    if name == "TERRAIN_REQUEST":
        return min(group_hz, ardupilot.TERRAIN_REQUEST_MAX_HZ)
    return group_hz


class StreamSet:
    """Per-vehicle stream intervals (sim seconds) and next due times.

    All of a vehicle's streams are phase-aligned on the physics step grid (offset ``phase`` steps), so
    one wake-up sends everything due and a lone vehicle wakes its host loop about 10 times a second,
    not once per stream; vehicles of a fleet get different phases, which spreads their sends. Only
    streams that are on are scheduled (``next_due``). ``start_at`` holds a stream back until a time
    (the firmware's boot starts its streams one by one).
    """

    def __init__(self, dt: float, phase: int = 0, start_at: dict[str, float] | None = None) -> None:
        self.dt = dt
        self.interval: dict[str, float] = {}
        self.next_due: dict[str, float] = {}
        self.next_any = math.inf
        self.start_at: dict[str, float] = dict(start_at or {})
        self._phase = phase
        self._grid = max(1, round(0.1 / dt))  # first sends on the 10 Hz grid: everything within 0.1 s

    def _aligned(self, now: float, iv: float, first: bool = False) -> float:
        steps = max(1, round(iv / self.dt))
        if first:
            steps = min(steps, self._grid)
        k_now = round(now / self.dt)
        return (k_now + 1 + (self._phase - k_now - 1) % steps) * self.dt

    def set_rate(self, name: str, hz: float, now: float, first: bool = False) -> None:
        if not hz > 0 or not math.isfinite(hz):
            self.interval[name] = 0.0
            self.next_due.pop(name, None)
        else:
            iv = max(1.0 / hz, self.dt)
            self.interval[name] = iv
            t = self._aligned(now, iv, first)
            start = self.start_at.get(name, -math.inf)
            if start > t:
                t = self._aligned(start - self.dt, iv, True)
            self.next_due[name] = t
        self.next_any = min(self.next_due.values(), default=math.inf)

    def set_interval_us(self, name: str, interval_us: float, now: float, default_hz: float) -> None:
        """SET_MESSAGE_INTERVAL semantics: -1 off, 0 the default, else microseconds."""
        if interval_us < 0:
            self.set_rate(name, 0.0, now)
        elif interval_us == 0:
            self.set_rate(name, default_hz, now)
        else:
            self.set_rate(name, 1e6 / interval_us, now)

    def hz(self, name: str) -> float:
        iv = self.interval.get(name, 0.0)
        return 1.0 / iv if iv > 0 else 0.0

    def interval_us(self, name: str) -> int:
        iv = self.interval.get(name, 0.0)
        return int(round(iv * 1e6)) if iv > 0 else -1

    def due(self, now: float) -> list[str]:
        if now + 1e-9 < self.next_any:
            return []
        out = []
        nd = self.next_due
        for name, t in nd.items():
            if now + 1e-9 >= t:
                out.append(name)
                iv = self.interval[name]
                nt = t + iv
                nd[name] = nt if nt > now else now + iv
        self.next_any = min(nd.values())
        return out
