"""The parameter set of each flavour, its wire encoding, and the settings it drives.

Every parameter here changes behaviour (or is a fixed fact a GCS expects, like
COM_RC_IN_MODE=4 "no RC"). The vehicle reads the derived ``Settings`` (SI units, internal
action enums), rebuilt whenever a parameter is set.

Wire encoding (PARAM_VALUE/PARAM_SET): PX4 uses "bytewise" (an INT32 parameter's bit
pattern is carried in the float field), ArduPilot a C cast (float value of the integer).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field, replace
from enum import Enum

from uav_stack.fcu.dynamics import MultirotorParams
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
_INT_RANGE = {INT8: (-128, 127), INT16: (-32768, 32767), INT32: (-(2**31), 2**31 - 1)}


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
    gps_fix_t: float = 1.0  # sim seconds from boot to the first 3D fix (position, home, health)
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


def px4_param_defs(mp: MultirotorParams, sysid: int) -> list[ParamDef]:
    P = ParamDef
    return [
        P("MIS_TAKEOFF_ALT", 2.5, role="takeoff_alt", min=0.0, max=1000.0),
        P("MPC_XY_CRUISE", mp.xy_cruise, role="xy_cruise", min=0.1, max=50.0),
        P("MPC_XY_VEL_MAX", mp.xy_vel_max, role="xy_vel_max", min=0.1, max=50.0),
        P("MPC_Z_VEL_MAX_UP", mp.z_vel_up, role="z_vel_up", min=0.1, max=20.0),
        P("MPC_Z_VEL_MAX_DN", mp.z_vel_dn, role="z_vel_dn", min=0.1, max=20.0),
        P("MPC_ACC_HOR", mp.acc_hor, role="acc_hor", min=0.1, max=30.0),
        P("MPC_TILTMAX_AIR", mp.tilt_max_deg, role="tilt_max_deg", min=5.0, max=89.0),
        P("MPC_LAND_SPEED", mp.land_speed, role="land_speed", min=0.05, max=20.0),
        P("MPC_LAND_ALT2", mp.land_alt_slow, role="land_alt_slow", min=0.0, max=1000.0),
        P("MPC_TKO_SPEED", mp.takeoff_speed, role="tko_speed", min=0.1, max=20.0),
        P("MPC_YAWRAUTO_MAX", mp.yaw_rate_max_deg, role="yaw_rate_max_deg", min=1.0, max=1000.0),
        P("RTL_RETURN_ALT", 60.0, role="rtl_alt", min=0.0, max=1000.0),
        P("COM_OF_LOSS_T", 1.0, role="of_loss_t", min=0.0, max=3600.0),
        P("COM_OBL_RC_ACT", 5, INT32, role="of_loss_act", actions=_PX4_OBL),
        # emulator: seconds of > 2 Hz setpoint stream before OFFBOARD is allowed (PX4 docs: 1 s);
        # 0 = PX4's code: one setpoint younger than COM_OF_LOSS_T is enough
        P("SIM_OFB_STREAM_T", 0.0, role="of_stream_s", min=0.0, max=60.0),
        P("COM_DISARM_LAND", 2.0, role="disarm_land_s", min=-1.0, max=3600.0),
        P("COM_DISARM_PRFLT", 10.0, role="disarm_prflt_s", min=-1.0, max=3600.0),
        P("NAV_DLL_ACT", 0, INT32, role="dll_act", actions=_PX4_DLL),
        P("COM_DL_LOSS_T", 10, INT32, role="dll_t", min=1, max=3600),
        P("COM_LOW_BAT_ACT", 0, INT32, role="px4_low_bat_act", min=0, max=3),
        P("BAT_LOW_THR", 0.15, role="bat_low", min=0.0, max=1.0),
        P("BAT_CRIT_THR", 0.07, role="bat_crit", min=0.0, max=1.0),
        P("BAT_EMERGEN_THR", 0.05, role="bat_emerg", min=0.0, max=1.0),
        P("GF_ACTION", 2, INT32, role="gf_action", actions=_PX4_GF),
        P("GF_MAX_HOR_DIST", 0.0, role="gf_hor", min=0.0, max=1e6),
        P("GF_MAX_VER_DIST", 0.0, role="gf_ver", min=0.0, max=1e5),
        P("MAV_SYS_ID", sysid, INT32, min=1, max=255),  # takes effect after a reboot (never, here)
        P("MAV_TYPE", mavlink.MAV_TYPE_QUADROTOR, INT32),
        # stick input: MANUAL_CONTROL (there is no RC receiver); 4 = none, 0 = RC only (so none either)
        P("COM_RC_IN_MODE", 3, INT32, role="stick_input", min=0, max=4),
        P("COM_RC_LOSS_T", 0.5, role="rc_loss_t", min=0.1, max=35.0),
        P("NAV_RCL_ACT", 2, INT32, role="rc_loss_act", actions=_PX4_RCL),
        P("MPC_VEL_MANUAL", 10.0, role="vel_manual", min=0.5, max=50.0),
        P("NAV_ACC_RAD", 2.0, role="acc_rad", min=0.05, max=200.0),
        P("NAV_MC_ALT_RAD", 0.8, role="alt_rad", min=0.05, max=200.0),
        P("SIM_BAT_DRAIN", mp.battery_endurance_s, role="endurance_s", min=1.0, max=1e6),  # emulator: s to drain
        P("SIM_GPS_FIX_T", 1.0, role="gps_fix_t", min=0.0, max=600.0),  # emulator: s from boot to the first fix
    ]


def ardupilot_param_defs(mp: MultirotorParams, sysid: int) -> list[ParamDef]:
    P = ParamDef
    cm = 0.01
    return [
        P("SYSID_THISMAV", sysid, INT16, min=1, max=255),
        P("WPNAV_SPEED", mp.xy_cruise * 100, role="xy_cruise", scale=cm, min=10, max=5000),
        P("WPNAV_SPEED_UP", mp.z_vel_up * 100, role="z_vel_up", scale=cm, min=10, max=2000),
        P("WPNAV_SPEED_DN", mp.z_vel_dn * 100, role="z_vel_dn", scale=cm, min=10, max=2000),
        P("WPNAV_ACCEL", mp.acc_hor * 100, role="acc_hor", scale=cm, min=10, max=3000),
        P("ANGLE_MAX", mp.tilt_max_deg * 100, INT16, role="tilt_max_deg", scale=cm, min=500, max=8000),
        P("ATC_RATE_Y_MAX", mp.yaw_rate_max_deg, role="yaw_rate_max_deg", min=1.0, max=1000.0),
        P("LAND_SPEED", mp.land_speed * 100, INT16, role="land_speed", scale=cm, min=5, max=2000),
        P("LAND_ALT_LOW", mp.land_alt_slow * 100, INT16, role="land_alt_slow", scale=cm, min=0),
        P("RTL_ALT", 1500, INT32, role="rtl_alt", scale=cm, min=0, max=100000),
        P("RTL_SPEED", 0, role="rtl_speed", scale=cm, min=0, max=5000),
        P("DISARM_DELAY", 10, INT8, role="disarm_prflt_s", min=0),
        P("FS_GCS_ENABLE", 0, INT8, role="dll_act", actions=_APM_GCS),
        P("FS_GCS_TIMEOUT", 5.0, role="dll_t", min=2.0, max=3600.0),
        P("FS_THR_ENABLE", 1, INT8, role="rc_loss_act", actions=_APM_THR),  # stick (RC override) loss
        P("RC_OVERRIDE_TIME", 3.0, role="rc_loss_t", min=0.1, max=120.0),
        P("LOIT_SPEED", 1250, role="vel_manual", scale=cm, min=20, max=3500),
        P("PILOT_SPEED_UP", 250, INT16, role="pilot_vz_up", scale=cm, min=50, max=500),
        P("PILOT_SPEED_DN", 0, INT16, role="pilot_vz_dn", scale=cm, min=0, max=500),
        P("WPNAV_RADIUS", 200, role="acc_rad", scale=cm, min=5, max=1000),
        P("BATT_LOW_VOLT", 14.4, role="bat_low", min=0.0, max=100.0),  # volts, converted to a charge fraction
        P("BATT_CRT_VOLT", 14.2, role="bat_crit", min=0.0, max=100.0),
        P("BATT_FS_LOW_ACT", 0, INT8, role="bat_low_act", actions=_APM_BATT),
        P("BATT_FS_CRT_ACT", 0, INT8, role="bat_crit_act", actions=_APM_BATT),
        P("FENCE_ENABLE", 0, INT8, role="fence_enable", min=0, max=1),
        P("FENCE_ACTION", 1, INT8, role="gf_action", actions=_APM_FENCE),
        P("FENCE_RADIUS", 300.0, role="gf_hor", min=30.0, max=1e6),
        P("FENCE_ALT_MAX", 100.0, role="gf_ver", min=10.0, max=1e5),
        P("GUID_TIMEOUT", 3.0, role="guided_timeout", min=0.1, max=3600.0),
        P("SIM_BAT_DRAIN", mp.battery_endurance_s, role="endurance_s", min=1.0, max=1e6),  # emulator: s to drain
        P("SIM_GPS_FIX_T", 1.0, role="gps_fix_t", min=0.0, max=600.0),  # emulator: s from boot to the first fix
    ]


def _soc_for_voltage(mp: MultirotorParams, volts: float) -> float:
    full, empty = mp.battery_cells * mp.cell_v_full, mp.battery_cells * mp.cell_v_empty
    return min(max((volts - empty) / (full - empty), 0.0), 1.0)


def derive_settings(flavour: str, values: dict[str, float], defs: list[ParamDef], mp: MultirotorParams) -> Settings:
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
    for d in defs:
        if d.role is None:
            continue
        raw = values[d.name]
        if d.actions is not None:
            upd[d.role] = d.actions.get(int(raw), Action.NONE)
        else:
            upd[d.role] = raw * d.scale
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
            bat_low=_soc_for_voltage(mp, s.bat_low),
            bat_crit=_soc_for_voltage(mp, s.bat_crit),
            bat_emerg=0.0,
            disarm_land_s=1.0,  # ArduCopter disarms right after landing in LAND/RTL
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


@dataclass
class ParamStore:
    """Values by name in a fixed order, with the flavour's PARAM_VALUE encoding."""

    defs: list[ParamDef]
    bytewise: bool
    values: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._index = {d.name: k for k, d in enumerate(self.defs)}
        for d in self.defs:
            self.values.setdefault(d.name, float(d.default))

    def __len__(self) -> int:
        return len(self.defs)

    def __contains__(self, name: str) -> bool:
        return name in self._index

    def index(self, name: str) -> int:
        return self._index[name]

    def get(self, name: str) -> float:
        return self.values[name]

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
        self.values[name] = value
        return True

    def encode(self, k: int) -> tuple[str, float, int]:
        """(param_id, wire value, MAV_PARAM_TYPE) of parameter number k."""
        d = self.defs[k]
        v = self.values[d.name]
        if d.ptype in _INT_TYPES and self.bytewise:
            return d.name, _i2f(int(v)), d.ptype
        return d.name, float(v), d.ptype

    def decode(self, name: str, wire_value: float, wire_type: int) -> float:
        """The value a PARAM_SET means (NaN if it cannot be decoded)."""
        d = self.defs[self._index[name]]
        if d.ptype in _INT_TYPES:
            if self.bytewise and wire_type in _INT_TYPES:
                return float(_f2i(wire_value))
            # C cast (ArduPilot, or a PX4 client that sent a float for an int parameter)
            return float(round(wire_value)) if math.isfinite(wire_value) else math.nan
        return float(wire_value)
