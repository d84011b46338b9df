"""The edge pose feed: one batch of every UAV's latest pose per tick, instead of N-1 messages.

With direct pose keys every UAV receives a message per neighbour per pose period: 490
messages a second each at N = 50, and Zenoh's receive path alone then costs ~2-4 % of a
core per UAV before any Python runs (docs/benchmarks.md). A cellular downlink also prefers
few full packets to many tiny ones. The feed runs on the edge (inside the rendezvous/edge
router process): it subscribes to ``mrs/<swarm>/*/pose``, accepts every pose with the rule
a UAV applies to direct poses (:func:`~swarmnet.messages.accept_pose`: it decodes and names
the UAV of its key), keeps the latest per UAV, and every ``period`` s publishes the new ones
as one ``PoseBatch`` on ``mrs/<swarm>/feed/poses``. Agents with ``pose_feed: edge`` subscribe to that key only.

Each pose in a batch is still the UAV's own payload (at most 48 bytes) with its own timestamps,
listed with the UAV id of the key it arrived on, so receivers validate it again (it must name
that UAV) and measure its age exactly as for a direct pose; the batching adds on average half a
period of age.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Iterable
from typing import Any

import zenoh

from swarmnet.keyspace import ROOT, SwarmKeys, swarm_from_key
from swarmnet.messages import PoseBatch, accept_pose, encode_pose_batch
from swarmnet.receive import DRAIN_BUDGET, receive
from swarmnet.stats import NodeStats

DEFAULT_PERIOD = 0.04


class PoseFeed:
    """Aggregates poses of the given swarms (``["*"]``: every swarm) on an open session.

    ``period``: seconds between batches (default 40 ms, one UAV tick at 25 Hz).
    """

    def __init__(self, session: zenoh.Session, swarms: Iterable[str] = ("*",), period: float = DEFAULT_PERIOD,
                 clock: Callable[[], float] = time.time):
        if period <= 0:
            raise ValueError("period must be > 0")
        self.session = session
        self.period = period
        self.clock = clock
        self.stats = NodeStats()
        self.batches: Counter[str] = Counter()
        self._latest: dict[str, dict[int, bytes]] = {}
        self._pubs: dict[str, Any] = {}
        self._seq = 0
        self._subs = [
            session.declare_subscriber(f"{ROOT}/{sw}/*/pose", zenoh.handlers.RingChannel(8192)) for sw in swarms
        ]
        self.next_flush = clock()

    def poll(self, max_samples: int = DRAIN_BUDGET) -> None:
        """Drain the poses that arrived (at most ``max_samples`` per swarm subscription) and keep
        the newest payload per UAV; each must pass :func:`~swarmnet.messages.accept_pose`."""
        stats = self.stats
        for ring in self._subs:
            for key, pose, payload in receive(ring, accept_pose, stats, max_samples):
                swarm = swarm_from_key(key)
                assert swarm is not None  # the subscription only matches mrs/<swarm>/...
                stats.received["pose"] += 1
                self._latest.setdefault(swarm, {})[pose.uav] = payload

    def flush(self) -> int:
        """Publish one batch per swarm with the poses received since the last flush."""
        now = self.clock()
        self.next_flush = max(self.next_flush + self.period, now)
        sent = 0
        for swarm, latest in self._latest.items():
            if not latest:
                continue
            pub = self._pubs.get(swarm)
            if pub is None:
                pub = self._pubs[swarm] = self.session.declare_publisher(
                    SwarmKeys(swarm).pose_feed, congestion_control=zenoh.CongestionControl.DROP,
                    priority=zenoh.Priority.DATA_HIGH, express=True)
            pub.put(encode_pose_batch(PoseBatch(self._seq, now, list(latest), list(latest.values()))))
            self._seq += 1
            self.batches[swarm] += 1
            self.stats.sent["pose_batch"] += 1
            sent += len(latest)
            latest.clear()
        return sent

    def step(self) -> float:
        """poll + flush when due; return the time of the next flush."""
        self.poll()
        if self.clock() >= self.next_flush:
            self.flush()
        return self.next_flush
