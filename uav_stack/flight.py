"""The agent's flight state machine: one object owns the phase, the pending FCU command and the timers.

Who wants what:

* the **agent** drives it once per control tick (:meth:`Flight.progress`): the FCU-facing phases
  (init, arming, takeoff, entering offboard, landing, yielded) advance here, and in the phases
  under swarm control (:data:`~uav_stack.phases.CONTROLLED`) the agent flies its mission;
* **deciders** read the agent and ask for an intent: the ground station's overrides
  (:mod:`uav_stack.overrides`), the companion failsafes (:mod:`uav_stack.failsafe`) and the mission
  itself (done, land, hold, altitude);
* :meth:`Flight.apply` is the one place an intent becomes a phase change. It checks the change
  against :data:`TRANSITIONS` (a change the table does not allow is refused, logged and counted:
  ``illegal_transitions``) and then does what the intent means for the FCU.

An intent is a small frozen dataclass (:class:`Hold`, :class:`GoTo`, :class:`Resume`,
:class:`TakeControl`, :class:`YieldTo`, :class:`Land`, :class:`ReturnToLaunch`, :class:`Kill`,
:class:`Launch`, :class:`Finish`, :class:`Altitude`). Positions are in the swarm frame (metres east,
north and up from the swarm's origin).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from uav_stack.arming import RETRY_AFTER, Arming
from uav_stack.phases import CONTROLLED, AgentPhase

if TYPE_CHECKING:
    from uav_stack.fcu_link import CommandHandle, FcuLink

log = logging.getLogger(__name__)

P = AgentPhase
Vec2 = tuple[float, float]

OFFBOARD_PRESTREAM = 1.3  # s of setpoints before asking for the offboard mode (PX4 OFFBOARD needs > 1 s)
LANDED_BELOW_M = 1.0  # m above home under which a disarmed UAV counts as on the ground
AT_ALTITUDE_M = 1.0  # m under the target altitude at which a takeoff counts as done


@dataclass
class Own:
    """The UAV's own state in the swarm frame (m, m/s, rad), derived from the FCU's telemetry by the agent."""

    x: float = math.nan
    y: float = math.nan
    z: float = math.nan
    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0
    yaw: float = 0.0  # ENU


# ---- intents ------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Hold:
    """Hold ``point`` (x, y in m) under the agent's control, avoidance still on; ``None``: brake
    to a hover where the UAV is (zero velocity). ``operator``: the ground station's hold, kept
    until ``resume`` (the state's override ``hold``)."""

    point: Vec2 | None
    detail: str
    operator: bool = False


@dataclass(frozen=True, slots=True)
class GoTo:
    """Fly to (x, y) at altitude z (m above the swarm's origin), then hold there (override ``goto``)."""

    x: float
    y: float
    z: float
    detail: str


@dataclass(frozen=True, slots=True)
class Resume:
    """Back to the swarm's work: ``to`` the phase given, or the mission if it has started, else
    hover. ``operator``: the ground station's resume, which drops its override and goes back to
    the cruise altitude; ``override``: the override to show from now on (None: unchanged)."""

    detail: str
    to: AgentPhase | None = None
    operator: bool = False
    override: str | None = None


@dataclass(frozen=True, slots=True)
class TakeControl:
    """Take the FCU back (from a ground station, the FCU's own fallback or an RTL): stream
    setpoints, then ask for the offboard mode. ``keep_hold``: an operator's hold stays a hold."""

    detail: str
    keep_hold: bool = False


@dataclass(frozen=True, slots=True)
class YieldTo:
    """Someone else flies the UAV (a pilot, a ground station, the FCU's failsafe): stop sending setpoints."""

    override: str  # who: ``fcu:<mode>``, ``gcs:<command>``
    detail: str


@dataclass(frozen=True, slots=True)
class Land:
    """Land where the UAV is (the FCU's land mode). ``override``: who asked (``land``), if it is to show."""

    detail: str = ""
    override: str | None = None


@dataclass(frozen=True, slots=True)
class ReturnToLaunch:
    """The FCU returns to its home and lands; the agent sends no setpoints meanwhile."""

    detail: str
    override: str | None = None


@dataclass(frozen=True, slots=True)
class Kill:
    """Stop the motors now (the operator's kill: a forced disarm)."""

    detail: str


@dataclass(frozen=True, slots=True)
class Launch:
    """Arm and take off; ``go``: then fly the mission (``start``), else hover (``takeoff``); None: as before."""

    detail: str = ""
    go: bool | None = None


@dataclass(frozen=True, slots=True)
class Finish:
    """The mission has nothing left to do: hover where it ended (phase ``done``)."""

    detail: str


@dataclass(frozen=True, slots=True)
class Altitude:
    """Fly at ``z`` m above the swarm's origin from now on (no phase change)."""

    z: float


Intent = Hold | GoTo | Resume | TakeControl | YieldTo | Land | ReturnToLaunch | Kill | Launch | Finish | Altitude

# Where each phase may go next. Landing, returning to launch and a kill are allowed from every
# phase (a safety action is never refused by the table); staying in a phase is always allowed.
ANYTIME = frozenset({P.LANDING, P.RTL, P.KILLED})
_FLYING = frozenset({P.HOVER, P.MISSION, P.DONE, P.HOLD, P.GOTO, P.YIELDED})
TRANSITIONS: dict[AgentPhase, frozenset[AgentPhase]] = {
    P.INIT: frozenset({P.READY}),
    P.READY: frozenset({P.ARMING, P.YIELDED}),
    P.ARMING: frozenset({P.TAKEOFF, P.ERROR}),
    P.ERROR: frozenset({P.ARMING}),
    P.TAKEOFF: frozenset({P.OFFBOARD, P.YIELDED}),
    P.OFFBOARD: frozenset({P.HOVER, P.MISSION, P.HOLD, P.YIELDED}),
    P.HOVER: _FLYING,
    P.MISSION: _FLYING,
    P.DONE: _FLYING,
    P.HOLD: _FLYING,
    P.GOTO: _FLYING,
    P.YIELDED: frozenset({P.OFFBOARD, P.READY, P.LANDED}),
    P.RTL: _FLYING | {P.OFFBOARD, P.LANDED},  # an RTL the FCU refused goes back to where it was
    P.LANDING: frozenset({P.LANDED}),
    P.LANDED: frozenset({P.ARMING, P.YIELDED}),
    P.KILLED: frozenset({P.ARMING}),
}


class Flight:
    """One UAV's flight: the phase and its detail, the operator's override, the pending FCU
    command, the targets (altitude, hold point, goto point) and the timers of each phase."""

    def __init__(self, uav: int, link: FcuLink, own: Own, clock: Callable[[], float], cruise_alt: float,
                 home_alt: float, autostart: bool, arm_timeout_s: float):
        self.uav = uav
        self.link = link
        self.own = own  # kept current by the agent from the FCU's telemetry
        self.clock = clock
        self.cruise_alt = cruise_alt  # m above the swarm's origin: the mission's altitude
        self.home_alt = home_alt  # m AMSL of the swarm's origin
        self.phase = P.INIT
        self.detail = ""
        self.override = ""  # who overrides the swarm: hold, goto, rtl, land, kill, fcu:<mode>, gcs:<command>
        self.since = clock()  # when the current phase began (or its command was last sent)
        self.command: CommandHandle | None = None  # the phase's pending FCU command (takeoff, mode, land)
        self.alt_target = cruise_alt  # m above the swarm's origin
        self.hold_point: Vec2 = (math.nan, math.nan)  # NaN: brake where it is
        self.goto_target: Vec2 = (math.nan, math.nan)
        self.go = autostart  # fly the mission once airborne
        self.started_at: float | None = None  # when takeoff or start arrived
        self.mission_started_at: float | None = None
        self.gcs_takeover: str | None = None  # a ground station's motion command the router saw
        self.changed = True  # something a ground station should see now (the agent publishes its state)
        self.counters: dict[str, int] = {"illegal_transitions": 0}
        self.arming = Arming(arm_timeout_s)
        self._offboard_since: float | None = None  # when the setpoint stream before the offboard switch began
        self._yielded_from: AgentPhase | None = None  # the phase a takeover interrupted
        self._mode_at_phase = ""  # the FCU's mode when the phase began (a change while climbing is a takeover)
        self._apply: dict[type, Callable[..., None]] = {
            Hold: self._hold, GoTo: self._goto, Resume: self._resume, TakeControl: self._take_control,
            YieldTo: self._yield, Land: self._land, ReturnToLaunch: self._rtl, Kill: self._kill,
            Launch: self._launch, Finish: self._finish, Altitude: self._altitude,
        }
        self._progress: dict[AgentPhase, Callable[[float], bool]] = {
            P.ARMING: self._arming, P.TAKEOFF: self._takeoff, P.OFFBOARD: self._offboard,
            P.YIELDED: self._yielded, P.RTL: self._yielded, P.LANDING: self._landing,
            **{ph: self._controlled for ph in CONTROLLED},
        }

    # ---- what deciders read -----------------------------------------------------------------
    @property
    def airborne(self) -> bool:
        """Armed and more than a metre above home."""
        st = self.link.state
        return st.armed and st.relative_alt == st.relative_alt and st.relative_alt > 1.0

    @property
    def target_alt_amsl(self) -> float:
        return self.home_alt + self.alt_target

    def allows(self, phase: AgentPhase) -> bool:
        """True if the table lets the current phase go to ``phase``."""
        return phase == self.phase or phase in ANYTIME or phase in TRANSITIONS[self.phase]

    # ---- the one place intents are applied ----------------------------------------------------
    def apply(self, intent: Intent) -> bool:
        """Do what ``intent`` asks; False (logged, counted) if the table does not allow it now."""
        target = self._target(intent)
        if target is not None and not self.allows(target):
            self.counters["illegal_transitions"] += 1
            log.error("UAV %d: %s refused in phase %s (%s -> %s is not a transition)", self.uav,
                      type(intent).__name__, self.phase, self.phase, target)
            return False
        self._apply[type(intent)](intent)
        return True

    def _target(self, intent: Intent) -> AgentPhase | None:
        if isinstance(intent, Resume):
            return intent.to or (P.MISSION if self.mission_started_at is not None else P.HOVER)
        return _TARGETS.get(type(intent))

    def say(self, detail: str) -> None:
        """A new detail for the current phase (what it waits for): logged and published when it changes."""
        if detail != self.detail:
            log.info("UAV %d: %s: %s", self.uav, self.phase, detail)
            self.detail = detail
            self.changed = True

    def _enter(self, phase: AgentPhase, detail: str = "") -> None:
        if phase != self.phase:
            log.info("UAV %d: %s -> %s %s", self.uav, self.phase, phase, detail)
            self.phase = phase
            self.since = self.clock()
            self._mode_at_phase = self.link.state.mode
            self.changed = True
        self.detail = detail

    # ---- intents ------------------------------------------------------------------------------
    def _hold(self, i: Hold) -> None:
        self.hold_point = i.point if i.point is not None else (math.nan, math.nan)
        if i.operator:
            self.override = "hold"
        self._enter(P.HOLD, i.detail)

    def _goto(self, i: GoTo) -> None:
        self.goto_target = (i.x, i.y)
        self.alt_target = i.z
        self.override = "goto"
        self._enter(P.GOTO, i.detail)

    def _resume(self, i: Resume) -> None:
        if i.operator:
            self.override = ""
            self.alt_target = self.cruise_alt
        if i.override is not None:
            self.override = i.override
        target = self._target(i)
        assert target is not None
        self._enter(target, i.detail)

    def _take_control(self, i: TakeControl) -> None:
        self.override = "hold" if i.keep_hold else ""
        if not i.keep_hold:
            self.alt_target = self.cruise_alt
        self._offboard_since = self.clock()
        self.command = None
        self._enter(P.OFFBOARD, i.detail)

    def _yield(self, i: YieldTo) -> None:
        self._yielded_from = self.phase
        self.override = i.override[:32]
        self._enter(P.YIELDED, f"{i.detail}; setpoints stopped")

    def _land(self, i: Land) -> None:
        if i.override is not None:
            self.override = i.override
        if self.phase in (P.LANDING, P.LANDED):
            if i.detail:
                self.detail = i.detail
            return
        self.command = self.link.land()
        self._enter(P.LANDING, i.detail)

    def _rtl(self, i: ReturnToLaunch) -> None:
        self.command = self.link.return_to_launch()
        if i.override is not None:
            self.override = i.override
        self._enter(P.RTL, i.detail)

    def _kill(self, i: Kill) -> None:
        self.command = self.link.arm(False, force=True)
        self.override = "kill"
        self._enter(P.KILLED, i.detail)

    def _launch(self, i: Launch) -> None:
        if i.go is not None:
            self.go = i.go
        self.command = None
        self.arming.begin(self.clock())
        self._enter(P.ARMING, i.detail)

    def _finish(self, i: Finish) -> None:
        self._enter(P.DONE, i.detail)

    def _altitude(self, i: Altitude) -> None:
        self.alt_target = i.z

    # ---- progress, once per control tick ---------------------------------------------------------
    def progress(self, now: float, have_pos: bool) -> bool:
        """Advance the phase; True if the agent is to fly its mission (or hold, or goto) this tick."""
        ph = self.phase
        if ph == P.INIT:
            self._init(have_pos)
            return False
        if ph in (P.READY, P.LANDED) and (why := self._flown_by_someone_else()) is not None:
            self.apply(why)  # a ground station flies a UAV the swarm is not flying: show it
            return False
        if not self.link.connected and ph not in (P.READY, P.LANDED, P.ERROR):
            self.detail = "FCU link lost"
        if ph in (P.TAKEOFF, P.OFFBOARD) and (why := self._taken_over_climbing()) is not None:
            self.apply(why)
            return False
        if ph not in CONTROLLED:
            self.gcs_takeover = None
        step = self._progress.get(self.phase)
        return step(now) if step is not None else False

    def _init(self, have_pos: bool) -> None:
        if self.link.connected and have_pos:
            self._enter(P.READY)
            if self.go or self.started_at is not None:
                self.apply(Launch())
        else:
            self.say(self._init_waits_for())

    def _init_waits_for(self) -> str:
        """What the agent waits for before it can fly, in the autopilot's terms (the phase detail in ``init``)."""
        link = self.link
        if not link.connected:
            if link.fcu_ids is None:
                return f"no heartbeat from an autopilot on {link.url}" + (" (other messages only)" if link.counts["rx"] else "")
            return "FCU link lost: no heartbeat for 3 s"
        return link.contract.waiting_for() or f"no position from the autopilot: {link.state.no_position}"

    def _arming(self, now: float) -> bool:
        self.arming.step(self, now)
        return False

    def take_off(self, now: float) -> None:
        """Armed in a mode that takes off: the takeoff command (the arming step's last act)."""
        st = self.link.state
        self.command = self.link.takeoff(self.target_alt_amsl, self.target_alt_amsl - (st.home[2] if st.home else st.alt))
        self._enter(P.TAKEOFF)

    def give_up_arming(self, why: str) -> None:
        """The arming step's bound passed: phase ``error`` (a takeoff or start tries again)."""
        self._enter(P.ERROR, why)

    def _takeoff(self, now: float) -> bool:
        h = self.command
        if h is not None and h.done and not h.accepted and now - self.since > RETRY_AFTER:
            self.command = self.link.takeoff(self.target_alt_amsl, self.cruise_alt)
            self.since = now
        if self.link.state.alt >= self.target_alt_amsl - AT_ALTITUDE_M:
            self._offboard_since = now
            self._enter(P.OFFBOARD)
        return False

    def _offboard(self, now: float) -> bool:
        """Setpoints stream (zero velocity, the agent sends them) until the FCU is in its offboard mode."""
        link = self.link
        if link.in_offboard:
            if self.override == "hold":  # held while taking off
                self.apply(Hold(self.hold_here(), "operator hold", operator=True))
            elif self.mission_started_at is not None and self.go:  # control taken back: resume the mission
                self.apply(Resume("resumed", P.MISSION))
            else:
                self._enter(P.HOVER)
        elif now - (self._offboard_since or now) >= OFFBOARD_PRESTREAM and (self.command is None or self.command.done):
            self.command = link.set_mode(link.state.profile.offboard_mode)
        return False

    def hold_here(self) -> Vec2:
        """Where a hold that begins now holds: the UAV's own position (x, y in m)."""
        return (self.own.x, self.own.y)

    def _controlled(self, now: float) -> bool:
        why = self._taken_over()
        self.gcs_takeover = None
        if why is not None:
            self.apply(why)  # a human (or the FCU's failsafe) took over: stop fighting them, say so
            return False
        if self.phase == P.HOVER and self.go:
            if self.mission_started_at is None:
                self.mission_started_at = now
            self._enter(P.MISSION)
        return True

    def _yielded(self, now: float) -> bool:
        st = self.link.state
        if not st.armed and st.relative_alt < LANDED_BELOW_M:
            self._landed_after_takeover()
        return False

    def _landing(self, now: float) -> bool:
        st = self.link.state
        h = self.command
        if not st.armed and st.relative_alt < LANDED_BELOW_M:
            self._enter(P.LANDED)
        elif h is not None and h.done and not h.accepted and now - self.since > RETRY_AFTER:
            self.command = self.link.land()
            self.since = now
        return False

    # ---- takeovers: someone else flies the UAV ----------------------------------------------------
    def _taken_over(self) -> YieldTo | None:
        st = self.link.state
        if not st.armed:
            return YieldTo("fcu:disarmed", "FCU disarmed")
        if not self.link.in_offboard:
            return YieldTo(f"fcu:{st.mode}", f"FCU switched to {st.mode}")
        return self._gcs_took_over()

    def _taken_over_climbing(self) -> YieldTo | None:
        """The same while taking off or entering offboard, where other modes are expected."""
        st = self.link.state
        if st.mode not in st.profile.climb_modes and st.mode != self._mode_at_phase:
            return YieldTo(f"fcu:{st.mode}", f"FCU switched to {st.mode}")
        return self._gcs_took_over()

    def _gcs_took_over(self) -> YieldTo | None:
        if self.gcs_takeover is not None:
            return YieldTo(f"gcs:{self.gcs_takeover}", f"a ground station sent {self.gcs_takeover}")
        return None

    def _flown_by_someone_else(self) -> YieldTo | None:
        """In the air although the swarm is not flying it."""
        if not self.airborne:
            return None
        mode = self.link.state.mode
        return self._gcs_took_over() or YieldTo(f"fcu:{mode}", f"flying in {mode} under another controller")

    def _landed_after_takeover(self) -> None:
        """A yielded UAV is back on the ground: ready again if the swarm never flew it, else landed."""
        if self.phase == P.YIELDED and self._yielded_from in (P.INIT, P.READY):
            self.override = ""
            self._enter(P.READY, "landed under FCU control")
        else:
            self._enter(P.LANDED, "landed under FCU control")
        self._yielded_from = None


_TARGETS: dict[type, AgentPhase] = {
    Hold: P.HOLD, GoTo: P.GOTO, TakeControl: P.OFFBOARD, YieldTo: P.YIELDED, Land: P.LANDING,
    ReturnToLaunch: P.RTL, Kill: P.KILLED, Launch: P.ARMING, Finish: P.DONE,
}
