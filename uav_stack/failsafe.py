"""Companion failsafes: what the agent does when its links or its sensors fail (docs/reliability.md).

The same code runs on a real UAV's companion computer and in a virtual UAV. The semantics
follow PX4's failsafes (a timeout, then a hold, then an action), applied by the companion:

* **Swarm link lost**: no fresh neighbour pose and no link to the edge router for
  ``swarm_link_hold_s`` (T1, default 3 s) -> hold position (the mission stops, avoidance
  keeps working on what is known); still lost ``swarm_link_action_s`` after the loss (T2,
  default 15 s) -> ``swarm_link_action``, land (default) or RTL. The link coming back before T2
  resumes the mission. Armed only once the link has been seen, and only in the air.
* **FCU link lost** (no HEARTBEAT for 3 s, as MAVSDK): the pose is no longer published, so
  the neighbours see it go stale after their ``stale_after`` instead of trusting an old
  position. The FCU itself falls back to Hold (PX4's offboard loss, COM_OF_LOSS_T); when the
  link comes back the agent takes control again and resumes (or keeps the operator's hold).
* **Position suspect** (a GPS glitch): a position update farther than ``position_jump_m``
  from where the last one and its velocity predict -> brake and hover (zero velocity: a hold
  point would be wrong too) until ``position_settle_s`` pass without another jump.
* **Battery**: at or below ``battery_low`` a warning; at or below ``battery_critical`` ->
  ``battery_action`` (land by default).

Ground-station overrides keep priority where that is safe: an operator's kill, land or RTL,
and a ground station that took the FCU over MAVLink (the agent has yielded), are never
touched; an operator's hold stays a hold; an operator's goto becomes a hold while the swarm
link is lost (flying blind through the swarm is not safe), and T2's landing or the battery's
action apply over an operator's hold.

Every failsafe is visible: the agent publishes ``failsafe:<name>`` as its state's override
while one is active (``mrswarm gcs watch`` shows it beside the phase), and the events go into
the UAV's stats file (``failsafes``), from which the run's summary lists them.
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Annotated, Any, Literal, Protocol

from msgspec import Meta

from groundfloor.schema import Config, ConfigError
from uav_stack.flight import Hold, Land, Resume, ReturnToLaunch, TakeControl
from uav_stack.phases import CONTROLLED, AgentPhase

if TYPE_CHECKING:
    from swarmnet.node import SwarmNode
    from uav_stack.fcu_link import FcuLink
    from uav_stack.flight import Flight, Own

log = logging.getLogger(__name__)

PREFIX = "failsafe:"
MAX_EVENTS = 500
ROUTER_CHECK_S = 0.5  # how often the edge-router link is looked up (a call into Zenoh)
FCU_RESUME_WINDOW_S = 5.0  # after the FCU link returns, a fallback of the FCU to Hold is ours to undo
MAX_GAP_S = 1.0  # position updates further apart than this are not compared (a stall, a link loss)
STALL_S = 1.0  # the agent's own loop stopped this long (the process was stopped or starved): not a link loss
Action = Literal["land", "rtl"]
# phases in which someone or something else already flies the UAV, or it is safer than a hold
HANDS_OFF = frozenset({AgentPhase.YIELDED, AgentPhase.RTL, AgentPhase.LANDING, AgentPhase.LANDED, AgentPhase.KILLED,
                       AgentPhase.INIT, AgentPhase.READY, AgentPhase.ERROR})


class AgentView(Protocol):
    """What the failsafes read of the agent (and the flight they ask for intents)."""

    @property
    def uav(self) -> int: ...
    @property
    def link(self) -> FcuLink: ...
    @property
    def node(self) -> SwarmNode: ...
    @property
    def own(self) -> Own: ...
    @property
    def flight(self) -> Flight: ...


class FailsafeConfig(Config, frozen=True):
    """Thresholds and actions of the companion failsafes (scenario section ``failsafe``)."""

    swarm_link_hold_s: Annotated[float, Meta(gt=0.0, le=600.0, description="s without swarm link before holding (T1)")] = 3.0
    swarm_link_action_s: Annotated[float, Meta(gt=0.0, le=3600.0,
                                               description="s without swarm link before the action (T2)")] = 15.0
    swarm_link_action: Action = "land"
    resume: bool = True  # resume the mission when a lost link comes back (before T2)
    position_jump_m: Annotated[float, Meta(gt=0.0, le=1000.0, description="position innovation that marks a glitch, m")] = 5.0
    position_settle_s: Annotated[float, Meta(gt=0.0, le=600.0, description="s without a jump before trusting it again")] = 2.0
    battery_low: Annotated[float, Meta(ge=0.0, le=1.0, description="remaining fraction: warning")] = 0.15
    battery_critical: Annotated[float, Meta(ge=0.0, le=1.0, description="remaining fraction: battery_action")] = 0.07
    battery_action: Action = "land"
    # s the agent keeps trying to arm (its autopilot's pre-arm checks failing, or its arms refused)
    # before it gives up: phase error, with the autopilot's reason; a takeoff or start tries again
    arm_timeout_s: Annotated[float, Meta(gt=0.0, le=3600.0, description="s of arming before giving up")] = 60.0

    def __post_init__(self) -> None:
        if self.swarm_link_action_s <= self.swarm_link_hold_s:
            raise ConfigError("swarm_link_action_s", f"must be larger than swarm_link_hold_s ({self.swarm_link_hold_s} s)")
        if self.battery_critical > self.battery_low:
            raise ConfigError("battery_critical", f"must not be above battery_low ({self.battery_low})")


class Failsafes:
    """The failsafe state of one agent; :meth:`step` runs on every control tick, before the phase machine."""

    def __init__(self, cfg: FailsafeConfig | None = None):
        self.cfg = cfg or FailsafeConfig()
        self.active: dict[str, float] = {}  # failsafe name -> wall time it triggered
        self.events: list[dict[str, Any]] = []
        self.counts: dict[str, int] = {}
        self._holding: set[str] = set()  # failsafes that put the agent into its hold
        self._restore: tuple[AgentPhase, str] | None = None  # phase and operator override before our hold
        self._link_at = -math.inf  # last evidence of the swarm link
        self._link_seen = False
        self._router_up = False
        self._next_router_check = 0.0
        self._acted: set[str] = set()  # actions taken (land/rtl), once per loss
        self._fcu_seen = False
        self._fcu_resume_until = -math.inf
        self._fcu_saved_override = ""
        self._pos: tuple[float, float, float, float, float] | None = None  # x, y, vx, vy, position_at
        self._suspect_at = -math.inf
        self._battery_warned = False
        self._last_step = -math.inf

    # ---- what others read ---------------------------------------------------------------------
    @property
    def label(self) -> str:
        """``failsafe:<name>`` of the most serious active failsafe, "" if none (the state's override)."""
        for name in ("battery", "swarm_link", "fcu_link", "position"):
            if name in self.active:
                return PREFIX + name
        return ""

    @property
    def fcu_link_lost(self) -> bool:
        return "fcu_link" in self.active

    def as_dict(self) -> dict[str, Any]:
        return {"active": sorted(self.active), "counts": dict(self.counts), "events": list(self.events)}

    # ---- the tick -----------------------------------------------------------------------------
    def step(self, agent: AgentView, now: float) -> None:
        gap = now - self._last_step
        self._last_step = now
        if STALL_S < gap < math.inf:
            self._link_at += gap  # the companion itself was not running: that time says nothing about the link
        before = self.label
        self._fcu_link(agent, now)
        self._swarm_link(agent, now)
        self._position(agent, now)
        self._battery(agent, now)
        if self.label != before:
            agent.flight.changed = True  # tell the ground station now

    def _event(self, agent: AgentView, now: float, name: str, what: str, detail: str) -> None:
        if what == "triggered":
            self.counts[name] = self.counts.get(name, 0) + 1
        self.events.append({"t": round(now, 3), "failsafe": name, "event": what, "detail": detail})
        del self.events[:-MAX_EVENTS]
        log.warning("UAV %d: failsafe %s %s: %s", agent.uav, name, what, detail)

    # ---- FCU link -----------------------------------------------------------------------------
    def _fcu_link(self, agent: AgentView, now: float) -> None:
        connected = agent.link.connected
        if connected:
            self._fcu_seen = True
        if not self._fcu_seen:
            return
        if not connected and "fcu_link" not in self.active:
            self.active["fcu_link"] = now
            self._fcu_saved_override = agent.flight.override
            self._event(agent, now, "fcu_link", "triggered", "no FCU heartbeat for 3 s: pose no longer published")
        elif connected and "fcu_link" in self.active:
            lost = now - self.active.pop("fcu_link")
            self._fcu_resume_until = now + FCU_RESUME_WINDOW_S
            self._event(agent, now, "fcu_link", "cleared", f"FCU link back, {lost:.1f} s after its loss was detected")
        f = agent.flight
        if now < self._fcu_resume_until and f.phase == AgentPhase.YIELDED and f.override.startswith("fcu:") \
                and self.cfg.resume and f.airborne:
            # the FCU fell back to Hold because our setpoints stopped reaching it: take control back
            self._fcu_resume_until = -math.inf
            f.apply(TakeControl("taking control back after the FCU link loss", keep_hold=self._fcu_saved_override == "hold"))
            self._event(agent, now, "fcu_link", "resumed", "control taken back from the FCU's fallback")

    # ---- swarm link ---------------------------------------------------------------------------
    def _swarm_link(self, agent: AgentView, now: float) -> None:
        cfg = self.cfg
        if now >= self._next_router_check:
            self._next_router_check = now + ROUTER_CHECK_S
            self._router_up = bool(agent.node.routers())
        if self._router_up or agent.node.neighbours.fresh(now):
            self._link_at = now
            self._link_seen = True
        if not self._link_seen:
            return
        lost_for = now - self._link_at
        if "swarm_link" in self.active:
            if lost_for == 0.0:
                del self.active["swarm_link"]
                self._acted.discard("swarm_link")
                self._event(agent, now, "swarm_link", "cleared", "swarm link back")
                self._release(agent, "swarm_link", "swarm link back")
            elif lost_for >= cfg.swarm_link_action_s and "swarm_link" not in self._acted and agent.flight.phase not in HANDS_OFF:
                self._acted.add("swarm_link")
                self._act(agent, now, "swarm_link", cfg.swarm_link_action, f"swarm link lost for {lost_for:.1f} s")
            return
        if lost_for >= cfg.swarm_link_hold_s and agent.flight.airborne and agent.flight.phase not in HANDS_OFF:
            self.active["swarm_link"] = now
            what = f"no fresh neighbour and no edge router for {lost_for:.1f} s: holding, " \
                   f"{cfg.swarm_link_action} at {cfg.swarm_link_action_s:g} s"
            self._event(agent, now, "swarm_link", "triggered", what)
            self._hold(agent, "swarm_link", "swarm link lost: holding", brake=False)

    # ---- position (GPS) -------------------------------------------------------------------------
    def _position(self, agent: AgentView, now: float) -> None:
        st, o = agent.link.state, agent.own
        if st.position_at > (self._pos[4] if self._pos else -math.inf):
            prev = self._pos
            self._pos = (o.x, o.y, o.vx, o.vy, st.position_at)
            if prev is not None and 0.0 < st.position_at - prev[4] <= MAX_GAP_S:
                dt = st.position_at - prev[4]
                err = math.hypot(o.x - (prev[0] + prev[2] * dt), o.y - (prev[1] + prev[3] * dt))
                if err > self.cfg.position_jump_m:
                    self._suspect_at = now
                    if "position" not in self.active:
                        self.active["position"] = now
                        self._event(agent, now, "position", "triggered", f"position jumped {err:.1f} m: braking")
                        if agent.flight.airborne and agent.flight.phase not in HANDS_OFF:
                            self._hold(agent, "position", f"position jumped {err:.1f} m: braking", brake=True)
        if "position" in self.active and now - self._suspect_at >= self.cfg.position_settle_s:
            del self.active["position"]
            self._event(agent, now, "position", "cleared", f"no jump for {self.cfg.position_settle_s:g} s")
            self._release(agent, "position", "position trusted again")

    # ---- battery --------------------------------------------------------------------------------
    def _battery(self, agent: AgentView, now: float) -> None:
        b = agent.link.state.battery
        if not 0.0 <= b <= 1.0 or not agent.link.state.armed:
            return
        cfg = self.cfg
        if b <= cfg.battery_critical and "battery" not in self.active:
            self.active["battery"] = now
            self._battery_warned = True
            self._event(agent, now, "battery", "triggered", f"battery {100 * b:.0f} %: {cfg.battery_action}")
            if agent.flight.airborne and agent.flight.phase not in HANDS_OFF:
                self._act(agent, now, "battery", cfg.battery_action, f"battery critical ({100 * b:.0f} %)")
        elif b <= cfg.battery_low and not self._battery_warned:
            self._battery_warned = True
            self._event(agent, now, "battery", "warning", f"battery low ({100 * b:.0f} %)")

    # ---- actions --------------------------------------------------------------------------------
    def _hold(self, agent: AgentView, name: str, detail: str, brake: bool) -> None:
        """Hold (or brake to a hover) under the agent's control; remember what to go back to."""
        f = agent.flight
        if f.phase not in CONTROLLED:  # still climbing or entering offboard: the action at T2 covers it
            return
        if not self._holding:
            op = f.override if f.override in ("hold", "goto") else ""
            phase = f.phase if f.phase != AgentPhase.GOTO else AgentPhase.HOLD  # a goto becomes a hold
            self._restore = (phase, op if op != "goto" else "hold")
        self._holding.add(name)
        f.apply(Hold(None if brake else f.hold_here(), detail))

    def _release(self, agent: AgentView, name: str, detail: str) -> None:
        if name not in self._holding:
            return
        self._holding.discard(name)
        if self._holding or self._restore is None:
            return
        phase, op = self._restore
        self._restore = None
        f = agent.flight
        if f.phase != AgentPhase.HOLD or not self.cfg.resume:
            return  # someone changed it meanwhile (an operator, an action): leave it
        if op == "hold" or phase == AgentPhase.HOLD:
            f.apply(Hold(f.hold_here(), f"{detail}; operator hold kept", operator=True))
            return
        f.apply(Resume(f"{detail}: resumed", to=phase))

    def _act(self, agent: AgentView, now: float, name: str, action: Action, why: str) -> None:
        self._holding.clear()
        self._restore = None
        if action == "rtl":
            agent.flight.apply(ReturnToLaunch(f"{why}: returning to launch"))
        else:
            agent.flight.apply(Land(f"{why}: landing"))
        self._event(agent, now, name, action, why)
