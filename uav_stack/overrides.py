"""Ground-station commands to the agent: takeoff, start, land, stop and the overrides hold, resume,
goto, rtl, arm, disarm, kill (docs/gcs.md).

:class:`Overrides` decides: it checks a command's arguments and the flight's phase, answers with
an acknowledgement, and asks the flight (:class:`uav_stack.flight.Flight`) for the intent the
command means. An acknowledgement that depends on the FCU (rtl, land, arm, disarm, kill) waits
for the FCU's COMMAND_ACK (:class:`DeferredAck`). An override beats the swarm behaviour: its
setpoints stay suspended until ``resume``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from uav_stack.flight import GoTo, Hold, Kill, Land, Launch, Resume, ReturnToLaunch, TakeControl, YieldTo
from uav_stack.phases import CONTROLLED, AgentPhase

if TYPE_CHECKING:
    from swarmnet.messages import Command
    from swarmnet.node import SwarmNode
    from uav_stack.config import AgentConfig, Rect
    from uav_stack.fcu_link import CommandHandle, FcuLink
    from uav_stack.flight import Flight
    from uav_stack.geo import LocalFrame

log = logging.getLogger(__name__)

P = AgentPhase
DEFERRED_ACK_TIMEOUT = 4.0  # s: a command the FCU must confirm is acknowledged as failed after this
ON_THE_GROUND = (P.INIT, P.READY, P.LANDED, P.KILLED)
CLIMBING = (P.ARMING, P.TAKEOFF, P.OFFBOARD)

Answer = tuple[bool, str]


@dataclass
class DeferredAck:
    """A command acknowledged once the FCU has answered the MAVLink command it caused."""

    cmd_id: int
    verb: str
    handle: CommandHandle
    ok_message: str
    sent_at: float
    on_fail: Callable[[], None] | None = None  # undo what the agent did in anticipation


OVERRIDE_VERBS = ("hold", "resume", "goto", "rtl", "arm", "disarm", "kill")


def _number(args: dict[str, Any], name: str) -> float:
    if not isinstance(args, dict) or name not in args:
        raise ValueError(f"missing argument {name!r}")
    v = args[name]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"argument {name}={v!r} is not a finite number")
    return float(v)


class Overrides:
    """The ground station's commands to one agent: verb handlers and the acknowledgements that
    wait for the FCU."""

    def __init__(self, cfg: AgentConfig, flight: Flight, link: FcuLink, node: SwarmNode, frame: LocalFrame):
        self.cfg = cfg
        self.flight = flight
        self.link = link
        self.node = node
        self.frame = frame  # the swarm frame: ENU metres from the origin
        g = cfg.gcs
        m = cfg.mission
        # x_min, x_max, y_min, y_max (ENU m): where a goto may lead
        self.fence: Rect | None = g.geofence if g.geofence is not None else (m.area if m.type == "coverage" else None)
        self.counters = {"commands": 0, "rejected_commands": 0}
        self.deferred: list[DeferredAck] = []
        self._verbs: dict[str, Callable[[dict[str, Any], float], Answer | DeferredAck]] = {
            "hold": self._hold, "resume": self._resume, "goto": self._goto, "rtl": self._rtl,
            "arm": self._arm, "disarm": self._disarm, "kill": self._kill,
        }

    # ---- a command in, its acknowledgement out -------------------------------------------------
    def handle(self, cmd: Command, now: float) -> None:
        """Answer one command (now, or once the FCU has answered what it caused)."""
        self.counters["commands"] += 1
        verb = cmd.verb
        try:
            res = self._answer(verb, cmd.args, now)
        except Exception as exc:  # noqa: BLE001 - a bad command must never stop the agent
            log.exception("UAV %d: command %s failed", self.cfg.uav, verb)
            res = (False, f"{verb} failed in the agent: {type(exc).__name__}: {exc}")
        if isinstance(res, DeferredAck):
            res.cmd_id = cmd.cmd_id
            self._defer(res)
            return
        ok, msg = res
        if not ok:
            self.counters["rejected_commands"] += 1
        self.node.ack(cmd.cmd_id, ok, msg)

    def _answer(self, verb: str, args: dict[str, Any], now: float) -> Answer | DeferredAck:
        handler = self._verbs.get(verb)
        if handler is not None:
            return handler(args, now)
        if verb in ("takeoff", "start"):
            return self._launch(verb, now)
        if verb in ("land", "stop"):
            return self._land(verb, now)
        return False, f"unknown command {verb!r}"

    # ---- takeoff, start, land, stop ---------------------------------------------------------
    def _launch(self, verb: str, now: float) -> Answer:
        """takeoff: climb and hover; start: also begin the mission (taking off first if needed)."""
        f = self.flight
        if verb == "start":
            f.go = True
        ph = f.phase
        if ph in (P.INIT, P.READY, P.ERROR):
            f.started_at = now
            if ph == P.INIT:
                return True, "will take off once the FCU is up"
            f.apply(Launch())  # ready, or arming gave up (error): try (again)
            return True, "taking off"
        if ph == P.HOVER and f.go:
            return True, "mission starting"
        return self._relaunch(verb)  # landed (or killed) on the ground: fly again

    def _relaunch(self, verb: str) -> Answer:
        """``takeoff``/``start`` for a UAV on the ground after landing: fly again, from its mission's state."""
        f = self.flight
        ph = f.phase
        if ph == P.YIELDED:
            return False, f"yielded: the FCU is in {self.link.state.mode} (someone took over); send resume to take control back"
        if ph not in (P.LANDED, P.KILLED):
            return True, f"already {ph}"
        if f.airborne:
            return False, f"{verb}: still in the air ({self.link.state.mode}); wait until it has landed"
        f.override = ""
        f.apply(Launch(f"relaunched ({verb})", go=verb == "start"))  # takeoff: climb and hover; start: the mission
        return True, "taking off again" + (", then back to the mission" if f.go else "")

    def _land(self, verb: str, now: float) -> Answer | DeferredAck:
        f = self.flight
        if f.phase in ON_THE_GROUND and not self.link.state.armed:
            return True, f"on the ground ({f.phase})"
        if f.phase in (P.LANDING, P.LANDED):
            return True, "already landing"
        f.apply(Land(override="land" if verb == "land" else None))
        if f.command is not None:  # acknowledged with the FCU's answer to NAV_LAND
            return DeferredAck(0, verb, f.command, "landing", now)
        return True, "landing"

    # ---- overrides ----------------------------------------------------------------------------
    def _hold(self, args: dict[str, Any], now: float) -> Answer:
        f = self.flight
        ph = f.phase
        if ph in CONTROLLED:
            f.apply(Hold(f.hold_here(), "operator hold", operator=True))
            x, y = f.hold_point
            return True, f"holding at ({x:.1f}, {y:.1f}, {f.alt_target:.1f})"
        if ph in CLIMBING:
            f.override = "hold"  # the flight holds once in its offboard mode
            return True, "will hold once airborne under swarm control"
        if ph == P.YIELDED:
            return False, f"yielded: the FCU is in {self.link.state.mode} (someone took over); send resume to take control back"
        return False, f"cannot hold in phase {ph}"

    def _goto(self, args: dict[str, Any], now: float) -> Answer:
        f = self.flight
        try:
            if isinstance(args, dict) and "lat" in args:  # geodetic: degrees, metres AMSL
                x, y, z = self._geo_to_swarm(_number(args, "lat"), _number(args, "lon"), _number(args, "alt"))
            else:
                x, y = _number(args, "x"), _number(args, "y")
                z = _number(args, "z") if args.get("z") is not None else f.alt_target
        except ValueError as exc:
            return False, f"goto: {exc}"
        g = self.cfg.gcs
        if not g.min_alt <= z <= g.max_alt:
            return False, f"goto: altitude {z:g} m outside the allowed {g.min_alt:g}..{g.max_alt:g} m above the origin"
        if self.fence is not None:
            x0, x1, y0, y1 = self.fence
            if not (x0 <= x <= x1 and y0 <= y <= y1):
                return False, f"goto: ({x:g}, {y:g}) is outside the geofence x {x0:g}..{x1:g}, y {y0:g}..{y1:g}"
        if f.phase not in CONTROLLED:
            hint = " (someone took over; send resume first)" if f.phase == P.YIELDED else ""
            return False, f"goto: not airborne under swarm control (phase {f.phase}){hint}"
        f.apply(GoTo(x, y, z, f"going to ({x:g}, {y:g}, {z:g})"))
        return True, f"going to ({x:g}, {y:g}, {z:g})"

    def _resume(self, args: dict[str, Any], now: float) -> Answer:
        f = self.flight
        ph = f.phase
        if ph in (P.HOLD, P.GOTO):
            f.apply(Resume("resumed", operator=True))
            return True, "behaviour resumed"
        if ph in (P.YIELDED, P.RTL):
            if not f.airborne:
                return False, f"cannot resume: on the ground ({self.link.state.mode}); use start"
            f.apply(TakeControl("taking control back"))
            return True, f"taking control back from {self.link.state.mode}, then resuming"
        if ph in CLIMBING and f.override == "hold":
            f.override = ""
            return True, "pending hold cancelled"
        if ph in (P.HOVER, P.MISSION, P.DONE):
            return True, f"nothing to resume ({ph})"
        if ph in (P.LANDED, P.KILLED):
            return False, f"cannot resume in phase {ph}: on the ground; start relaunches it into the mission (takeoff: to hover)"
        return False, f"cannot resume in phase {ph}"

    def _rtl(self, args: dict[str, Any], now: float) -> Answer | DeferredAck:
        f = self.flight
        if not f.airborne:
            return False, f"rtl: not flying (phase {f.phase})"
        prev, prev_override = f.phase, f.override
        f.apply(ReturnToLaunch("returning to launch (operator)", override="rtl"))
        assert f.command is not None

        def undo() -> None:
            if f.phase != P.RTL:
                return
            if self.link.in_offboard:
                f.apply(Resume("RTL refused by the FCU", to=prev, override=prev_override))
            else:
                f.apply(YieldTo(f"fcu:{self.link.state.mode}", "RTL refused by the FCU"))

        return DeferredAck(0, "rtl", f.command, "returning to launch", now, undo)

    def _arm(self, args: dict[str, Any], now: float) -> Answer | DeferredAck:
        if self.flight.phase not in (P.READY, P.LANDED):
            return False, f"arm: only on the ground when idle (phase {self.flight.phase})"
        if self.link.state.armed:
            return True, "already armed"
        return DeferredAck(0, "arm", self.link.arm(True), "armed", now)

    def _disarm(self, args: dict[str, Any], now: float) -> Answer | DeferredAck:
        if not self.link.state.armed:
            return True, "already disarmed"
        if self.flight.airborne:
            return False, "disarm: in the air (the motors would stop); land first, or use kill"
        return DeferredAck(0, "disarm", self.link.arm(False), "disarmed", now)

    def _kill(self, args: dict[str, Any], now: float) -> DeferredAck:
        f = self.flight
        f.apply(Kill("motors stopped by the operator"))
        assert f.command is not None
        return DeferredAck(0, "kill", f.command, "motors stopped", now)

    def _geo_to_swarm(self, lat: float, lon: float, alt: float) -> tuple[float, float, float]:
        """A geodetic point (deg, deg, m AMSL) in the swarm frame (m east, north, up from the origin)."""
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise ValueError(f"latitude/longitude {lat:g},{lon:g} out of range")
        return self.frame.to_enu(lat, lon, alt)

    # ---- acknowledgements that wait for the FCU ---------------------------------------------------
    def _defer(self, d: DeferredAck) -> None:
        # FcuLink keeps one pending handle per MAVLink command: a newer one (kill after disarm)
        # replaces the older, which would never resolve. Both acks follow the newer answer.
        for old in self.deferred:
            if old.handle.command == d.handle.command and not old.handle.done:
                old.handle = d.handle
        self.deferred.append(d)

    def settle(self, now: float) -> None:
        """Acknowledge the deferred commands the FCU has answered (or not, within DEFERRED_ACK_TIMEOUT)."""
        keep: list[DeferredAck] = []
        for d in self.deferred:
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
        self.deferred = keep
