"""One virtual vehicle: its boot, mode state machine, arming, guidance into the shared dynamics arrays,
the 10 Hz supervisor (boot output, takeoff/RTL/land progress, auto-disarm, failsafes) and its link.
The mission it flies is mission.py's, the stick input manual.py's; what differs between the firmwares is
in ardupilot.py and px4.py.

Everything time-related runs on the fleet's sim clock (``ctx.clock.sim_time``), except the
link-level heartbeat floor and peer bookkeeping, which use wall time.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from uav_stack.fcu import ardupilot, px4
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
from uav_stack.fcu.params import Action, ParamStore, Settings, derive_settings, param_defs
from uav_stack.fcu.stats import FcuStats
from uav_stack.fcu.streams import ENCODERS_BY_FLAVOUR, StreamSet, ardupilot_group_hz, firmware_rates
from uav_stack.fcu.telemetry import heartbeat
from uav_stack.geo import GeoPoint, LocalFrame
from uav_stack.mav import mavlink

M = mavlink
NAN = math.nan
ACCEPTED = M.MAV_RESULT_ACCEPTED
DENIED = M.MAV_RESULT_DENIED
FAILED = M.MAV_RESULT_FAILED
TEMPORARILY_REJECTED = M.MAV_RESULT_TEMPORARILY_REJECTED
PARAMS_PER_TICK = {"px4": 100, "ardupilot": 165}  # a parameter list streams at ~1000 (PX4) / ~1650 (ArduPilot) a second


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
        px = self.flavour.is_px4
        self.boot = (px4.timeline if px else ardupilot.timeline)(cfg.boot)
        self.booted = False  # every boot milestone passed (the steady state's checks short-cut on this)
        self.events = px4.EventLog() if px else None
        mp = ctx.dyn.params
        self.params = ParamStore(param_defs(self.flavour.name, mp, self.sysid), bytewise=self.flavour.bytewise_params)
        for name, value in cfg.params.items():
            if name not in self.params:
                raise ValueError(f"params: unknown {self.flavour.name} parameter {name!r} (sysid {self.sysid})")
            if not self.params.set(name, float(value)):
                raise ValueError(f"params: invalid value {value!r} for {name} (sysid {self.sysid})")
        self.settings: Settings = derive_settings(self.flavour.name, self.params, mp)
        self.encoders = ENCODERS_BY_FLAVOUR[self.flavour.name]
        unknown = set(stream_rates) - set(self.encoders)
        if unknown:
            raise ValueError(f"stream_rates: {self.flavour.name} sends no {sorted(unknown)}")
        # vehicles on sockets get phases of their own (their sends spread over the period); a pool's
        # vehicles (in-process links) all send on the ticks' grid: the pool's loop takes every vehicle's
        # telemetry at the same instants, so a phase would only make a position up to 80 ms older
        self.streams = StreamSet(ctx.clock.dt, phase=0 if cfg.inproc else 7 * i, start_at=self._stream_starts())
        rates = firmware_rates(self.flavour.name, self.params.get)
        rates.update(stream_rates)
        for name in self.encoders:
            if name != "HEARTBEAT":
                self.streams.set_rate(name, rates.get(name, 0.0), now=0.0, first=True)
        # HEARTBEAT every 1 s of sim time and at least every 1 s of wall time (a slow sim keeps its link alive)
        self.hb_period = 1.0 / rates["HEARTBEAT"] if rates.get("HEARTBEAT", 0) > 0 else 1.0
        self.hb_interval_wall = self.hb_period / max(1.0, ctx.clock.target_rtf)
        self.next_hb_wall = 0.0
        self.heartbeats_sent = 0
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
        self.guided_target = False  # ArduPilot: GUIDED flies to a position target it was given
        self.gcs_last: float | None = None
        self.dll_tripped = False
        self.bat_level = 0  # 0 ok, 1 low, 2 critical, 3 emergency (latched)
        self.fence_breached = False
        self.missions: dict[int, list[MissionItem]] = {0: [], 1: [], 2: []}  # by MAV_MISSION_TYPE
        self.upload: dict[str, object] | None = None
        self.mission_int_protocol = False  # PX4: the ground station speaks MISSION_ITEM_INT (asked with _REQUEST_INT)
        self.mission = MissionRun(self)
        self.sticks = StickStream()
        self._sticks_in_mode = False  # a stick message arrived since the stick mode was entered
        self._stick_xy_held = self._stick_z_held = False  # holding the braking point, per axis
        self._deferred: list[mavlink.MAVLink_message] | None = None  # output held until a command's ACK is out
        # PX4: the mode the user asked for last (CURRENT_MODE.intended_custom_mode; a failsafe changes the mode, not
        # the intention), and the last such mode it can arm in: where it goes back to after a disarm
        self.intended_mode: ModeSpec = self.mode
        self.after_disarm_mode: ModeSpec = self.mode
        self.px4_failsafe = False  # PX4 flies a failsafe's mode (CRITICAL) until the user picks another
        self._health_state = ""  # the last health report PX4 sent
        # a battery fault injected below SIM_BAT_MIN_PCT: the floor limits the simulated drain, not a failing battery
        self.battery_failed = False
        self.home_override = False  # DO_SET_HOME (or arming) set home before the boot did
        self.pending_takeoff: tuple[float, float, float] | None = None  # ArduPilot: (start time, target z, yaw)
        self.arm_refused = False  # ArduPilot reports its pre-arm failures every 30 s once an arm was refused
        self._next_prearm = ardupilot.PREARM_PERIOD_S + 0.46
        self._next_stat_runtime = ardupilot.STAT_RUNTIME_FIRST_S
        self.param_queue: deque[int] = deque()  # a PARAM_REQUEST_LIST being answered, paced like the firmware
        self.param_echo_again: list[mavlink.MAVLink_message] = []  # PX4 echoes a PARAM_SET twice
        self.ping_seq = 0
        self.rc_failsafe = False  # ArduPilot SITL's RC receiver lost (SIM_RC_FAIL)
        self.rc_fail_since: float | None = None
        self.disarm_prflt_grace = px4.DISARM_PRFLT_GRACE_S if px else 0.0
        self.log_closed = False
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
        return self.dll_tripped or self.fence_breached or self.bat_level >= 2 or self.px4_failsafe or self.rc_failsafe

    def _stream_starts(self) -> dict[str, float]:
        """When each stream may first go out: PX4 starts each at its boot milestone, ArduPilot all of them once
        it is up (TIMESYNC: a period after launch)."""
        at = self.boot.at
        if self.flavour.is_px4:
            starts = {name: at["sensors"] for name in self.encoders}
            starts.update({name: at[stage] for name, (_, stage) in px4.STREAMS.items()})
            return starts
        starts = {name: at["streams"] for name in self.encoders}
        starts["TIMESYNC"] = ardupilot.TIMESYNC_PERIOD_S
        return starts

    def finish_boot(self) -> None:
        """Skip the boot: every milestone passed, no boot output (tests, benchmarks)."""
        self.boot.skip()
        self.booted = True
        st = self.streams
        st.start_at.clear()
        for name in list(st.next_due):
            st.set_rate(name, st.hz(name), self.now, first=True)

    def send(self, msg: mavlink.MAVLink_message) -> None:
        if self._deferred is not None:
            self._deferred.append(msg)  # packed (and numbered) once the command's ACK is out
            return
        self.send_frame(msg.pack(self.mav))

    def send_now(self, msg: mavlink.MAVLink_message) -> None:
        """Send ahead of a command's ACK (PX4 replies to REQUEST_MESSAGE before it ACKs)."""
        self.send_frame(msg.pack(self.mav))

    def send_frame(self, frame: bytes) -> None:
        """A frame packed with this vehicle's next sequence number (by :meth:`send`, or whole by telemetry.FRAMERS)."""
        mav = self.mav
        mav.seq = (mav.seq + 1) & 0xFF
        self.link.queue(frame)
        self.ctx.stats.messages_out += 1

    def send_heartbeat(self) -> None:
        self.send(heartbeat(self))
        self.next_hb_wall = self.ctx.wall() + self.hb_interval_wall

    def mode_changed(self) -> None:
        """ArduPilot sends one extra HEARTBEAT at every mode change (after the command's ACK); PX4 shows the new
        mode at its next regular one."""
        if not self.flavour.is_px4:
            self.send(heartbeat(self))  # (the 1 Hz cadence carries on as before)

    def statustext(self, severity: int, text: str) -> None:
        """A STATUSTEXT (PX4 sends none on its onboard link: it reports with events, :meth:`event`)."""
        self.send(self.mav.statustext_encode(severity, text.encode()[:50]))

    def event(self, ev: px4.Event) -> None:
        if self.events is not None:
            self.events.emit(self, ev)

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
        """Booted far enough to arm: the position estimate is good (ArduPilot's EKF uses GPS, PX4's checks pass)."""
        return self.booted or self.now + 1e-9 >= self.boot.ready_at

    @property
    def gps_fix(self) -> bool:
        """The GPS has a 3D fix (PX4's simulated GPS has one from its first message)."""
        return self.booted or self.boot.passed("sensors" if self.flavour.is_px4 else "gps_fix", self.now)

    @property
    def origin_set(self) -> bool:
        return self.booted or self.boot.passed("origin", self.now)

    @property
    def home_set(self) -> bool:
        return self.booted or self.home_override or self.boot.passed("home" if self.flavour.is_px4 else "origin", self.now)

    def has_flown_since_arming(self) -> bool:
        return self.has_flown or (self.armed and not self.landed)

    def guided_position_target(self) -> bool:
        """ArduPilot GUIDED is flying to a position target (POSITION_TARGET_GLOBAL_INT is streamed then)."""
        return self.mode.guidance is Guidance.OFFBOARD and self.phase == P_OFFBOARD and self.guided_target and self.armed

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
        encoders = self.encoders
        for name in st.due(now):
            msg = encoders[name](self)
            if msg is not None:  # None: nothing to say yet (no position before the estimate is valid)
                self.send(msg)

    def default_rate(self, name: str) -> float:
        """The rate SET_MESSAGE_INTERVAL(0) restores: PX4's own for the link, ArduPilot's stream group's."""
        if name == "HEARTBEAT":
            return 1.0
        if self.flavour.is_px4:
            return px4.STREAMS.get(name, (0.0, ""))[0]
        group = ardupilot.GROUP_OF.get(name)
        if group is None:
            return 1.0 / ardupilot.TIMESYNC_PERIOD_S if name == "TIMESYNC" else 0.0
        return ardupilot_group_hz(name, self.params.get(group))

    def request_data_stream(self, stream_id: int, rate_hz: int, start: int) -> None:
        """ArduPilot's REQUEST_DATA_STREAM: the group's MAV1_* rate, and every message of the group at it
        (also those given their own interval before); ALL sets every group but the parameter stream."""
        if start not in (0, 1):
            return
        hz = float(rate_hz) if start == 1 else 0.0
        if stream_id == M.MAV_DATA_STREAM_ALL:
            groups = [g for g in ardupilot.STREAM_GROUPS if g not in ardupilot.ALL_SKIPS]
        elif stream_id in ardupilot.STREAM_PARAMS:
            groups = [ardupilot.STREAM_PARAMS[stream_id]]
        else:
            return
        for group in groups:
            self.params.set(group, hz)
            for name in ardupilot.STREAM_GROUPS[group]:
                self.streams.set_rate(name, ardupilot_group_hz(name, hz), self.now)

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
        self.settings = derive_settings(self.flavour.name, self.params, self.ctx.dyn.params)
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
        self.guided_vel = self.guided_target = False
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
        self.guided_target = not sp.has_velocity

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
        else:
            self.phase = P_OFFBOARD
            self.guided_vel = False
            self.guided_target = True
            self._targets(target, yaw=yaw)
            self._apply_limits()

    # ------------------------------------------------------------------ modes
    def enter_mode(self, spec: ModeSpec, hold_target: np.ndarray | None = None) -> None:
        """Switch to an (already validated) mode and start its guidance."""
        if not self.px4_failsafe:
            self.intended_mode = spec
            if spec.can_arm and spec.guidance is not Guidance.TAKEOFF:
                self.after_disarm_mode = spec
        changed = spec is not self.mode
        if changed and self.mode.guidance is Guidance.MISSION:
            self.mission.pause()
        self.mode = spec
        if changed:
            self.speed_xy = self.speed_up = self.speed_dn = NAN
        self._start_guidance(hold_target)
        if changed:
            self.mode_changed()
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
        """A mode change asked for by a GCS/companion (a mode or a NAV command): (MAV_RESULT, reason if refused).
        It becomes PX4's intended mode, and, if PX4 can arm in it, the one it returns to after a disarm (from a
        landing in LAND: the mode before)."""
        if spec is self.mode:
            if self.px4_failsafe:
                self.px4_failsafe = False  # the user has taken over
                self.enter_mode(spec)
            return ACCEPTED, ""
        refused = TEMPORARILY_REJECTED if self.flavour.is_px4 else FAILED  # how each firmware refuses a mode
        if spec.guidance is Guidance.MANUAL and not self.landed:
            return refused, f"{spec.name} needs RC input (none here)"
        if self.flavour.is_px4 and spec.guidance is Guidance.OFFBOARD and not self.offboard_ready():
            return refused, "Offboard: no setpoint stream (>2Hz for 1s)"
        if self.flavour.is_px4 and spec.guidance is Guidance.STICKS and not self.landed and not self.sticks_fresh:
            return refused, f"{spec.name}: no manual control input"
        if spec.guidance is Guidance.MISSION:
            ok, why = self.mission.can_start()
            if not ok:
                return refused, why
        if spec.guidance is Guidance.TAKEOFF:
            self.takeoff_alt_amsl = NAN
            self.takeoff_yaw = NAN
        self.px4_failsafe = False  # the user has taken over
        self.enter_mode(spec)
        return ACCEPTED, ""

    # ----------------------------------------------------------------- arming
    def arm_refusal(self, on_ground: bool = True) -> str | None:
        """Why arming would be refused now (None: it would pass), in words of our own (the firmwares' replies
        are sent by :meth:`arm`). ``on_ground=False``: the checks alone, wherever the vehicle is."""
        if not self.mode.can_arm:
            return "mode not armable"
        if self.flavour.is_px4:
            if self.mode.guidance is Guidance.OFFBOARD and not self.offboard_ready():
                return "no offboard signal"
            if self.mode.guidance is Guidance.MISSION and not self.mission.flyable():
                return "no valid mission"
        if not self.gps_ok:
            return "no position estimate"
        if not self.prearm_ok():
            return "battery too low"
        if on_ground and not self.landed:
            return "not on the ground"
        return None

    def arming_checks_pass(self) -> bool:
        """The arming checks pass in the current mode (PX4: HEARTBEAT STANDBY, not UNINIT; SYS_STATUS's
        PREARM_CHECK health, both flavours)."""
        return self.arm_refusal(on_ground=False) is None

    def arm(self, force: bool = False) -> tuple[int, str]:
        """Arm, as each firmware answers: PX4 refuses with TEMPORARILY_REJECTED and an event (no text),
        ArduPilot with FAILED and its "Arm: ..." texts (CRITICAL), one per failing check."""
        if self.armed:
            return ACCEPTED, ""
        px = self.flavour.is_px4
        if not force:
            why = self.arm_refusal()
            if why is not None:
                if px:
                    self.event(px4.ARM_DENIED)
                    return TEMPORARILY_REJECTED, ""
                self.arm_refused = True
                crit = M.MAV_SEVERITY_CRITICAL
                if why == "mode not armable":
                    self.statustext(crit, f"Arm: {self.mode.name} mode not armable")
                elif why == "no position estimate":
                    for text in ardupilot.arm_failures(self):
                        self.statustext(crit, f"Arm: {text}")
                elif why == "battery too low":
                    self.statustext(crit, "Arm: Battery below minimum")
                else:
                    self.statustext(crit, "Arm: Vehicle not landed")
                return FAILED, ""
        d, i = self.ctx.dyn, self.i
        self.armed = True
        d.armed[i] = True
        d.acc[i] = 0.0
        self.has_flown = False
        self.landed_since = self.now
        self.bat_level = 0
        self.pending_takeoff = None
        # restart the mode's guidance from where the vehicle is now (a pending takeoff, a mission)
        self.speed_xy = self.speed_up = self.speed_dn = NAN
        if self.mode.guidance is Guidance.RTL:  # forced arming in RTL: hold, like any other refused mode
            self._start_hold()
        else:
            self._start_guidance()
        if px:
            self.event(px4.ARMED_BY)
            if self.log_closed:  # PX4 logs from boot; a disarm closed that log, arming opens a new one
                self.log_closed = False
                self.event(px4.LOGGER_OPEN)
        else:  # ArduCopter sets home where it arms, then says so
            lat, lon, alt = self.geodetic()
            self.set_home(GeoPoint(lat, lon, alt))
            self.statustext(M.MAV_SEVERITY_INFO, "Arming motors")
        return ACCEPTED, ""

    def set_home(self, home: GeoPoint) -> None:
        """A new home (DO_SET_HOME, ArduPilot arming): HOME_POSITION at once (ArduPilot: GPS_GLOBAL_ORIGIN first)."""
        self.home = home
        self.home_ned = self.ned_of(home.lat, home.lon, home.alt)
        self.home_override = True
        if not self.flavour.is_px4:
            msg = self.encoders["GPS_GLOBAL_ORIGIN"](self)
            if msg is not None:
                self.send(msg)
        msg = self.encoders["HOME_POSITION"](self)
        if msg is not None:
            self.send(msg)

    def disarm(self, force: bool = False, why: str = "command") -> tuple[int, str]:
        """Disarm. ``why``: "command", "forced", "landing", "preflight" (auto-disarm without takeoff) or a
        failsafe's; PX4 reports it with an event and goes back to the intended mode, ArduPilot says
        "Disarming motors"."""
        if not self.armed:
            return ACCEPTED, ""
        if not force and not self.landed:  # (PX4: TEMPORARILY_REJECTED, as for arming; ArduCopter: FAILED)
            return (TEMPORARILY_REJECTED if self.flavour.is_px4 else FAILED), "Disarming denied: not landed"
        self.armed = False
        self.ctx.dyn.armed[self.i] = False
        self.landed_since = None
        self.pending_takeoff = None
        if self.flavour.is_px4:
            by = {"landing": px4.DISARMED_BY_LANDING, "preflight": px4.DISARMED_PREFLIGHT}
            self.event(by.get(why, px4.DISARMED_BY_COMMAND))
            self.px4_failsafe = False
            self.log_closed = True
            self.ctx.dyn.battery[self.i] = 1.0  # PX4's simulated battery is full again when disarmed
            self.battery_failed = False
            self.bat_level = 0
            if self.after_disarm_mode is not self.mode:
                self.enter_mode(self.after_disarm_mode)
        else:
            self.statustext(M.MAV_SEVERITY_INFO, "Disarming motors")
        return ACCEPTED, ""

    # ------------------------------------------------------------- supervisor
    def tick(self, now: float) -> None:
        """Runs at ~10 Hz sim: boot output, phase progress, auto-disarm, failsafes, paced replies."""
        if not self.booted:
            self._boot_tick(now)
        if self.param_queue or self.param_echo_again:
            self._param_tick()
        if self.flavour.is_px4:
            self._px4_tick(now)
        elif not self.armed:
            self._ardupilot_disarmed_tick(now)
        landed = self.landed
        if self.armed and self._armed_tick(now, landed):
            return
        mission = self.mode.guidance is Guidance.MISSION
        self._phase_tick(now, landed, mission)
        if mission:
            self.mission.tick(now)
        self._failsafes(now, landed)

    def _armed_tick(self, now: float, landed: bool) -> bool:
        """Takeoff and landing detection, the auto-disarm on the ground, a delayed takeoff; True once disarmed."""
        s, px = self.settings, self.flavour.is_px4
        if not landed:
            if not self.has_flown and px:
                self.event(px4.TAKEOFF_DETECTED)
            self.has_flown = True
            self.landed_since = None
        else:
            if self.landed_since is None:
                self.landed_since = now
                if self.has_flown and px:
                    self.event(px4.LANDING_DETECTED)
            limit = s.disarm_land_s if self.has_flown else s.disarm_prflt_s + self.disarm_prflt_grace
            if (self.has_flown and s.disarm_land_s > 0 or not self.has_flown and s.disarm_prflt_s > 0) and \
                    now - self.landed_since >= limit:  # fmt: skip
                self.disarm(why="landing" if self.has_flown else "preflight")
                return True
        if self.pending_takeoff is not None and now >= self.pending_takeoff[0]:
            _, z, yaw = self.pending_takeoff
            self.pending_takeoff = None
            self._start_takeoff(z, yaw)
        return False

    def _phase_tick(self, now: float, landed: bool, mission: bool) -> None:
        """A flight phase's progress: takeoff done, landing speed, RTL's climb and return, a timed-out velocity."""
        d, i, ph = self.ctx.dyn, self.i, self.phase
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
        elif ph == P_OFFBOARD and not self.flavour.is_px4 and self.guided_vel and \
                self.setpoints.age(now) > self.settings.guided_timeout:  # fmt: skip
            self.guided_vel = False
            self._targets(d.stop_point(i))  # ArduPilot: velocity target timed out, stop
        elif ph == P_STICKS:
            self._stick_tick(landed)

    # ------------------------------------------------------------------ boot
    def _boot_tick(self, now: float) -> None:
        for ev in self.boot.due(now):
            kind, payload = ev.kind, ev.payload
            if kind == "statustext":
                sev, text = payload
                self.statustext(sev, text)
            elif kind == "param_value":
                self._boot_param_value(*payload)
            elif kind == "event":
                self.event(payload)
            elif kind in ("gps_origin", "home"):  # the EKF origin, home (PX4 sets it again once ready)
                msg = self.encoders["GPS_GLOBAL_ORIGIN" if kind == "gps_origin" else "HOME_POSITION"](self)
                if msg is not None:
                    self.send(msg)
        if now >= self.boot.done_at:
            self.booted = True

    def _boot_param_value(self, name: str, value: float | None, ptype: int | None, count: int | None) -> None:
        """An unsolicited PARAM_VALUE (index 65535) of the firmware's boot: calibration, device ids, autoconfig."""
        k = self.params.on_mavlink(name)
        if k is None:
            return
        pname, wire, ty = self.params.encode(k)
        if value is not None and ptype is not None:
            wire, ty = self.params.wire(value, ptype), ptype
        n = count if count is not None else len(self.params)
        idx = 65535 if not self.flavour.is_px4 else k
        self.send(self.mav.param_value_encode(pname.encode(), wire, ty, n, idx))

    def _param_tick(self) -> None:
        for m in self.param_echo_again:
            self.send(m)
        self.param_echo_again.clear()
        q = self.param_queue
        for _ in range(min(len(q), PARAMS_PER_TICK[self.flavour.name])):
            k = q.popleft()
            name, value, ptype = self.params.encode(k)
            self.send(self.mav.param_value_encode(name.encode(), value, ptype, len(self.params), k))

    def _px4_tick(self, now: float) -> None:
        """PX4's health reports when its checks change, its battery's floor, MISSION_ITEM_REACHED repeats."""
        if self.booted or self.boot.passed("estimate", now):
            state = "no_estimate" if not self.gps_ok else "ready_offboard" if self.offboard_ready() else "ready"
            if state != self._health_state:
                self._health_state = state
                if self.events is not None:
                    self.events.report(self, state)
        d, i = self.ctx.dyn, self.i
        floor = self.settings.bat_floor
        if floor > 0 and not self.battery_failed and d.get(BATTERY, i) < floor:
            d.battery[i] = floor
        self.mission.repeat_reached(now)

    def _ardupilot_disarmed_tick(self, now: float) -> None:
        """ArduPilot's periodic output while disarmed: pre-arm failures every 30 s (once an arm was refused),
        STAT_RUNTIME saved about every 31 s."""
        if now >= self._next_prearm:
            self._next_prearm += ardupilot.PREARM_PERIOD_S
            if self.arm_refused:
                for text in ardupilot.arm_failures(self):
                    self.statustext(M.MAV_SEVERITY_CRITICAL, f"PreArm: {text}")
        if now >= self._next_stat_runtime:
            self._next_stat_runtime += ardupilot.STAT_RUNTIME_PERIOD_S
            self._boot_param_value("STAT_RUNTIME", float(int(now)), M.MAV_PARAM_TYPE_INT32, None)

    def _failsafes(self, now: float, landed: bool) -> None:
        s, d, i = self.settings, self.ctx.dyn, self.i
        px = self.flavour.is_px4
        # offboard loss (PX4)
        if px and self.mode.guidance is Guidance.OFFBOARD and self.setpoints.age(now) > s.of_loss_t and self.armed:
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
                if not px:
                    self.statustext(M.MAV_SEVERITY_WARNING, "GCS Failsafe Cleared")
        # ArduPilot SITL's RC receiver (SIM_RC_FAIL): "Radio Failsafe" 1 s after the pulses stop
        if not px:
            self._radio_failsafe(now, flying)
        # battery
        soc = d.get(BATTERY, i)
        level = 3 if soc <= s.bat_emerg else 2 if soc <= s.bat_crit else 1 if soc <= s.bat_low else 0
        if level > self.bat_level:
            self.bat_level = level
            name = {1: "low", 2: "critical", 3: "emergency"}[level]
            act = {1: s.bat_low_act, 2: s.bat_crit_act, 3: s.bat_emerg_act}[level]
            if not self.flavour.is_px4:  # (PX4 reports it in BATTERY_STATUS.charge_state and its events)
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

    def _radio_failsafe(self, now: float, flying: bool) -> None:
        lost = self.params.get("SIM_RC_FAIL") != 0
        if not lost:
            self.rc_fail_since = None
            if self.rc_failsafe:
                self.rc_failsafe = False
                self.statustext(M.MAV_SEVERITY_WARNING, "Radio Failsafe Cleared")
            return
        if self.rc_fail_since is None:
            self.rc_fail_since = now
        if not self.rc_failsafe and now - self.rc_fail_since >= 1.0 - 1e-9 and flying:
            self.rc_failsafe = True
            self.failsafe(self.settings.rc_loss_act, "radio")

    def failsafe(self, action: Action, reason: str) -> None:
        """Run a failsafe action. PX4 reports it with an event and flies the action's mode as a failsafe
        (CRITICAL) without changing the intended mode; ArduPilot says so in its words."""
        self.ctx.stats.failsafes[reason] += 1
        if action is Action.NONE:
            return
        fl = self.flavour
        if fl.is_px4:
            self.event(px4.FAILSAFE_ENTER)
        else:
            text = {"no connection to GCS": "GCS Failsafe", "radio": "Radio Failsafe"}.get(reason)
            sev = M.MAV_SEVERITY_WARNING if text is not None or action is Action.WARN else M.MAV_SEVERITY_CRITICAL
            self.statustext(sev, text or f"Failsafe: {reason}, {action.value}"[:50])
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
            self.disarm(force=True, why="failsafe")
        if target is None:
            return
        if fl.is_px4 and action is not Action.WARN:
            self.px4_failsafe = True
        if target is not self.mode:
            self.enter_mode(target)
        elif target.guidance in (Guidance.HOLD, Guidance.STICKS):
            self._start_guidance()  # already holding (e.g. flying to a reposition target): stop here
