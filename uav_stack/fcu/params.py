"""The parameter set of each flavour, its wire encoding, and the settings it drives.

Each flavour lists its firmware's parameters, every one of them, with the firmware's names, index order,
types and factory defaults (uav_stack/fcu/firmware.py: 901 for PX4 1.16, 1338 for ArduCopter 4.7). A few of
them drive the emulation (``PX4_ROLES``, ``ARDUPILOT_ROLES``); the others are stored and echoed only. The
vehicle reads the derived ``Settings`` (SI units, internal action enums), rebuilt whenever a parameter is
set. The emulator's own settings (``hidden_param_defs``) are set from the configuration and never listed.

Wire encoding (PARAM_VALUE/PARAM_SET): PX4 uses "bytewise" (an integer parameter's bit
pattern is carried in the float field), ArduPilot a C cast (float value of the integer).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field, replace
from enum import Enum

from uav_stack.fcu.dynamics import MultirotorParams
from uav_stack.fcu.firmware import firmware
from uav_stack.mav import mavlink

REAL32 = mavlink.MAV_PARAM_TYPE_REAL32
INT32 = mavlink.MAV_PARAM_TYPE_INT32
INT16 = mavlink.MAV_PARAM_TYPE_INT16
INT8 = mavlink.MAV_PARAM_TYPE_INT8
_INT_TYPES = {
    mavlink.MAV_PARAM_TYPE_UINT8,
    mavlink.MAV_PARAM_TYPE_INT8,
    mavlink.MAV_PARAM_TYPE_UINT16,
    mavlink.MAV_PARAM_TYPE_INT16,
    mavlink.MAV_PARAM_TYPE_UINT32,
    mavlink.MAV_PARAM_TYPE_INT32,
}
UINT32 = mavlink.MAV_PARAM_TYPE_UINT32
_INT_RANGE = {INT8: (-128, 127), INT16: (-32768, 32767), INT32: (-(2**31), 2**31 - 1), UINT32: (0, 2**32 - 1),
              mavlink.MAV_PARAM_TYPE_UINT8: (0, 255), mavlink.MAV_PARAM_TYPE_UINT16: (0, 65535)}  # fmt: skip
ARDUPILOT_LAND_DISARM_S = 2.0  # ArduCopter disarms about 2 s after touching down in LAND/RTL (its land detector)


class Action(str, Enum):
    """What a failsafe does (internal; each flavour's parameter values map onto these)."""

    NONE = "none"
    WARN = "warn"
    HOLD = "hold"
    POSCTL = "posctl"  # PX4 position mode (hold-like without RC)
    ALTCTL = "altctl"
    RTL = "rtl"
    LAND = "land"
    TERMINATE = "terminate"  # motors off
    DISARM = "disarm"  # motors off (same as terminate here)


@dataclass(frozen=True)
class ParamDef:
    name: str
    default: float
    ptype: int = REAL32
    role: str | None = None  # Settings field it drives
    scale: float = 1.0  # settings value = raw * scale
    actions: dict[int, Action] | None = None  # enum parameters: raw value -> Action
    min: float = -math.inf
    max: float = math.inf
    hidden: bool = False  # the emulator's own: set from the configuration, not on the MAVLink parameter list


@dataclass
class Settings:
    """Behaviour-relevant values in SI units (metres, seconds, m/s, fractions)."""

    takeoff_alt: float = 2.5
    xy_cruise: float = 5.0
    xy_vel_max: float = 12.0
    z_vel_up: float = 3.0
    z_vel_dn: float = 1.5
    acc_hor: float = 3.0
    tilt_max_deg: float = 45.0
    land_speed: float = 0.7
    land_alt_slow: float = 5.0
    tko_speed: float = 1.5
    yaw_rate_max_deg: float = 60.0
    rtl_alt: float = 60.0
    rtl_speed: float = 0.0  # 0 = xy_cruise
    of_loss_t: float = 1.0
    of_loss_act: Action = Action.HOLD
    of_stream_s: float = 1.0
    disarm_land_s: float = 2.0  # <= 0 disables
    disarm_prflt_s: float = 10.0  # <= 0 disables
    dll_act: Action = Action.NONE
    dll_t: float = 10.0
    bat_low: float = 0.15
    bat_crit: float = 0.07
    bat_emerg: float = 0.05
    bat_low_act: Action = Action.WARN
    bat_crit_act: Action = Action.WARN
    bat_emerg_act: Action = Action.WARN
    gf_action: Action = Action.HOLD
    gf_hor: float = 0.0  # 0 = disabled
    gf_ver: float = 0.0
    guided_timeout: float = 3.0  # ArduPilot GUIDED velocity target timeout
    endurance_s: float = 1200.0
    acc_rad: float = 2.0  # mission: waypoint acceptance radius when an item gives none, m
    alt_rad: float = 0.8  # mission: vertical acceptance, m
    vel_manual: float = 10.0  # stick modes: horizontal speed at full stick, m/s
    pilot_vz_up: float = 0.0  # stick modes: climb at full stick, m/s (0 = z_vel_up)
    pilot_vz_dn: float = 0.0  # stick modes: descent at full stick, m/s (0 = the climb speed)
    stick_input: float = 1.0  # 0 = MANUAL_CONTROL / RC_CHANNELS_OVERRIDE ignored
    rc_loss_t: float = 0.5  # stick stream silent this long in a stick mode = lost, s
    rc_loss_act: Action = Action.RTL
    bat_floor: float = 0.0  # PX4's simulated battery never drains below this fraction (SIM_BAT_MIN_PCT)
    sysid: float = 1.0  # MAV_SYS_ID / MAV_SYSID: informative (a reboot would apply it)
    gcs_sysid: float = 255.0  # ArduPilot MAV_GCS_SYSID: only its heartbeats keep the GCS failsafe away
    # internal helpers for flavour-specific combinations
    px4_low_bat_act: int = 0
    fence_enable: float = 1.0


_PX4_OBL = {0: Action.POSCTL, 1: Action.ALTCTL, 2: Action.HOLD, 3: Action.RTL, 4: Action.LAND, 5: Action.HOLD,
            6: Action.TERMINATE, 7: Action.DISARM}  # fmt: skip
_PX4_DLL = {0: Action.NONE, 1: Action.HOLD, 2: Action.RTL, 3: Action.LAND, 5: Action.TERMINATE, 6: Action.DISARM}
_PX4_GF = {0: Action.NONE, 1: Action.WARN, 2: Action.HOLD, 3: Action.RTL, 4: Action.TERMINATE, 5: Action.LAND}
_APM_GCS = {0: Action.NONE, 1: Action.RTL, 2: Action.RTL, 3: Action.RTL, 4: Action.RTL, 5: Action.LAND, 6: Action.RTL,
            7: Action.LAND}  # fmt: skip
_APM_BATT = {0: Action.WARN, 1: Action.LAND, 2: Action.RTL, 3: Action.RTL, 4: Action.RTL, 5: Action.TERMINATE}
_PX4_RCL = {0: Action.NONE, 1: Action.HOLD, 2: Action.RTL, 3: Action.LAND, 5: Action.TERMINATE, 6: Action.DISARM}
_PX4_RC_IN = {0: 0.0, 1: 1.0, 2: 1.0, 3: 1.0, 4: 0.0}  # COM_RC_IN_MODE -> MAVLink sticks used (no RC receiver here)
_APM_THR = {0: Action.NONE, 1: Action.RTL, 2: Action.RTL, 3: Action.LAND, 4: Action.RTL, 5: Action.LAND, 6: Action.RTL,
            7: Action.LAND}  # fmt: skip
_APM_FENCE = {0: Action.WARN, 1: Action.RTL, 2: Action.LAND, 3: Action.RTL, 4: Action.HOLD, 5: Action.RTL}


@dataclass(frozen=True)
class Role:
    """What one firmware parameter drives: a Settings field (value * scale, or an action from its enum),
    and the values the emulator accepts for it."""

    role: str
    scale: float = 1.0
    actions: dict[int, Action] | None = None
    min: float = -math.inf
    max: float = math.inf


R = Role
# PX4 1.16 parameters the emulator flies by (their defaults are the firmware's, data/px4.json)
PX4_ROLES: dict[str, Role] = {
    "MIS_TAKEOFF_ALT": R("takeoff_alt", min=0.0, max=1000.0),
    "MPC_XY_CRUISE": R("xy_cruise", min=0.1, max=50.0),
    "MPC_XY_VEL_MAX": R("xy_vel_max", min=0.1, max=50.0),
    "MPC_Z_VEL_MAX_UP": R("z_vel_up", min=0.1, max=20.0),
    "MPC_Z_VEL_MAX_DN": R("z_vel_dn", min=0.1, max=20.0),
    "MPC_ACC_HOR": R("acc_hor", min=0.1, max=30.0),
    "MPC_TILTMAX_AIR": R("tilt_max_deg", min=5.0, max=89.0),
    "MPC_LAND_SPEED": R("land_speed", min=0.05, max=20.0),
    "MPC_LAND_ALT2": R("land_alt_slow", min=0.0, max=1000.0),
    "MPC_TKO_SPEED": R("tko_speed", min=0.1, max=20.0),
    "MPC_YAWRAUTO_MAX": R("yaw_rate_max_deg", min=1.0, max=1000.0),
    "RTL_RETURN_ALT": R("rtl_alt", min=0.0, max=1000.0),
    "COM_OF_LOSS_T": R("of_loss_t", min=0.0, max=3600.0),
    "COM_OBL_RC_ACT": R("of_loss_act", actions=_PX4_OBL),
    "COM_DISARM_LAND": R("disarm_land_s", min=-1.0, max=3600.0),
    "COM_DISARM_PRFLT": R("disarm_prflt_s", min=-1.0, max=3600.0),
    "NAV_DLL_ACT": R("dll_act", actions=_PX4_DLL),
    "COM_DL_LOSS_T": R("dll_t", min=1, max=3600),
    "COM_LOW_BAT_ACT": R("px4_low_bat_act", min=0, max=3),
    "BAT_LOW_THR": R("bat_low", min=0.0, max=1.0),
    "BAT_CRIT_THR": R("bat_crit", min=0.0, max=1.0),
    "BAT_EMERGEN_THR": R("bat_emerg", min=0.0, max=1.0),
    "GF_ACTION": R("gf_action", actions=_PX4_GF),
    "GF_MAX_HOR_DIST": R("gf_hor", min=0.0, max=1e6),
    "GF_MAX_VER_DIST": R("gf_ver", min=0.0, max=1e5),
    "MAV_SYS_ID": R("sysid", min=1, max=255),  # takes effect after a reboot (never, here)
    # stick input: MANUAL_CONTROL (there is no RC receiver); 4 = none, 0 = RC only (so none either)
    "COM_RC_IN_MODE": R("stick_input", min=0, max=4),
    "COM_RC_LOSS_T": R("rc_loss_t", min=0.1, max=35.0),
    "NAV_RCL_ACT": R("rc_loss_act", actions=_PX4_RCL),
    "MPC_VEL_MANUAL": R("vel_manual", min=0.5, max=50.0),
    "NAV_ACC_RAD": R("acc_rad", min=0.05, max=200.0),
    "NAV_MC_ALT_RAD": R("alt_rad", min=0.05, max=200.0),
    # PX4's simulated battery: drains while armed over SIM_BAT_DRAIN s, never below SIM_BAT_MIN_PCT, full when disarmed
    "SIM_BAT_DRAIN": R("endurance_s", min=1.0, max=1e6),
    "SIM_BAT_MIN_PCT": R("bat_floor", scale=0.01, min=0.0, max=100.0),
}

# ArduCopter 4.7 parameters the emulator flies by (cm-based ones converted; defaults from data/ardupilot_copter.json)
_CM = 0.01
ARDUPILOT_ROLES: dict[str, Role] = {
    "MAV_SYSID": R("sysid", min=1, max=255),
    "MAV_GCS_SYSID": R("gcs_sysid", min=1, max=255),
    "WPNAV_SPEED": R("xy_cruise", scale=_CM, min=10, max=5000),
    "WPNAV_SPEED_UP": R("z_vel_up", scale=_CM, min=10, max=2000),
    "WPNAV_SPEED_DN": R("z_vel_dn", scale=_CM, min=10, max=2000),
    "WPNAV_ACCEL": R("acc_hor", scale=_CM, min=10, max=3000),
    "ANGLE_MAX": R("tilt_max_deg", scale=_CM, min=500, max=8000),
    "ATC_RATE_Y_MAX": R("yaw_rate_max_deg", min=0.0, max=1080.0),  # 0: no limit of its own (the default)
    "LAND_SPEED": R("land_speed", scale=_CM, min=5, max=2000),
    "LAND_ALT_LOW": R("land_alt_slow", scale=_CM, min=0),
    "RTL_ALT": R("rtl_alt", scale=_CM, min=0, max=100000),
    "RTL_SPEED": R("rtl_speed", scale=_CM, min=0, max=5000),
    "DISARM_DELAY": R("disarm_prflt_s", min=0),
    "FS_GCS_ENABLE": R("dll_act", actions=_APM_GCS),
    "FS_GCS_TIMEOUT": R("dll_t", min=2.0, max=3600.0),
    "FS_THR_ENABLE": R("rc_loss_act", actions=_APM_THR),  # stick (RC override) loss
    "RC_OVERRIDE_TIME": R("rc_loss_t", min=0.1, max=120.0),
    "LOIT_SPEED": R("vel_manual", scale=_CM, min=20, max=3500),
    "PILOT_SPEED_UP": R("pilot_vz_up", scale=_CM, min=50, max=500),
    "PILOT_SPEED_DN": R("pilot_vz_dn", scale=_CM, min=0, max=500),
    "WPNAV_RADIUS": R("acc_rad", scale=_CM, min=5, max=1000),
    "BATT_LOW_VOLT": R("bat_low", min=0.0, max=100.0),  # volts, converted to a charge fraction
    "BATT_CRT_VOLT": R("bat_crit", min=0.0, max=100.0),
    "BATT_FS_LOW_ACT": R("bat_low_act", actions=_APM_BATT),
    "BATT_FS_CRT_ACT": R("bat_crit_act", actions=_APM_BATT),
    "FENCE_ENABLE": R("fence_enable", min=0, max=1),
    "FENCE_ACTION": R("gf_action", actions=_APM_FENCE),
    "FENCE_RADIUS": R("gf_hor", min=30.0, max=1e6),
    "FENCE_ALT_MAX": R("gf_ver", min=10.0, max=1e5),
    "GUID_TIMEOUT": R("guided_timeout", min=0.1, max=3600.0),
}


def hidden_param_defs(flavour: str, mp: MultirotorParams) -> list[ParamDef]:
    """The emulator's own settings in parameter form: set from the configuration (VehicleConfig.params,
    ``--param``), not on the firmware's parameter list (a ground station never sees them)."""
    P = ParamDef
    if flavour == "px4":
        # seconds of > 2 Hz setpoint stream before OFFBOARD is allowed (PX4 docs: 1 s);
        # 0 = PX4's code: one setpoint younger than COM_OF_LOSS_T is enough
        return [P("SIM_OFB_STREAM_T", 0.0, role="of_stream_s", min=0.0, max=60.0, hidden=True)]
    return [P("SIM_BAT_DRAIN", mp.battery_endurance_s, role="endurance_s", min=1.0, max=1e6, hidden=True)]


def param_defs(flavour: str, mp: MultirotorParams, sysid: int) -> list[ParamDef]:
    """Every parameter of a flavour: the firmware's own, in its index order with its types and defaults
    (the behaviour ones with their Role), then the emulator's hidden ones."""
    roles = PX4_ROLES if flavour == "px4" else ARDUPILOT_ROLES
    defs: list[ParamDef] = []
    for p in firmware(flavour).params:
        r = roles.get(p.name)
        default = float(sysid) if r is not None and r.role == "sysid" else p.default
        if r is None:
            defs.append(ParamDef(p.name, default, p.ptype))
        else:
            defs.append(ParamDef(p.name, default, p.ptype, r.role, r.scale, r.actions, r.min, r.max))
    missing = set(roles) - {d.name for d in defs}
    assert not missing, f"{flavour}: roles for parameters the firmware does not have: {sorted(missing)}"
    return defs + hidden_param_defs(flavour, mp)


def _soc_for_voltage(mp: MultirotorParams, volts: float) -> float:
    full, empty = mp.battery_cells * mp.cell_v_full, mp.battery_cells * mp.cell_v_empty
    return min(max((volts - empty) / (full - empty), 0.0), 1.0)


def derive_settings(flavour: str, store: ParamStore, mp: MultirotorParams) -> Settings:
    s = Settings(
        xy_cruise=mp.xy_cruise,
        xy_vel_max=mp.xy_vel_max,
        z_vel_up=mp.z_vel_up,
        z_vel_dn=mp.z_vel_dn,
        acc_hor=mp.acc_hor,
        tilt_max_deg=mp.tilt_max_deg,
        land_speed=mp.land_speed,
        land_alt_slow=mp.land_alt_slow,
        tko_speed=mp.takeoff_speed,
        yaw_rate_max_deg=mp.yaw_rate_max_deg,
        endurance_s=mp.battery_endurance_s,
    )
    upd: dict[str, object] = {}
    for d in store.role_defs:
        raw = store.get(d.name)
        if d.actions is not None:
            upd[d.role] = d.actions.get(int(raw), Action.NONE)  # type: ignore[index]
        else:
            upd[d.role] = raw * d.scale  # type: ignore[index]
    s = replace(s, **upd)  # type: ignore[arg-type]
    if flavour == "px4":
        act = int(s.px4_low_bat_act)
        crit, emerg = {0: (Action.WARN, Action.WARN), 1: (Action.RTL, Action.RTL), 2: (Action.LAND, Action.LAND),
                       3: (Action.RTL, Action.LAND)}.get(act, (Action.WARN, Action.WARN))  # fmt: skip
        s = replace(s, bat_low_act=Action.WARN, bat_crit_act=crit, bat_emerg_act=emerg,
                    stick_input=_PX4_RC_IN.get(int(s.stick_input), 0.0), pilot_vz_up=s.z_vel_up, pilot_vz_dn=s.z_vel_dn)
    else:
        s = replace(
            s,
            tko_speed=s.z_vel_up,
            yaw_rate_max_deg=s.yaw_rate_max_deg if s.yaw_rate_max_deg > 0 else mp.yaw_rate_max_deg,
            bat_low=_soc_for_voltage(mp, s.bat_low),
            bat_crit=_soc_for_voltage(mp, s.bat_crit),
            bat_emerg=0.0,
            bat_floor=0.0,
            disarm_land_s=ARDUPILOT_LAND_DISARM_S,
            gf_hor=s.gf_hor if s.fence_enable else 0.0,
            gf_ver=s.gf_ver if s.fence_enable else 0.0,
            of_loss_act=Action.NONE,
            alt_rad=s.acc_rad,  # ArduCopter: one radius, in three dimensions
            pilot_vz_dn=s.pilot_vz_dn or s.pilot_vz_up,
        )
    return s


def _i2f(i: int) -> float:
    return struct.unpack("<f", struct.pack("<i", i))[0]


def _f2i(f: float) -> int:
    return struct.unpack("<i", struct.pack("<f", f))[0]


def _u2f(u: int) -> float:
    return struct.unpack("<f", struct.pack("<I", u & 0xFFFFFFFF))[0]


def _f2u(f: float) -> int:
    return struct.unpack("<I", struct.pack("<f", f))[0]


@dataclass
class ParamStore:
    """Values by name in the firmware's order, with the flavour's PARAM_VALUE encoding.

    Defaults are shared (``defs``); a vehicle stores only the values set since boot. Hidden
    (emulator) parameters come after the firmware's and are invisible on MAVLink.
    """

    defs: list[ParamDef]
    bytewise: bool
    _set: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._index = {d.name: k for k, d in enumerate(self.defs)}
        self.listed = sum(1 for d in self.defs if not d.hidden)  # MAVLink's param_count
        self.role_defs = [d for d in self.defs if d.role is not None]

    def __len__(self) -> int:
        return self.listed

    def __contains__(self, name: str) -> bool:
        """A parameter of the configuration (the firmware's or the emulator's)."""
        return name in self._index

    def on_mavlink(self, name: str) -> int | None:
        """The index of a parameter a ground station can see, or None."""
        k = self._index.get(name)
        return k if k is not None and k < self.listed else None

    def index(self, name: str) -> int:
        return self._index[name]

    def get(self, name: str) -> float:
        v = self._set.get(name)
        return v if v is not None else float(self.defs[self._index[name]].default)

    def changed(self) -> dict[str, float]:
        """Values set since boot that differ from the defaults."""
        return {n: v for n, v in self._set.items() if v != self.defs[self._index[n]].default}

    def set(self, name: str, value: float) -> bool:
        """Set a value (already decoded); False if unknown, NaN or out of range."""
        k = self._index.get(name)
        if k is None or not math.isfinite(value):
            return False
        d = self.defs[k]
        if d.ptype in _INT_TYPES:
            value = float(round(value))
            lo, hi = _INT_RANGE.get(d.ptype, (-(2**31), 2**31 - 1))
            if not lo <= value <= hi:
                return False
        if not d.min <= value <= d.max:
            return False
        self._set[name] = value
        return True

    def encode(self, k: int) -> tuple[str, float, int]:
        """(param_id, wire value, MAV_PARAM_TYPE) of parameter number k."""
        d = self.defs[k]
        return d.name, self.wire(self.get(d.name), d.ptype), d.ptype

    def wire(self, value: float, ptype: int) -> float:
        if ptype in _INT_TYPES and self.bytewise:
            return _u2f(int(value)) if ptype == UINT32 else _i2f(int(value))
        return float(value)

    def decode(self, name: str, wire_value: float, wire_type: int) -> float:
        """The value a PARAM_SET means (NaN if it cannot be decoded)."""
        d = self.defs[self._index[name]]
        if d.ptype in _INT_TYPES:
            if self.bytewise and wire_type in _INT_TYPES:
                return float(_f2u(wire_value) if d.ptype == UINT32 else _f2i(wire_value))
            # C cast (ArduPilot, or a PX4 client that sent a float for an int parameter)
            return float(round(wire_value)) if math.isfinite(wire_value) else math.nan
        return float(wire_value)
