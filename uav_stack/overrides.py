"""Ground-station overrides in the agent: hold, resume, goto, rtl, arm, disarm, kill (docs/gcs.md).

:class:`OverridesMixin` is part of :class:`uav_stack.agent.Agent`; it holds the verb handlers,
the acknowledgements that wait for the FCU's COMMAND_ACK, and the takeover checks (a human or
a failsafe taking the FCU from the agent). An override beats the swarm behaviour: its
setpoints stay suspended until ``resume``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from uav_stack.fcu_link import CommandHandle
from uav_stack.phases import CONTROLLED, AgentPhase

if TYPE_CHECKING:
    from swarmnet.node import SwarmNode
    from uav_stack.agent import Own
    from uav_stack.config import AgentConfig, Rect
    from uav_stack.fcu_link import FcuLink
    from uav_stack.geo import LocalFrame

log = logging.getLogger(__name__)


DEFERRED_ACK_TIMEOUT = 4.0  # s: an override the FCU must confirm is acked as failed after this
HOLD_GAIN = 0.8  # 1/s: velocity towards a hold/goto point = gain * distance (capped)
ARRIVED_M = 1.0


@dataclass
class _DeferredAck:
    """A command acknowledged once the FCU has answered the MAVLink command it caused."""

    cmd_id: int
    verb: str
    handle: CommandHandle
    ok_message: str
    sent_at: float
    on_fail: Any = None  # () -> None: undo what the agent did in anticipation


OVERRIDE_VERBS = ("hold", "resume", "goto", "rtl", "arm", "disarm", "kill")


def _number(args: dict[str, Any], name: str) -> float:
    if not isinstance(args, dict) or name not in args:
        raise ValueError(f"missing argument {name!r}")
    v = args[name]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"argument {name}={v!r} is not a finite number")
    return float(v)


class OverridesMixin:
    """Verb handlers and takeover checks; mixed into Agent, which provides the state they use."""

    # The Agent state these handlers read and write (set in Agent.__init__; annotations only).
    cfg: AgentConfig
    node: SwarmNode
    link: FcuLink
    own: Own
    phase: AgentPhase
    override: str
    counters: dict[str, int]
    mission_started_at: float | None
    alt_target: float  # m above the swarm origin
    hold_point: tuple[float, float]
    goto_target: tuple[float, float]
    fence: Rect | None  # x_min, x_max, y_min, y_max (ENU m)
    _handle: CommandHandle | None
    _offboard_stream_since: float | None
    _deferred: list[_DeferredAck]
    _gcs_takeover: str | None
    _mode_at_phase: str
    _yielded_from: AgentPhase | None
    frame: LocalFrame  # the swarm frame: ENU metres from the origin
    go: bool  # fly the mission once airborne

    if TYPE_CHECKING:
        def _set_phase(self, phase: AgentPhase, detail: str = "") -> None: ...  # Agent's
        def _begin_flight(self, detail: str = "") -> None: ...  # Agent's

    def _airborne(self) -> bool:
        st = self.link.state
        return st.armed and st.relative_alt == st.relative_alt and st.relative_alt > 1.0

    def _cmd_hold(self, args: dict[str, Any], now: float) -> tuple[bool, str]:
        ph = self.phase
        if ph in CONTROLLED:
            self._hold_here()
            x, y = self.hold_point
            return True, f"holding at ({x:.1f}, {y:.1f}, {self.alt_target:.1f})"
        if ph in (AgentPhase.ARMING, AgentPhase.TAKEOFF, AgentPhase.OFFBOARD):
            self.override = "hold"
            return True, "will hold once airborne under swarm control"
        if ph == AgentPhase.YIELDED:
            return False, f"yielded: the FCU is in {self.link.state.mode} (someone took over); send resume to take control back"
        return False, f"cannot hold in phase {ph}"

    def _hold_here(self) -> None:
        o = self.own
        self.hold_point = (o.x, o.y)
        self.override = "hold"
        self._set_phase(AgentPhase.HOLD, "operator hold")

    def _cmd_goto(self, args: dict[str, Any], now: float) -> tuple[bool, str]:
        try:
            if isinstance(args, dict) and "lat" in args:  # geodetic: degrees, metres AMSL
                x, y, z = self._geo_to_swarm(_number(args, "lat"), _number(args, "lon"), _number(args, "alt"))
            else:
                x, y = _number(args, "x"), _number(args, "y")
                z = _number(args, "z") if args.get("z") is not None else self.alt_target
        except ValueError as exc:
            return False, f"goto: {exc}"
        g = self.cfg.gcs
        if not g.min_alt <= z <= g.max_alt:
            return False, f"goto: altitude {z:g} m outside the allowed {g.min_alt:g}..{g.max_alt:g} m above the origin"
        if self.fence is not None:
            x0, x1, y0, y1 = self.fence
            if not (x0 <= x <= x1 and y0 <= y <= y1):
                return False, f"goto: ({x:g}, {y:g}) is outside the geofence x {x0:g}..{x1:g}, y {y0:g}..{y1:g}"
        if self.phase not in CONTROLLED:
            hint = " (someone took over; send resume first)" if self.phase == AgentPhase.YIELDED else ""
            return False, f"goto: not airborne under swarm control (phase {self.phase}){hint}"
        self.goto_target = (x, y)
        self.alt_target = z
        self.override = "goto"
        self._set_phase(AgentPhase.GOTO, f"going to ({x:g}, {y:g}, {z:g})")
        return True, f"going to ({x:g}, {y:g}, {z:g})"

    def _cmd_resume(self, args: dict[str, Any], now: float) -> tuple[bool, str]:
        ph = self.phase
        if ph in (AgentPhase.HOLD, AgentPhase.GOTO):
            self.override = ""
            self.alt_target = self.cfg.altitude
            if self.mission_started_at is not None:
                self._set_phase(AgentPhase.MISSION, "resumed")
            else:
                self._set_phase(AgentPhase.HOVER, "resumed")
            return True, "behaviour resumed"
        if ph in (AgentPhase.YIELDED, AgentPhase.RTL):
            if not self._airborne():
                return False, f"cannot resume: on the ground ({self.link.state.mode}); use start"
            self.override = ""
            self.alt_target = self.cfg.altitude
            self._offboard_stream_since = now
            self._handle = None
            self._set_phase(AgentPhase.OFFBOARD, "taking control back")
            return True, f"taking control back from {self.link.state.mode}, then resuming"
        if ph in (AgentPhase.ARMING, AgentPhase.TAKEOFF, AgentPhase.OFFBOARD) and self.override == "hold":
            self.override = ""
            return True, "pending hold cancelled"
        if ph in (AgentPhase.HOVER, AgentPhase.MISSION, AgentPhase.DONE):
            return True, f"nothing to resume ({ph})"
        if ph in (AgentPhase.LANDED, AgentPhase.KILLED):
            return False, f"cannot resume in phase {ph}: on the ground; start relaunches it into the mission (takeoff: to hover)"
        return False, f"cannot resume in phase {ph}"

    def _cmd_rtl(self, args: dict[str, Any], now: float) -> tuple[bool, str] | _DeferredAck:
        if not self._airborne():
            return False, f"rtl: not flying (phase {self.phase})"
        prev, prev_override = self.phase, self.override
        h = self.link.return_to_launch()
        self.override = "rtl"
        self._set_phase(AgentPhase.RTL, "returning to launch (operator)")

        def undo() -> None:
            if self.phase == AgentPhase.RTL:
                self.override = prev_override
                self._set_phase(prev if self.link.in_offboard else AgentPhase.YIELDED, "RTL refused by the FCU")

        return _DeferredAck(0, "rtl", h, "returning to launch", now, undo)

    def _cmd_arm(self, args: dict[str, Any], now: float) -> tuple[bool, str] | _DeferredAck:
        if self.phase not in (AgentPhase.READY, AgentPhase.LANDED):
            return False, f"arm: only on the ground when idle (phase {self.phase})"
        if self.link.state.armed:
            return True, "already armed"
        return _DeferredAck(0, "arm", self.link.arm(True), "armed", now)

    def _cmd_disarm(self, args: dict[str, Any], now: float) -> tuple[bool, str] | _DeferredAck:
        if not self.link.state.armed:
            return True, "already disarmed"
        if self._airborne():
            return False, "disarm: in the air (the motors would stop); land first, or use kill"
        return _DeferredAck(0, "disarm", self.link.arm(False), "disarmed", now)

    def _cmd_kill(self, args: dict[str, Any], now: float) -> tuple[bool, str] | _DeferredAck:
        h = self.link.arm(False, force=True)
        self.override = "kill"
        self._set_phase(AgentPhase.KILLED, "motors stopped by the operator")
        return _DeferredAck(0, "kill", h, "motors stopped", now)

    def _defer(self, d: _DeferredAck) -> None:
        # FcuLink keeps one pending handle per MAVLink command: a newer one (kill after disarm)
        # replaces the older, which would never resolve. Both acks follow the newer answer.
        for old in self._deferred:
            if old.handle.command == d.handle.command and not old.handle.done:
                old.handle = d.handle
        self._deferred.append(d)

    def _settle_acks(self, now: float) -> None:
        keep: list[_DeferredAck] = []
        for d in self._deferred:
            h = d.handle
            if not h.done and now - d.sent_at < DEFERRED_ACK_TIMEOUT:
                keep.append(d)
                continue
            if h.accepted:
                self.node.ack(d.cmd_id, True, d.ok_message)
                continue
            status = h.status if h.done else "no answer"
            texts = self.link.state.statustext
            why = f"FCU {status}" + (f" (last FCU message: {texts[-1]})" if texts and h.done else "")
            if d.on_fail is not None:
                d.on_fail()
            self.counters["rejected_commands"] += 1
            self.node.ack(d.cmd_id, False, f"{d.verb} failed: {why}")
        self._deferred = keep

    def _taken_over(self) -> tuple[str, str] | None:
        """(override, detail) if a human or a failsafe took the FCU from us."""
        st = self.link.state
        if not st.armed:
            return "fcu:disarmed", "FCU disarmed"
        if not self.link.in_offboard:
            return f"fcu:{st.mode}", f"FCU switched to {st.mode}"
        if self._gcs_takeover is not None:
            return f"gcs:{self._gcs_takeover}", f"a ground station sent {self._gcs_takeover}"
        return None

    def _taken_over_climbing(self) -> tuple[str, str] | None:
        """The same while taking off / entering OFFBOARD, where other modes are expected."""
        st = self.link.state
        if st.mode not in st.profile.climb_modes and st.mode != self._mode_at_phase:
            return f"fcu:{st.mode}", f"FCU switched to {st.mode}"
        if self._gcs_takeover is not None:
            return f"gcs:{self._gcs_takeover}", f"a ground station sent {self._gcs_takeover}"
        return None

    def _geo_to_swarm(self, lat: float, lon: float, alt: float) -> tuple[float, float, float]:
        """A geodetic point (deg, deg, m AMSL) in the swarm frame (m east, north, up from the origin)."""
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise ValueError(f"latitude/longitude {lat:g},{lon:g} out of range")
        return self.frame.to_enu(lat, lon, alt)

    def _relaunch(self, verb: str) -> tuple[bool, str]:
        """``takeoff``/``start`` for a UAV on the ground after landing: fly again, from its mission's state."""
        ph = self.phase
        if ph == AgentPhase.YIELDED:
            return False, f"yielded: the FCU is in {self.link.state.mode} (someone took over); send resume to take control back"
        if ph not in (AgentPhase.LANDED, AgentPhase.KILLED):
            return True, f"already {ph}"
        if self._airborne():
            return False, f"{verb}: still in the air ({self.link.state.mode}); wait until it has landed"
        self.go = verb == "start"  # takeoff: climb and hover; start: back into the mission
        self.override = ""
        self._begin_flight(f"relaunched ({verb})")
        return True, "taking off again" + (", then back to the mission" if self.go else "")

    def _flown_by_someone_else(self) -> tuple[str, str] | None:
        """(override, detail) when the UAV is in the air although the swarm is not flying it."""
        if not self._airborne():
            return None
        if self._gcs_takeover is not None:
            return f"gcs:{self._gcs_takeover}", f"a ground station sent {self._gcs_takeover}"
        mode = self.link.state.mode
        return f"fcu:{mode}", f"flying in {mode} under another controller"

    def _landed_after_takeover(self) -> None:
        """A yielded UAV is back on the ground: ready again if the swarm never flew it, else landed."""
        if self.phase == AgentPhase.YIELDED and self._yielded_from in (AgentPhase.INIT, AgentPhase.READY):
            self.override = ""
            self._set_phase(AgentPhase.READY, "landed under FCU control")
        else:
            self._set_phase(AgentPhase.LANDED, "landed under FCU control")
        self._yielded_from = None

    def _yield(self, why: tuple[str, str]) -> None:
        self._yielded_from = self.phase
        self.override = why[0][:32]
        self._set_phase(AgentPhase.YIELDED, f"{why[1]}; setpoints stopped")

    def _towards(self, target: tuple[float, float]) -> tuple[float, float]:
        o = self.own
        ex, ey = target[0] - o.x, target[1] - o.y
        d = math.hypot(ex, ey)
        if not d > 0.2:  # also NaN
            return 0.0, 0.0
        v = min(self.cfg.speed, HOLD_GAIN * d, math.sqrt(2.0 * 1.5 * d))
        return ex / d * v, ey / d * v

