"""Chaos: the scenario's ``faults:`` schedule, injected during the mission (docs/reliability.md).

Each entry happens at ``at`` seconds after the mission start, or at a random time within
``window: [from, to]`` drawn from the scenario's seed (the same seed gives the same schedule).
Kinds, and how each is injected:

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
(mrswarm/fault_report.py).
"""

from __future__ import annotations

import random
import signal
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from msgspec import Meta

from groundfloor.schema import Config, ConfigError, to_builtins
from mrswarm.summary import FaultRecord
from uav_stack.config import UavId
from uav_stack.phases import WORKING

FaultKind = Literal[
    "kill_uav", "stop_uav", "continue_uav", "restart_uav",
    "kill_discovery", "restart_discovery", "kill_router", "restart_router",
    "fcu_link_loss", "gps_jump", "gps_noise", "battery_drop",
    "partition", "outage",
]
UAV_PROCESS = ("kill_uav", "stop_uav", "continue_uav", "restart_uav")
SERVICE = ("kill_discovery", "restart_discovery", "kill_router", "restart_router")
INJECTED = ("fcu_link_loss", "gps_jump", "gps_noise", "battery_drop")
NETWORK = ("partition", "outage")
Seconds = Annotated[float, Meta(ge=0.0, le=7200.0, description="s after the mission start")]
STALE_S = 1.0  # a UAV's pose older than this counts as stale (the agents' default stale_after)
SETTLE_S = 30.0  # a fault not recovered this long after it ended is watched no longer
QUERY_EVERY_S = 1.0


class FaultSpec(Config, frozen=True):
    """One entry of a scenario's ``faults:`` list."""

    kind: FaultKind
    at: Seconds | None = None
    window: tuple[Seconds, Seconds] | None = None  # a random time in [from, to], seeded
    uav: UavId | None = None  # the UAV (UAV process and FCU faults)
    uavs: tuple[UavId, ...] | None = None  # outage: the UAVs cut off (default: all)
    groups: tuple[tuple[UavId, ...], ...] | None = None  # partition: groups that cannot hear each other
    duration: Annotated[float, Meta(gt=0.0, le=600.0, description="s")] | None = None
    offset: tuple[Annotated[float, Meta(ge=-1000.0, le=1000.0)], Annotated[float, Meta(ge=-1000.0, le=1000.0)]] | None = None
    sigma: Annotated[float, Meta(gt=0.0, le=100.0, description="m")] | None = None
    level: Annotated[float, Meta(ge=0.0, le=1.0, description="remaining battery fraction")] | None = None

    def __post_init__(self) -> None:
        if (self.at is None) == (self.window is None):
            raise ConfigError("at", "give either 'at' (s after the mission start) or 'window: [from, to]'")
        if self.window is not None and not self.window[0] < self.window[1]:
            raise ConfigError("window", f"needs from < to, got {list(self.window)}")
        k = self.kind
        needs = {"uav": k in UAV_PROCESS or k in INJECTED,
                 "duration": k in ("fcu_link_loss", "gps_jump", "gps_noise") or k in NETWORK,
                 "offset": k == "gps_jump", "sigma": k == "gps_noise", "level": k == "battery_drop", "groups": k == "partition"}
        allowed = dict(needs, uavs=k == "outage", duration=needs["duration"] or k == "stop_uav")
        for name, required in needs.items():
            if required and getattr(self, name) is None:
                raise ConfigError(name, f"required for {k}")
        for name, ok in allowed.items():
            if not ok and getattr(self, name) is not None:
                raise ConfigError(name, f"not used by {k}")
        if self.groups is not None:
            flat = [u for g in self.groups for u in g]
            if len(self.groups) < 2 or any(not g for g in self.groups):
                raise ConfigError("groups", "at least two non-empty groups")
            if len(flat) != len(set(flat)):
                raise ConfigError("groups", "a UAV is in two groups")

    def targets(self) -> list[int]:
        if self.uav is not None:
            return [self.uav]
        if self.groups is not None:
            return sorted(u for g in self.groups for u in g)
        return sorted(self.uavs or ())


@dataclass
class PlannedFault:
    index: int
    spec: FaultSpec
    at: float  # s after the mission start


def plan(faults: tuple[FaultSpec, ...], seed: int) -> list[PlannedFault]:
    """Every fault with its time, in time order; a window's time is drawn from ``seed`` and the entry's index."""
    out = []
    for i, f in enumerate(faults):
        at = f.at if f.at is not None else random.Random(f"faults:{seed}:{i}").uniform(*f.window)  # type: ignore[misc]
        out.append(PlannedFault(i, f, round(at, 3)))
    return sorted(out, key=lambda p: (p.at, p.index))


def fit_to_duration(data: dict[str, Any], duration: float) -> list[str]:
    """A mission shortened on the command line (``--set duration=N``): leave out of the scenario mapping ``data``
    (before validation) the scheduled faults that cannot happen in ``duration`` s, and say what was left out.

    A fault fits when it is due before the end: ``at`` (or the end of its ``window``) earlier than ``duration``.
    Entries that are not well formed are left for validation to name. Returns a sentence naming what was
    left out (numbered as in the scenario file), or nothing.
    """
    faults = data.get("faults")
    if not isinstance(faults, list):
        return []
    keep, dropped = [], []
    for i, f in enumerate(faults):
        last = None
        if isinstance(f, dict):
            window = f.get("window")
            last = f.get("at") if "at" in f else window[1] if isinstance(window, list) and len(window) == 2 else None
        if isinstance(last, int | float) and not isinstance(last, bool) and last >= duration:
            when = f"at {f['at']:g} s" if "at" in f else f"in [{f['window'][0]:g}, {f['window'][1]:g}] s"
            dropped.append(f"{i} ({f.get('kind', '?')} {when})")
        else:
            keep.append(f)
    data["faults"] = keep
    if not dropped:
        return []
    return [f"faults: {len(keep)} of {len(faults)} kept; left out, not within the {duration:g} s mission: " + ", ".join(dropped)]


def check_against(faults: tuple[FaultSpec, ...], ids: set[int], duration: float, connectivity: str) -> None:
    """Rules between the schedule and the rest of the scenario (``ConfigError`` naming ``faults.<i>.<field>``)."""
    for i, f in enumerate(faults):
        where = f"faults.{i}"
        unknown = sorted(set(f.targets()) - ids)
        if unknown:
            field = "uav" if f.uav is not None else "groups" if f.groups is not None else "uavs"
            raise ConfigError(f"{where}.{field}", f"UAV {unknown[0]} is not in the fleet ({len(ids)} UAVs)")
        last = f.at if f.at is not None else f.window[1]  # type: ignore[index]
        if last >= duration:
            raise ConfigError(f"{where}.{'at' if f.at is not None else 'window'}",
                              f"{last:g} s is not within the mission's {duration:g} s")
        if "discovery" in f.kind and connectivity != "discovery":
            raise ConfigError(f"{where}.kind", f"{f.kind} needs network.connectivity: discovery "
                                               "(this run has no discovery server)")


@dataclass
class Swarm:
    """What the fault schedule acts on and watches (the runner provides it)."""

    runtime: Any  # mrswarm.runtime.Runtime: signals and restarts
    supervisor: Any  # mrswarm.supervisor.Supervisor: planned restarts, what is down
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
