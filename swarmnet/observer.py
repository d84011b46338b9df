"""A non-flying participant that watches a swarm and commands it (runner, ground station).

It reads every UAV's pose, telemetry, agent state and command acks, and sends commands to
one UAV or the whole swarm. Poses, liveliness and swarm messages come through its
:class:`~swarmnet.node.SwarmNode`; telemetry, agent states and acks through inlets of its own
(acks wake :attr:`SwarmObserver.waker`, so a runner waiting for them can sleep on it).
:meth:`SwarmObserver.poll` drains all of them through the one receive path
(:mod:`swarmnet.receive`) with the same rules as a UAV: a message on a per-UAV key must name
that UAV (``key_mismatch`` otherwise).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, TypeVar

import zenoh

from swarmnet.connectivity import Connectivity
from swarmnet.messages import (
    AgentState,
    Command,
    CommandAck,
    FaultInjection,
    Pose,
    Telemetry,
    accept_ack,
    accept_state,
    accept_telemetry,
    encode_command,
    encode_fault,
)
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.receive import Accept, Inlet, Waker, receive, subscribe
from swarmnet.stats import NodeStats

T = TypeVar("T")


@dataclass
class UavView:
    """Everything the observer knows about one UAV."""

    uav: int
    pose: Pose | None = None
    pose_recv: float = 0.0  # wall time the pose arrived (its transport age: pose_recv - pose.t_wall)
    telemetry: Telemetry | None = None
    state: AgentState | None = None
    state_recv: float = 0.0
    poses: int = 0


# commands and faults are rare and must arrive: never dropped in a full queue (BLOCK), not batched (express)
_MUST_ARRIVE: dict[str, Any] = {"congestion_control": zenoh.CongestionControl.BLOCK, "priority": zenoh.Priority.INTERACTIVE_HIGH,
                                "express": True}


@dataclass
class PendingCommand:
    cmd: Command
    targets: set[int]
    acks: dict[int, CommandAck] = field(default_factory=dict)
    acked_at: dict[int, float] = field(default_factory=dict)  # wall time each ack arrived
    resend: tuple[str, bytes] | None = None  # (key, payload) to put again while unanswered (a fault)

    @property
    def complete(self) -> bool:
        return self.targets <= set(self.acks)


class SwarmObserver:
    """Watches one swarm and commands it; ``node_id`` is unique among nodes of the same ``role``.

    Not thread-safe: one owner thread calls :meth:`poll` and :meth:`command`.
    """

    def __init__(self, swarm: str, connectivity: Connectivity, *, node_id: int = 1, role: str = "observer",
                 name: str = "observer", clock: Callable[[], float] = time.time):
        # ring channels for the bulk streams: a runner's or ground station's loop is busy in Python
        # with every UAV's messages, and a callback would make Zenoh's receive thread wait for it
        self.node = SwarmNode(NodeIdentity(swarm, node_id, role=role), connectivity, clock=clock, arrival_stamps=False)
        self.name = name
        self.clock = clock
        self.keys = self.node.keys
        self.uavs: dict[int, UavView] = {}
        self.pending: dict[int, PendingCommand] = {}
        self._ids = itertools.count(int(clock() * 1000) % 1_000_000)
        self._subs: dict[str, Inlet] = {}  # telemetry, state, ack
        self._subscribers: list[Any] = []
        # optional sink for everything poll() receives, as (kind, message): "pose", "telemetry",
        # "state", "ack", "joined"/"left" (liveliness keys). Used by `mrswarm gcs record`.
        self.tap: Callable[[str, Any], None] | None = None

    @property
    def stats(self) -> NodeStats:
        return self.node.stats

    def open(self) -> SwarmObserver:
        self.node.open()
        s = self.node.session
        assert s is not None
        clock = self.clock
        for name, key, size, waker in (("telemetry", self.keys.all_telemetry, 1024, None),
                                       ("state", self.keys.all_states, 1024, None),
                                       ("ack", self.keys.all_acks, 4096, self.node.waker)):  # acks: stamped, and wake
            inlet = self._subs[name] = Inlet(size, waker, clock, "callback" if waker is not None else "ring")
            self._subscribers.append(subscribe(s, key, inlet))
        return self

    @property
    def waker(self) -> Waker:
        """Readable when a command or an ack arrived (wait on it instead of sleeping)."""
        return self.node.waker

    def close(self) -> None:
        self._subs.clear()
        self.node.close()
        self._subscribers.clear()

    def __enter__(self) -> SwarmObserver:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def view(self, uav: int) -> UavView:
        v = self.uavs.get(uav)
        if v is None:
            v = self.uavs[uav] = UavView(uav)
        return v

    def _receive(self, name: str, accept: Accept[T]) -> Iterator[tuple[T, float]]:
        """The accepted messages of stream ``name`` (telemetry, state, ack) with their arrival
        time, counted as received."""
        inlet = self._subs.get(name)
        if inlet is None:  # not open
            return
        received = self.stats.received
        for arrival in receive(inlet, accept, self.stats):
            received[name] += 1
            yield arrival.item, arrival.at

    def poll(self) -> list[Pose]:
        """Drain everything that arrived; return the new poses (the newest per UAV is kept in ``uavs``).

        At most :data:`~swarmnet.receive.DRAIN_BUDGET` samples per subscription per call.
        """
        now = self.clock()
        before = {u: n.received for u, n in ((n.uav, n) for n in self.node.neighbours)}
        inbox = self.node.poll(now)
        tap = self.tap
        if tap is not None:
            for key in inbox.joined:
                tap("joined", key)
            for key in inbox.left:
                tap("left", key)
        fresh: list[Pose] = []
        for n in self.node.neighbours:
            if n.received != before.get(n.uav):
                v = self.view(n.uav)
                if v.pose is None or v.pose.t_wall != n.pose.t_wall:
                    v.pose, v.pose_recv = n.pose, n.last_recv
                    v.poses = n.received
                    fresh.append(n.pose)
                    if tap is not None:
                        tap("pose", n.pose)
        for t, _at in self._receive("telemetry", accept_telemetry):
            self.view(t.uav).telemetry = t
            if tap is not None:
                tap("telemetry", t)
        for st, at in self._receive("state", accept_state):
            v = self.view(st.uav)
            v.state, v.state_recv = st, at
            if tap is not None:
                tap("state", st)
        for ack, at in self._receive("ack", accept_ack):
            if tap is not None:
                tap("ack", ack)
            p = self.pending.get(ack.cmd_id)
            if p is not None and ack.uav in p.targets:
                p.acks[ack.uav] = ack
                p.acked_at.setdefault(ack.uav, at)
        return fresh

    def alive_uavs(self) -> set[int]:
        return self.node.alive_uavs()

    def phases(self) -> dict[int, str]:
        return {u: v.state.phase for u, v in self.uavs.items() if v.state is not None}

    def command(self, verb: str, targets: Iterable[int] | None = None, args: dict[str, Any] | None = None) -> PendingCommand:
        """Send ``verb`` to the given UAVs (None: the whole swarm, acked by every alive UAV)."""
        s = self.node.session
        assert s is not None
        cmd_id = next(self._ids) & 0xFFFFFFFF
        tset = set(targets) if targets is not None else self.alive_uavs()
        qos = _MUST_ARRIVE
        if targets is None:
            cmd = Command(self.name, cmd_id, 0, verb, args or {}, self.clock())
            s.put(self.keys.swarm_cmd, encode_command(cmd), **qos)
        else:
            cmd = Command(self.name, cmd_id, 0, verb, args or {}, self.clock())
            for t in sorted(tset):
                one = Command(self.name, cmd_id, t, verb, args or {}, cmd.t_wall)
                s.put(self.keys.cmd(t), encode_command(one), **qos)
        p = self.pending[cmd_id] = PendingCommand(cmd, tset)
        self.stats.sent["cmd"] += 1
        return p

    def inject(self, uav: int, kind: str, args: dict[str, float] | None = None) -> PendingCommand:
        """Inject a fault into one virtual UAV (``mrs/<swarm>/<uav>/fault``); its ack resolves the pending entry."""
        s = self.node.session
        assert s is not None
        fault_id = next(self._ids) & 0xFFFFFFFF
        f = FaultInjection(self.name, fault_id, uav, kind, dict(args or {}), self.clock())
        key, payload = self.keys.fault(uav), encode_fault(f)
        s.put(key, payload, **_MUST_ARRIVE)
        cmd = Command(self.name, fault_id, uav, "fault", {"kind": kind, **f.args}, f.t_wall)
        p = self.pending[fault_id] = PendingCommand(cmd, {uav}, resend=(key, payload))
        self.stats.sent["fault"] += 1
        return p

    def send_again(self, p: PendingCommand) -> None:
        """Put an unanswered fault once more (its UAV applies a fault id once, and acks every copy):
        sent while the UAV's link was being re-established (a router restart), the first may be lost."""
        s = self.node.session
        if p.resend is None or p.complete or s is None:
            return
        s.put(*p.resend, **_MUST_ARRIVE)
        self.stats.sent["fault"] += 1
