"""Chaos: the scenario's ``faults:`` schedule (mrswarm/scenario/faults.py), injected during the mission
(docs/reliability.md). Kinds, and how each is injected:

* UAV processes, with real signals: ``kill_uav`` (SIGKILL), ``stop_uav`` (SIGSTOP, then SIGCONT
  after ``duration`` if given), ``continue_uav`` (SIGCONT), ``restart_uav`` (SIGTERM, then
  started again).
* The edge services, with real signals: ``kill_discovery`` / ``kill_router`` (SIGKILL; the
  supervisor restarts them with backoff), ``restart_discovery`` / ``restart_router``.
* A virtual UAV's FCU, through its fault key (uav_stack/sim_faults.py): ``fcu_link_loss``
  (``duration``), ``gps_jump`` (``offset: [east, north]`` m, ``duration``), ``gps_noise``
  (``sigma`` m, ``duration``), ``battery_drop`` (``level``, the remaining fraction).
* The network, through the netem shim's control key (``mrswarm netem set``): ``partition``
  (``groups`` that cannot hear each other, ``duration``) and ``outage`` (the listed ``uavs``, or
  all, hear no other UAV, ``duration``). The scenario's own netem configuration comes back after.

While the run goes on, the runner watches each fault's symptom and the swarm's recovery
(:meth:`Chaos.tick`); the per-fault table of the summary is computed from those times
(mrswarm/results/fault_report.py).
"""

from __future__ import annotations

import signal
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from groundfloor.schema import to_builtins
from mrswarm.records.summary import FaultRecord
from mrswarm.scenario.faults import INJECTED, SERVICE, STALE_S, UAV_PROCESS, FaultSpec, PlannedFault
from uav_stack.phases import WORKING

SETTLE_S = 30.0  # a fault not recovered this long after it ended is watched no longer
QUERY_EVERY_S = 1.0


@dataclass
class Swarm:
    """What the fault schedule acts on and watches (the runner provides it)."""

    runtime: Any  # mrswarm.run.runtime.Runtime: signals and restarts
    supervisor: Any  # mrswarm.run.supervisor.Supervisor: planned restarts, what is down
    observer: Any  # swarmnet.observer.SwarmObserver: injected faults, netem changes, the swarm's state
    base_netem: dict[str, Any] | None  # the scenario's network.netem, restored after a partition
    discovery: tuple[str, str, str] | None  # server, swarm, key: the registry check after a discovery fault
    ids: list[int]


@dataclass
class _Active:
    planned: PlannedFault
    record: FaultRecord
    follow_up: float | None = None  # wall: SIGCONT or the netem restore
    done_following: bool = False
    ack: Any = None  # a PendingCommand
    mark: float = 0.0  # wall: when the symptom check may start (e.g. after the service is back)
    next_query: float = 0.0
    resend_at: float = 0.0  # wall: when an unanswered injected fault is sent again


class Chaos:
    """Injects the planned faults at their time and watches the swarm's reaction."""

    def __init__(self, faults: list[PlannedFault], swarm: Swarm, clock: Callable[[], float] = time.time):
        self.pending = list(faults)
        self.swarm = swarm
        self.clock = clock
        self.active: list[_Active] = []
        self.records: list[FaultRecord] = [FaultRecord(index=p.index, kind=p.spec.kind, at_s=p.at, targets=p.spec.targets(),
                                                       args=_args(p.spec)) for p in sorted(faults, key=lambda p: p.index)]
        self.changed = False  # a record changed since the runner last saved run.json

    def tick(self, mission_t: float) -> None:
        now = self.clock()
        while self.pending and self.pending[0].at <= mission_t:
            p = self.pending.pop(0)
            rec = next(r for r in self.records if r.index == p.index)
            a = _Active(p, rec)
            try:
                self._inject(a, now)
            except Exception as exc:  # noqa: BLE001 - a fault that cannot be injected is reported, the run goes on
                rec.ok, rec.detail = False, f"not injected: {type(exc).__name__}: {exc}"[:300]
            rec.injected = now
            self.active.append(a)
            self.changed = True
        for a in list(self.active):
            self._follow_up(a, now)
            self._watch(a, now)
            r = a.record
            settled = r.recovered is not None or (now > (r.ends or r.injected or now) + SETTLE_S)
            if a.done_following and settled:
                self.active.remove(a)

    # ---- injecting --------------------------------------------------------------------------------
    def _inject(self, a: _Active, now: float) -> None:
        f, rec, sw = a.planned.spec, a.record, self.swarm
        k = f.kind
        if f.duration is not None:
            rec.ends = now + f.duration
        a.done_following = True
        if k in UAV_PROCESS:
            name = f"uav{f.uav}"
            if k == "restart_uav":
                self._restart(rec, name)
                a.mark = self.clock()
                return
            sig = {"kill_uav": signal.SIGKILL, "stop_uav": signal.SIGSTOP, "continue_uav": signal.SIGCONT}[k]
            rec.ok = sw.runtime.signal(name, sig)
            rec.detail = f"{sig.name} sent" if rec.ok else f"{name} is not running"
            if k == "stop_uav" and f.duration is not None and rec.ok:
                a.follow_up, a.done_following = now + f.duration, False
            return
        if k in SERVICE:
            name = "discovery" if "discovery" in k else "router"
            if k.startswith("kill"):
                rec.ok = sw.runtime.signal(name, signal.SIGKILL)
                rec.detail = "SIGKILL sent" if rec.ok else f"{name} is not running"
            else:
                self._restart(rec, name)
                rec.detected = now  # planned: nothing to detect
            return
        if k in INJECTED:
            a.ack = sw.observer.inject(f.uav, k, _fault_args(f))
            a.resend_at = now + 1.0
            rec.detail = "sent, waiting for the UAV's acknowledgement"
            a.done_following = False
            return
        # network: the netem shim of every UAV, through its control key
        cfg = dict(sw.base_netem or {})
        groups = [list(g) for g in f.groups] if f.groups is not None else [[u] for u in (f.uavs or sw.ids)]
        parts = dict(cfg.get("partitions") or {})
        parts.update({f"chaos{i}": g for i, g in enumerate(groups)})
        if f.kind == "outage" and f.uavs:  # the others stay together
            rest = [u for u in sw.ids if u not in f.uavs]
            if rest:
                parts["chaos_rest"] = rest
        cfg["partitions"] = parts
        a.ack = self._netem(cfg)
        a.follow_up, a.done_following = now + (f.duration or 0.0), False
        rec.detail = f"netem partitions {list(parts.values())}"

    def _restart(self, rec: FaultRecord, name: str) -> None:
        ev = self.swarm.supervisor.restart_now(name)
        rec.ok = ev is not None and ev.event == "restarted"
        rec.detail = "stopped (SIGTERM) and started again" if rec.ok else f"restart failed: {ev.detail if ev else 'unknown'}"

    def _netem(self, config: dict[str, Any] | None) -> Any:
        from swarmnet.messages import Command
        from swarmnet.netem.control import NetemSet, encode_netem_set
        from swarmnet.observer import PendingCommand

        obs = self.swarm.observer
        msg_id = int(self.clock() * 1000) & 0xFFFFFFFF
        cfg = config if config is not None else {"preset": "none"}
        msg = NetemSet(id=msg_id, sender="chaos", t_wall=self.clock(), config=cfg, targets=None)
        cmd = Command("chaos", msg_id, 0, "netem", {}, msg.t_wall)
        pending = obs.pending[msg_id] = PendingCommand(cmd, set(obs.alive_uavs()))
        obs.node.session.put(obs.keys.netem_set, encode_netem_set(msg))
        return pending

    def _follow_up(self, a: _Active, now: float) -> None:
        f, rec = a.planned.spec, a.record
        if a.ack is not None and f.kind in INJECTED and not a.done_following:
            if a.ack.acks:
                ack = a.ack.acks[f.uav]
                rec.ok, rec.detail = ack.ok, ack.message
                a.done_following = True
                self.changed = True
            elif now - (rec.injected or now) > 5.0:
                rec.ok, rec.detail = False, "no acknowledgement from the UAV"
                a.done_following = True
                self.changed = True
            elif now >= a.resend_at:  # unanswered: once more each second (the UAV applies it once)
                a.resend_at = now + 1.0
                self.swarm.observer.send_again(a.ack)
        if a.follow_up is not None and now >= a.follow_up and not a.done_following:
            a.done_following = True
            if f.kind == "stop_uav":
                self.swarm.runtime.signal(f"uav{f.uav}", signal.SIGCONT)
                rec.detail += "; SIGCONT sent"
            else:  # the network comes back as the scenario configured it
                acks = a.ack.acks if a.ack is not None else {}
                rec.ok = bool(acks) and all(k.ok for k in acks.values())
                self._netem(self.swarm.base_netem)
                rec.detail += f"; applied by {len(acks)} UAVs; restored"
            self.changed = True

    # ---- watching -----------------------------------------------------------------------------------
    def _watch(self, a: _Active, now: float) -> None:
        rec, f = a.record, a.planned.spec
        if rec.injected is None or not rec.ok and a.done_following:
            return
        before = (rec.detected, rec.recovered)
        k = f.kind
        if k in UAV_PROCESS:
            self._watch_uav(a, now)
        elif k in SERVICE:
            self._watch_service(a, now)
        elif k in INJECTED:
            self._watch_failsafe(a, now)
        # network faults: from the UAVs' own age-of-information records, after the run (fault_report.py)
        if (rec.detected, rec.recovered) != before:
            self.changed = True

    def _view(self, uav: int) -> Any:
        return self.swarm.observer.uavs.get(uav)

    def _working(self, uav: int, after: float) -> bool:
        """Back in its mission: a working phase, no failsafe, fresh poses, reported after ``after``."""
        v = self._view(uav)
        now = self.clock()
        if v is None or v.state is None or v.pose is None:
            return False
        return (v.state.phase in WORKING and not v.state.override.startswith("failsafe:") and v.state_recv > after
                and now - v.pose_recv < STALE_S)

    def _watch_uav(self, a: _Active, now: float) -> None:
        rec, f = a.record, a.planned.spec
        uav = f.uav
        assert uav is not None and rec.injected is not None
        v = self._view(uav)
        if rec.detected is None:
            gone = uav not in self.swarm.observer.alive_uavs()
            stale = v is None or v.pose is None or now - v.pose_recv > STALE_S
            if gone or stale:
                rec.detected = now
        if f.kind == "continue_uav" and rec.detected is None:
            rec.detected = rec.injected
        elif rec.detected is not None and rec.recovered is None:
            came_back = f.kind != "kill_uav" or not self.swarm.supervisor.down.get(f"uav{uav}")
            if came_back and self._working(uav, max(rec.detected, a.mark)):
                rec.recovered = now

    def _watch_service(self, a: _Active, now: float) -> None:
        rec, f = a.record, a.planned.spec
        name = "discovery" if "discovery" in f.kind else "router"
        sup = self.swarm.supervisor
        if rec.detected is None and name in sup.down:
            rec.detected = sup.down[name]
        if rec.detected is None or rec.recovered is not None or name in sup.down:
            return
        if name == "router":  # back when the runner, a client of the router, hears the swarm again
            if a.mark == 0.0:
                a.mark = now
            fresh = [v for v in self.swarm.observer.uavs.values() if v.pose is not None and v.pose_recv > a.mark]
            if fresh:
                rec.recovered = now
        elif now >= a.next_query and self.swarm.discovery is not None:  # back when its registry holds the swarm again
            a.next_query = now + QUERY_EVERY_S
            from discovery.client import QueryTimeout, query_registry

            server, swarm, key = self.swarm.discovery
            try:
                nodes, _ = query_registry(server, swarm, key, timeout=0.2, attempts=1)
            except (QueryTimeout, OSError, socket.gaierror):
                return
            alive = self.swarm.observer.alive_uavs()
            if len([n for n in nodes if n.entry.role == "uav"]) >= len(alive):
                rec.recovered = now

    def _watch_failsafe(self, a: _Active, now: float) -> None:
        rec, f = a.record, a.planned.spec
        uav = f.uav
        assert uav is not None
        v = self._view(uav)
        want = {"fcu_link_loss": "failsafe:fcu_link", "gps_jump": "failsafe:position", "gps_noise": "failsafe:position",
                "battery_drop": "failsafe:battery"}[f.kind]
        if rec.detected is None and v is not None and v.state is not None and v.state.override == want \
                and v.state_recv >= (rec.injected or now):
            rec.detected = v.state_recv
        end = rec.ends or rec.injected or now
        back = rec.recovered is None and now >= end and self._working(uav, end)
        if back and (rec.detected is not None or f.kind != "battery_drop"):
            rec.recovered = now


def _args(f: FaultSpec) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name in ("duration", "offset", "sigma", "level", "groups", "uavs"):
        v = getattr(f, name)
        if v is not None:
            out[name] = to_builtins(v)
    return out


def _fault_args(f: FaultSpec) -> dict[str, float]:
    """The FaultInjection arguments of an FCU fault (uav_stack/sim_faults.py names them with units)."""
    if f.kind == "fcu_link_loss":
        return {"duration_s": float(f.duration or 0.0)}
    if f.kind == "gps_jump":
        assert f.offset is not None
        return {"dx_m": float(f.offset[0]), "dy_m": float(f.offset[1]), "duration_s": float(f.duration or 0.0)}
    if f.kind == "gps_noise":
        return {"sigma_m": float(f.sigma or 0.0), "duration_s": float(f.duration or 0.0)}
    return {"level": float(f.level if f.level is not None else 1.0)}
