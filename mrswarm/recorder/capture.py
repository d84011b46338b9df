"""Everything a swarm publishes, as raw samples with their arrival time: what the recorder and Foxglove read.

A :class:`SwarmCapture` adds two subscriptions to a :class:`~swarmnet.observer.SwarmObserver`'s
session (so it joins the swarm exactly as a ground station does, with the same connectivity and
credentials): every key of the swarm (``mrs/<swarm>/**``) and every liveliness token
(``mrs/<swarm>/alive/**``, with history, so the nodes already up are listed at once). Both are
bounded ring channels drained from the owner's loop (no Python on Zenoh's threads; see
swarmnet/receive.py). The arrival time is taken when a sample is drained, so its resolution is
the owner's polling period (20 ms in the recorder).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import NamedTuple

import zenoh

from swarmnet.observer import SwarmObserver
from swarmnet.receive import DRAIN_BUDGET, drain

RING = 65536  # samples held between two drains: 1.3 s of a 50-UAV swarm's whole traffic at 50 kmsg/s


class Sample(NamedTuple):
    """One Zenoh sample as it arrived."""

    key: str
    payload: bytes  # empty for a liveliness event
    arrival: float  # s since the Unix epoch, when drained
    alive: bool | None = None  # liveliness events only: True appeared, False disappeared


class SwarmCapture:
    """The raw subscriptions of one swarm on an observer's session; :meth:`drain` gives what arrived."""

    def __init__(self, observer: SwarmObserver, ring: int = RING, clock: Callable[[], float] = time.time):
        session = observer.node.session
        if session is None:
            raise RuntimeError("the observer is not open")
        self.swarm = observer.keys.swarm
        self.clock = clock
        keys = observer.keys
        handler = zenoh.handlers.RingChannel
        self._data = session.declare_subscriber(f"{keys.prefix}/**", handler(ring))
        self._alive = session.liveliness().declare_subscriber(keys.all_alive, handler(4096), history=True)

    def drain(self, budget: int = DRAIN_BUDGET) -> Iterator[Sample]:
        """Liveliness changes first, then data, oldest first, at most ``budget`` of each; never blocks."""
        now = self.clock()
        for s in drain(self._alive, budget):
            yield Sample(str(s.key_expr), b"", now, s.kind == zenoh.SampleKind.PUT)
        for s in drain(self._data, budget):
            yield Sample(str(s.key_expr), s.payload.to_bytes(), now)

    def close(self) -> None:
        for sub in (self._data, self._alive):
            try:
                sub.undeclare()
            except zenoh.ZError:  # the session is already closed
                pass
