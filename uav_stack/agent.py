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
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from swarmnet.messages import Command, FaultInjection, Realm, SwarmMessage
from swarmnet.neighbours import neighbour_counters
from swarmnet.node import SwarmNode
from swarmnet.shared_session import NeighbourView as PoolTableView
from uav_stack.behaviours.avoidance import CollisionAvoidance
from uav_stack.behaviours.base import Behaviour, Cooperative, NeighbourView, Rect, SelfState
from uav_stack.behaviours.zones import ZoneField, zone_field
from uav_stack.config import AgentConfig
from uav_stack.failsafe import Failsafes
from uav_stack.fcu_link import FcuLink
from uav_stack.flight import Altitude, Finish, Flight, Land, Own, Resume
from uav_stack.geo import LocalFrame
from uav_stack.overrides import Overrides
from uav_stack.phases import WORKING, AgentPhase
from uav_stack.pose_age import AgeWindow, PoseAgeLog
from uav_stack.recorder import RecordHealth, SwappedJsonFile, TrajectoryRecorder, links_file_name
from uav_stack.sensors import Payload, make_payload, traffic_views

if TYPE_CHECKING:  # imported by the runtime only when a ground-station endpoint is configured
    from uav_stack.mavlink_router import MavlinkRouter
    from uav_stack.sdk.adapter import BehaviourMission

log = logging.getLogger(__name__)

ALT_GAIN = 0.8  # 1/s, altitude hold in the mission (vertical velocity = gain * error)
MAX_CLIMB = 2.0  # m/s, vertical speed limit of the altitude hold
HOLD_GAIN = 0.8  # 1/s: velocity towards a hold/goto point = gain * distance (capped)
ARRIVED_M = 1.0  # m from a goto point (horizontally and vertically) that counts as arrived
LINK_STATS_EVERY = 10.0  # s between two writes of the per-link pose-age histograms (their own file)
MAX_FAULTS_REMEMBERED = 64  # injected faults whose answer a copy gets (the oldest forgotten first)


def make_mission(cfg: AgentConfig, payload: Payload | None = None, zones: ZoneField | None = None) -> Behaviour | None:
    """The mission behaviour the configuration asks for; None for an idle UAV (it hovers).

    Every mission is a behaviour of the SDK (uav_stack/sdk, docs/sdk.md), flown through its guarded
    adapter: the user's (``mission.type: behaviour``) or a built-in one. Behaviours read the
    ``payload``'s sensors and drive its actuators through their Context (the plume and wildfire
    missions, docs/world.md), and ask it whether a point lies in the ``zones`` (the wildfire's
    targets there are skipped).
    """
    m = cfg.mission
    if m.type == "behaviour":  # a behaviour of the SDK (uav_stack/sdk, docs/sdk.md), guarded by its adapter
        from uav_stack.sdk.adapter import make_behaviour_mission

        return make_behaviour_mission(cfg, payload, zones)
    if m.type == "wildfire" and m.wildfire is None:
        raise ValueError("a wildfire mission needs its section (hub, fire_hint)")
    if m.type == "coverage":
        if m.strategy not in ("random", "lawnmower"):
            raise ValueError(f"unknown coverage strategy {m.strategy!r}")
        Rect(*m.area)  # a valid area, or ValueError now
    if m.type == "goto" and m.goal is None:
        raise ValueError("a goto mission needs a goal")
    if m.type in ("coverage", "goto", "plume", "wildfire"):  # the built-in behaviours of the SDK (uav_stack/sdk)
        from uav_stack.sdk.builtins import builtin_mission

        return builtin_mission(cfg, payload, zones)
    if m.type == "idle":
        return None
    raise ValueError(f"unknown mission type {m.type!r}")


class Agent:
    """One UAV's swarm agent: its flight (:class:`~uav_stack.flight.Flight`), mission behaviour,
    avoidance, the ground station's commands (:class:`~uav_stack.overrides.Overrides`), the
    companion failsafes and the reports.

    The owner opens the FCU link and the swarm node, then calls :meth:`step` every tick and
    :meth:`close` at the end.
    """

    def __init__(self, cfg: AgentConfig, node: SwarmNode, link: FcuLink, router: MavlinkRouter | None = None):
        self.cfg = cfg
        self.node = node
        self.link = link
        self.router = router
        # more sections for the stats file: name -> what to write (the virtual FCU's counters, in a virtual UAV)
        self.stats_sources: dict[str, Callable[[], Any]] = {}
        self.neighbours_in: str | None = None  # a pool's file of the per-neighbour counters its UAVs share
        self.clock = node.clock
        self.frame = LocalFrame(cfg.origin)
        self.realm = Realm.parse(cfg.realm)
        self.own = Own()
        self._own_at = -math.inf  # FcuState.position_at of the position in self.own
        self.flight = Flight(cfg.uav, link, self.own, self.clock, cruise_alt=cfg.altitude, home_alt=cfg.origin.alt,
                             autostart=cfg.autostart, arm_timeout_s=cfg.failsafe.arm_timeout_s)
        self.overrides = Overrides(cfg, self.flight, link, node, self.frame)
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
        self._next_control = 0.0
        self._published_position_at = -math.inf
        self._next_telemetry = 0.0
        self._next_state = 0.0
        self._next_stats = 0.0
        self._next_link_stats = 0.0
        self.counters: dict[str, int] = {"avoidance_active": 0, "control_ticks": 0, "pose_unencodable": 0}
        self.closest_seen = math.inf
        self.failsafes = Failsafes(cfg.failsafe)  # uav_stack/failsafe.py
        # set by a virtual UAV process: applies injected faults to its virtual FCU (uav_stack/sim_faults.py);
        # None on a real UAV, whose agent refuses them
        self.fault_handler: Callable[[FaultInjection, float], tuple[bool, str]] | None = None
        self._faults_seen: dict[tuple[str, int], tuple[bool, str]] = {}  # (sender, fault id) -> its answer
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

    # ---- what others read -------------------------------------------------------------------
    @property
    def uav(self) -> int:
        return self.cfg.uav

    @property
    def phase(self) -> AgentPhase:
        return self.flight.phase

    @property
    def detail(self) -> str:
        return self.flight.detail

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
        have_pos = self._update_own()
        self._publish_pose(now, have_pos)  # a position that came meanwhile leaves now, not at the next instant
        self._act(now, have_pos)

    def _sense(self, now: float) -> bool:
        """FCU in, pose out; True if the own position is known."""
        link = self.link
        link.poll()
        link.service()
        router = self.router
        if router is not None:
            router.poll()  # ground stations -> FCU (sent by router.flush(): in sense, or in _act)
            if router.takeover is not None:
                self.flight.gcs_takeover = router.takeover[1]
                router.takeover = None
        have_pos = self._update_own()
        if self.payload is not None:
            self.payload.poll(now)  # sensor readings that arrived: the behaviour reads the latest
        self._publish_pose(now, have_pos)
        return have_pos

    def _publish_pose(self, now: float, have_pos: bool) -> None:
        """Publish a pose as soon as a new FCU position arrives (capped at the pose rate), before
        anything else, so that its stamp (when the position was read) is its publication time.
        No pose while the FCU link is lost: neighbours must see it go stale, not trust an old one."""
        st, node = self.link.state, self.node
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

    def _unencodable(self, exc: ValueError) -> None:
        n = self.counters["pose_unencodable"] = self.counters["pose_unencodable"] + 1
        if n == 1 or n % 100 == 0:
            log.warning("UAV %d: own pose not published (%d so far): %s; is the swarm's origin near the UAV?",
                        self.cfg.uav, n, exc)

    def _act(self, now: float, have_pos: bool) -> None:
        """Swarm in, control and reports out."""
        link, node, router = self.link, self.node, self.router
        self.react(now)
        if self.overrides.deferred:
            self.overrides.settle(now)
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
        f = self.flight
        if f.changed or now >= self._next_state:
            f.changed = False
            self._next_state = now + 1.0
            node.publish_state(f.phase, self.behaviour_name, self.failsafes.label or f.override, f.detail)
        if self.sdk is not None:  # what an SDK behaviour recorded and its message counters, once a second
            self.sdk.report(now)
        wall = time.monotonic()  # the stats file once a second of the wall clock's (lock-step time runs faster)
        if wall >= self._next_stats:
            self._next_stats = wall + 1.0
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
        if m.type == "behaviour":  # an SDK behaviour: its name (mypkg.flock:Flocking -> Flocking), as the wire holds it
            spec = self.sdk.spec if self.sdk is not None else (m.behaviour or m.type)
            return spec.rsplit(":", 1)[-1].rsplit(".", 1)[-1][:32] or m.type
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
        """An injected fault: applied by the virtual UAV process's handler, refused by a real UAV.
        A copy of one already handled (the controller sends again until it hears the ack) is
        acknowledged with the first answer, never applied twice."""
        seen = self._faults_seen.get((fault.sender, fault.fault_id))
        if seen is not None:
            self.node.ack(fault.fault_id, *seen)
            return
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
        self._faults_seen[(fault.sender, fault.fault_id)] = (ok, msg)
        if len(self._faults_seen) > MAX_FAULTS_REMEMBERED:
            del self._faults_seen[next(iter(self._faults_seen))]
        self.node.ack(fault.fault_id, ok, msg)

    def _on_command(self, cmd: Command, now: float) -> None:
        self.overrides.handle(cmd, now)

    # ---- control: the flight, then the mission ------------------------------------------------
    def _control(self, now: float, have_pos: bool) -> None:
        """The flight advances; under swarm control the mission flies; while the FCU is being
        taken into its offboard mode, zero-velocity setpoints stream (PX4 needs them first)."""
        f = self.flight
        entering_offboard = f.phase == AgentPhase.OFFBOARD
        if f.progress(now, have_pos):
            self._fly(now)
        elif entering_offboard and f.phase != AgentPhase.YIELDED:
            self._send_velocity(0.0, 0.0)

    def _send_velocity(self, vx: float, vy: float) -> None:
        err = self.flight.target_alt_amsl - self.link.state.alt
        vz = max(-MAX_CLIMB, min(MAX_CLIMB, ALT_GAIN * err)) if err == err else 0.0
        self.link.send_velocity_ned(vy, vx, -vz)

    def _fly(self, now: float) -> None:
        o = self.own
        me = SelfState(uav=self.cfg.uav, pos=(o.x, o.y), vel=(o.vx, o.vy), t=now)
        self.counters["control_ticks"] += 1
        ph = self.flight.phase
        if ph == AgentPhase.HOLD:
            vx, vy = self._towards(self.flight.hold_point)
        elif ph == AgentPhase.GOTO:
            vx, vy = self._goto()
        elif self.mission is not None and ph in WORKING:
            vx, vy = self._mission_velocity(me)
            if self.flight.phase == AgentPhase.LANDING:
                return
        else:
            vx, vy = 0.0, 0.0
        if self.avoidance is not None:
            vx, vy = self._avoid(me, vx, vy, now)
        self._send_velocity(vx, vy)

    def _goto(self) -> tuple[float, float]:
        f, o = self.flight, self.own
        tx, ty = f.goto_target
        if math.hypot(tx - o.x, ty - o.y) < ARRIVED_M and abs(f.alt_target - o.z) < ARRIVED_M \
                and not f.detail.startswith("arrived"):
            f.say(f"arrived at ({tx:g}, {ty:g}, {f.alt_target:g})")  # the ground station hears it now
        return self._towards(f.goto_target)

    def _mission_velocity(self, me: SelfState) -> tuple[float, float]:
        """The mission's velocity; its end lands the UAV or leaves it hovering (``done``)."""
        mission, f = self.mission, self.flight
        assert mission is not None
        vx, vy = mission.velocity(me, self.node.members())
        sdk = self.sdk
        if sdk is not None:  # an SDK behaviour's altitude target and landing (uav_stack/sdk/adapter.py)
            if sdk.altitude is not None and sdk.altitude != f.alt_target:
                f.apply(Altitude(sdk.altitude))
            if sdk.request == "land":
                f.apply(Land("the behaviour asked to land"))
                return 0.0, 0.0
        if self.cooperative is not None:
            self._share(self.cooperative)
        if mission.done:
            if self.cfg.mission.land_when_done:
                f.apply(Land())
            else:
                f.apply(Finish("mission complete"))
            return 0.0, 0.0
        if f.phase == AgentPhase.DONE:  # a re-split (a member left) gave us more to do
            f.apply(Resume("more work after a re-split", AgentPhase.MISSION))
        return vx, vy

    def _avoid(self, me: SelfState, vx: float, vy: float, now: float) -> tuple[float, float]:
        """Collision avoidance on the preferred velocity, from the neighbours that could matter."""
        avoidance = self.avoidance
        assert avoidance is not None
        # only the neighbours within reach (avoidance looks at most neighbour_range away, and a
        # neighbour closes at most 2 x speed over the time it is trusted): in a pool the node finds
        # them in the pool's index, without a loop over the whole swarm. The time of use is taken
        # now, after the poll, so each pose's age (sender's stamp to now) and age at use are exact.
        reach = avoidance.neighbour_range + 2.0 * self.cfg.speed * avoidance.forget_after
        r2 = reach * reach
        t_use = self.clock()
        o = self.own
        neigh = [NeighbourView(p.uav, (p.x, p.y), (p.vx, p.vy), t_use - p.t_wall)  # its age from the sender's stamp
                 for p in (n.pose for n in self.node.take_neighbours(t_use, (o.x, o.y, reach)))]
        if self.payload is not None and self.payload.traffic is not None:
            neigh += traffic_views(self.payload, o.x, o.y, o.z, now, r2, self.cfg.avoidance.safety_distance)
        res = avoidance.adjust(me, (vx, vy), neigh, altitude=o.z)
        if res.active:
            self.counters["avoidance_active"] += 1
        self.closest_seen = min(self.closest_seen, res.closest)
        return res.velocity

    def _towards(self, target: tuple[float, float]) -> tuple[float, float]:
        """Velocity towards a hold or goto point: proportional, capped by the speed and by braking
        distance; zero when there (or when the point is NaN: brake)."""
        o = self.own
        ex, ey = target[0] - o.x, target[1] - o.y
        d = math.hypot(ex, ey)
        if not d > 0.2:  # also NaN
            return 0.0, 0.0
        v = min(self.cfg.speed, HOLD_GAIN * d, math.sqrt(2.0 * 1.5 * d))
        return ex / d * v, ey / d * v

    def _share(self, mission: Cooperative) -> None:
        """Broadcast what a cooperative mission wants the swarm to know; refresh the state detail."""
        for topic, body in mission.outbox():
            try:
                self.node.send(topic, body)
            except ValueError as exc:  # an oversized or malformed message of the mission: say so, fly on
                log.warning("UAV %d: cannot send %s: %s", self.cfg.uav, topic, exc)
        f = self.flight
        if f.phase == AgentPhase.MISSION and f.detail != mission.status:
            f.detail = mission.status
            f.changed = True

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
            "started_at": self.flight.started_at,
            "mission_started_at": self.flight.mission_started_at,
            "rtf": self.link.rtf.value,
            "rtf_total": self.link.rtf.total(),
            "rtf_reported": self.link.state.rtf_reported,
            "agent": {**self.counters, **self.overrides.counters, **self.flight.counters, **self.flight.arming.counters},
            "closest_predicted": self.closest_seen if self.closest_seen != math.inf else None,
            "fcu_link": dict(self.link.counts),
            "fcu": self.link.summary(),
            "mavlink_router": self.router.stats.as_dict() if self.router is not None else None,
            # "zenoh_runtime": the process's ZENOH_RUNTIME ("": Zenoh's defaults; swarmnet.connectivity.lean_zenoh_runtime)
            "net": {**self.node.stats.to_dict(links), "zenoh_runtime": os.environ.get("ZENOH_RUNTIME", "")},
            **self._neighbour_counters(),
            "netem": self.node.netem_stats(),
            "failsafes": self.failsafes.as_dict(),
            "records": self.records.as_dict(),
            "payload": self.payload.stats() if self.payload is not None else None,
            "mission": {"status": getattr(self.mission, "status", None)},
            **{name: source() for name, source in self.stats_sources.items()},
            "written_at": now,
        }

    def _neighbour_counters(self) -> dict[str, Any]:
        """The per-neighbour pose counters, or where they are: a pool's UAV that sees the pool's
        table (no netem shim of its own) has them in the pool's file, once for all its UAVs."""
        if self.neighbours_in is not None and isinstance(self.node.neighbours, PoolTableView):
            return {"neighbours_in": self.neighbours_in}
        return {"neighbours": neighbour_counters(self.node.neighbours)}

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
        if self.sdk is not None:
            self.sdk.final_report(now)
        self.write_stats(now, final=True)
        for f in (self.counters_file, self.links_file):
            if f is not None:
                f.close()
        if self.recorder is not None:
            self.recorder.close(now)
        if self.age_log is not None:
            self.age_log.close()
