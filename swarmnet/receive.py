"""The one receive path: stamp on arrival, queue, then accept or reject each sample in the owner's loop.

Every subscription of :class:`~swarmnet.node.SwarmNode` and :class:`~swarmnet.observer.SwarmObserver`
delivers into an :class:`Inlet`. In a UAV, a minimal callback, run
by Zenoh on the thread that read the sample from the network, takes the wall-clock time and
appends ``(time, sample)`` to a bounded deque (the oldest is dropped when it is full). That is
all the Python that runs on Zenoh's threads: a slow zenoh-python callback stalls the whole
session (measured: one slow callback delayed an unrelated 10 Hz topic from the same peer by up
to 11 s), whereas an append takes about a microsecond and never blocks. The callback runs on
Zenoh's own thread (``indirect=False``), not on a Python thread of its own, so a sample costs
no extra thread wake-up. (An observer, whose loop is busy in Python, keeps its bulk streams in
Zenoh ring channels instead: see :class:`Inlet`.)

Streams that must be handled at once (commands, netem changes) also notify a :class:`Waker`,
whose file descriptor the owner's loop waits on between its ticks; poses do not wake anyone:
they are taken in at the next control tick, with their arrival time.

The path, top to bottom::

    Inlet (callback on Zenoh's thread): (arrival time, sample) -> bounded deque [-> Waker]
    drain(inlet, budget)           at most `budget` samples per call, oldest first
      -> accept(key, payload)      decode + the stream's rules (swarmnet.messages.accept_*)
      -> Accepted(key, item, payload, at), or Rejected: counted in NodeStats.rejected[reason]

What happens to an accepted item (the netem shim, the neighbour table, the inbox) is the
owner's business; counting it as received is too, because the owner knows when it is
delivered.
"""

from __future__ import annotations

import os
import select
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Generic, NamedTuple, TypeVar

import zenoh

from swarmnet.messages import Rejected
from swarmnet.stats import NodeStats

T = TypeVar("T")
Accept = Callable[[str, bytes], T]  # (key, payload) -> message, or raises Rejected

DRAIN_BUDGET = 10_000  # samples per subscription per call: a flood cannot hold the owner's loop in one drain


class Accepted(NamedTuple, Generic[T]):
    """A sample that passed its stream's rules."""

    key: str  # the Zenoh key it arrived on
    item: T  # the decoded message
    payload: bytes  # as received (the edge feed forwards it; the netem shim's rate limit counts its length)
    at: float  # wall-clock time it arrived in this process, s since the Unix epoch


class Waker:
    """A file descriptor that becomes readable when a waking stream receives something.

    Notifications coalesce: any number of them before :meth:`clear` wake the owner once. An
    ``eventfd`` on Linux (one syscall to notify), a pipe elsewhere.
    """

    def __init__(self) -> None:
        if hasattr(os, "eventfd"):
            self._r = self._w = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        else:  # pragma: no cover - not Linux
            self._r, self._w = os.pipe()
            os.set_blocking(self._r, False)
            os.set_blocking(self._w, False)
        self.notifications = 0  # how often a sample woke (or would have woken) the owner
        self.closed = False

    def fileno(self) -> int:
        return self._r

    def notify(self) -> None:
        """Called on Zenoh's thread: never blocks (a full pipe means a wake-up is pending anyway)."""
        self.notifications += 1
        try:
            os.write(self._w, b"\x01\x00\x00\x00\x00\x00\x00\x00")
        except (BlockingIOError, OSError):
            pass

    def clear(self) -> None:
        """Consume the pending notifications (the owner is about to drain everything)."""
        try:
            os.read(self._r, 4096)
        except (BlockingIOError, OSError):
            pass

    def wait(self, timeout: float) -> bool:
        """Block until notified or ``timeout`` s have passed; True if notified (then cleared)."""
        if timeout < 0.0:
            timeout = 0.0
        ready, _, _ = select.select((self._r,), (), (), timeout)
        if ready:
            self.clear()
            return True
        return False

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for fd in {self._r, self._w}:
            try:
                os.close(fd)
            except OSError:
                pass


class Inlet:
    """Where one subscription's samples wait for the owner: ``(arrival time, sample)``, oldest first.

    ``size`` bounds the queue (the oldest sample is dropped when full, as a ring channel does);
    ``waker``, if given, is notified of every sample (for streams the owner handles at once).
    ``clock`` stamps the arrival (wall time, s).

    ``stamped=False`` keeps the samples in a Zenoh ``RingChannel`` instead, which runs no Python
    at all on Zenoh's thread: the arrival is then the time of the drain. For an owner whose own
    loop is busy in Python with many samples arriving (the runner and the ground station watch
    every UAV): a callback needs the interpreter's lock, and while the owner holds it, Zenoh's
    receive thread would wait, and with it everything the session receives (declarations too).
    A stamped inlet takes the lock for about a microsecond per sample, which a UAV's loop, mostly
    asleep, gives at once. (The edge router's feed uses neither: its own thread blocks on a ring
    channel, see :mod:`swarmnet.feed`.)
    """

    __slots__ = ("_q", "_sub", "waker", "clock", "stamped", "size", "__weakref__")

    def __init__(self, size: int, waker: Waker | None = None, clock: Callable[[], float] = time.time, stamped: bool = True):
        if waker is not None and not stamped:
            raise ValueError("only a stamped inlet (a callback) can wake its owner")
        self._q: deque[tuple[float, zenoh.Sample]] = deque(maxlen=size)
        self._sub: Any = None  # the ring channel's subscriber (stamped=False)
        self.waker = waker
        self.clock = clock
        self.stamped = stamped
        self.size = size

    def handler(self) -> Any:
        """The Zenoh handler to subscribe with: a closure that only stamps and appends (and
        notifies), or a ring channel (``stamped=False``)."""
        if not self.stamped:
            return zenoh.handlers.RingChannel(self.size)
        append, stamp, waker = self._q.append, self.clock, self.waker
        if waker is None:
            def on_sample(sample: zenoh.Sample) -> None:
                append((stamp(), sample))
        else:
            notify = waker.notify

            def on_sample(sample: zenoh.Sample) -> None:
                append((stamp(), sample))
                notify()
        return zenoh.handlers.Callback(on_sample, indirect=False)

    def attach(self, subscriber: Any) -> None:
        """The subscriber declared with :meth:`handler` (a ring channel is drained through it)."""
        self._sub = subscriber

    def __len__(self) -> int:
        """Samples waiting (a stamped inlet; a ring channel cannot tell without taking them)."""
        return len(self._q)

    def drain(self, budget: int = DRAIN_BUDGET) -> Iterator[tuple[float, zenoh.Sample]]:
        """The waiting ``(arrival time, sample)`` pairs, oldest first, at most ``budget``; never blocks."""
        if not self.stamped:
            if self._sub is None:
                return
            now, take = self.clock(), self._sub.try_recv
            for _ in range(budget):
                sample = take()
                if sample is None:
                    return
                yield now, sample
            return
        q = self._q
        for _ in range(budget):
            if not q:
                return
            yield q.popleft()


def drain(ring: Any, budget: int = DRAIN_BUDGET) -> Iterator[zenoh.Sample]:
    """The samples waiting in a subscriber with a Zenoh ring channel, oldest first, at most
    ``budget`` of them; never blocks (for owners that subscribe with ring channels directly,
    such as the flight recorder)."""
    for _ in range(budget):
        sample = ring.try_recv()
        if sample is None:
            return
        yield sample


def accept_each(arrivals: Iterable[tuple[str, bytes, float]], accept: Accept[T], stats: NodeStats) -> Iterator[Accepted[T]]:
    """Run ``accept`` on every ``(key, payload, arrival time)``; count each rejection in ``stats`` and skip it."""
    for key, payload, at in arrivals:
        try:
            item = accept(key, payload)
        except Rejected as exc:
            stats.reject(exc.reason, key, exc.detail)
            continue
        yield Accepted(key, item, payload, at)


def receive(inlet: Inlet, accept: Accept[T], stats: NodeStats, budget: int = DRAIN_BUDGET) -> Iterator[Accepted[T]]:
    """The accepted samples waiting in ``inlet`` (at most ``budget`` drained per call): drain and
    :func:`accept_each` in one loop (every pose passes here)."""
    for at, s in inlet.drain(budget):
        key, payload = str(s.key_expr), s.payload.to_bytes()
        try:
            item = accept(key, payload)
        except Rejected as exc:
            stats.reject(exc.reason, key, exc.detail)
            continue
        yield Accepted(key, item, payload, at)


def subscribe(session: zenoh.Session, key: str, inlet: Inlet, **options: Any) -> Any:
    """Declare a subscriber on ``key`` that feeds ``inlet`` (``options``: ``allowed_origin``...).
    Keep the returned subscriber as long as the inlet is used; closing the session ends it too."""
    sub = session.declare_subscriber(key, inlet.handler(), **options)
    inlet.attach(sub)
    return sub
