"""SwarmNode: one Zenoh session per agent, speaking the swarm key space.

Receiving runs almost no Python on Zenoh's threads: every subscription is an
:class:`~swarmnet.receive.Inlet`, whose callback only stamps each sample's arrival and queues
it (a slow zenoh-python callback stalls the whole session; a slow owner only loses its oldest
samples). Commands and netem changes also notify :attr:`SwarmNode.waker`, so the owner's loop
can handle them at once. :meth:`SwarmNode.poll` drains the inlets from the owner's loop through
the one receive path of :mod:`swarmnet.receive`, top to bottom:

1. runtime netem changes (``mrs/<swarm>/netem/set``, decoded by their codec,
   :func:`~swarmnet.netem.control.accept_netem_set`), so a change applies to this poll;
2. every data stream drained and accepted (poses first, then edge-feed batches, swarm
   messages, commands), rejections counted in :attr:`SwarmNode.stats`; poses and batches are
   kept as they came for step 3;
3. poses decoded and checked, edge-feed batches unpacked into the poses they carry;
4. the netem shim (docs/netem.md), if any: the one place items are offered to it and released;
5. delivery: poses into the neighbour table with their arrival time (their transport age
   recorded), messages and commands into the :class:`Inbox`;
6. liveliness changes, links of identities outside the roster (secured swarms), and
   neighbours silent too long forgotten.

The controller takes the neighbours with :meth:`SwarmNode.take_neighbours`, which records
each pose's age at use (arrival to first use). Both ages live in ``stats.ages``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Any, TypeVar

import zenoh

from swarmnet.connectivity import Connectivity, to_zenoh
from swarmnet.keyspace import SwarmKeys, check_swarm
from swarmnet.lockstep import SLACK_S as LOCKSTEP_SLACK_S
from swarmnet.messages import (
    DEFAULT_MAX_MESSAGE_BYTES,
    AgentState,
    Command,
    CommandAck,
    FaultInjection,
    Pose,
    PoseBatch,
    Realm,
    Rejected,
    SwarmMessage,
    Telemetry,
    accept_command,
    accept_fault,
    accept_neighbour_pose,
    accept_pose,
    accept_pose_batch,
    accept_swarm_message,
    batched_pose_count,
    encode_ack,
    encode_pose,
    encode_state,
    encode_swarm_message,
    encode_telemetry,
)
from swarmnet.neighbours import Neighbour, NeighbourTable
from swarmnet.receive import (
    DRAIN_BUDGET,
    Accept,
    Accepted,
    How,
    Inlet,
    Waker,
    batched_poses,
    receive,
    subscribe,
    token_changes,
)
from swarmnet.shared_session import NeighbourView
from swarmnet.stats import NodeStats

if TYPE_CHECKING:
    from swarmnet.netem import NetemShim
    from swarmnet.netem.shim import Link
    from swarmnet.security.links import LinkWatch
    from swarmnet.shared_session import SharedSession

log = logging.getLogger(__name__)
T = TypeVar("T")

ROLES = ("uav", "gcs", "edge", "observer")
# Where an accepted item goes; also the ``kind`` the netem shim keeps with an item it holds.
POSE, MESSAGE, COMMAND = 0, 1, 2
_BATCH = 3  # an edge-feed batch: unpacked into POSE items before the shim
FAULT = 4  # an injected fault (docs/reliability.md); never impaired by the shim
_HANDED = 5  # a pose a pool's shared session decoded and handed over (a member with a netem shim of its own)
_HANDED_PAYLOAD = bytes(32)  # what a handed pose weighs for the shim's rate limit: a pose's usual size on the wire, bytes
INLET_JOIN_S = 2.0  # s a receive thread gets to end after the session closed (its channel is then closed)
HELD_MESSAGES_MAX = 4096  # lock-step time: swarm messages a node holds for its next poll, at most


@dataclass(frozen=True)
class NodeIdentity:
    swarm: str
    uav: int  # for non-UAV roles: any id unique within the role
    realm: Realm = Realm.VIRTUAL
    role: str = "uav"

    def __post_init__(self) -> None:
        check_swarm(self.swarm)
        if not 1 <= self.uav <= 65535:
            raise ValueError(f"node id must be in 1..65535, got {self.uav}")
        if self.role not in ROLES:
            raise ValueError(f"role must be one of {ROLES}, got {self.role!r}")


@dataclass
class Inbox:
    """What arrived since the last poll (poses go straight into the neighbour table)."""

    messages: list[SwarmMessage] = field(default_factory=list)
    commands: list[Command] = field(default_factory=list)
    faults: list[FaultInjection] = field(default_factory=list)  # injected by the experiment controller
    joined: list[str] = field(default_factory=list)  # liveliness keys that appeared
    left: list[str] = field(default_factory=list)  # ... and disappeared


def _as_received(key: str, data: bytes) -> bytes:
    """The pose streams (direct poses, the edge feed's batches) keep a sample as it came: the
    stream's rule in :meth:`SwarmNode._accept` takes it from there."""
    return data


class SwarmNode:
    """A UAV's (or ground station's) presence in the swarm.

    Use as a context manager or call :meth:`open`/:meth:`close`. Not thread-safe: one owner
    thread calls ``publish_*``, ``send`` and ``poll``.
    """

    def __init__(
        self,
        identity: NodeIdentity,
        connectivity: Connectivity,
        *,
        pose_rate_hz: float = 10.0,
        stale_after: float = 1.0,
        forget_after: float = 10.0,
        max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
        ring_size: int = 1024,
        pose_feed: str = "direct",
        clock: Callable[[], float] = time.time,
        netem: dict[str, Any] | None = None,
        netem_control: bool = True,
        arrival_stamps: bool = True,
        near_feed: bool = False,
        shared: SharedSession | None = None,
    ):
        if pose_rate_hz <= 0:
            raise ValueError("pose_rate_hz must be > 0")
        if pose_feed not in ("direct", "edge"):
            raise ValueError(f"pose_feed must be 'direct' or 'edge', not {pose_feed!r}")
        if near_feed and (pose_feed != "edge" or identity.role != "uav"):
            raise ValueError("near_feed (spatial interest) needs pose_feed 'edge' and a UAV node")
        self.pose_feed = pose_feed
        self.near_feed = near_feed  # spatial interest: also the edge's batches for this UAV only (swarmnet/interest.py)
        self.identity = identity
        self.connectivity = connectivity
        self.keys = SwarmKeys(identity.swarm)
        self.pose_period = 1.0 / pose_rate_hz
        self.max_message_bytes = max_message_bytes
        self.ring_size = ring_size
        self.clock = clock
        # a pool's member (uav_stack/pool.py): the pool's one session, its poses and liveliness
        # (swarmnet/shared_session.py); the rest is the node's own
        self.shared = shared
        if shared is not None and identity.role != "uav":
            raise ValueError("only a UAV node shares a pool's session")
        self.neighbours: NeighbourTable | NeighbourView = (
            NeighbourTable(stale_after, forget_after) if shared is None
            else NeighbourView(shared.neighbours, identity.uav, shared.positions))
        self._token: Any = None  # the liveliness token, while open
        self._handed: list[tuple[Pose, float]] = []  # poses the shared session handed over, for the next poll
        self._alive_cursor = 0  # where this member is in the shared session's liveliness changes
        self._pose_rule: Accept[Pose] = accept_pose  # a direct pose's rule; a UAV's (not its own id) once open
        self.stats = NodeStats()
        self.alive: set[str] = set()  # liveliness keys currently present
        if shared is not None:  # the pool's: its poses arrive once (their ages noted here), and so do the tokens
            self.stats.ages.exclude = identity.uav
            self.alive = shared.alive
        self._alive_uavs: set[int] | None = None  # alive_uavs() parsed from alive (None: to parse again)
        self._members: tuple[int, ...] | None = None  # members(), kept with _alive_uavs
        self.session: zenoh.Session | None = None
        # readable when a command or a netem change arrived: the owner's loop waits on it
        self.waker = Waker()
        # the data streams poll() drains, in order: (where accepted items go, inlet, acceptance rule)
        self._streams: list[tuple[int, Inlet, Accept[Any]]] = []
        self._subscribers: list[Any] = []  # kept for as long as the session is open
        self._alive_inlet: Inlet | None = None
        self._netem_inlet: Inlet | None = None
        self._pose_inlet: Inlet | None = None  # the poses expect_poses() counts: direct, or the edge feed's batches
        self._expected_since = math.inf  # the instant (wall time, s) whose poses expect_poses() waits for
        self._links: LinkWatch | None = None  # secured swarms: counts links of non-members
        self._pubs: dict[str, Any] = {}
        self._seq: dict[str, int] = {"pose": 0, "telemetry": 0, "state": 0, "msg": 0}
        self._held_messages: list[SwarmMessage] = []  # lock-step time: sent at or after the last poll's instant
        self._next_pose = 0.0
        # netem shim (docs/netem.md): receive-side impairment of UAV and ground-station nodes
        self.netem: NetemShim | None = None
        self.netem_changes: list[dict[str, Any]] = []
        self.netem_control = netem_control and identity.role in ("uav", "gcs")
        # False: data streams in Zenoh ring channels, arrival = drain time (swarmnet.receive.Inlet)
        self.arrival_stamps = arrival_stamps
        self.own_position: tuple[float, float, float] | None = None  # as last published, for distance models
        if netem is not None:
            self.set_netem(netem, source="config")

    # ---- lifecycle ----------------------------------------------------------------------
    def open(self) -> SwarmNode:
        if self.session is not None:
            return self
        if self.waker.closed:  # opened again after a close
            self.waker = Waker()
        s = self._open_session()
        try:
            ident, k = self.identity, self.keys
            if ident.role == "uav":
                self._declare_publishers(s)
            self._subscribe_poses(s)  # poses first: the hot path
            self._subscribe_rest(s)
            self._token = s.liveliness().declare_token(k.alive(ident.role, ident.uav))
            if self.shared is None:  # (the shared session watches its links, and attaches its connectivity)
                self._watch_links(s)
                self.connectivity.attach(s)
            elif self.netem is not None:
                self.shared.impair(self)
        except BaseException:
            self.close()
            raise
        return self

    def _open_session(self) -> zenoh.Session:
        """A session of the node's own, or a pool's shared one (joined)."""
        shared = self.shared
        if shared is None:
            bind = getattr(self.connectivity, "bind", None)
            if callable(bind):  # strategies that announce the node (discovery) take its identity, and count its refusals
                bind(self.identity, self.stats.refused)
            self.session = zenoh.open(to_zenoh(self.connectivity.zenoh_config()))
            return self.session
        if shared.session is None:
            raise RuntimeError(f"UAV {self.identity.uav}: the pool's shared session is not open")
        self.session = shared.session
        shared.join(self)
        self._alive_cursor = 0  # every change the pool has seen is news to a member that just joined
        return self.session

    def _inlet(self, s: zenoh.Session, key: str, size: int, how: How, wakes: bool = False,
               weigh: Callable[[zenoh.Sample], int] | None = None, lazy: bool = False, **options: Any) -> Inlet:
        """An inlet subscribed to ``key`` on session ``s``; ``wakes``: it notifies :attr:`waker`."""
        if not self.arrival_stamps and not wakes:
            how = "ring"  # an observer: the drain's time will do
        into = Inlet(size, self.waker if wakes else None, self.clock, how, weigh, lazy)
        self._subscribers.append(subscribe(s, key, into, **options))
        return into

    @property
    def lockstep(self) -> bool:
        """In lock-step time (swarmnet/lockstep.py): a member of a pool whose shared session says so."""
        return self.shared is not None and self.shared.lossless

    def _declare_publishers(self, s: zenoh.Session) -> None:
        k, me = self.keys, self.identity.uav
        # lock-step time: nothing may be lost, a full queue waits instead
        lossless = self.lockstep
        cc = zenoh.CongestionControl.BLOCK if lossless else zenoh.CongestionControl.DROP
        # (lock-step: batched with the pool's other puts, not a batch each: the clock's step waits for all of them anyway)
        self._pubs["pose"] = s.declare_publisher(k.pose(me), congestion_control=cc, priority=zenoh.Priority.DATA_HIGH,
                                                 express=not lossless)
        self._pubs["telemetry"] = s.declare_publisher(k.telemetry(me), congestion_control=cc)
        self._pubs["state"] = s.declare_publisher(k.state(me), congestion_control=cc)
        self._pubs["ack"] = s.declare_publisher(k.ack(me), priority=zenoh.Priority.INTERACTIVE_HIGH, express=True)

    def _subscribe_poses(self, s: zenoh.Session) -> None:
        """The pose stream: direct poses, or the edge feed's batches (and the near feed, with
        spatial interest); for a pool's member, the shared session's."""
        k, ident, me = self.keys, self.identity, self.identity.uav
        if self.shared is not None:  # the pool's session takes them in, once for every member
            if self.near_feed:
                self.shared.add_near_feed(me)
            return
        if self.pose_feed == "edge":  # batches of the edge router's feed instead of a message per neighbour
            # a UAV counts the neighbours' poses in each batch as it arrives (expect_poses); not with
            # spatial interest, whose far poses come at a lower rate on a feed of their own
            counts = ident.role == "uav" and not self.near_feed
            weigh = (lambda sample: batched_pose_count(sample.payload.to_bytes(), me)) if counts else None
            feed = self._inlet(s, k.pose_feed, 256, "thread", weigh=weigh, lazy=counts)
            if counts and feed.how == "thread":
                self._pose_inlet = feed
            self._streams.append((_BATCH, feed, _as_received))
            if self.near_feed:
                self._streams.append((_BATCH, self._inlet(s, k.near_feed(me), 256, "thread"), _as_received))
            return
        self._pose_rule = partial(accept_neighbour_pose, me=me) if ident.role == "uav" else accept_pose
        poses = self._inlet(s, k.all_poses, self.ring_size, "thread", lazy=ident.role == "uav",
                            allowed_origin=zenoh.Locality.REMOTE)
        if poses.how == "thread":
            self._pose_inlet = poses
        self._streams.append((POSE, poses, _as_received))

    def _subscribe_rest(self, s: zenoh.Session) -> None:
        """Messages, commands, faults, liveliness (a pool's member: the shared session's), netem changes."""
        k, ident, me, streams = self.keys, self.identity, self.identity.uav, self._streams
        message_rule = partial(accept_swarm_message, me=me, max_bytes=self.max_message_bytes)
        # a pool's members share a session: their broadcasts to each other are local (and their own come back)
        origin: dict[str, Any] = {} if self.shared is not None else {"allowed_origin": zenoh.Locality.REMOTE}
        streams.append((MESSAGE, self._inlet(s, k.all_broadcast, 256, "ring", **origin), message_rule))
        if ident.role == "uav":
            streams.append((MESSAGE, self._inlet(s, k.all_unicast(me), 64, "ring"), message_rule))
            command_rule = partial(accept_command, me=me)
            streams.append((COMMAND, self._inlet(s, k.cmd(me), 64, "callback", wakes=True), command_rule))
            streams.append((COMMAND, self._inlet(s, k.swarm_cmd, 64, "callback", wakes=True), command_rule))
            streams.append((FAULT, self._inlet(s, k.fault(me), 16, "callback", wakes=True), partial(accept_fault, me=me)))
        if self.shared is None:
            self._alive_inlet = alive = Inlet(256, None, self.clock, "ring")  # joins and leaves: the drain's time will do
            self._subscribers.append(sub := s.liveliness().declare_subscriber(k.all_alive, alive.handler(), history=True))
            alive.attach(sub)
        if self.netem_control:
            self._netem_inlet = self._inlet(s, k.netem_set, 16, "callback", wakes=True)

    def _watch_links(self, session: zenoh.Session) -> None:
        creds = self.connectivity.credentials
        if creds is None:
            return
        from swarmnet.security.acl import member_names
        from swarmnet.security.links import LinkWatch

        self._links = LinkWatch(session, member_names(creds.roster()), self.stats)

    def close(self) -> None:
        if self.session is None:
            return
        if self.shared is not None:
            self._leave_shared()
            return
        try:
            self.connectivity.detach()
        finally:
            s, self.session = self.session, None
            threaded = [inlet for _, inlet, _ in self._streams if inlet.how == "thread"]
            if self._links is not None:
                self._links.close()
                self._links = None
            self._streams.clear()
            self._alive_inlet = self._netem_inlet = self._pose_inlet = None
            self._pubs.clear()
            try:
                s.close()
            except zenoh.ZError as exc:  # closing twice or a dead runtime must not raise on shutdown
                log.debug("zenoh close: %s", exc)
            self._subscribers.clear()
            for inlet in threaded:  # their channels are closed now: let the threads leave Zenoh before exit
                if not inlet.join(INLET_JOIN_S):
                    log.warning("a receive thread did not end within %.1f s of the session's close", INLET_JOIN_S)
            self.waker.close()

    def _leave_shared(self) -> None:
        """A pool's member leaves the shared session (which stays open for the others): its
        publishers, subscribers and token undeclared."""
        assert self.shared is not None
        shared, self.session = self.shared, None
        shared.leave(self)
        declared = [*self._pubs.values(), *self._subscribers]
        if self._token is not None:
            declared.append(self._token)
            self._token = None
        for d in declared:
            try:
                d.undeclare()
            except zenoh.ZError as exc:  # the shared session closed first: nothing left to undeclare
                log.debug("undeclare: %s", exc)
        self._streams.clear()
        self._netem_inlet = self._pose_inlet = None
        self._pubs.clear()
        self._subscribers.clear()
        self.waker.close()

    def __enter__(self) -> SwarmNode:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def _own_uav(self) -> int | None:
        """The UAV whose own pose comes back in the swarm's batches and is no neighbour (None: not a UAV)."""
        return self.identity.uav if self.identity.role == "uav" else None

    @property
    def zid(self) -> str:
        assert self.session is not None
        return str(self.session.info.zid())

    def routers(self) -> list[str]:
        """ZIDs of the routers this session has a link to (the edge router; empty while it is down)."""
        if self.session is None:
            return []
        return [str(z) for z in self.session.info.routers_zid()]

    def peers(self) -> list[str]:
        """ZIDs of the peers this session has a direct link to."""
        assert self.session is not None
        return [str(z) for z in self.session.info.peers_zid()]

    # ---- publishing ---------------------------------------------------------------------
    def _next(self, stream: str, mod: int) -> int:
        v = self._seq[stream]
        self._seq[stream] = (v + 1) % mod
        return v

    def pose_due(self, now: float) -> bool:
        return now >= self._next_pose

    def publish_pose(
        self, *, t_sim: float, x: float, y: float, z: float, vx: float, vy: float, vz: float, yaw: float,
        t_wall: float | None = None,
    ) -> Pose:
        now = self.clock()
        # keep the schedule on a fixed grid, but never burst after a stall
        self._next_pose = max(self._next_pose + self.pose_period, now)
        pose = Pose(
            uav=self.identity.uav,
            realm=self.identity.realm,
            seq=self._next("pose", 1 << 16),
            t_sim=t_sim,
            t_wall=now if t_wall is None else t_wall,
            x=x, y=y, z=z, vx=vx, vy=vy, vz=vz, yaw=yaw,
        )
        self._put("pose", encode_pose(pose))
        self.stats.sent["pose"] += 1
        self.own_position = (x, y, z)
        if self.netem is not None:
            self.netem.own_pos = self.own_position
        return pose

    def publish_telemetry(self, *, mode: str, armed: bool, battery: float, voltage: float, lat: float, lon: float, alt: float,
                          rtf: float, transport_ms: float = -1.0, use_ms: float = -1.0) -> None:
        """Flight-controller status, and the UAV's pose ages (p50 over its last second, ms; -1 or NaN: unknown)."""
        t = Telemetry(
            uav=self.identity.uav, realm=self.identity.realm, seq=self._next("telemetry", 1 << 32), t_wall=self.clock(),
            mode=mode, armed=armed, battery=battery, voltage=voltage, lat=lat, lon=lon, alt=alt, rtf=rtf,
            transport_ms=transport_ms, use_ms=use_ms,
        )
        self._put("telemetry", encode_telemetry(t))
        self.stats.sent["telemetry"] += 1

    def publish_state(self, phase: str, behaviour: str, override: str = "", detail: str = "") -> None:
        st = AgentState(
            uav=self.identity.uav, realm=self.identity.realm, seq=self._next("state", 1 << 32), t_wall=self.clock(),
            phase=phase, behaviour=behaviour, override=override, detail=detail,
        )
        self._put("state", encode_state(st))
        self.stats.sent["state"] += 1

    def _put(self, kind: str, payload: bytes) -> None:
        """Put on this node's publisher of ``kind``: now, or inside a pool's
        :meth:`~swarmnet.shared_session.SharedSession.together` back to back with its pool-mates' puts."""
        held = self.shared.held if self.shared is not None else None
        if held is None:
            self._pubs[kind].put(payload)
        else:
            held.append((self._pubs[kind], payload))

    def send(self, topic: str, body: Any, to: int | None = None) -> None:
        """Send a swarm message: to one UAV (unicast) or, with ``to=None``, to the whole swarm."""
        assert self.session is not None
        msg = SwarmMessage(src=self.identity.uav, dst=to or 0, topic=topic, seq=self._next("msg", 1 << 32), t_wall=self.clock(),
                           body=body)
        data = encode_swarm_message(msg, self.max_message_bytes)
        me = self.identity.uav
        key = self.keys.broadcast(me, topic) if to is None else self.keys.unicast(me, to, topic)
        if self.lockstep:  # nothing may be lost
            self.session.put(key, data, congestion_control=zenoh.CongestionControl.BLOCK)
        else:
            self.session.put(key, data)
        self.stats.sent["broadcast" if to is None else "unicast"] += 1

    def ack(self, cmd_id: int, ok: bool, message: str = "") -> None:
        a = CommandAck(uav=self.identity.uav, cmd_id=cmd_id, ok=ok, message=message, t_wall=self.clock())
        self._pubs["ack"].put(encode_ack(a))
        self.stats.sent["ack"] += 1

    # ---- receiving ----------------------------------------------------------------------
    def hand(self, poses: list[tuple[Pose, float]]) -> None:
        """Poses a pool's shared session decoded, with their arrival times (wall, s), for this
        member's own table and netem shim: taken in at its next :meth:`poll`."""
        self._handed += poses
        del self._handed[:-4 * self.ring_size]  # a member that stopped polling: a bounded backlog

    def poll(self, now: float | None = None, max_samples: int = DRAIN_BUDGET) -> Inbox:
        """Take in what arrived since the last poll: poses into :attr:`neighbours`, the rest returned.

        ``now`` is the local wall-clock time in s (default: the node's clock). At most
        ``max_samples`` samples are drained per subscription per call; the rest wait for the
        next poll. Rejected samples are counted in ``stats.rejected`` and never returned.
        """
        now = self.clock() if now is None else now
        inbox = Inbox()
        if self.session is None:
            return inbox
        self._apply_netem_sets(now, max_samples)  # first, so a change applies to what this poll drains
        if self.shared is not None:  # the pool's poses: the first member to poll takes them in for all
            self.shared.pump(now, max_samples)
        waiting = self._pose_inlet if self._pose_inlet is not None and not self._pose_inlet.started else None
        if waiting is not None:
            waiting.poke()  # a pose came before its sender's token: the inlet's thread starts now
        self._take_in(self._arrivals(max_samples), now, inbox)
        if self.lockstep:
            self._hold_early_messages(inbox, now)
        self._track_liveliness(inbox, max_samples)
        if waiting is not None and inbox.joined and self.alive_uavs() - {self.identity.uav}:
            waiting.start()  # the first other UAV: its poses are stamped as they arrive from now on
        if self._links is not None:
            self._links.poll()
        self.neighbours.expire(now)
        return inbox

    def _hold_early_messages(self, inbox: Inbox, now: float) -> None:
        """Lock-step time (swarmnet/lockstep.py): a swarm message sent at simulated time ``t`` is
        taken at the first poll at or after ``t`` plus the pool's :attr:`~swarmnet.shared_session.SharedSession.message_hold_s`
        (a tick: the receivers' next act, by which every pool's messages of the act before are in,
        whichever pool ran first); those held from before, now due, come first, in the order they were sent."""
        assert self.shared is not None
        hold = self.shared.message_hold_s - LOCKSTEP_SLACK_S
        held = self._held_messages
        due = [m for m in held if m.t_wall + hold <= now]
        later = [m for m in held if m.t_wall + hold > now]
        for m in inbox.messages:
            (due if m.t_wall + hold <= now else later).append(m)
        due.sort(key=lambda m: (m.t_wall, m.src, m.seq))  # one order, however the pools' messages interleaved
        inbox.messages = due
        self._held_messages = later[-HELD_MESSAGES_MAX:]

    def take_neighbours(self, now: float | None = None,
                        around: tuple[float, float, float] | None = None) -> list[Neighbour]:
        """The neighbours, for the controller about to use them at ``now`` (default: the clock):
        every one, or with ``around = (x, y, radius)`` (m) those whose latest pose is at most
        ``radius`` horizontally from (x, y) (a pool's member finds them in the pool's index).

        Records the age at use (``now`` minus its arrival) of each pose returned for the first
        time. Call it right before the poses are used, after :meth:`poll`, so that ``now`` is
        never earlier than an arrival.
        """
        now = self.clock() if now is None else now
        table = self.neighbours
        out = table.snapshot() if around is None else table.around(*around)
        if self.lockstep:  # one order, however the poses arrived
            out.sort(key=lambda n: n.pose.uav)
        if isinstance(table, NeighbourView):  # a pool's member: its own first uses
            self.stats.ages.used_many(table.first_uses(out, now))
            return out
        ages = []
        for n in out:
            if not n.used:
                n.used = True
                ages.append(now - n.last_recv)
        self.stats.ages.used_many(ages)
        return out

    def expect_poses(self, instant: float) -> int | None:
        """Wake the owner (:attr:`waker`) once the poses of the tick at ``instant`` (wall time, s)
        have arrived: one from each neighbour heard from at the instant before, directly or in
        the edge feed's batches. Returns how many it waits for: 0 if nobody was heard, None if
        it cannot tell (an observer; the edge feed with spatial interest, whose far neighbours
        send less often), and then nothing is armed.

        For aligned ticks (``network.align_ticks``): every UAV publishes at the same instants,
        so the control can run on the swarm's poses of this instant as soon as they are in
        (:meth:`expected_poses_due`).
        """
        inlet = self._pose_inlet
        if inlet is None:
            return None
        self._expected_since = instant
        since = instant - 1.5 * self.pose_period
        count = len([n for n in self.neighbours.snapshot() if n.last_recv >= since])  # (a list: faster than a generator)
        if count:
            inlet.expect(count, instant, self.waker)
        return count

    def expected_poses_in(self) -> bool:
        """The poses :meth:`expect_poses` waits for have arrived (a :meth:`poll` takes them in)."""
        inlet = self._pose_inlet
        return inlet is not None and inlet.expectation_met

    def expected_poses_due(self) -> float | None:
        """Once :meth:`expected_poses_in` and a :meth:`poll` took them in: the wall time (s) at
        which a netem shim releases the last of them it holds; None if it holds none (or there
        is no shim): they are delivered. A lost pose never comes: the others do not wait for it."""
        if self.netem is None:
            return None
        return self.netem.held_until(POSE, self._expected_since)

    def stop_expecting_poses(self) -> None:
        """Forget what :meth:`expect_poses` armed, met or not: the owner no longer waits."""
        if self._pose_inlet is not None:
            self._pose_inlet.cancel_expectation()

    def _arrivals(self, budget: int) -> Iterator[tuple[int, Accepted[Any]]]:
        """Every accepted sample of the data streams, stream by stream (poses first: a pool's
        member with a table of its own gets those its shared session handed over)."""
        if self._handed:
            handed, self._handed = self._handed, []
            own, pose_key = self.identity.uav, self.keys.pose
            for pose, at in handed:
                if pose.uav != own:
                    yield _HANDED, Accepted(pose_key(pose.uav), pose, _HANDED_PAYLOAD, at)
        for kind, ring, accept in self._streams:
            for arrival in receive(ring, accept, self.stats, budget):
                yield kind, arrival

    def _take_in(self, arrivals: Iterable[tuple[int, Accepted[Any]]], now: float, inbox: Inbox) -> None:
        """Steps 3 to 5 of the receive path (the module's docstring): batches unpacked, the netem
        shim, delivery.

        Without a shim (the common case, and the hot one: a UAV of 50 takes in about 500 poses a
        second) each item is delivered as it comes, and a batch's poses go straight into the
        neighbour table (:meth:`_take_poses`), with nothing built per pose for the shim that is
        not there: the same outcome as the stages chained, with a third less Python per pose
        (2.30 -> 1.56 µs warm, ``benchmarks/receive_path.py``)."""
        if self.netem is not None:
            for kind, item, at in self._through_netem(self._unbatch(arrivals), now):
                self._deliver(kind, item, at, inbox)
            return
        for kind, arrival in arrivals:
            if kind == POSE:
                pose = self._accept(self._pose_rule, arrival.key, arrival.payload)
                if pose is not None:
                    self._deliver(POSE, pose, arrival.at, inbox)
            elif kind == _BATCH:
                self._take_batch(arrival.key, arrival.payload, arrival.at)
            elif kind == _HANDED:
                self._deliver(POSE, arrival.item, arrival.at, inbox)
            else:
                self._deliver(kind, arrival.item, arrival.at, inbox)

    def _take_batch(self, key: str, payload: bytes, at: float) -> None:
        """An edge-feed batch that arrived at ``at`` (wall time, s) into the neighbour table
        (:func:`~swarmnet.messages.accept_pose_batch`, :meth:`_batch_poses`, :meth:`_take_poses`),
        what any rule refuses named and counted."""
        batch = self._accept(accept_pose_batch, key, payload)
        if batch is not None:
            self._take_poses(self._batch_poses(batch), at)

    def _accept(self, rule: Accept[T], key: str, payload: bytes) -> T | None:
        """A pose or batch kept as it came (:func:`_as_received`), decoded and checked by ``rule``;
        None, the reason counted in ``stats.rejected``, if the rule refuses it (as
        :func:`~swarmnet.receive.receive` counts the other streams')."""
        try:
            return rule(key, payload)
        except Rejected as exc:
            self.stats.reject(exc.reason, key, exc.detail)
            return None

    def _unbatch(self, arrivals: Iterable[tuple[int, Accepted[Any]]]) -> Iterator[tuple[int, Accepted[Any]]]:
        """Poses decoded for the netem shim: a direct pose by its stream's rule (:meth:`_accept`),
        an edge-feed batch into the poses it carries (:meth:`_batch_poses`). Each keeps the key and
        arrival stamp it came with: that is where and when it arrived."""
        for kind, arrival in arrivals:
            if kind == _HANDED:  # decoded by a pool's shared session
                yield POSE, arrival
                continue
            if kind == POSE:  # a direct pose, kept as it came: decoded here
                pose = self._accept(self._pose_rule, arrival.key, arrival.payload)
                if pose is not None:
                    yield POSE, Accepted(arrival.key, pose, arrival.payload, arrival.at)
                continue
            if kind != _BATCH:
                yield kind, arrival
                continue
            key, at = arrival.key, arrival.at
            batch = self._accept(accept_pose_batch, key, arrival.payload)
            if batch is None:
                continue
            for pose, data in self._batch_poses(batch):
                yield POSE, Accepted(key, pose, data, at)

    def _batch_poses(self, batch: PoseBatch) -> Iterator[tuple[Pose, bytes]]:
        """The poses an edge-feed batch carries, with their payloads, each accepted on its own as
        from the sender the batch names for it (:func:`~swarmnet.messages.accept_batched_pose`: a
        bad one is counted under the sender's pose key, the others kept); our own pose, which
        comes back in the swarm's batch, left out."""
        self.stats.received["pose_batch"] += 1
        return batched_poses(batch, self.stats, self.keys.pose, self._own_uav)

    def _take_poses(self, poses: Iterable[tuple[Pose, bytes]], at: float) -> None:
        """Poses that arrived at ``at`` (local wall time, s) into the neighbour table, counted as
        received, the transport age of each one the table takes recorded (as :meth:`_deliver`
        does for one)."""
        table = self.neighbours
        assert isinstance(table, NeighbourTable)  # (a pool's member takes in none: its shared session does)
        update = table.update
        srcs: list[int] = []
        ages: list[float] = []
        n = 0
        for pose, _ in poses:
            n += 1
            if update(pose, at):
                srcs.append(pose.uav)
                ages.append(at - pose.t_wall)
        self.stats.ages.arrived_many(srcs, ages)
        self.stats.received["pose"] += n

    def _through_netem(self, arrivals: Iterable[tuple[int, Accepted[Any]]], now: float) -> Iterator[tuple[int, Any, float]]:
        """The netem shim as a filter (docs/netem.md): the one place items are offered to it and released.

        Yields ``(kind, item, arrival time)``. Each item crosses the link from its sender
        (:meth:`_netem_link`) from its arrival stamp on: a pass-through link delivers it at once;
        otherwise the shim holds it until its time to send, which becomes its arrival, or drops
        it. Items due at ``now`` follow the fresh ones. Only a node with a shim comes here
        (:meth:`_take_in`): one without delivers each item as it comes.
        """
        shim = self.netem
        assert shim is not None
        for kind, arrival in arrivals:
            item = arrival.item
            link = self._netem_link(shim, kind, item)
            if link is None or shim.offer(link, arrival.at, kind, item, arrival.key, len(arrival.payload)):
                yield kind, item, arrival.at
        for kind, item, _key, tts in shim.release(now):
            yield kind, item, tts

    def _netem_link(self, shim: NetemShim, kind: int, item: Any) -> Link | None:
        """The link ``item`` crossed to reach this node (None: a link the shim never impairs)."""
        if kind == POSE:
            link = shim.links.get(item.uav)
            if link is None or link.realm is not item.realm:
                link = shim.link(item.uav, item.realm)
            if link.distance is not None:
                link.pos = (item.x, item.y, item.z)  # the sender's position when it sent this pose
            return link
        if kind == MESSAGE:
            if item.src == self.identity.uav and self.identity.role == "uav":
                return None  # a UAV's message to itself crossed no link
            return shim.link(item.src)
        if kind == FAULT:
            return None
        return None if shim.config.exempt_commands else shim.link(f"gcs:{item.sender}")

    def _deliver(self, kind: int, item: Any, at: float, inbox: Inbox) -> None:
        """Count ``item`` (arrived at ``at``) as received and hand it over: a pose to the neighbour
        table (its transport age recorded), the rest to ``inbox``."""
        stats = self.stats
        if kind == POSE:
            stats.received["pose"] += 1
            table = self.neighbours
            if isinstance(table, NeighbourTable) and table.update(item, at):  # (a view: a shared member's, none come)
                stats.ages.arrived(item.uav, at - item.t_wall)
        elif kind == MESSAGE:
            if item.dst == 0 and self.shared is not None and item.src == self.identity.uav:
                return  # a pool's member: its own broadcast, back through the shared session
            stats.received["broadcast" if item.dst == 0 else "unicast"] += 1
            inbox.messages.append(item)
        elif kind == FAULT:
            stats.received["fault"] += 1
            inbox.faults.append(item)
        else:
            stats.received["cmd"] += 1
            inbox.commands.append(item)

    def _track_liveliness(self, inbox: Inbox, budget: int) -> None:
        """Update :attr:`alive` from the liveliness tokens that appeared or disappeared."""
        if self.shared is not None:  # the pool's session keeps alive; this member reads what changed
            changes, self._alive_cursor = self.shared.changes_since(self._alive_cursor)
        elif self._alive_inlet is not None:
            changes = token_changes(self._alive_inlet, self.alive, budget)
        else:
            return
        for key, appeared in changes:
            (inbox.joined if appeared else inbox.left).append(key)
        if changes:
            self._alive_uavs = None

    # ---- netem shim (docs/netem.md) ----------------------------------------------------------
    def set_netem(self, config: dict[str, Any] | None, *, source: str = "api", now: float | None = None,
                  msg_id: int | None = None) -> str:
        """Apply a netem configuration (the ``network.netem`` mapping; None: no shim at all, and
        whatever the shim still holds is discarded; ``{"preset": "none"}`` releases it instead).

        Raises :class:`~swarmnet.netem.NetemConfigError` for an invalid one. A missing ``seed``
        keeps the current seed. Returns a one-line description of what now applies.
        """
        from swarmnet.netem import NetemShim, parse_netem

        if self.identity.role not in ("uav", "gcs"):
            raise ValueError(f"a {self.identity.role} node does not impair its links")
        now = self.clock() if now is None else now
        if config is None:
            self.netem = None
            desc = "off"
        else:
            seed = self.netem.config.seed if self.netem is not None else 0
            cfg = parse_netem(config, default_seed=seed)
            if self.netem is None:
                self.netem = NetemShim(cfg, self.identity.uav, self.identity.realm, self.identity.role)
                self.netem.own_pos = self.own_position
                self._own_table()
            else:
                self.netem.reconfigure(cfg)
            desc = cfg.describe()
        preset = self.netem.config.preset if self.netem is not None else None
        self.netem_changes.append({"t": now, "source": source, "id": msg_id, "preset": preset, "config": desc})
        del self.netem_changes[:-50]  # a bounded history
        return desc

    def _own_table(self) -> None:
        """A pool's member whose links are impaired from now on: a neighbour table of its own, fed
        with the poses the shared session decodes, through its shim (it starts with what the
        pool's table holds now, as it was delivered)."""
        view = self.neighbours
        if not isinstance(view, NeighbourView):
            return
        table = NeighbourTable(view.stale_after, view.forget_after)
        for n in view.snapshot():
            table.update(n.pose, n.last_recv)
        self.neighbours = table
        if self.shared is not None and self.session is not None:
            self.shared.impair(self)

    def _apply_netem_sets(self, now: float, budget: int) -> None:
        """Apply the runtime changes that arrived on ``mrs/<swarm>/netem/set``, each acked (ok or not)."""
        if self._netem_inlet is None or not len(self._netem_inlet):  # the usual case, every tick: nothing to import
            return
        from swarmnet.netem import NetemConfigError
        from swarmnet.netem.control import accept_netem_set

        for arrival in receive(self._netem_inlet, accept_netem_set, self.stats, budget):
            m = arrival.item
            if not m.applies_to(self.identity.uav):
                continue  # a change for other UAVs
            try:
                desc = self.set_netem(m.config, source=m.sender, now=now, msg_id=m.id)
            except NetemConfigError as exc:  # the one error of a config that decoded (tests/test_netem_control.py)
                self.stats.reject("bad_netem_config", arrival.key, str(exc))
                if "ack" in self._pubs:
                    self.ack(m.id, False, f"netem: {exc}"[:200])
                continue
            self.stats.received["netem_set"] += 1
            self.netem_changes[-1]["t_sent"] = m.t_wall
            if "ack" in self._pubs:
                self.ack(m.id, True, f"netem: {desc}"[:200])

    def netem_stats(self) -> dict[str, Any] | None:
        """Per-link statistics and the history of changes, for the stats JSON (None: never configured)."""
        if self.netem is None and not self.netem_changes:
            return None
        out: dict[str, Any] = self.netem.stats() if self.netem is not None else {"config": "off", "links": {}}
        out["changes"] = list(self.netem_changes)
        return out

    def alive_uavs(self) -> set[int]:
        """UAV ids whose liveliness token is present (the node's own included). Parsed again only
        after a token appeared or disappeared (the controller asks every tick)."""
        if self._alive_uavs is None:
            prefix = f"{self.keys.prefix}/alive/uav/"
            out = set()
            for key in self.alive:
                if key.startswith(prefix):
                    tail = key[len(prefix):]
                    if tail.isdigit():
                        out.add(int(tail))
            self._alive_uavs = out
            self._members = None
        return set(self._alive_uavs)

    def members(self) -> tuple[int, ...]:
        """The swarm's UAV ids in order: :meth:`alive_uavs` and the node's own. The same tuple
        until a token appears or disappears (a cooperative mission splits its work by it every tick)."""
        if self._alive_uavs is None or self._members is None:
            alive = self.alive_uavs()
            if self._own_uav is not None:
                alive.add(self._own_uav)
            self._members = tuple(sorted(alive))
        return self._members
