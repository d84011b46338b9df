"""Stick input: MANUAL_CONTROL and RC_CHANNELS_OVERRIDE move the vehicle in the stick modes.

A ground station's joystick reaches PX4 as MANUAL_CONTROL (QGroundControl, MAVSDK's
ManualControl) and ArduCopter as RC_CHANNELS_OVERRIDE (MAVProxy's ``rc 3 1700``). Both become
one :class:`Sticks` value. In the stick modes (``Guidance.STICKS``: PX4 POSCTL/ALTCTL,
ArduCopter LOITER/POSHOLD/ALT_HOLD) a deflected stick commands a velocity, as PX4's position
mode and ArduCopter's LOITER do: full forward stick flies at MPC_VEL_MANUAL / LOIT_SPEED, full
throttle climbs at MPC_Z_VEL_MAX_UP / PILOT_SPEED_UP; a centred stick brakes and holds where the
vehicle stops. No stick message for COM_RC_LOSS_T / RC_OVERRIDE_TIME while flying in a stick
mode is a lost stick stream: the vehicle holds and runs NAV_RCL_ACT / FS_THR_ENABLE.

Units: sticks are fractions of full deflection, -1..1; PWM in microseconds; speeds in m/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from uav_stack.mav import mavlink

M = mavlink
INT16_MAX = 32767  # MANUAL_CONTROL: this axis is invalid
RC_IGNORE = 65535  # RC_CHANNELS_OVERRIDE: leave this channel as it is
RC_RELEASE = 0  # ... hand it back to the RC receiver (there is none: centred)
RC_MIN, RC_TRIM, RC_MAX = 1100, 1500, 1900  # ArduCopter SITL's RCn_MIN/TRIM/MAX, us
RC_DZ = 20  # RC1_DZ, RC2_DZ, RC4_DZ: roll, pitch and yaw dead zone, us
THR_DZ = 100  # ArduCopter THR_DZ: throttle dead zone around mid stick, on its 0..1000 scale
STICK_DZ = 0.1  # PX4 MPC_HOLD_DZ: MANUAL_CONTROL dead zone, fraction of full stick


@dataclass(frozen=True)
class Sticks:
    """Stick deflections, each -1..1 (0 = centred)."""

    forward: float = 0.0  # pitch stick: + flies forward (nose down)
    right: float = 0.0  # roll stick: + flies right
    up: float = 0.0  # throttle around mid stick: + climbs
    yaw: float = 0.0  # yaw stick: + turns clockwise

    @property
    def centred(self) -> bool:
        return self.forward == 0.0 and self.right == 0.0 and self.up == 0.0 and self.yaw == 0.0


CENTRED = Sticks()


def _clamp(x: float) -> float:
    return max(-1.0, min(1.0, x)) if math.isfinite(x) else 0.0


def _dead(x: float, dz: float) -> float:
    """A dead zone around 0, rescaled so that full stick stays 1."""
    if abs(x) <= dz:
        return 0.0
    return math.copysign((abs(x) - dz) / (1.0 - dz), x)


def from_manual_control(m: mavlink.MAVLink_message) -> Sticks:
    """MANUAL_CONTROL: x forward, y right, r clockwise in -1000..1000; z thrust 0..1000 (500 = hover).

    An axis of INT16_MAX is invalid (treated as centred).
    """

    def axis(v: int, scale: float = 1000.0, offset: float = 0.0) -> float:
        return 0.0 if v == INT16_MAX else _dead(_clamp((v - offset) / scale), STICK_DZ)

    return Sticks(forward=axis(m.x), right=axis(m.y), up=axis(m.z, 500.0, 500.0), yaw=axis(m.r))


@dataclass
class RcOverride:
    """The latest RC_CHANNELS_OVERRIDE values of channels 1-4 (roll, pitch, throttle, yaw), us; 0 = none."""

    pwm: list[int] = field(default_factory=lambda: [0, 0, 0, 0])

    def update(self, m: mavlink.MAVLink_message) -> Sticks:
        """Apply one override message (UINT16_MAX keeps a channel, 0 releases it) and read the sticks."""
        for k, v in enumerate((m.chan1_raw, m.chan2_raw, m.chan3_raw, m.chan4_raw)):
            if v != RC_IGNORE:
                self.pwm[k] = v if RC_MIN - 200 <= v <= RC_MAX + 200 else RC_RELEASE
        return self.sticks()

    def sticks(self) -> Sticks:
        roll, pitch, thr, yaw = (RC_TRIM if v == RC_RELEASE else v for v in self.pwm)
        return Sticks(forward=-_rc(pitch), right=_rc(roll), up=_throttle(thr), yaw=_rc(yaw))


def _rc(pwm: int) -> float:
    """A centred channel (roll, pitch, yaw) as -1..1 with RCn_DZ."""
    d = pwm - RC_TRIM
    if abs(d) <= RC_DZ:
        return 0.0
    span = (RC_MAX - RC_TRIM) - RC_DZ
    return _clamp(math.copysign(abs(d) - RC_DZ, d) / span)


def _throttle(pwm: int) -> float:
    """ArduCopter's climb-rate stick: 0..1000 over RC3_MIN..MAX, THR_DZ around mid stick."""
    thr = (min(max(pwm, RC_MIN), RC_MAX) - RC_MIN) * 1000.0 / (RC_MAX - RC_MIN)
    mid = 500.0
    if thr > mid + THR_DZ:
        return (thr - mid - THR_DZ) / (1000.0 - mid - THR_DZ)
    if thr < mid - THR_DZ:
        return (thr - (mid - THR_DZ)) / (mid - THR_DZ)
    return 0.0


@dataclass
class StickStream:
    """Stick input of one vehicle on sim time: the latest value, when it came, whether it was lost."""

    sticks: Sticks = CENTRED
    last: float = -math.inf  # sim time of the latest stick message
    count: int = 0
    rc: RcOverride = field(default_factory=RcOverride)
    lost: bool = False  # latched: the stream stopped while flying in a stick mode

    def note(self, sticks: Sticks, now: float) -> None:
        self.sticks = sticks
        self.last = now
        self.count += 1
        self.lost = False

    def fresh(self, now: float, loss_t: float) -> bool:
        return now - self.last <= loss_t

    def current(self, now: float, loss_t: float) -> Sticks:
        """What the sticks say now: centred once the stream is older than ``loss_t``."""
        return self.sticks if self.fresh(now, loss_t) else CENTRED


@dataclass(frozen=True)
class StickCommand:
    """A stick value as the vehicle's setpoints: NED velocity (m/s) and yaw rate (rad/s)."""

    vn: float
    ve: float
    vd: float
    yaw_rate: float
    moving_xy: bool
    moving_z: bool


def command(s: Sticks, yaw: float, vxy: float, vz_up: float, vz_dn: float, yaw_rate_max: float) -> StickCommand:
    """Sticks (body frame: forward/right) -> NED velocity at the vehicle's heading ``yaw`` (rad)."""
    c, sn = math.cos(yaw), math.sin(yaw)
    fwd, right = s.forward * vxy, s.right * vxy
    vd = -s.up * (vz_up if s.up > 0 else vz_dn)
    return StickCommand(
        vn=c * fwd - sn * right,
        ve=sn * fwd + c * right,
        vd=vd,
        yaw_rate=s.yaw * yaw_rate_max,
        moving_xy=s.forward != 0.0 or s.right != 0.0,
        moving_z=s.up != 0.0,
    )
