"""The one receive path: stamp on arrival, queue, then accept or reject each sample in the owner's loop.

Every subscription of :class:`~swarmnet.node.SwarmNode` and :class:`~swarmnet.observer.SwarmObserver`
delivers into an :class:`Inlet`, which stamps each sample's arrival (wall clock) and queues it
in a bounded deque (the oldest is dropped when it is full) until the owner's loop takes it.
No Python that could wait runs on Zenoh's threads: a slow zenoh-python callback stalls the
whole session (measured: one slow callback delayed an unrelated 10 Hz topic from the same peer
by up to 11 s), and even a fast one waits for the interpreter's lock while the owner holds it.
So a hot stream (neighbour poses) is a Zenoh ring channel that a thread of the inlet's own
empties and stamps; a rare stream (commands) may use a minimal callback; an owner that needs no
stamps drains a ring channel itself (:class:`Inlet`).

Streams that must be handled at once (commands, netem changes) also notify a :class:`Waker`,
whose file descriptor the owner's loop waits on between its ticks. Poses wake nobody one by
one: they are taken in at the next control, with their arrival time; with aligned ticks the
pose inlet counts them and wakes the owner once the instant's poses are in (:meth:`Inlet.expect`).

The path, top to bottom::

    Inlet: (arrival time, sample) -> bounded deque [-> Waker]
    drain(inlet, budget)           at most `budget` samples per call, oldest first
      -> accept(key, payload)      decode + the stream's rules (swarmnet.messages.accept_*)
      -> Accepted(key, item, payload, at), or Rejected: counted in NodeStats.rejected[reason]

What happens to an accepted item (the netem shim, the neighbour table, the inbox) is the
owner's business; counting it as received is too, because the owner knows when it is
delivered.
"""

from __future__ import annotations

import math
import os
import select
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Generic, Literal, NamedTuple, TypeVar

import zenoh

from swarmnet.messages import Pose, PoseBatch, Rejected, accept_batched_pose
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

    def __del__(self) -> None:  # a node never opened, or dropped without close(): its descriptor back
        try:
            self.close()
        except Exception:  # noqa: BLE001, S110 - at interpreter exit os may be gone; nothing to report
            pass

    def close(self) -> None:
        if getattr(self, "closed", True):  # (also when __init__ failed before setting it)
            return
        self.closed = True
        for fd in {self._r, self._w}:
            try:
                os.close(fd)
            except OSError:
                pass


How = Literal["thread", "callback", "ring"]


class Inlet:
    """Where one subscription's samples wait for the owner: ``(arrival time, sample)``, oldest first.

    ``size`` bounds the queue (the oldest sample is dropped when full, as a ring channel does);
    ``waker``, if given, is notified of every sample (for streams the owner handles at once);
    ``clock`` stamps the arrival (wall time, s); ``weigh``, if given, says how many of the items
    :meth:`expect` counts a sample carries (an edge-feed batch: the neighbours' poses in it; by
    default each sample is one). Three ways to take samples from Zenoh (``how``):

    * ``"thread"`` (a hot stream: a UAV's neighbour poses): a Zenoh ring channel, and a thread
      of the inlet's own blocked in it (the interpreter's lock released) that stamps each sample
      as it comes out and queues it. Nothing runs on Zenoh's threads; the channel drops its
      oldest sample rather than ever making them wait.
    * ``"callback"`` (a rare stream: commands, netem changes, acknowledgements): a minimal
      callback on Zenoh's receive thread, no thread of its own. It needs the interpreter's lock
      for about a microsecond per sample; while the owner holds it, Zenoh's receive thread waits,
      and with it everything the session receives. Measured on 2 loaded cores at N = 25, a
      callback on every pose raised the p99 transport age several times over and lost poses
      (the senders' queues overflowed), so only rare streams take this way.
    * ``"ring"`` (an owner that does not need arrival stamps: the runner and the ground station
      watch every UAV): a ring channel drained by the owner; the arrival is the drain's time.
    """

    __slots__ = ("_q", "_sub", "waker", "clock", "how", "size", "weigh", "_thread", "_lock", "_since", "_short",
                 "_quorum_waker", "lazy", "__weakref__")

    def __init__(self, size: int, waker: Waker | None = None, clock: Callable[[], float] = time.time, how: How = "callback",
                 weigh: Callable[[zenoh.Sample], int] | None = None, lazy: bool = False):
        if waker is not None and how == "ring":
            raise ValueError("a ring inlet is drained by its owner: it cannot wake it")
        self._q: deque[tuple[float, zenoh.Sample]] = deque(maxlen=size)
        self._sub: Any = None  # the ring channel's subscriber ("thread", "ring")
        self._thread: threading.Thread | None = None
        self.waker = waker
        self.clock = clock
        self.how = how
        self.size = size
        self.weigh = weigh
        self._lock = threading.Lock()  # the expectation (below), between the owner and the inlet's thread
        self._since = math.inf  # wall time (s) from which arrivals count towards the expectation
        self._short = 0  # arrivals still expected before the quorum waker is notified (0: none armed)
        self._quorum_waker: Waker | None = None
        # a "thread" inlet whose thread waits for start() or a sample found by poke(): see poke()
        self.lazy = lazy and how == "thread"

    @property
    def stamped(self) -> bool:
        """Arrival times are the samples' own (taken as they arrive), not the drain's."""
        return self.how != "ring"

    def handler(self) -> Any:
        """The Zenoh handler to subscribe with: a ring channel, or a closure that only stamps and
        appends (and notifies)."""
        if self.how != "callback":
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
        """The subscriber declared with :meth:`handler`: drained through it ("ring"), or by the
        inlet's thread, started here ("thread"; a lazy inlet's by :meth:`start` or :meth:`poke`),
        which ends when the subscription does."""
        self._sub = subscriber
        if not self.lazy:
            self.start()

    @property
    def started(self) -> bool:
        """Samples are taken as they arrive: the inlet's thread runs, or it needs none."""
        return self.how != "thread" or self._thread is not None

    def start(self) -> None:
        """Start the inlet's thread (a "thread" inlet, once attached); nothing if it runs already."""
        if self.how != "thread" or self._thread is not None or self._sub is None:
            return
        self._thread = threading.Thread(target=self._receive, args=(self._sub.handler,), name="swarmnet-inlet",
                                        daemon=True)
        self._thread.start()

    def poke(self) -> bool:
        """A lazy inlet whose thread has not started: whatever its channel holds is queued,
        stamped now, and the thread started if there was any. True once the thread runs.

        Why: a blocked ``recv`` of zenoh-python wakes every 100 ms to look for signals, so an
        inlet's thread costs a UAV ten wake-ups a second even when nothing comes: 5 % of a lone
        UAV's CPU (docs/benchmarks.md). A UAV's pose inlet therefore starts its thread when the
        first other UAV joins (:class:`~swarmnet.node.SwarmNode`), and the owner pokes it once a
        tick until then, so that a pose that came before the join waits at most a tick. Such a pose
        is stamped when poked, not when it arrived: its transport age is then up to a tick too long.
        """
        if self.started:
            return True
        if self._sub is None:
            return False
        take = self._sub.handler.try_recv
        try:
            sample = take()
            if sample is None:
                return False
            burst = [(self.clock(), sample)]
            while (more := take()) is not None:
                burst.append((self.clock(), more))
        except zenoh.ZError:  # the subscription or the session ended
            return False
        with self._lock:
            self._q.extend(burst)
        self.start()
        return True

    def join(self, timeout: float) -> bool:
        """Wait at most ``timeout`` s for the inlet's thread to end, once its subscription or
        session is closed; True when it has (or there is none).

        Why: a thread still blocked in Zenoh when the interpreter exits is stopped inside Rust
        frames, which cannot be unwound: the process aborts ("FATAL: exception not rethrown",
        exit -6) after an otherwise clean run."""
        t = self._thread
        if t is None:
            return True
        t.join(timeout)
        return not t.is_alive()

    def expect(self, count: int, since: float, waker: Waker) -> None:
        """Notify ``waker`` once ``count`` samples (or items, with ``weigh``) stamped at or after
        ``since`` (wall time, s) have arrived, those already waiting included; a new expectation
        replaces the last.

        Why: a UAV whose ticks are aligned (``network.align_ticks``) controls as soon as its
        neighbours' poses of the tick's instant are in, rather than at a fixed offset that must
        cover the slowest of them. Only an inlet with its own thread ("thread") counts arrivals.
        """
        if self.how != "thread":
            raise ValueError("only an inlet with its own thread counts arrivals")
        with self._lock:
            self._since = since
            self._quorum_waker = waker
            # the inlet's thread queues under this lock too: the queue holds still while counted
            short = count - self._weight(s for at, s in self._q if at >= since)
            self._short = short if short > 0 else 0
        if short <= 0:
            waker.notify()

    @property
    def expectation_met(self) -> bool:
        """The samples :meth:`expect` waits for have all arrived (until :meth:`cancel_expectation`)."""
        return self._short == 0 and self._since != math.inf

    def cancel_expectation(self) -> None:
        """Forget the expectation, met or not (the owner has stopped waiting)."""
        with self._lock:
            self._short = 0
            self._since = math.inf

    def _weight(self, samples: Iterable[zenoh.Sample]) -> int:
        """How many items :meth:`expect` counts in ``samples``: one each, or what ``weigh`` says.
        A rule that fails counts 0: it must end neither the inlet's thread nor the owner's loop."""
        weigh = self.weigh
        if weigh is None:
            return sum(1 for _ in samples)
        try:
            return sum(weigh(s) for s in samples)
        except Exception:  # noqa: BLE001
            return 0

    def _receive(self, channel: Any) -> None:
        extend, stamp, notify = self._q.extend, self.clock, (self.waker.notify if self.waker is not None else None)
        recv, try_recv, lock = channel.recv, channel.try_recv, self._lock
        while True:
            try:
                sample = recv()  # blocks, the interpreter's lock released
                at = stamp()
                burst = [(at, sample)]
                while (more := try_recv()) is not None:  # those that came meanwhile: one wake-up
                    burst.append((stamp(), more))
            except zenoh.ZError:  # the subscription or the session ended
                return
            reached = None
            with lock:  # queued and counted at once: expect() sees each sample either waiting or counted
                extend(burst)
                if self._short and at >= self._since:
                    self._short = max(self._short - self._weight(s for _, s in burst), 0)
                    if not self._short:
                        reached = self._quorum_waker
            if reached is not None:
                reached.notify()
            if notify is not None:
                notify()

    def __len__(self) -> int:
        """Samples waiting (a stamped inlet; a ring channel cannot tell without taking them)."""
        return len(self._q)

    def drain(self, budget: int = DRAIN_BUDGET) -> Iterable[tuple[float, zenoh.Sample]]:
        """The waiting ``(arrival time, sample)`` pairs, oldest first, at most ``budget``; never blocks.

        A stamped inlet with nothing waiting gives ``()`` at once: a UAV's loop drains several
        inlets a tick, most of them empty (commands, netem changes, swarm messages)."""
        if self.how != "ring" and not self._q:
            return ()
        return self._drain(budget)

    def _drain(self, budget: int) -> Iterator[tuple[float, zenoh.Sample]]:
        if self.how == "ring":
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


def receive(inlet: Inlet, accept: Accept[T], stats: NodeStats, budget: int = DRAIN_BUDGET) -> Iterable[Accepted[T]]:
    """The accepted samples waiting in ``inlet`` (at most ``budget`` drained per call): drain, run
    ``accept`` on each, count every rejection in ``stats`` and skip it, in one loop (every direct
    pose passes here). ``()`` at once when a stamped inlet has nothing waiting."""
    samples = inlet.drain(budget)
    if samples == ():
        return ()
    return _accepted(samples, accept, stats)


def _accepted(samples: Iterable[tuple[float, zenoh.Sample]], accept: Accept[T], stats: NodeStats) -> Iterator[Accepted[T]]:
    for at, s in samples:
        key, payload = str(s.key_expr), s.payload.to_bytes()
        try:
            item = accept(key, payload)
        except Rejected as exc:
            stats.reject(exc.reason, key, exc.detail)
            continue
        yield Accepted(key, item, payload, at)


def token_changes(inlet: Inlet, alive: set[str], budget: int = DRAIN_BUDGET) -> list[tuple[str, bool]]:
    """The liveliness tokens that appeared (True) or disappeared (False) in what ``inlet`` holds,
    in order, applied to ``alive`` (the keys present); a token seen twice is one change."""
    changes: list[tuple[str, bool]] = []
    for _at, sample in inlet.drain(budget):
        key = str(sample.key_expr)
        if sample.kind == zenoh.SampleKind.PUT:
            if key not in alive:
                alive.add(key)
                changes.append((key, True))
        elif key in alive:
            alive.discard(key)
            changes.append((key, False))
    return changes


def batched_poses(batch: PoseBatch, stats: NodeStats, pose_key: Callable[[int], str],
                  own: int | None = None) -> Iterator[tuple[Pose, bytes]]:
    """The poses an edge-feed batch carries, with their payloads, each accepted on its own as from
    the sender the batch names for it (:func:`~swarmnet.messages.accept_batched_pose`: a bad one is
    counted in ``stats`` under the sender's pose key ``pose_key(sender)``, the others kept); ``own``'s
    pose, which comes back in the swarm's batch, left out."""
    for sender, data in zip(batch.senders, batch.poses, strict=True):
        try:
            pose = accept_batched_pose(sender, data)
        except Rejected as exc:
            stats.reject(exc.reason, pose_key(sender), exc.detail)
            continue
        if pose.uav != own:
            yield pose, data


def subscribe(session: zenoh.Session, key: str, inlet: Inlet, **options: Any) -> Any:
    """Declare a subscriber on ``key`` that feeds ``inlet`` (``options``: ``allowed_origin``...).
    Keep the returned subscriber as long as the inlet is used; closing the session ends it too."""
    sub = session.declare_subscriber(key, inlet.handler(), **options)
    inlet.attach(sub)
    return sub
