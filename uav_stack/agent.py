"""The agent: the same code on a real UAV's companion computer and in a virtual UAV.

Data path, top to bottom, once per tick (see :meth:`Agent.step`):

    FCU (MAVLink) -> FcuLink.poll -> own ENU pose from the swarm origin -> SwarmNode.publish_pose
    SwarmNode.poll -> neighbour table -> mission behaviour -> collision avoidance -> FcuLink setpoint

The agent owns no thread and never blocks: its owner calls :meth:`Agent.step` once per tick
of a fixed-rate sleep loop (:func:`uav_stack.runtime.run_loop`, 10 Hz by default); the
control, telemetry, state and stats timers inside ``step`` run on their own rates and fire on
the first tick at or after they are due.
"""

from __future__ import annotations

import logging
import math
import os
import random
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from swarmnet.messages import Command, FaultInjection, Realm, SwarmMessage
from swarmnet.node import SwarmNode
from uav_stack.behaviours.avoidance import CollisionAvoidance
from uav_stack.behaviours.base import Behaviour, Cooperative, NeighbourView, Rect, SelfState
from uav_stack.behaviours.zones import ZoneField, zone_field
from uav_stack.config import AgentConfig
from uav_stack.failsafe import Failsafes
from uav_stack.fcu_link import CommandHandle, FcuLink
from uav_stack.geo import LocalFrame
from uav_stack.mav import mavlink
from uav_stack.overrides import ARRIVED_M, OVERRIDE_VERBS, OverridesMixin, _DeferredAck
from uav_stack.phases import CONTROLLED, WORKING, AgentPhase
from uav_stack.pose_age import AgeWindow, PoseAgeLog
from uav_stack.recorder import RecordHealth, SwappedJsonFile, TrajectoryRecorder, links_file_name
from uav_stack.sensors import Payload, make_payload, traffic_views

if TYPE_CHECKING:  # imported by the runtime only when a ground-station endpoint is configured
    from uav_stack.mavlink_router import MavlinkRouter
    from uav_stack.sdk.adapter import BehaviourMission

log = logging.getLogger(__name__)

ALT_GAIN = 0.8  # 1/s, altitude hold in the mission (vertical velocity = gain * error)
MAX_CLIMB = 2.0  # m/s, vertical speed limit of the altitude hold
OFFBOARD_PRESTREAM = 1.3  # s of setpoints before asking for the offboard mode (PX4 OFFBOARD needs > 1 s)
RETRY_AFTER = 1.5  # s: a refused or unanswered arm/mode/takeoff/land command is sent again after this
PREARM_PROBE_S = 10.0  # while the autopilot reports failing pre-arm checks, an arm is tried this often (its answer says why)
CONFIRM_S = 1.5  # s an accepted arm or mode change may take to show in the heartbeat (ArduPilot: its next 1 Hz beat)
LINK_STATS_EVERY = 10.0  # s between two writes of the per-link pose-age histograms (their own file)


@dataclass
class Own:
    """The UAV's own state in the swarm frame, derived from the FCU's telemetry."""

    x: float = math.nan
    y: float = math.nan
    z: float = math.nan
    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0
    yaw: float = 0.0  # ENU


def make_mission(cfg: AgentConfig, payload: Payload | None = None, zones: ZoneField | None = None) -> Behaviour | None:
    """The mission behaviour the configuration asks for; None for an idle UAV (it hovers).

    Plume and wildfire missions read the ``payload``'s sensors (docs/world.md) and stay out of
    the ``zones`` (their targets there are skipped).
    """
    m = cfg.mission
    if m.type == "behaviour":  # a behaviour of the SDK (uav_stack/sdk, docs/sdk.md), guarded by its adapter
        from uav_stack.sdk.adapter import make_behaviour_mission

        return make_behaviour_mission(cfg)
    if m.type in ("plume", "wildfire"):
        from uav_stack.behaviours.sensing_missions import make_sensing_mission

        return make_sensing_mission(cfg, payload or Payload(), zones, random.Random(cfg.seed * 1_000_003 + cfg.uav))
    if m.type == "coverage":
        if m.strategy not in ("random", "lawnmower"):
            raise ValueError(f"unknown coverage strategy {m.strategy!r}")
        Rect(*m.area)  # a valid area, or ValueError now
    if m.type == "goto" and m.goal is None:
        raise ValueError("a goto mission needs a goal")
    if m.type in ("coverage", "goto"):  # the built-in behaviours of the SDK (uav_stack/sdk/builtins.py)
        from uav_stack.sdk.builtins import builtin_mission

        return builtin_mission(cfg)
    if m.type == "idle":
        return None
    raise ValueError(f"unknown mission type {m.type!r}")


class Agent(OverridesMixin):
    """One UAV's swarm agent: its phase machine, mission behaviour, avoidance and reports.

    The owner opens the FCU link and the swarm node, then calls :meth:`step` every tick and
    :meth:`close` at the end; ground-station overrides come from :class:`OverridesMixin`.
    """

    def __init__(self, cfg: AgentConfig, node: SwarmNode, link: FcuLink, router: MavlinkRouter | None = None):
        self.cfg = cfg
        self.node = node
        self.link = link
        self.router = router
        # more sections for the stats file: name -> what to write (the virtual FCU's counters, in a virtual UAV)
        self.stats_sources: dict[str, Callable[[], Any]] = {}
        self.clock = node.clock
        self.frame = LocalFrame(cfg.origin)
        self.realm = Realm.parse(cfg.realm)
        self.own = Own()
        self._own_at = -math.inf  # FcuState.position_at of the position in self.own
        self.phase = AgentPhase.INIT
        self.override = ""
        self.detail = ""
        self.payload = make_payload(cfg, node, self.frame)
        a = cfg.avoidance
        self.zones = zone_field(a.zones, a.zone_margin)
        self.mission = make_mission(cfg, self.payload, self.zones)
        # asked once: isinstance against a runtime-checkable Protocol costs tens of µs, every tick
        self.cooperative: Cooperative | None = self.mission if isinstance(self.mission, Cooperative) else None
        self.avoidance = (
            CollisionAvoidance(a.safety_distance, max_speed=cfg.speed * 1.2, time_horizon=a.time_horizon,
                               stale_after=a.stale_after, zones=self.zones)
            if a.enabled
            else None
        )
        # an SDK behaviour (uav_stack/sdk): bound to this agent; asks for an altitude or a landing (read in _fly)
        self.sdk = cast("BehaviourMission", self.mission) if getattr(self.mission, "sdk", False) else None
        if self.sdk is not None:
            self.sdk.attach(self)
        self.started_at: float | None = None
        self.go = cfg.autostart  # begin the mission as soon as airborne
        self.mission_started_at: float | None = None
        self._phase_since = self.clock()
        self._handle: CommandHandle | None = None
        self._next_control = 0.0
        self._published_position_at = -math.inf
        self._next_telemetry = 0.0
        self._next_state = 0.0
        self._next_stats = 0.0
        self._next_link_stats = 0.0
        self._offboard_stream_since: float | None = None
        self._arming_since = -math.inf  # when the agent began to arm (the failsafe.arm_timeout_s bound)
        self._sent_at = -math.inf  # when the arming phase's current command was first sent
        self._arm_at = -math.inf  # when the last arm was sent
        self._arm_tries = 0
        self._refusal: CommandHandle | None = None  # the refused command already reported
        self.counters: dict[str, int] = {"commands": 0, "rejected_commands": 0, "avoidance_active": 0, "control_ticks": 0,
                                         "arm_refused": 0, "arm_gave_up": 0, "pose_unencodable": 0}
        self.closest_seen = math.inf
        self.alt_target = cfg.altitude  # m above the swarm origin
        self.hold_point: tuple[float, float] = (math.nan, math.nan)
        self.goto_target: tuple[float, float] = (math.nan, math.nan)
        g = cfg.gcs
        self.fence = g.geofence if g.geofence is not None else (cfg.mission.area if cfg.mission.type == "coverage" else None)
        self._deferred: list[_DeferredAck] = []
        self._gcs_takeover: str | None = None  # a ground station's motion command seen by the router
        self._yielded_from: AgentPhase | None = None  # the phase a takeover interrupted (ready: lands back in ready)
        self._mode_at_phase = ""
        self.failsafes = Failsafes(cfg.failsafe)  # uav_stack/failsafe.py
        # set by a virtual UAV process: applies injected faults to its virtual FCU (uav_stack/sim_faults.py);
        # None on a real UAV, whose agent refuses them
        self.fault_handler: Callable[[FaultInjection, float], tuple[bool, str]] | None = None
        # set by a virtual UAV process: its FCU's ground truth (x, y, z, vx, vy, vz in the swarm frame, armed),
        # recorded instead of the reported position, which an injected fault may falsify
        self.truth: Callable[[], tuple[float, float, float, float, float, float, bool]] | None = None
        self.records = RecordHealth()  # recording errors degrade, never stop the flight
        self.recorder: TrajectoryRecorder | None = None
        self.age_window = AgeWindow(node.stats.ages)
        self.age_log: PoseAgeLog | None = None
        self.counters_file: SwappedJsonFile | None = None  # uav<N>.json, every second
        self.links_file: SwappedJsonFile | None = None  # age_links_uav<N>.json, every LINK_STATS_EVERY s
        if cfg.record_dir:
            self.counters_file = SwappedJsonFile(Path(cfg.record_dir) / f"uav{cfg.uav}.json")
            self.links_file = SwappedJsonFile(Path(cfg.record_dir) / links_file_name(cfg.uav))
            self.recorder = TrajectoryRecorder(Path(cfg.record_dir) / f"uav{cfg.uav}.csv", health=self.records)
            self.age_log = PoseAgeLog(Path(cfg.record_dir) / f"age_uav{cfg.uav}.csv", node, health=self.records)

    # ---- helpers ------------------------------------------------------------------------
    def _set_phase(self, phase: AgentPhase, detail: str = "") -> None:
        if phase != self.phase:
            log.info("UAV %d: %s -> %s %s", self.cfg.uav, self.phase, phase, detail)
            self.phase = phase
            self._phase_since = self.clock()
            self._mode_at_phase = self.link.state.mode
            self._next_state = 0.0  # publish the change now
        self.detail = detail

    def _say(self, detail: str) -> None:
        """A new detail for the current phase (what it waits for): logged and published when it changes."""
        if detail != self.detail:
            log.info("UAV %d: %s: %s", self.cfg.uav, self.phase, detail)
            self.detail = detail
            self._next_state = 0.0

    def _update_own(self) -> bool:
        st = self.link.state
        if not st.has_position:
            return False
        o = self.own
        o.yaw = math.remainder(math.pi / 2 - st.yaw, math.tau)  # also from ATTITUDE, between two positions
        if st.position_at == self._own_at:
            return True  # no new position since the last tick: nothing to convert
        self._own_at = st.position_at
        o.x, o.y, o.z = self.frame.to_enu(st.lat, st.lon, st.alt)
        # The swarm lives in wall-clock time: a virtual FCU at RTF 0.4 that reports 5 m/s is
        # really covering 2 m/s of ground per wall second, and neighbours extrapolate with that.
        k = self.link.rtf.value
        k = k if 0.0 < k < 1.0 else 1.0  # also NaN (not measured yet): take the FCU's word
        o.vx, o.vy, o.vz = st.ve * k, st.vn * k, -st.vd * k
        return True

    @property
    def target_alt_amsl(self) -> float:
        return self.cfg.origin.alt + self.alt_target

    # ---- the loop body --------------------------------------------------------------------
    def step(self, now: float) -> None:
        """One tick: :meth:`sense` then :meth:`act` at once."""
        self._act(now, self._sense(now))

    def sense(self, now: float) -> None:
        """The first half of a tick whose halves run apart (``network.align_ticks``): the FCU's
        messages in, the own pose out. :meth:`act` follows once the swarm's poses of the same
        instant are in (uav_stack.runtime). What ground stations sent the FCU leaves now, not then."""
        self._sense(now)
        if self.router is not None:
            self.router.flush()

    def act(self, now: float) -> None:
        """The second half of a tick whose halves run apart: the FCU's messages that came
        meanwhile, then what arrived from the swarm, control, setpoints and reports."""
        self.link.poll()
        self._act(now, self._update_own())

    def _sense(self, now: float) -> bool:
        """FCU in, pose out; True if the own position is known."""
        link, node = self.link, self.node
        link.poll()
        link.service()
        router = self.router
        if router is not None:
            router.poll()  # ground stations -> FCU (sent by router.flush(): in sense, or in _act)
            if router.takeover is not None:
                self._gcs_takeover = router.takeover[1]
                router.takeover = None
        have_pos = self._update_own()
        if self.payload is not None:
            self.payload.poll(now)  # sensor readings that arrived: the behaviour reads the latest
        st = link.state
        # Publish a pose as soon as a new FCU position arrives (capped at the pose rate), before
        # anything else, so that its stamp (when the position was read) is its publication time.
        # No pose while the FCU link is lost: neighbours must see it go stale, not trust an old one.
        if have_pos and st.position_at > self._published_position_at and node.pose_due(now + 0.3 * node.pose_period) \
                and not self.failsafes.fcu_link_lost:
            self._published_position_at = st.position_at
            o = self.own
            try:
                node.publish_pose(
                    t_sim=st.position_boot_s, x=o.x, y=o.y, z=o.z, vx=o.vx, vy=o.vy, vz=o.vz, yaw=o.yaw,
                    t_wall=st.position_at,
                )
            except ValueError as exc:  # a pose the wire cannot hold (far from the swarm's origin): skipped, never fatal
                self._unencodable(exc)
        return have_pos

    def _unencodable(self, exc: ValueError) -> None:
        n = self.counters["pose_unencodable"] = self.counters["pose_unencodable"] + 1
        if n == 1 or n % 100 == 0:
            log.warning("UAV %d: own pose not published (%d so far): %s; is the swarm's origin near the UAV?",
                        self.cfg.uav, n, exc)

    def _act(self, now: float, have_pos: bool) -> None:
        """Swarm in, control and reports out."""
        link, node, router = self.link, self.node, self.router
        self.react(now)
        if self._deferred:
            self._settle_acks(now)
        if now >= self._next_control:
            self._next_control = max(self._next_control + 1.0 / self.cfg.control_rate_hz, now)
            self.failsafes.step(self, now)
            self._control(now, have_pos)
            if have_pos:
                self._record(now)
        if now >= self._next_telemetry and have_pos:
            self._next_telemetry = now + 1.0 / self.cfg.telemetry_rate_hz
            st = link.state
            rtf = link.rtf.value
            ages = self.age_window.last  # of the last full second
            node.publish_telemetry(
                mode=st.mode, armed=st.armed, battery=st.battery, voltage=st.voltage,
                lat=st.lat, lon=st.lon, alt=st.alt, rtf=0.0 if math.isnan(rtf) else rtf,  # 0.0: unknown on the wire
                transport_ms=1000.0 * ages.transport_p50, use_ms=1000.0 * ages.use_p50,  # NaN: -1 on the wire
            )
        if now >= self._next_state:
            self._next_state = now + 1.0
            node.publish_state(self.phase, self.behaviour_name, self.failsafes.label or self.override, self.detail)
        if now >= self._next_stats:
            self._next_stats = now + 1.0
            self.write_stats(now)
        if router is not None:
            router.flush()

    def react(self, now: float) -> None:
        """Take in what arrived (poses into the neighbour table, swarm messages to a cooperative
        mission) and handle the commands and injected faults at once.

        Called by :meth:`step`, and by the loop between ticks when the node's waker says a
        command (or fault) arrived, so a command is acknowledged within a millisecond of its arrival."""
        inbox = self.node.poll(now)
        if inbox.messages and self.cooperative is not None:
            self._hand_over(self.cooperative, inbox.messages, now)
        for cmd in inbox.commands:
            self._on_command(cmd, now)
        for fault in inbox.faults:
            self._on_fault(fault, now)

    @property
    def behaviour_name(self) -> str:
        m = self.cfg.mission
        return f"{m.type}/{m.strategy}" if m.type == "coverage" else m.type

    def _hand_over(self, mission: Cooperative, messages: list[SwarmMessage], now: float) -> None:
        """Swarm messages on a cooperative mission's topics go to it; a bad one is counted, never fatal."""
        for m in messages:
            if m.topic in mission.topics and m.src != self.cfg.uav:
                try:
                    mission.receive(m.src, m.topic, m.body, now)
                except Exception:  # noqa: BLE001 - bad input never stops the agent
                    self.node.stats.reject("bad_mission_message", m.topic, f"from UAV {m.src}")

    # ---- commands -------------------------------------------------------------------------
    def _on_fault(self, fault: FaultInjection, now: float) -> None:
        """An injected fault: applied by the virtual UAV process's handler, refused by a real UAV."""
        self.counters["faults"] = self.counters.get("faults", 0) + 1
        if self.fault_handler is None or self.realm is Realm.PHYSICAL:
            ok, msg = False, "fault injection refused: a physical UAV takes no injected faults"
        else:
            try:
                ok, msg = self.fault_handler(fault, now)
            except Exception as exc:  # noqa: BLE001 - a bad fault must never stop the agent
                log.exception("UAV %d: fault %s failed", self.cfg.uav, fault.kind)
                ok, msg = False, f"fault {fault.kind} failed: {type(exc).__name__}: {exc}"
        if not ok:
            self.counters["rejected_faults"] = self.counters.get("rejected_faults", 0) + 1
        log.warning("UAV %d: injected fault %s %s: %s", self.cfg.uav, fault.kind, "applied" if ok else "refused", msg)
        self.node.ack(fault.fault_id, ok, msg)

    def _on_command(self, cmd: Command, now: float) -> None:
        self.counters["commands"] += 1
        verb = cmd.verb
        ok, msg = True, ""
        if verb in OVERRIDE_VERBS:
            try:
                res = getattr(self, f"_cmd_{verb}")(cmd.args, now)
            except Exception as exc:  # noqa: BLE001 - a bad command must never stop the agent
                log.exception("UAV %d: command %s failed", self.cfg.uav, verb)
                res = (False, f"{verb} failed in the agent: {type(exc).__name__}: {exc}")
            if isinstance(res, _DeferredAck):
                res.cmd_id = cmd.cmd_id
                self._defer(res)
                return
            ok, msg = res
            if not ok:
                self.counters["rejected_commands"] += 1
            self.node.ack(cmd.cmd_id, ok, msg)
            return
        if verb in ("takeoff", "start"):
            # takeoff: climb and hover; start: also begin the mission (taking off first if needed)
            if verb == "start":
                self.go = True
            if self.phase in (AgentPhase.INIT, AgentPhase.READY, AgentPhase.ERROR):
                self.started_at = now
                if self.phase != AgentPhase.INIT:  # ready, or arming gave up (error): try (again)
                    self._begin_flight()
                msg = "taking off" if self.phase != AgentPhase.INIT else "will take off once the FCU is up"
            elif self.phase == AgentPhase.HOVER and self.go:
                msg = "mission starting"
            else:
                ok, msg = self._relaunch(verb)  # landed (or killed) on the ground: fly again
        elif verb in ("land", "stop"):
            if (self.phase in (AgentPhase.INIT, AgentPhase.READY, AgentPhase.LANDED, AgentPhase.KILLED)
                    and not self.link.state.armed):
                msg = f"on the ground ({self.phase})"
            elif self.phase in (AgentPhase.LANDING, AgentPhase.LANDED):
                msg = "already landing"
            else:
                self._land()
                self.override = "land" if verb == "land" else self.override  # _land() has just set LANDING
                if self._handle is not None:  # acknowledged with the FCU's answer to NAV_LAND
                    self._defer(_DeferredAck(cmd.cmd_id, verb, self._handle, "landing", now))
                    return
                msg = "landing"
        else:
            ok, msg = False, f"unknown command {verb!r}"
            self.counters["rejected_commands"] += 1
        self.node.ack(cmd.cmd_id, ok, msg)

    def _begin_flight(self, detail: str = "") -> None:
        self._set_phase(AgentPhase.ARMING, detail)
        self._handle = None
        self._refusal = None
        # the first arm goes at once if the pre-arm checks pass; while they fail, the first probe after PREARM_PROBE_S
        self._arming_since = self._arm_at = self.clock()
        self._arm_tries = 0

    def _land(self) -> None:
        if self.phase in (AgentPhase.LANDING, AgentPhase.LANDED):
            return
        self._handle = self.link.land()
        self._set_phase(AgentPhase.LANDING)

    # ---- the state machine ------------------------------------------------------------------
    def _control(self, now: float, have_pos: bool) -> None:
        link = self.link
        st = link.state
        ph = self.phase
        since = now - self._phase_since
        if ph == AgentPhase.INIT:
            if link.connected and have_pos:
                self._set_phase(AgentPhase.READY)
                if self.go or self.started_at is not None:
                    self._begin_flight()
            else:
                self._say(self._init_waits_for())
            return
        if ph in (AgentPhase.READY, AgentPhase.LANDED) and (why := self._flown_by_someone_else()) is not None:
            self._yield(why)  # a ground station flies a UAV the swarm is not flying: show it
            return
        if not link.connected and ph not in (AgentPhase.READY, AgentPhase.LANDED, AgentPhase.ERROR):
            self.detail = "FCU link lost"
        if ph in (AgentPhase.TAKEOFF, AgentPhase.OFFBOARD) and (why := self._taken_over_climbing()) is not None:
            self._yield(why)
            return
        self._gcs_takeover = None if ph not in CONTROLLED else self._gcs_takeover
        if ph == AgentPhase.ARMING:
            self._arming(now)
        elif ph == AgentPhase.TAKEOFF:
            if self._handle is not None and self._handle.done and not self._handle.accepted and since > RETRY_AFTER:
                self._handle = link.takeoff(self.target_alt_amsl, self.cfg.altitude)
                self._phase_since = now
            if st.alt >= self.target_alt_amsl - 1.0:
                self._offboard_stream_since = now
                self._set_phase(AgentPhase.OFFBOARD)
        elif ph == AgentPhase.OFFBOARD:
            self._send_velocity(0.0, 0.0)
            if link.in_offboard:
                if self.override == "hold":  # held while taking off
                    self._hold_here()
                elif self.mission_started_at is not None and self.go:  # control taken back: resume the mission
                    self._set_phase(AgentPhase.MISSION, "resumed")
                else:
                    self._set_phase(AgentPhase.HOVER)
            elif now - (self._offboard_stream_since or now) >= OFFBOARD_PRESTREAM and (self._handle is None or self._handle.done):
                self._handle = link.set_mode(st.profile.offboard_mode)
        elif ph in CONTROLLED:
            why = self._taken_over()
            self._gcs_takeover = None
            if why is not None:
                # a human (or a failsafe) took over: stop fighting them, say so
                self._yield(why)
                return
            if ph == AgentPhase.HOVER and self.go:
                if self.mission_started_at is None:
                    self.mission_started_at = now
                self._set_phase(AgentPhase.MISSION)
            self._fly(now)
        elif ph in (AgentPhase.YIELDED, AgentPhase.RTL):
            if not st.armed and st.relative_alt < 1.0:
                self._landed_after_takeover()
        elif ph == AgentPhase.LANDING:
            if not st.armed and st.relative_alt < 1.0:
                self._set_phase(AgentPhase.LANDED)
            elif self._handle is not None and self._handle.done and not self._handle.accepted and since > RETRY_AFTER:
                self._handle = link.land()
                self._phase_since = now

    def _init_waits_for(self) -> str:
        """What the agent waits for before it can fly, in the autopilot's terms (the phase detail in ``init``)."""
        link = self.link
        if not link.connected:
            if link.fcu_ids is None:
                return f"no heartbeat from an autopilot on {link.url}" + (" (other messages only)" if link.counts["rx"] else "")
            return "FCU link lost: no heartbeat for 3 s"
        return link.contract.waiting_for() or f"no position from the autopilot: {link.state.no_position}"

    def _arming(self, now: float) -> None:
        """Arm, then take off. First out of any mode the autopilot cannot arm in (its profile's
        ``arm_modes``: PX4 returns to OFFBOARD after a landing), then once its own pre-arm checks
        pass (SYS_STATUS); a refusal is reported with the autopilot's reason and the arm tried
        again, for ``failsafe.arm_timeout_s`` at most, then phase ``error`` (a takeoff or start tries again)."""
        link = self.link
        st = link.state
        prof = st.profile
        if st.armed:
            need = prof.takeoff_mode if prof.takeoff_mode not in (None, st.mode) else None  # ArduPilot: GUIDED
            if need is None:
                self._handle = link.takeoff(self.target_alt_amsl, self.target_alt_amsl - (st.home[2] if st.home else st.alt))
                self._set_phase(AgentPhase.TAKEOFF)
                return
        else:
            need = None if st.mode in prof.arm_modes else prof.arming_mode
        limit = self.cfg.failsafe.arm_timeout_s
        if now - self._arming_since > limit:
            self.counters["arm_gave_up"] += 1
            why = self.detail or "no answer"
            log.error("UAV %d: not armed after %.0f s: %s", self.cfg.uav, limit, why)
            self._set_phase(AgentPhase.ERROR, f"not armed after {limit:.0f} s (takeoff or start tries again): {why}")
            return
        h = self._handle
        if h is not None:
            if not h.done:
                return  # its answer is pending (FcuLink retries it)
            if h.accepted and now - self._sent_at < CONFIRM_S:
                return  # accepted: give the heartbeat time to show it
            if not h.accepted:
                if self._refusal is not h:
                    self._refused(h, need, now)
                if now - self._sent_at < RETRY_AFTER:
                    return
        if need is not None:
            if h is None or h.command != mavlink.MAV_CMD_DO_SET_MODE or h.accepted:
                self._say(f"switching from {st.mode} to {need} to arm ({prof.label} arms in {', '.join(sorted(prof.arm_modes))})")
            self._send_arming(link.set_mode(need), now)
            return
        if not st.has_position:
            self._say(f"waiting for a position: {st.no_position}")
            return
        if st.prearm_ok is None and link.contract.pending("SYS_STATUS"):
            self._say("waiting for the autopilot's SYS_STATUS (its pre-arm checks)")
            return
        if st.prearm_ok is False and now - self._arm_at < PREARM_PROBE_S:
            reasons = (st.reasons_since(now - 30.0) + [f"PX4 reports: {c}" for c in st.px4_checks])[-3:]
            self._say("waiting for the autopilot's pre-arm checks (SYS_STATUS)" + (f": {'; '.join(reasons)}" if reasons else ""))
            return
        self._arm_at = now
        self._arm_tries += 1
        self._send_arming(link.arm(True), now)

    def _send_arming(self, h: CommandHandle, now: float) -> None:
        self._handle = h
        self._sent_at = now
        self._phase_since = now

    def _refused(self, h: CommandHandle, need: str | None, now: float) -> None:
        """Say why the autopilot refused the arming phase's command, in its own words."""
        self._refusal = h
        st = self.link.state
        arming = h.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM
        reasons = st.reasons_since(self._sent_at - 0.05)
        if st.px4_checks and any(r.startswith("commander_arm_denied") for r in reasons):
            reasons.append(f"PX4 reports: {', '.join(st.px4_checks)}")
        what = f"arm {h.status}" if arming else f"switch to {need} {h.status}"
        if arming:
            self.counters["arm_refused"] += 1
            what += f" ({self._arm_tries} tr{'y' if self._arm_tries == 1 else 'ies'} in {now - self._arming_since:.0f} s)"
        detail = f"{what}: {'; '.join(reasons) if reasons else 'the autopilot gave no reason'}"
        new_reason = detail.split(": ", 1)[-1] != self.detail.split(": ", 1)[-1]
        log.log(logging.WARNING if new_reason else logging.INFO, "UAV %d: %s", self.cfg.uav, detail)
        self.detail = detail
        self._next_state = 0.0

    def _send_velocity(self, vx: float, vy: float) -> None:
        err = self.target_alt_amsl - self.link.state.alt
        vz = max(-MAX_CLIMB, min(MAX_CLIMB, ALT_GAIN * err)) if err == err else 0.0
        self.link.send_velocity_ned(vy, vx, -vz)

    def _fly(self, now: float) -> None:
        o = self.own
        me = SelfState(uav=self.cfg.uav, pos=(o.x, o.y), vel=(o.vx, o.vy), t=now)
        self.counters["control_ticks"] += 1
        vx, vy = 0.0, 0.0
        if self.phase == AgentPhase.HOLD:
            vx, vy = self._towards(self.hold_point)
        elif self.phase == AgentPhase.GOTO:
            vx, vy = self._towards(self.goto_target)
            if (math.hypot(self.goto_target[0] - o.x, self.goto_target[1] - o.y) < ARRIVED_M
                    and abs(self.alt_target - o.z) < ARRIVED_M and not self.detail.startswith("arrived")):
                self.detail = f"arrived at ({self.goto_target[0]:g}, {self.goto_target[1]:g}, {self.alt_target:g})"
                self._next_state = 0.0  # tell the ground station now
        elif self.mission is not None and self.phase in WORKING:
            members = self.node.members()
            vx, vy = self.mission.velocity(me, members)
            sdk = self.sdk
            if sdk is not None:  # an SDK behaviour's altitude target and landing (uav_stack/sdk/adapter.py)
                if sdk.altitude is not None:
                    self.alt_target = sdk.altitude
                if sdk.request == "land":
                    self._land()
                    return
            if self.cooperative is not None:
                self._share(self.cooperative)
            if self.mission.done:
                if self.cfg.mission.land_when_done:
                    self._land()
                    return
                self._set_phase(AgentPhase.DONE, "mission complete")
                vx, vy = 0.0, 0.0
            elif self.phase == AgentPhase.DONE:  # a re-split (a member left) gave us more to do
                self._set_phase(AgentPhase.MISSION, "more work after a re-split")
        if self.avoidance is not None:
            # only neighbours that could matter (avoidance looks at most neighbour_range away);
            # at N = 50 this skips building ~40 views per tick. The time of use is taken now,
            # after the poll: each pose's age (sender's stamp to now) and age at use are exact.
            # (a plain loop: at N = 50 it runs 49 times a tick, and costs half the comprehension
            # it replaced, 11 against 22 µs warm)
            reach = self.avoidance.neighbour_range + 2.0 * self.cfg.speed * self.avoidance.forget_after
            r2 = reach * reach
            t_use = self.clock()
            ox, oy = o.x, o.y
            neigh: list[NeighbourView] = []
            for n in self.node.take_neighbours(t_use):
                p = n.pose
                dx, dy = p.x - ox, p.y - oy
                if dx * dx + dy * dy <= r2:  # its age from the sender's stamp (avoidance takes < 0 as 0)
                    neigh.append(NeighbourView(p.uav, (p.x, p.y), (p.vx, p.vy), t_use - p.t_wall))
            if self.payload is not None and self.payload.traffic is not None:
                neigh += traffic_views(self.payload, o.x, o.y, o.z, now, r2, self.cfg.avoidance.safety_distance)
            res = self.avoidance.adjust(me, (vx, vy), neigh, altitude=o.z)
            if res.active:
                self.counters["avoidance_active"] += 1
            self.closest_seen = min(self.closest_seen, res.closest)
            vx, vy = res.velocity
        self._send_velocity(vx, vy)

    def _share(self, mission: Cooperative) -> None:
        """Broadcast what a cooperative mission wants the swarm to know; refresh the state detail."""
        for topic, body in mission.outbox():
            try:
                self.node.send(topic, body)
            except ValueError as exc:  # an oversized or malformed message of the mission: say so, fly on
                log.warning("UAV %d: cannot send %s: %s", self.cfg.uav, topic, exc)
        if self.phase == AgentPhase.MISSION and self.detail != mission.status:
            self.detail = mission.status
            self._next_state = 0.0

    def _record(self, now: float) -> None:
        if self.recorder is None:
            return
        st, o = self.link.state, self.own
        rtf = self.link.rtf.value
        x, y, z, vx, vy, vz, armed = self.truth() if self.truth is not None else (o.x, o.y, o.z, o.vx, o.vy, o.vz, st.armed)
        self.recorder.write(now, (now, st.position_boot_s, x, y, z, vx, vy, vz, o.yaw, self.phase, st.mode, int(armed),
                                  -1.0 if math.isnan(rtf) else rtf))  # -1: not measured yet

    # ---- reporting ------------------------------------------------------------------------
    def stats(self, now: float, links: bool = True) -> dict[str, Any]:
        """The counters file's content; ``links=False`` leaves out the per-link pose-age histograms."""
        return {
            "uav": self.cfg.uav,
            "realm": self.realm.label,
            "phase": self.phase,
            "detail": self.detail,
            "started_at": self.started_at,
            "mission_started_at": self.mission_started_at,
            "rtf": self.link.rtf.value,
            "rtf_total": self.link.rtf.total(),
            "rtf_reported": self.link.state.rtf_reported,
            "agent": dict(self.counters),
            "closest_predicted": self.closest_seen if self.closest_seen != math.inf else None,
            "fcu_link": dict(self.link.counts),
            "fcu": self.link.summary(),
            "mavlink_router": self.router.stats.as_dict() if self.router is not None else None,
            # "intake": how edge-feed batches enter the neighbour table, "compiled" or "python" (swarmnet.intake);
            # "zenoh_runtime": the process's ZENOH_RUNTIME ("": Zenoh's defaults; swarmnet.connectivity.lean_zenoh_runtime)
            "net": {**self.node.stats.to_dict(links), "intake": "compiled" if self.node.intake.compiled else "python",
                    "zenoh_runtime": os.environ.get("ZENOH_RUNTIME", "")},
            "neighbours": {
                str(n.uav): {"received": n.received, "lost": n.lost, "duplicates": n.duplicates, "out_of_order": n.out_of_order,
                             "rate": round(n.rate, 2)}
                for n in self.node.neighbours
            },
            "netem": self.node.netem_stats(),
            "failsafes": self.failsafes.as_dict(),
            "records": self.records.as_dict(),
            "payload": self.payload.stats() if self.payload is not None else None,
            "mission": {"status": getattr(self.mission, "status", None)},
            **{name: source() for name, source in self.stats_sources.items()},
            "written_at": now,
        }

    def write_stats(self, now: float, final: bool = False) -> None:
        """The counters file (every second), the per-link pose-age histograms in a file of their
        own (every LINK_STATS_EVERY s and at the end: with 49 neighbours they are 90 % of the
        bytes, and every reader of the counters file would re-read them each second), the
        trajectory's flush, the pose ages' second."""
        if self.counters_file is not None and self.links_file is not None:
            if final or now >= self._next_link_stats:
                self._next_link_stats = now + LINK_STATS_EVERY
                self.links_file.write({"uav": self.cfg.uav, "written_at": now,
                                       "transport_age_links": self.node.stats.ages.links_dict()}, self.records, now)
            self.counters_file.write(self.stats(now, links=False), self.records, now)
        if self.recorder is not None:
            self.recorder.flush(now)
        ages = self.age_window.sample()
        if self.age_log is not None:
            self.age_log.write(now, ages)

    def close(self, now: float) -> None:
        self.write_stats(now, final=True)
        for f in (self.counters_file, self.links_file):
            if f is not None:
                f.close()
        if self.recorder is not None:
            self.recorder.close(now)
        if self.age_log is not None:
            self.age_log.close()
