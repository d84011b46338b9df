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
second at 3 ms, against 10 (N-1) with direct poses). ``window=0`` forwards at once: each
wake-up of the feed's loop sends what arrived since the last one. The loop sleeps on
the feed's :class:`~swarmnet.receive.Waker` while no pose waits and sleeps until the window
closes while one does, so it wakes about once per batch, and an idle feed costs nothing.

Each pose in a batch is still the UAV's own payload (at most 48 bytes) with its own timestamps,
so receivers validate it again and measure its transport age exactly as for a direct pose.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Iterable
from typing import Any

import zenoh

from swarmnet.keyspace import ROOT, SwarmKeys, swarm_from_key
from swarmnet.messages import PoseBatch, accept_pose, encode_pose_batch
from swarmnet.receive import DRAIN_BUDGET, Inlet, Waker, receive, subscribe
from swarmnet.stats import NodeStats

DEFAULT_WINDOW = 0.003  # s a pose may wait at the edge for others to share its batch
MAX_WINDOW = 1.0  # s


class PoseFeed:
    """Aggregates poses of the given swarms (``["*"]``: every swarm) on an open session.

    ``window``: seconds from the first pose of a batch to its departure (0: forward at once).
    """

    def __init__(self, session: zenoh.Session, swarms: Iterable[str] = ("*",), window: float = DEFAULT_WINDOW,
                 clock: Callable[[], float] = time.time):
        if not 0.0 <= window <= MAX_WINDOW:
            raise ValueError(f"window must be in 0..{MAX_WINDOW} s, got {window}")
        self.session = session
        self.window = window
        self.clock = clock
        self.stats = NodeStats()
        self.batches: Counter[str] = Counter()
        self.waker = Waker()
        self._latest: dict[str, dict[int, bytes]] = {}
        self._pubs: dict[str, Any] = {}
        self._seq = 0
        self._opened: float | None = None  # arrival of the oldest pose waiting for a batch
        self._inlets: list[Inlet] = []
        self._subscribers: list[Any] = []
        for sw in swarms:
            # on a Python thread of its own: the router's receive threads never wait for this loop
            inlet = Inlet(8192, self.waker, clock, own_thread=True)
            self._subscribers.append(subscribe(session, f"{ROOT}/{sw}/*/pose", inlet))
            self._inlets.append(inlet)

    def poll(self, max_samples: int = DRAIN_BUDGET) -> None:
        """Drain the poses that arrived (at most ``max_samples`` per swarm subscription) and keep
        the newest payload per UAV; each must pass :func:`~swarmnet.messages.accept_pose`."""
        stats = self.stats
        for inlet in self._inlets:
            for key, pose, payload, at in receive(inlet, accept_pose, stats, max_samples):
                swarm = swarm_from_key(key)
                assert swarm is not None  # the subscription only matches mrs/<swarm>/...
                stats.received["pose"] += 1
                self._latest.setdefault(swarm, {})[pose.uav] = payload
                if self._opened is None or at < self._opened:
                    self._opened = at

    def flush(self) -> int:
        """Publish one batch per swarm with the poses received since the last flush; return how many poses left."""
        now = self.clock()
        self._opened = None
        sent = 0
        for swarm, latest in self._latest.items():
            if not latest:
                continue
            pub = self._pubs.get(swarm)
            if pub is None:
                pub = self._pubs[swarm] = self.session.declare_publisher(
                    SwarmKeys(swarm).pose_feed, congestion_control=zenoh.CongestionControl.DROP,
                    priority=zenoh.Priority.DATA_HIGH, express=True)
            pub.put(encode_pose_batch(PoseBatch(self._seq, now, list(latest.values()))))
            self._seq += 1
            self.batches[swarm] += 1
            self.stats.sent["pose_batch"] += 1
            sent += len(latest)
            latest.clear()
        return sent

    def step(self) -> float | None:
        """poll + flush when the window is over; return when the open window closes (wall time,
        s), or None when no pose waits."""
        self.poll()
        if self._opened is None:
            return None
        due = self._opened + self.window
        if self.clock() >= due:
            self.flush()
            return None
        return due

    def run(self, keep_going: Callable[[], bool], idle_wait: float = 0.5) -> None:
        """The feed's loop: :meth:`step`, then sleep until a pose arrives (idle) or until the open
        window closes (poses arriving meanwhile do not wake it). ``keep_going`` is checked at
        least every ``idle_wait`` s."""
        while keep_going():
            self.waker.clear()  # before draining: a pose arriving after the drain wakes the next wait
            due = self.step()
            if due is None:
                self.waker.wait(idle_wait)
            else:
                time.sleep(min(idle_wait, max(0.0, due - self.clock())))

    def close(self) -> None:
        self._subscribers.clear()
        self.waker.close()
