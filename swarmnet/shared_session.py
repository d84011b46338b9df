"""One Zenoh session for the swarm nodes of a pool of virtual UAVs (``uav_stack/pool.py``).

A pool hosts K virtual UAVs in one process. Each is still its own :class:`~swarmnet.node.SwarmNode`:
its own id, its publishers under its own keys (``mrs/<swarm>/<uav>/pose`` ...), its liveliness
token, its commands, faults, unicasts and netem changes. What they share is this session, so
that the pool has one link to its router instead of K, and the poses that reach the pool:

* **one pose stream for the pool.** The swarm's poses (direct, or the edge feed's batches, and
  with spatial interest the pool's one near feed ``mrs/<swarm>/feed/near/pool-<n>``: every
  sender near any member, each once) arrive once, are decoded once into one
  :class:`~swarmnet.neighbours.NeighbourTable` holding every UAV the pool hears, its own
  members included. A member sees that table through a
  :class:`NeighbourView` without itself. A member with a netem shim of its own (docs/netem.md)
  keeps a table of its own instead, and the pool hands it each decoded pose to impair.
* **one liveliness view**: who is alive, kept once for every member.
* **one decode for the ages**: the pool notes each pose's transport age once, and hands the
  notes to every member (which leaves its own pose out when it files them).

Everything else a member receives it subscribes to itself on this session (commands, faults,
netem changes, broadcasts, unicasts): rare streams, which Zenoh delivers to each subscriber.

Security: the session speaks as the pool's identity (``pool-<id>.<swarm>``), whose certificate
speaks for the UAVs of its roster entry and for no other (swarmnet/security/acl.py).
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np
import zenoh

from swarmnet.connectivity import Connectivity, to_zenoh
from swarmnet.keyspace import SwarmKeys
from swarmnet.lockstep import SLACK_S as LOCKSTEP_SLACK_S
from swarmnet.messages import Pose, Rejected, accept_pose, accept_pose_batch
from swarmnet.neighbours import Neighbour, NeighbourTable
from swarmnet.receive import DRAIN_BUDGET, Inlet, batched_poses, subscribe, token_changes
from swarmnet.stats import NodeStats

if TYPE_CHECKING:
    from swarmnet.interest import Interest  # (a node without interest never loads the configuration system)
    from swarmnet.node import SwarmNode
    from swarmnet.security.links import LinkWatch

log = logging.getLogger(__name__)

INLET_JOIN_S = 2.0  # s a receive thread gets to end after the session closed
MAX_CHANGES = 4096  # liveliness changes kept for members that have not read them yet
EARLY_MAX = 65536  # lock-step time: poses held for a later instant, at most (a whole tick of 1,000 UAVs fits)


class Positions:
    """Where each UAV of the pool's table was at its latest pose (x, y, m), in one array, so that
    each member finds the neighbours around it with one vectorised comparison instead of a
    Python loop over the whole table (at N = 1,000 that loop is most of a member's tick).

    The pool updates it with the UAVs each pump took a pose of and those the table forgot.
    A free row holds NaN, which no comparison selects."""

    __slots__ = ("_ids", "_index", "_free", "_xy")

    def __init__(self, capacity: int = 64):
        self._ids: list[int] = []  # row -> UAV (0: a free row)
        self._index: dict[int, int] = {}  # UAV -> row
        self._free: list[int] = []
        self._xy = np.full((capacity, 2), np.nan)

    def moved(self, table: NeighbourTable, uavs: list[int]) -> None:
        """The UAVs in ``uavs`` have a new latest pose in ``table``."""
        index, entries = self._index, table._table  # noqa: SLF001 - the pool owns this table
        for u in uavs:
            n = entries.get(u)
            if n is None:
                continue
            i = index.get(u)
            if i is None:
                i = index[u] = self._row(u)
            row = self._xy[i]
            row[0] = n.pose.x
            row[1] = n.pose.y

    def _row(self, uav: int) -> int:
        if self._free:
            i = self._free.pop()
            self._ids[i] = uav
            return i
        i = len(self._ids)
        if i == len(self._xy):
            grown = np.full((2 * i, 2), np.nan)
            grown[:i] = self._xy
            self._xy = grown
        self._ids.append(uav)
        return i

    def forget(self, uavs: list[int]) -> None:
        for u in uavs:
            i = self._index.pop(u, None)
            if i is not None:
                self._xy[i] = np.nan
                self._ids[i] = 0
                self._free.append(i)

    def within(self, x: float, y: float, radius: float) -> list[int]:
        """The UAVs whose latest pose is at most ``radius`` (m, horizontal) from (x, y)."""
        n = len(self._ids)
        if not n:
            return []
        d = self._xy[:n] - (x, y)
        rows = np.flatnonzero(np.einsum("ij,ij->i", d, d) <= radius * radius)
        ids = self._ids
        return [ids[i] for i in rows.tolist()]


class NeighbourView:
    """A pool member's neighbours: the pool's table (:class:`SharedSession`) without the member
    itself, read-only (the pool's session takes the poses in and forgets the silent ones). Its
    own first uses are its own: the age at use it records is from each pose's arrival to this
    member's first use of it."""

    __slots__ = ("table", "own", "positions", "_used")

    def __init__(self, table: NeighbourTable, own: int, positions: Positions | None = None):
        self.table = table
        self.own = own
        self.positions = positions  # the pool's index of the table's positions (None: none kept)
        self._used: dict[int, float] = {}  # neighbour -> arrival of the pose this member used last

    @property
    def stale_after(self) -> float:
        return self.table.stale_after

    @property
    def forget_after(self) -> float:
        return self.table.forget_after

    def get(self, uav: int) -> Neighbour | None:
        return None if uav == self.own else self.table.get(uav)

    def fresh(self, now: float) -> list[Neighbour]:
        own = self.own
        return [n for n in self.table.fresh(now) if n.pose.uav != own]

    def expire(self, now: float) -> list[int]:
        """Nothing: the pool's session forgets silent neighbours for all its members."""
        return []

    def snapshot(self) -> list[Neighbour]:
        own = self.own
        return [n for n in self.table.snapshot() if n.pose.uav != own]

    def around(self, x: float, y: float, radius: float) -> list[Neighbour]:
        """The neighbours whose latest pose is at most ``radius`` (m, horizontal) from (x, y)."""
        if self.positions is None:
            return [n for n in self.table.around(x, y, radius) if n.pose.uav != self.own]
        entries, own = self.table._table, self.own  # noqa: SLF001 - read-only, the pool's loop owns it
        out = []
        for u in self.positions.within(x, y, radius):
            n = entries.get(u)
            if n is not None and u != own:
                out.append(n)
        return out

    def first_uses(self, neighbours: list[Neighbour], now: float) -> list[float]:
        """The age at use (``now`` minus arrival, s) of each of ``neighbours`` whose pose this
        member had not used yet; they count as used from now on."""
        used = self._used
        ages = []
        for n in neighbours:
            at = n.last_recv
            if used.get(n.pose.uav) != at:
                used[n.pose.uav] = at
                ages.append(now - at)
        return ages

    def __iter__(self) -> Iterator[Neighbour]:
        return iter(self.snapshot())

    def __len__(self) -> int:
        return len(self.table) - (self.own in self.table)

    def __contains__(self, uav: object) -> bool:
        return uav != self.own and uav in self.table


class SharedSession:
    """The one Zenoh session of a pool, shared by its members' :class:`~swarmnet.node.SwarmNode`.

    Open it, then open each member with ``SwarmNode(..., shared=this)``; close the members, then
    this. Not thread-safe: the pool's loop is its one owner. ``pose_feed``, ``stale_after``,
    ``forget_after`` and ``interest`` are the members' (every member of a pool has the same);
    ``number`` is the pool's (``pool-<number>``: its identity and its near feed).
    """

    def __init__(self, swarm: str, connectivity: Connectivity, *, pose_feed: str = "direct", stale_after: float = 1.0,
                 forget_after: float = 10.0, ring_size: int = 1024, clock: Callable[[], float] = time.time,
                 name: str = "pool", number: int | None = None, interest: Interest | None = None, lossless: bool = False):
        if pose_feed not in ("direct", "edge"):
            raise ValueError(f"pose_feed must be 'direct' or 'edge', not {pose_feed!r}")
        self.keys = SwarmKeys(swarm)
        self.connectivity = connectivity
        self.pose_feed = pose_feed
        self.ring_size = ring_size
        self.clock = clock
        self.name = name
        self.number = number
        self.interest = interest
        # lock-step time (swarmnet/lockstep.py): the members' publishers wait rather than drop; a pose
        # stamped after :attr:`instant` (a pool ahead by a half tick sent it) waits until the pool's loop
        # moves the instant there, and a swarm message waits :attr:`message_hold_s` of simulated time
        self.lossless = lossless
        self.instant = math.inf  # lock-step: the latest instant whose poses the members may see (set by the loop)
        self.message_hold_s = 0.0  # lock-step: the pool's tick
        self._early: list[Pose] = []
        self.neighbours = NeighbourTable(stale_after, forget_after)  # every UAV the pool hears, its members too
        self.positions = Positions()  # where each of them is, for the members' queries (NeighbourView.around)
        self.stats = NodeStats()  # the pose stream's: received, rejected; the links of outsiders
        self.alive: set[str] = set()  # liveliness keys present (the members' alive)
        self._changes: list[tuple[str, bool]] = []  # (key, appeared) in order; members read from their cursors
        self._changes_base = 0  # the index of _changes[0] in the whole history
        self.members: dict[int, SwarmNode] = {}
        self.impaired: list[SwarmNode] = []  # members with a table of their own (a netem shim): handed each pose
        self.session: zenoh.Session | None = None
        # (a feed of batches, the pool's near feed (its poses for the members near their senders) or for all, inlet)
        self._pose_inlets: list[tuple[bool, bool, Inlet]] = []
        self._alive_inlet: Inlet | None = None
        self._subscribers: list[Any] = []
        self._links: LinkWatch | None = None
        self.held: list[tuple[Any, bytes]] | None = None  # inside together(): (publisher, payload) not put yet

    # ---- lifecycle ------------------------------------------------------------------------------
    def open(self) -> SharedSession:
        if self.session is not None:
            return self
        self.session = s = zenoh.open(to_zenoh(self.connectivity.zenoh_config()))
        try:
            k = self.keys
            if self.pose_feed == "edge":
                self._pose_inlet(k.pose_feed, batches=True, size=256)
            else:  # every pose, the members' own too (published on this session: delivered locally)
                self._pose_inlet(k.all_poses, batches=False, size=self.ring_size)
            self._alive_inlet = alive = Inlet(4096, None, self.clock, "ring")
            self._subscribers.append(sub := s.liveliness().declare_subscriber(k.all_alive, alive.handler(), history=True))
            alive.attach(sub)
            creds = self.connectivity.credentials
            if creds is not None:
                from swarmnet.security.acl import member_names
                from swarmnet.security.links import LinkWatch

                self._links = LinkWatch(s, member_names(creds.roster()), self.stats)
            self.connectivity.attach(s)
        except BaseException:
            self.close()
            raise
        return self

    def _pose_inlet(self, key: str, batches: bool, size: int, near: bool = False) -> None:
        assert self.session is not None
        # lock-step: taken in on Zenoh's receive thread as it runs, so that every pose put before a clock
        # step is in before the step is (a thread of the inlet's own could still hold it)
        inlet = Inlet(size, None, self.clock, "callback" if self.lossless else "thread")
        self._subscribers.append(subscribe(self.session, key, inlet))
        self._pose_inlets.append((batches, near, inlet))

    def add_near_feed(self, uav: int) -> None:
        """Spatial interest: member ``uav`` takes the near feed. The pool subscribes once, to its own
        ``mrs/<swarm>/feed/near/pool-<n>`` (the edge sends it one batch per flush for all its
        members, each sender once), into the pool's table like every other batch."""
        if self.number is None or self.interest is None:
            raise ValueError(f"{self.name}: a near feed needs the pool's number and the members' interest")
        if not any(near for _, near, _ in self._pose_inlets):
            self._pose_inlet(self.keys.pool_near_feed(self.number), batches=True, size=256, near=True)

    def close(self) -> None:
        if self.session is None:
            return
        try:
            self.connectivity.detach()
        finally:
            s, self.session = self.session, None
            if self._links is not None:
                self._links.close()
                self._links = None
            inlets = [inlet for _, _, inlet in self._pose_inlets]
            self._pose_inlets.clear()
            self._alive_inlet = None
            try:
                s.close()
            except zenoh.ZError as exc:
                log.debug("zenoh close: %s", exc)
            self._subscribers.clear()
            for inlet in inlets:
                if not inlet.join(INLET_JOIN_S):
                    log.warning("a receive thread did not end within %.1f s of the session's close", INLET_JOIN_S)

    def __enter__(self) -> SharedSession:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- members --------------------------------------------------------------------------------
    def join(self, node: SwarmNode) -> None:
        self.members[node.identity.uav] = node

    def leave(self, node: SwarmNode) -> None:
        self.members.pop(node.identity.uav, None)
        if node in self.impaired:
            self.impaired.remove(node)

    def impair(self, node: SwarmNode) -> None:
        """``node`` has a netem shim from now on: it gets each pose the pool takes in, to impair."""
        if node not in self.impaired:
            self.impaired.append(node)

    def changes_since(self, cursor: int) -> tuple[list[tuple[str, bool]], int]:
        """The liveliness changes from ``cursor`` on (a member's position in the history), and the new cursor."""
        start = max(cursor - self._changes_base, 0)
        return self._changes[start:], self._changes_base + len(self._changes)

    # ---- sending --------------------------------------------------------------------------------
    @contextlib.contextmanager
    def together(self) -> Iterator[None]:
        """The poses, telemetry and states the members publish inside leave back to back as it
        ends, in their order.

        A pool publishes one pose per member and tick, each between two members' other work (their
        FCU's messages, their control). Put one at a time like that, every put runs Zenoh's send
        path with the CPU's caches cold and wakes Zenoh's transmit thread for a message of its own:
        several times the CPU of the same puts back to back, and more than access control, TLS,
        Zenoh's runtime or the publishers' options change (docs/scale.md). For a pool's loop, around
        a few members' turn at a time (a pose then waits for at most their work). A member that
        raises inside does not keep the others' puts in. Nested: the outer one puts.
        """
        if self.held is not None:
            yield
            return
        held: list[tuple[Any, bytes]] = []
        self.held = held
        try:
            yield
        finally:
            self.held = None
            for pub, payload in held:
                try:
                    pub.put(payload)
                except zenoh.ZError as exc:  # (a member closed meanwhile: its publisher is gone)
                    log.debug("a held put not made: %s", exc)

    # ---- receiving ------------------------------------------------------------------------------
    def pump(self, now: float | None = None, budget: int = DRAIN_BUDGET) -> int:
        """Take in what reached the pool since the last pump: poses into the pool's table (each
        decoded once; the rejected counted in :attr:`stats`, under the sender's key), liveliness
        changes, the links of outsiders. Every member's poll pumps first; the first finds what
        is new, the rest find nothing. Returns how many poses were taken in.

        A pose on the swarm's stream counts as received by every member; one on the pool's near
        feed (spatial interest) by the members near its sender only (:meth:`_credit_near`), as it
        would have counted in a process of its own (and only their netem shims are handed it)."""
        if self.session is None:
            return 0
        now = self.clock() if now is None else now
        total = 0
        for batches, near, inlet in self._pose_inlets:
            handed: list[tuple[Pose, float]] | None = [] if self.impaired else None
            srcs: list[int] = []
            ages: list[float] = []
            n = 0
            if self._early and not batches:  # lock-step: the poses whose instant has come, as they left then
                until = self.instant + LOCKSTEP_SLACK_S
                due = [p for p in self._early if p.t_wall <= until]
                self._early = [p for p in self._early if p.t_wall > until]
                for pose in due:
                    self._update(pose, pose.t_wall, srcs, ages, handed)
                n += len(due)
            for at, sample in inlet.drain(budget):
                payload = sample.payload.to_bytes()
                if batches:
                    n += self._take_batch(str(sample.key_expr), payload, at, srcs, ages, handed)
                else:
                    n += self._take_pose(str(sample.key_expr), payload, at, srcs, ages, handed)
            if n:
                total += n
                if near:
                    self._credit_near(srcs, ages, handed)
                else:
                    self._credit(n, srcs, ages, handed)
                self.positions.moved(self.neighbours, srcs)
        if total:
            self.stats.received["pose"] += total
        self._track_liveliness(budget)
        if self._links is not None:
            self._links.poll()
        self.positions.forget(self.neighbours.expire(now))
        return total

    def _credit(self, n: int, srcs: list[int], ages: list[float], handed: list[tuple[Pose, float]] | None) -> None:
        """Count ``n`` poses as received by every member (each leaves its own pose out as it files
        the ages), and hand the decoded ones to the netem shims."""
        for node in self.members.values():
            node.stats.received["pose"] += n
            if node in self.impaired:
                if handed:
                    node.hand(handed)
            else:
                node.stats.ages.arrived_many(srcs, ages)

    def _credit_near(self, srcs: list[int], ages: list[float], handed: list[tuple[Pose, float]] | None) -> None:
        """The poses the pool's near feed brought (``srcs``, each just taken into the table): each
        counts as received by the members within the interest radius plus its margin of its
        sender, as the edge would have sent it to each of them alone, and its age and decoded pose
        go to those members only. (A member between the radius and the margin that never came
        within the radius counts too, though the edge sent the pose for a pool-mate: a slight
        overcount.) Member positions are their own latest published poses; a member that has
        published none yet is near nobody."""
        nodes = [node for node in self.members.values() if node.near_feed]
        if not nodes or not srcs:
            return
        assert self.interest is not None  # (add_near_feed checked it)
        reach = self.interest.radius_m + self.interest.margin_m
        entries = self.neighbours._table  # noqa: SLF001 - the pool's own table; every sender in srcs is in it
        senders = np.array([(entries[u].pose.x, entries[u].pose.y) for u in srcs])
        at = np.array([node.own_position[:2] if node.own_position is not None else (np.nan, np.nan) for node in nodes])
        d = senders[:, None, :] - at[None, :, :]  # senders x members
        near = np.einsum("ijk,ijk->ij", d, d) <= reach * reach
        near &= np.array(srcs)[:, None] != np.array([node.identity.uav for node in nodes])[None, :]  # not its own
        counts = near.sum(axis=0).tolist()
        for j, node in enumerate(nodes):
            if not counts[j]:
                continue
            node.stats.received["pose"] += counts[j]
            rows = np.flatnonzero(near[:, j]).tolist()
            if node in self.impaired:
                if handed:
                    node.hand([handed[i] for i in rows])
            else:
                node.stats.ages.arrived_many([srcs[i] for i in rows], [ages[i] for i in rows])

    def _take_batch(self, key: str, payload: bytes, at: float, srcs: list[int], ages: list[float],
                    handed: list[tuple[Pose, float]] | None) -> int:
        try:
            batch = accept_pose_batch(key, payload)
        except Rejected as exc:
            self.stats.reject(exc.reason, key, exc.detail)
            return 0
        self.stats.received["pose_batch"] += 1
        taken = 0
        for pose, _ in batched_poses(batch, self.stats, self.keys.pose):
            taken += 1
            self._update(pose, at, srcs, ages, handed)
        return taken

    def _take_pose(self, key: str, payload: bytes, at: float, srcs: list[int], ages: list[float],
                   handed: list[tuple[Pose, float]] | None) -> int:
        try:
            pose = accept_pose(key, payload)
        except Rejected as exc:
            self.stats.reject(exc.reason, key, exc.detail)
            return 0
        if pose.t_wall > self.instant + LOCKSTEP_SLACK_S:  # lock-step: from a pool already at a later instant
            self._early.append(pose)
            del self._early[:-EARLY_MAX]
            return 0
        self._update(pose, at, srcs, ages, handed)
        return 1

    def _update(self, pose: Pose, at: float, srcs: list[int], ages: list[float],
                handed: list[tuple[Pose, float]] | None) -> None:
        if self.lossless and at < pose.t_wall:  # lock-step: it left at its sender's instant, before this clock got there
            at = pose.t_wall
        if self.neighbours.update(pose, at):
            srcs.append(pose.uav)
            ages.append(at - pose.t_wall)
            if handed is not None:
                handed.append((pose, at))

    def _track_liveliness(self, budget: int) -> None:
        if self._alive_inlet is None:
            return
        changes = self._changes
        changes += token_changes(self._alive_inlet, self.alive, budget)
        if len(changes) > MAX_CHANGES:  # members read every tick: the old ones have been seen
            drop = len(changes) - MAX_CHANGES
            del changes[:drop]
            self._changes_base += drop
