"""One virtual vehicle: mode state machine, arming, guidance into the shared dynamics arrays,
the 10 Hz supervisor (takeoff/RTL/land progress, auto-disarm, failsafes) and its link.
The mission it flies is mission.py's, the stick input manual.py's.

Everything time-related runs on the fleet's sim clock (``ctx.clock.sim_time``), except the
link-level heartbeat floor and peer bookkeeping, which use wall time.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from uav_stack.fcu.clock import SimClock
from uav_stack.fcu.config import VehicleConfig
from uav_stack.fcu.dynamics import BATTERY, LANDED, POS, G, MultirotorArray
from uav_stack.fcu.link import DatagramParser, UdpLink
from uav_stack.fcu.manual import CENTRED, Sticks, StickStream, command
from uav_stack.fcu.mission import MissionItem, MissionRun
from uav_stack.fcu.modes import (
    P_HOLD,
    P_LAND,
    P_OFFBOARD,
    P_RTL_CLIMB,
    P_RTL_RETURN,
    P_STICKS,
    P_TAKEOFF,
    TAKEOFF_DONE_M,
    Guidance,
    ModeSpec,
    get_flavour,
)
from uav_stack.fcu.offboard import Setpoint, SetpointStream
from uav_stack.fcu.params import Action, ParamStore, Settings, ardupilot_param_defs, derive_settings, px4_param_defs
from uav_stack.fcu.stats import FcuStats
from uav_stack.fcu.telemetry import ENCODERS, FRAMERS, StreamSet, heartbeat
from uav_stack.geo import GeoPoint, LocalFrame
from uav_stack.mav import mavlink
from uav_stack.mavcodec import pack

M = mavlink
NAN = math.nan
ACCEPTED = M.MAV_RESULT_ACCEPTED
DENIED = M.MAV_RESULT_DENIED
FAILED = M.MAV_RESULT_FAILED


RTL_ARRIVED_M = 0.7  # horizontal distance to home at which RTL starts landing


@dataclass
class FleetContext:
    """What all vehicles of one FCU share."""

    clock: SimClock
    dyn: MultirotorArray
    stats: FcuStats
    rtf: Callable[[], float]
    wall: Callable[[], float]
    unix_at_start: float
    log: logging.Logger


class Vehicle:
    def __init__(self, i: int, cfg: VehicleConfig, ctx: FleetContext, stream_rates: dict[str, float], link: UdpLink):
        self.i = i
        self.cfg = cfg
        self.ctx = ctx
        self.link = link
        self.sysid = int(cfg.sysid)
        self.compid = M.MAV_COMP_ID_AUTOPILOT1
        self.flavour = get_flavour(cfg.flavour)
        self.mav = M.MAVLink(None, self.sysid, self.compid)
        self.parser = DatagramParser()
        self.frame = LocalFrame(cfg.home)  # local NED origin = initial home (EKF origin)
        self.home: GeoPoint = cfg.home
        self.home_ned = np.zeros(3)
        mp = ctx.dyn.params
        defs = (px4_param_defs if self.flavour.is_px4 else ardupilot_param_defs)(mp, self.sysid)
        self.params = ParamStore(defs, bytewise=self.flavour.bytewise_params)
        for name, value in cfg.params.items():
            if name not in self.params:
                raise ValueError(f"sysid {self.sysid}: unknown {self.flavour.name} parameter {name!r}")
            if not self.params.set(name, float(value)):
                raise ValueError(f"sysid {self.sysid}: invalid value {value!r} for parameter {name!r}")
        self.settings: Settings = derive_settings(self.flavour.name, self.params.values, defs, mp)
        self.streams = StreamSet(stream_rates, stream_rates, ctx.clock.dt, phase=7 * i)
        self.hb_interval_wall = 1.0 / stream_rates["HEARTBEAT"] if stream_rates.get("HEARTBEAT", 0) > 0 else 1.0
        self.next_hb_wall = 0.0
        # state
        self.mode: ModeSpec = self.flavour.mode(self.flavour.initial_mode)
        self.phase = P_HOLD
        self.armed = False
        self.has_flown = False
        self.landed_since: float | None = None
        self.takeoff_target = np.zeros(3)
        self.takeoff_alt_amsl = NAN  # requested takeoff altitude (PX4 NAV_TAKEOFF), NaN = MIS_TAKEOFF_ALT
        self.takeoff_yaw = NAN
        self.speed_xy = NAN  # DO_CHANGE_SPEED / DO_REPOSITION override for the current mode
        self.speed_up = NAN
        self.speed_dn = NAN
        self.rtl_z = 0.0
        self.setpoints = SetpointStream()
        self.guided_vel = False  # ArduPilot: current GUIDED target is a velocity (times out)
        self.gcs_last: float | None = None
        self.dll_tripped = False
        self.bat_level = 0  # 0 ok, 1 low, 2 critical, 3 emergency (latched)
        self.fence_breached = False
        self.missions: dict[int, list[MissionItem]] = {0: [], 1: [], 2: []}  # by MAV_MISSION_TYPE
        self.upload: dict[str, object] | None = None
        self.mission = MissionRun(self)
        self.sticks = StickStream()
        self._sticks_in_mode = False  # a stick message arrived since the stick mode was entered
        self._stick_xy_held = self._stick_z_held = False  # holding the braking point, per axis
        self.after_ack: list[mavlink.MAVLink_message] = []
        self.in_command = False  # a COMMAND_LONG/INT is being handled (its ACK not yet sent)
        self.hb_after_ack = False
        self._geo_cache: tuple[int, tuple[float, float, float]] = (-1, (0.0, 0.0, 0.0))
        # error of the position estimate the FCU reports (north, east, down, m); zero unless a fault
        # is injected (uav_stack/sim_faults.py: a GPS glitch). Guidance and physics use the truth.
        self.position_error: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.msg_cache: dict[str, mavlink.MAVLink_message] = {}  # reused instances of high-rate messages
        d = ctx.dyn
        d.yaw[i] = cfg.yaw
        d.pos_sp[i] = d.pos[i]
        self.apply_settings()

    # ----------------------------------------------------------------- basics
    @property
    def now(self) -> float:
        return self.ctx.clock.sim_time

    @property
    def landed(self) -> bool:
        return bool(self.ctx.dyn.get(LANDED, self.i))

    @property
    def fence_enabled(self) -> bool:
        return self.settings.gf_hor > 0 or self.settings.gf_ver > 0

    @property
    def failsafe_active(self) -> bool:
        return self.dll_tripped or self.fence_breached or self.bat_level >= 2

    def send(self, msg: mavlink.MAVLink_message) -> None:
        self.send_frame(pack(msg, self.mav))

    def send_frame(self, frame: bytes) -> None:
        """A frame packed with this vehicle's next sequence number (by :meth:`send`, or whole by telemetry.FRAMERS)."""
        mav = self.mav
        mav.seq = (mav.seq + 1) & 0xFF
        self.link.queue(frame)
        self.ctx.stats.messages_out += 1

    def send_heartbeat(self) -> None:
        if self.in_command:  # after the COMMAND_ACK, like PX4 (its next heartbeat shows the change)
            self.hb_after_ack = True
            return
        self.send(heartbeat(self))
        self.next_hb_wall = self.ctx.wall() + self.hb_interval_wall

    def statustext(self, severity: int, text: str) -> None:
        self.send(self.mav.statustext_encode(severity, text.encode()[:50]))

    def geodetic(self) -> tuple[float, float, float]:
        step = self.ctx.clock.steps
        if self._geo_cache[0] != step:
            n, e, dn = self.ctx.dyn.get(POS, self.i)
            self._geo_cache = (step, self.frame.to_geodetic(e, n, -dn))
        return self._geo_cache[1]

    def reported_geodetic(self) -> tuple[float, float, float]:
        """The position the FCU reports: :meth:`geodetic` plus :attr:`position_error`."""
        dn, de, dd = self.position_error
        if dn == 0.0 and de == 0.0 and dd == 0.0:
            return self.geodetic()
        n, e, d = self.ctx.dyn.pos[self.i].tolist()
        return self.frame.to_geodetic(e + de, n + dn, -(d + dd))

    def ned_of(self, lat: float, lon: float, alt: float) -> np.ndarray:
        e, n, u = self.frame.to_enu(lat, lon, alt)
        return np.array([n, e, -u])

    def alt_to_z(self, alt_amsl: float) -> float:
        return self.frame.origin.alt - alt_amsl

    def battery_readings(self) -> tuple[float, float, int]:
        d, i = self.ctx.dyn, self.i
        soc = d.get(BATTERY, i)
        volts = d.params.voltage(soc)
        amps = 0.0
        if self.armed:
            amps = d.params.hover_current_a() * (d.params.battery_idle_fraction if self.landed else 1.0)
        return volts, amps, int(round(soc * 100))

    @property
    def gps_ok(self) -> bool:
        """The first 3D fix has come (SIM_GPS_FIX_T after boot): position, home and health are known."""
        return self.now >= self.settings.gps_fix_t

    @property
    def sticks_fresh(self) -> bool:
        s = self.settings
        return bool(s.stick_input) and self.sticks.fresh(self.now, s.rc_loss_t)

    def prearm_ok(self) -> bool:
        return self.gps_ok and self.ctx.dyn.get(BATTERY, self.i) > self.settings.bat_emerg

    def offboard_ready(self) -> bool:
        """PX4 entry rule for OFFBOARD (see offboard.py; SIM_OFB_STREAM_T = 0 relaxes it)."""
        s = self.settings
        return self.setpoints.active(self.now, s.of_stream_s, s.of_loss_t)

    def landed_state(self) -> int:
        if self.landed:
            return M.MAV_LANDED_STATE_ON_GROUND
        if self.phase == P_TAKEOFF:
            return M.MAV_LANDED_STATE_TAKEOFF
        if self.phase == P_LAND:
            return M.MAV_LANDED_STATE_LANDING
        return M.MAV_LANDED_STATE_IN_AIR

    def send_due_telemetry(self, now: float) -> None:
        st = self.streams
        if now + 1e-9 < st.next_any:
            return
        for name in st.due(now):
            if name == "HEARTBEAT":
                continue  # paced on wall time, see VirtualFcu.service
            framer = FRAMERS.get(name)
            if framer is not None:
                frame = framer(self)  # the whole frame in one compiled call, when it can
                if frame is not None:
                    self.send_frame(frame)
                    continue
            msg = ENCODERS[name](self)
            if msg is not None:  # None: nothing to say yet (no position before the first fix)
                self.send(msg)

    # --------------------------------------------------------------- settings
    def apply_settings(self) -> None:
        s = self.settings
        d, i = self.ctx.dyn, self.i
        d.acc_hor[i] = s.acc_hor
        d.tilt_acc[i] = G * math.tan(math.radians(s.tilt_max_deg))
        d.yaw_rate_max[i] = math.radians(s.yaw_rate_max_deg)
        d.endurance_s[i] = s.endurance_s
        self._apply_limits()

    def _apply_limits(self) -> None:
        """Per-phase speed limits into the dynamics arrays."""
        s, d, i = self.settings, self.ctx.dyn, self.i
        ph = self.phase
        if ph == P_OFFBOARD:
            vxy = s.xy_vel_max
        elif ph == P_STICKS:
            vxy = s.vel_manual
        elif ph in (P_RTL_CLIMB, P_RTL_RETURN):
            vxy = s.rtl_speed if s.rtl_speed > 0 else s.xy_cruise
        else:
            vxy = s.xy_cruise
        if self.speed_xy == self.speed_xy:
            vxy = self.speed_xy
        up = s.tko_speed if ph == P_TAKEOFF else s.pilot_vz_up if ph == P_STICKS else s.z_vel_up
        if self.speed_up == self.speed_up:
            up = self.speed_up
        dn = s.pilot_vz_dn if ph == P_STICKS else max(s.z_vel_dn, s.land_speed)
        if self.speed_dn == self.speed_dn:
            dn = self.speed_dn
        d.vxy_max[i] = min(vxy, s.xy_vel_max)
        d.vz_up[i] = up
        d.vz_dn[i] = dn

    def set_param(self, name: str, value: float) -> bool:
        if not self.params.set(name, value):
            return False
        self.settings = derive_settings(self.flavour.name, self.params.values, self.params.defs, self.ctx.dyn.params)
        self.apply_settings()
        if self.phase == P_LAND:
            self._update_land_speed()
        return True

    # --------------------------------------------------------------- guidance
    def _targets(self, pos: np.ndarray | tuple[float, float, float], vel: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 yaw: float = NAN, yaw_rate: float = NAN) -> None:  # fmt: skip
        self.ctx.dyn.set_targets(self.i, pos, vel, yaw, yaw_rate)

    def _start_hold(self, target: np.ndarray | None = None, yaw: float = NAN) -> None:
        self.phase = P_HOLD
        if target is None:
            target = self.ctx.dyn.stop_point(self.i)
        target = target.copy()
        target[2] = min(target[2], self.ctx.dyn.ground_z[self.i])
        self._targets(target, yaw=yaw)
        self._apply_limits()

    def _start_takeoff(self, target_z: float, yaw: float = NAN) -> None:
        d, i = self.ctx.dyn, self.i
        p = d.pos[i]
        self.phase = P_TAKEOFF
        self.takeoff_target = np.array([p[0], p[1], target_z])
        self._targets(self.takeoff_target, yaw=yaw)
        self._apply_limits()

    def _update_land_speed(self) -> None:
        d, i, s = self.ctx.dyn, self.i, self.settings
        h = d.height(i)
        d.vel_ff[i, 2] = s.z_vel_dn if h > s.land_alt_slow else s.land_speed

    def _start_land(self, xy: np.ndarray | None = None) -> None:
        self.phase = P_LAND
        d, i = self.ctx.dyn, self.i
        if xy is None:
            xy = d.stop_point(i)[:2]
        self._targets(np.array([xy[0], xy[1], NAN]))
        self._update_land_speed()
        self._apply_limits()

    def _start_rtl(self) -> None:
        d, i = self.ctx.dyn, self.i
        if self.landed:
            self._start_land()
            return
        self.rtl_z = min(self.home_ned[2] - self.settings.rtl_alt, d.ground_z[i])
        sp = d.stop_point(i)
        if sp[2] > self.rtl_z + 0.5:  # lower than the return altitude: climb first
            self.phase = P_RTL_CLIMB
            self._targets(np.array([sp[0], sp[1], self.rtl_z]))
        else:
            self.rtl_z = float(sp[2])
            self.phase = P_RTL_RETURN
            self._targets(np.array([self.home_ned[0], self.home_ned[1], self.rtl_z]))
        self._apply_limits()

    def _start_offboard(self) -> None:
        self.phase = P_OFFBOARD
        self.guided_vel = False
        sp = self.setpoints.latest
        if self.flavour.is_px4 and sp is not None:
            self.apply_setpoint(sp)
        else:  # ArduPilot GUIDED starts by holding where it is
            target = self.ctx.dyn.stop_point(self.i)
            self._targets(target)
        self._apply_limits()

    def apply_setpoint(self, sp: Setpoint) -> None:
        d, i = self.ctx.dyn, self.i
        pos = list(sp.pos)
        a, b, c = vel = sp.vel
        if a != a or b != b or c != c:
            for k in range(3):
                if pos[k] != pos[k] and vel[k] != vel[k]:  # neither position nor velocity: hold that axis where it is
                    cur = float(d.pos_sp[i, k])
                    pos[k] = cur if cur == cur else float(d.pos[i, k])
            a, b, c = (0.0 if a != a else a), (0.0 if b != b else b), (0.0 if c != c else c)
        self._targets((pos[0], pos[1], pos[2]), (a, b, c), sp.yaw, sp.yaw_rate)
        self.guided_vel = sp.has_velocity

    def on_setpoint(self, sp: Setpoint) -> None:
        self.setpoints.note(sp, self.now)
        if self.mode.guidance is not Guidance.OFFBOARD:
            return
        if self.flavour.is_px4:
            if self.phase == P_OFFBOARD:
                self.apply_setpoint(sp)
        elif self.armed and not self.landed and self.phase in (P_OFFBOARD, P_HOLD):
            self.phase = P_OFFBOARD  # ArduPilot GUIDED: targets act only while flying
            self.apply_setpoint(sp)
            self._apply_limits()

    def goto(self, target: np.ndarray, speed: float = NAN, yaw: float = NAN) -> None:
        """Fly to a local NED target and hold there (PX4 HOLD reposition / ArduPilot GUIDED)."""
        if speed == speed and speed > 0:
            self.speed_xy = min(speed, self.settings.xy_vel_max)
        if self.flavour.is_px4:
            hold = self.flavour.mode(self.flavour.hold_mode)
            changed = hold is not self.mode
            if changed and self.mode.guidance is Guidance.MISSION:
                self.mission.pause()
            self.mode = hold
            self._start_hold(target, yaw)
            if changed:
                self.send_heartbeat()
        else:
            self.phase = P_OFFBOARD
            self.guided_vel = False
            self._targets(target, yaw=yaw)
            self._apply_limits()

    # ------------------------------------------------------------------ modes
    def enter_mode(self, spec: ModeSpec, hold_target: np.ndarray | None = None) -> None:
        """Switch to an (already validated) mode and start its guidance."""
        changed = spec is not self.mode
        if changed and self.mode.guidance is Guidance.MISSION:
            self.mission.pause()
        self.mode = spec
        if changed:
            self.speed_xy = self.speed_up = self.speed_dn = NAN
        self._start_guidance(hold_target)
        if changed:
            self.send_heartbeat()
            self.mission.announce()  # MISSION_CURRENT says whether the mission mode is on

    def _start_guidance(self, hold_target: np.ndarray | None = None) -> None:
        """Start the current mode's guidance from where the vehicle is now."""
        b = self.mode.guidance
        if b is Guidance.TAKEOFF:
            self._begin_takeoff_px4()
        elif b is Guidance.LAND:
            self._start_land()
        elif b is Guidance.RTL:
            self._start_rtl()
        elif b is Guidance.OFFBOARD:
            self._start_offboard()
        elif b is Guidance.MISSION:
            self.mission.start()
        elif b is Guidance.STICKS:
            self._start_sticks(hold_target)
        else:
            self._start_hold(hold_target)

    def _begin_takeoff_px4(self) -> None:
        s = self.settings
        alt = self.takeoff_alt_amsl
        if alt != alt:
            alt = self.home.alt + s.takeoff_alt
        z = self.alt_to_z(alt)
        if not self.landed:
            z = min(z, float(self.ctx.dyn.pos[self.i, 2]))  # already higher: keep altitude
        self._start_takeoff(z, self.takeoff_yaw)

    def request_mode(self, spec: ModeSpec) -> tuple[int, str]:
        """A mode change asked for by a GCS/companion: (MAV_RESULT, reason if refused)."""
        if spec is self.mode:
            return ACCEPTED, ""
        if spec.guidance is Guidance.MANUAL and not self.landed:
            return DENIED, f"{spec.name} needs RC input (none here)"
        if self.flavour.is_px4 and spec.guidance is Guidance.OFFBOARD and not self.offboard_ready():
            return DENIED, "Offboard: no setpoint stream (>2Hz for 1s)"
        if self.flavour.is_px4 and spec.guidance is Guidance.STICKS and not self.landed and not self.sticks_fresh:
            return DENIED, f"{spec.name}: no manual control input"
        if spec.guidance is Guidance.MISSION:
            ok, why = self.mission.can_start()
            if not ok:
                return DENIED, why
        if spec.guidance is Guidance.TAKEOFF:
            self.takeoff_alt_amsl = NAN
            self.takeoff_yaw = NAN
        self.enter_mode(spec)
        return ACCEPTED, ""

    # ----------------------------------------------------------------- arming
    def arm(self, force: bool = False) -> tuple[int, str]:
        if self.armed:
            return ACCEPTED, ""
        if not force:
            px4 = self.flavour.is_px4
            if not self.mode.can_arm:
                return DENIED, f"Arming denied: {self.mode.name} mode not armable" if px4 else "Arm: Mode not armable"
            if px4 and self.mode.guidance is Guidance.OFFBOARD and not self.offboard_ready():
                return DENIED, "Arming denied: no offboard setpoints"
            if not self.gps_ok:
                return DENIED, "Arming denied: no 3D GPS fix yet" if px4 else "PreArm: Need 3D Fix"
            if not self.prearm_ok():
                return DENIED, "Arming denied: battery too low" if px4 else "PreArm: Battery below minimum"
            if not self.landed:
                return DENIED, "Arming denied: not on the ground"
        d, i = self.ctx.dyn, self.i
        self.armed = True
        d.armed[i] = True
        d.acc[i] = 0.0
        self.has_flown = False
        self.landed_since = self.now
        self.bat_level = 0
        # restart the mode's guidance from where the vehicle is now (a pending takeoff, a mission)
        self.speed_xy = self.speed_up = self.speed_dn = NAN
        if self.mode.guidance is Guidance.RTL:  # forced arming in RTL: hold, like any other refused mode
            self._start_hold()
        else:
            self._start_guidance()
        self.send_heartbeat()
        return ACCEPTED, ""

    def disarm(self, force: bool = False, reason: str = "") -> tuple[int, str]:
        if not self.armed:
            return ACCEPTED, ""
        if not force and not self.landed:
            return DENIED, "Disarming denied: not landed"
        self.armed = False
        self.ctx.dyn.armed[self.i] = False
        self.landed_since = None
        if reason:
            self.statustext(M.MAV_SEVERITY_INFO, reason)
        self.send_heartbeat()
        return ACCEPTED, ""

    # ------------------------------------------------------------- supervisor
    def tick(self, now: float) -> None:
        """Runs at ~10 Hz sim: phase progress, auto-disarm, failsafes."""
        d, i, s = self.ctx.dyn, self.i, self.settings
        landed = self.landed
        if self.armed:
            if not landed:
                self.has_flown = True
                self.landed_since = None
            else:
                if self.landed_since is None:
                    self.landed_since = now
                limit = s.disarm_land_s if self.has_flown else s.disarm_prflt_s
                if limit > 0 and now - self.landed_since >= limit:
                    why = "Disarmed by landing" if self.has_flown else "Disarmed: no takeoff (auto preflight disarm)"
                    self.disarm(reason=why)
                    return
        ph = self.phase
        mission = self.mode.guidance is Guidance.MISSION
        if ph == P_TAKEOFF and not mission:  # a mission's takeoff is the mission's to finish
            if self.armed and not landed and abs(d.pos[i, 2] - self.takeoff_target[2]) < TAKEOFF_DONE_M:
                if self.flavour.is_px4:
                    self.enter_mode(self.flavour.mode(self.flavour.hold_mode), hold_target=self.takeoff_target)
                else:
                    self.phase = P_OFFBOARD
                    self._apply_limits()
        elif ph == P_LAND:
            self._update_land_speed()
        elif ph == P_RTL_CLIMB:
            if d.pos[i, 2] - self.rtl_z < TAKEOFF_DONE_M:
                self.phase = P_RTL_RETURN
                self._targets(np.array([self.home_ned[0], self.home_ned[1], self.rtl_z]))
                self._apply_limits()
        elif ph == P_RTL_RETURN:
            dxy = math.hypot(d.pos[i, 0] - self.home_ned[0], d.pos[i, 1] - self.home_ned[1])
            if dxy < RTL_ARRIVED_M and math.hypot(d.vel[i, 0], d.vel[i, 1]) < 0.5:
                self._start_land(self.home_ned[:2])
        elif ph == P_OFFBOARD and not self.flavour.is_px4 and self.guided_vel and self.setpoints.age(now) > s.guided_timeout:
            self.guided_vel = False
            self._targets(d.stop_point(i))  # ArduPilot: velocity target timed out, stop
        elif ph == P_STICKS:
            self._stick_tick(landed)
        if mission:
            self.mission.tick(now)
        self._failsafes(now, landed)

    def _failsafes(self, now: float, landed: bool) -> None:
        s, d, i = self.settings, self.ctx.dyn, self.i
        # offboard loss (PX4)
        if self.flavour.is_px4 and self.mode.guidance is Guidance.OFFBOARD and self.setpoints.age(now) > s.of_loss_t:
            self.failsafe(s.of_loss_act if s.of_loss_act is not Action.NONE else Action.HOLD, "offboard signal lost")
        flying = self.armed and not landed
        # GCS datalink loss (only once a GCS has been heard)
        if self.gcs_last is not None and s.dll_act is not Action.NONE:
            lost = now - self.gcs_last > s.dll_t
            if lost and not self.dll_tripped:
                self.dll_tripped = True
                if flying:
                    self.failsafe(s.dll_act, "no connection to GCS")
            elif not lost and self.dll_tripped:
                self.dll_tripped = False
                self.statustext(M.MAV_SEVERITY_INFO, "GCS connection regained")
        # battery
        soc = d.get(BATTERY, i)
        level = 3 if soc <= s.bat_emerg else 2 if soc <= s.bat_crit else 1 if soc <= s.bat_low else 0
        if level > self.bat_level:
            self.bat_level = level
            name = {1: "low", 2: "critical", 3: "emergency"}[level]
            act = {1: s.bat_low_act, 2: s.bat_crit_act, 3: s.bat_emerg_act}[level]
            self.statustext(M.MAV_SEVERITY_WARNING, f"Battery {name}: {int(soc * 100)}% remaining")
            if flying and act not in (Action.NONE, Action.WARN):
                self.failsafe(act, f"battery {name}")
        # geofence cylinder around home
        if self.fence_enabled and flying:
            p = d.get(POS, i)
            hor = math.hypot(p[0] - self.home_ned[0], p[1] - self.home_ned[1])
            ver = self.home_ned[2] - p[2]
            out = (s.gf_hor > 0 and hor > s.gf_hor) or (s.gf_ver > 0 and ver > s.gf_ver)
            if out and not self.fence_breached:
                self.fence_breached = True
                self.failsafe(s.gf_action, "geofence breached")
            elif not out:
                self.fence_breached = False
        elif not flying:
            self.fence_breached = False

    # ----------------------------------------------------------------- sticks
    def on_sticks(self, sticks: Sticks) -> None:
        """A MANUAL_CONTROL / RC_CHANNELS_OVERRIDE arrived (ignored with COM_RC_IN_MODE 0 or 4)."""
        if not self.settings.stick_input:
            return
        self.sticks.note(sticks, self.now)
        if self.phase == P_STICKS:
            self._sticks_in_mode = True
            self._apply_sticks()

    def _start_sticks(self, hold_target: np.ndarray | None = None) -> None:
        self.phase = P_STICKS
        self._sticks_in_mode = self.sticks_fresh
        self._stick_xy_held = self._stick_z_held = False
        self._apply_sticks(hold_target)
        self._apply_limits()

    def _apply_sticks(self, hold_target: np.ndarray | None = None) -> None:
        """Deflected sticks command velocities; a centred axis brakes and holds where it stops."""
        s, d, i = self.settings, self.ctx.dyn, self.i
        sticks = self.sticks.current(self.now, s.rc_loss_t) if s.stick_input else CENTRED
        cmd = command(sticks, float(d.yaw[i]), s.vel_manual, s.pilot_vz_up, s.pilot_vz_dn, math.radians(s.yaw_rate_max_deg))
        pos, vel = d.pos_sp[i].copy(), d.vel_ff[i].copy()
        stop = hold_target if hold_target is not None else d.stop_point(i)
        if cmd.moving_xy:
            pos[0] = pos[1] = NAN
            vel[0], vel[1] = cmd.vn, cmd.ve
            self._stick_xy_held = False
        elif not self._stick_xy_held:
            pos[0], pos[1] = stop[0], stop[1]
            vel[0] = vel[1] = 0.0
            self._stick_xy_held = True
        if cmd.moving_z:
            pos[2], vel[2] = NAN, cmd.vd
            self._stick_z_held = False
        elif not self._stick_z_held:
            pos[2], vel[2] = min(stop[2], float(d.ground_z[i])), 0.0
            self._stick_z_held = True
        self._targets(pos, (float(vel[0]), float(vel[1]), float(vel[2])), NAN, cmd.yaw_rate)

    def _stick_tick(self, landed: bool) -> None:
        """Re-aim the sticks at the current heading; a stick stream lost in flight fails safe."""
        s = self.settings
        if self._sticks_in_mode and not self.sticks.lost and not self.sticks_fresh:
            self.sticks.lost = True
            self._apply_sticks()  # centred: brake and hold
            if self.armed and not landed:
                self.failsafe(s.rc_loss_act, "manual control lost")
            return
        self._apply_sticks()

    def failsafe(self, action: Action, reason: str) -> None:
        self.ctx.stats.failsafes[reason] += 1
        if action is Action.NONE:
            return
        sev = M.MAV_SEVERITY_WARNING if action is Action.WARN else M.MAV_SEVERITY_CRITICAL
        self.statustext(sev, f"Failsafe: {reason}, {action.value}"[:50])
        fl = self.flavour
        target: ModeSpec | None = None
        if action is Action.HOLD:
            target = fl.mode(fl.hold_mode)
        elif action is Action.POSCTL and fl.is_px4:
            target = fl.mode("POSCTL")
        elif action is Action.ALTCTL and fl.is_px4:
            target = fl.mode("ALTCTL")
        elif action in (Action.POSCTL, Action.ALTCTL):
            target = fl.mode(fl.hold_mode)
        elif action is Action.RTL:
            target = fl.mode("RTL")
        elif action is Action.LAND:
            target = fl.mode("LAND")
        elif action in (Action.TERMINATE, Action.DISARM):
            self.disarm(force=True)
        if target is None:
            return
        if target is not self.mode:
            self.enter_mode(target)
        elif target.guidance in (Guidance.HOLD, Guidance.STICKS):
            self._start_guidance()  # already holding (e.g. flying to a reposition target): stop here
