"""The edge pose feed: every UAV's latest poses in a few batches instead of N-1 messages each.

With direct pose keys every UAV receives a message per neighbour per pose period: 490
messages a second each at N = 50, and Zenoh's receive path alone then costs ~2-4 % of a
core per UAV before any Python runs (docs/benchmarks.md). A cellular downlink also prefers
few full packets to many tiny ones. The feed runs on the edge (inside the rendezvous/edge
router process): it subscribes to ``mrs/<swarm>/*/pose``, accepts every pose with the rule
a UAV applies to direct poses (:func:`~swarmnet.messages.accept_pose`: it decodes and names
the UAV of its key) and keeps the latest per UAV. Agents with ``pose_feed: edge`` subscribe
to ``mrs/<swarm>/feed/poses`` only.

**When a batch leaves.** A pose arriving at an idle feed opens a *window*; when it closes
(``window`` s later, 3 ms by default) the poses received meanwhile leave as one ``PoseBatch``
per swarm, at most one per UAV. A pose therefore waits at most ``window`` at the edge, and a
UAV's download is bounded by one batch per window whatever N is (at most 333 messages a
second at 3 ms, against 10 (N-1) with direct poses). Each batch wakes every receiving UAV's
Zenoh and pose-inlet threads: with aligned ticks a 5 ms window carries an instant of 50 UAVs'
poses in 1.7 batches instead of 2.4 at 3 ms, for 2–5 % less CPU per UAV and 1.6 ms more
transport age (docs/benchmarks.md, 2026-11-29), which is why a scenario of more than 25 UAVs
takes 5 ms (``network.feed_window_ms``). ``window=0`` forwards at once: what
arrived while the previous batch was being sent leaves together.

**No Python on the router's receive threads.** The feed runs in the edge router, whose Zenoh
threads forward every UAV's traffic (commands, acknowledgements, states). Its subscriptions
are Zenoh ring channels, which never make those threads wait, and one Python thread per
subscription blocks in the channel's ``recv`` (the interpreter lock released) until a pose
opens a window, sleeps until the window closes, drains what came and sends the batch: two
wake-ups per batch, none while the swarm is silent.

Each pose in a batch is still the UAV's own payload (at most 48 bytes) with its own timestamps,
listed with the UAV id of the key it arrived on, so receivers validate it again (it must name
that UAV) and measure its transport age exactly as for a direct pose.

**Spatial interest** (``interest``, :mod:`swarmnet.interest`): each pose goes at full rate only to
the UAVs within the interest radius of its sender, each on its own key
``mrs/<swarm>/feed/near/<uav>``, and to the whole swarm on the shared key once every
``1 / far_rate_hz`` s. A UAV's download then grows with the UAVs around it, not with N.
The UAVs of a pool (``pools``: one process, one Zenoh session, uav_stack/pool.py) get one batch
for the pool instead, on ``mrs/<swarm>/feed/near/pool-<n>``: every sender near any of them,
each once. A pool of K UAVs then costs the edge one put per flush instead of K, and its session
one batch to decode, with no sender's pose in it twice.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import zenoh

from swarmnet.interest import Interest, NearFilter, PoolMembers, pool_groups
from swarmnet.keyspace import ROOT, SwarmKeys, swarm_from_key
from swarmnet.messages import PoseBatch, Rejected, accept_pose, encode_pose_batch
from swarmnet.receive import DRAIN_BUDGET
from swarmnet.stats import NodeStats

DEFAULT_WINDOW = 0.003  # s a pose may wait at the edge for others to share its batch
MAX_WINDOW = 1.0  # s


class PoseFeed:
    """Aggregates poses of the given swarms (``["*"]``: every swarm) on an open session.

    ``window``: seconds from the first pose of a batch to its departure (0: forward at once).
    ``interest``: spatial interest (None: every pose to every UAV); ``pools``: with it, the pools of
    virtual UAVs, each sent one near batch for all its UAVs (their UAV ids are the same in every
    swarm the feed serves: a run's ids differ across swarms).
    :meth:`start` runs one worker thread per swarm subscription; :meth:`close` ends them.
    """

    def __init__(self, session: zenoh.Session, swarms: Iterable[str] = ("*",), window: float = DEFAULT_WINDOW,
                 clock: Callable[[], float] = time.time, interest: Interest | None = None,
                 pools: Sequence[PoolMembers] = ()):
        if not 0.0 <= window <= MAX_WINDOW:
            raise ValueError(f"window must be in 0..{MAX_WINDOW} s, got {window}")
        if pools and interest is None:
            raise ValueError("pools group the near feed of spatial interest: give an interest too")
        self.session = session
        self.window = window
        self.clock = clock
        self.interest = interest
        self._groups = pool_groups(pools)  # UAV -> its pool's near feed (pool-<n>)
        self._filters: dict[str, NearFilter] = {}  # per swarm; each touched by the one worker of its subscription
        self._pubs: dict[tuple[str, int | str], Any] = {}
        self.stats = NodeStats()
        self.batches: Counter[str] = Counter()
        self._seq = itertools.count()
        self._lock = threading.Lock()  # publishers and counters, shared by the workers
        self._subscribers = [session.declare_subscriber(f"{ROOT}/{sw}/*/pose", zenoh.handlers.RingChannel(8192))
                             for sw in swarms]
        self._threads: list[threading.Thread] = []

    def start(self) -> PoseFeed:
        for k, sub in enumerate(self._subscribers):
            th = threading.Thread(target=self._work, args=(sub.handler,), name=f"pose-feed-{k}", daemon=True)
            th.start()
            self._threads.append(th)
        return self

    def _work(self, channel: Any) -> None:
        """One subscription: wait for a pose, let the window run, send what came; until closed."""
        latest: dict[str, dict[int, bytes]] = {}
        while True:
            try:
                first = channel.recv()  # blocks, the interpreter's lock released
            except zenoh.ZError:  # closed: the feed or the session ends
                return
            due = self.clock() + self.window
            self._take(first, latest)
            wait = due - self.clock()
            if wait > 0.0:
                time.sleep(wait)
            for _ in range(DRAIN_BUDGET):
                try:
                    sample = channel.try_recv()
                except zenoh.ZError:
                    return
                if sample is None:
                    break
                self._take(sample, latest)
            self._flush(latest)

    def _take(self, sample: zenoh.Sample, latest: dict[str, dict[int, bytes]]) -> None:
        """Keep the newest payload per UAV; each must pass :func:`~swarmnet.messages.accept_pose`."""
        key, payload = str(sample.key_expr), sample.payload.to_bytes()
        try:
            pose = accept_pose(key, payload)
        except Rejected as exc:
            self.stats.reject(exc.reason, key, exc.detail)
            return
        swarm = swarm_from_key(key)
        assert swarm is not None  # the subscription only matches mrs/<swarm>/...
        self.stats.received["pose"] += 1
        latest.setdefault(swarm, {})[pose.uav] = payload
        if self.interest is not None:
            near = self._filters.get(swarm)
            if near is None:
                near = self._filters[swarm] = NearFilter(self.interest, self._groups)
            near.seen(pose.uav, pose.x, pose.y, self.clock())

    def _flush(self, latest: dict[str, dict[int, bytes]]) -> int:
        """Publish the poses taken since the last flush (one batch per swarm, or with interest the
        batches :meth:`_flush_near` makes); return how many poses left."""
        now = self.clock()
        sent = 0
        for swarm, poses in latest.items():
            if not poses:
                continue
            if self.interest is not None:
                sent += self._flush_near(swarm, poses, now)
            else:
                self._put(swarm, SwarmKeys(swarm).pose_feed, list(poses), list(poses.values()), now)
                sent += len(poses)
            poses.clear()
        return sent

    def _flush_near(self, swarm: str, poses: dict[int, bytes], now: float) -> int:
        """Spatial interest: the senders due on the shared feed in one batch there, and to each
        UAV near the others a batch of those on its own key (to each pool one batch, on the
        pool's key); return how many poses left."""
        far, near = self._filters[swarm].split(list(poses), now)
        keys = SwarmKeys(swarm)
        if far:
            self._put(swarm, keys.pose_feed, far, [poses[s] for s in far], now)
        near_poses = 0
        for to, senders in near.items():
            self._put(swarm, keys.near_feed(to), senders, [poses[s] for s in senders], now, to)
            near_poses += len(senders)
        with self._lock:
            self.stats.sent["near_pose"] += near_poses
        return len(far) + near_poses

    def _put(self, swarm: str, key: str, senders: list[int], payloads: list[bytes], now: float, to: int | str = 0) -> None:
        """One batch on ``key`` (``to``: the UAV or pool of a near feed key, 0: the swarm's shared feed)."""
        with self._lock:
            pub = self._pubs.get((swarm, to))
            if pub is None:
                pub = self._pubs[(swarm, to)] = self.session.declare_publisher(
                    key, congestion_control=zenoh.CongestionControl.DROP, priority=zenoh.Priority.DATA_HIGH, express=True)
            self.batches[swarm] += 1
            self.stats.sent["pose_batch"] += 1
        pub.put(encode_pose_batch(PoseBatch(next(self._seq) & 0xFFFFFFFF, now, senders, payloads)))

    def run(self, keep_going: Callable[[], bool], check_every: float = 0.2) -> None:
        """Start the workers, return once ``keep_going()`` (checked every ``check_every`` s) is False."""
        self.start()
        while keep_going():
            time.sleep(check_every)

    def close(self) -> None:
        """End the workers (their channels close) and wait for them."""
        for sub in self._subscribers:
            try:
                sub.undeclare()
            except zenoh.ZError:  # the session is already closed
                pass
        for th in self._threads:
            th.join(2.0)
        self._subscribers.clear()
        self._threads.clear()
