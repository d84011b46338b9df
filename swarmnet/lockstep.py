"""Lock-step time: the runner's leader steps every pool of virtual UAVs through simulated time.

In a lock-step run (``time: lockstep``, docs/campaigns.md) no process reads the wall clock for the
flight: the leader (the runner's session, as ``ctl``) puts one :class:`ClockStep` per half tick on
``mrs/<swarm>/clock/step``, and every pool (``pool-<n>``) runs that half of its UAVs' tick at the
step's simulated time, then answers with a :class:`ClockDone` on ``mrs/<swarm>/clock/done/pool-<n>``.
The leader puts the next step when every pool has answered, so simulated time runs as fast as the
slowest pool allows, and never faster.

Why that is enough for every pool to see the same swarm at the same simulated instant: all traffic
crosses the one edge router, each pool's session keeps its order on its link, and the clock's
messages travel at the lowest priority, behind anything put before them. A pool's poses of a
tick are put before its answer, so they reach every other pool before the leader's next step does.

Step ``k`` (simulated time ``t_k``) is, in every pool: every UAV acts on the poses of instant
``t_(k-1)`` (at ``t_(k-1) + act_after x period``, as in real time), then the FCU steps to ``t_k``
and every UAV senses and puts its pose of ``t_k``. A pool may run ahead of another by that much:
what it puts is stamped with its simulated time, and a receiver holds what is stamped after its own
instant (a pose, :class:`~swarmnet.shared_session.SharedSession`) or at or after it (a swarm
message, :meth:`~swarmnet.node.SwarmNode.poll`) until its clock gets there, so that every pool sees
the same swarm at the same instant, whichever pool ran first.

Both ends bound every wait: :class:`LockstepStalled` names the pools that did not answer.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from typing import Annotated, Any, TypeVar

import msgspec
import zenoh

from groundfloor.errors import MrswarmError, Rejected
from swarmnet.keyspace import SwarmKeys
from swarmnet.messages import DecodeError, check_key_names

log = logging.getLogger(__name__)

T = TypeVar("T")
SEQ_MAX = 2**62
IDLE_S = 60.0  # wall s a follower waits without a step before it takes the leader for gone
# the simulated clock's origin, s since the Unix epoch (2026-01-01 00:00 UTC): one for every run, so that
# two runs of one seed compute with the same numbers (a float's rounding depends on its magnitude)
LOCKSTEP_EPOCH = 1_767_225_600.0
# s: what two stamps of one instant may differ by (a float near the epoch resolves 0.24 us, the wire 1 us);
# stamps of two different instants of a run differ by at least a tick's act offset (30 ms at 10 Hz)
SLACK_S = 1e-4


class ClockStep(msgspec.Struct, array_like=True, forbid_unknown_fields=True, frozen=True):
    """The leader's step: run tick ``k``, whose instant is simulated time ``t``."""

    k: Annotated[int, msgspec.Meta(ge=0, lt=SEQ_MAX)]  # tick number since the clock started
    t: Annotated[float, msgspec.Meta(ge=0.0, lt=2.0**40)]  # the tick's instant, s since the Unix epoch


WORLD = 0  # the world service's number among the clock's participants (pools are 1, 2, ...)


class ClockDone(msgspec.Struct, array_like=True, forbid_unknown_fields=True, frozen=True):
    """A participant's answer: it ran step ``k``; ``k = -1``: it is ready for the first step.
    ``pool``: the pool's number, or :data:`WORLD` for the world service."""

    pool: Annotated[int, msgspec.Meta(ge=0, le=65535)]
    k: Annotated[int, msgspec.Meta(ge=-1, lt=SEQ_MAX)]


_encode = msgspec.msgpack.Encoder().encode
_decode_step = msgspec.msgpack.Decoder(ClockStep).decode
_decode_done = msgspec.msgpack.Decoder(ClockDone).decode
# the clock's messages must arrive, in order, behind everything put before them (module docstring)
CLOCK_QOS: dict[str, Any] = {"congestion_control": zenoh.CongestionControl.BLOCK, "priority": zenoh.Priority.BACKGROUND,
                             "reliability": zenoh.Reliability.RELIABLE, "express": True}


class LockstepStalled(RuntimeError, MrswarmError):
    """A wait of the lock-step clock ran out; ``missing`` names who did not answer."""

    def __init__(self, message: str, missing: Iterable[int] = ()):
        super().__init__(message)
        self.missing = sorted(missing)


def _decoded(decode: Callable[[bytes], T], what: str, data: bytes) -> T:
    """``decode(data)``, or :class:`DecodeError` (``bad_field``, ``malformed``) naming ``what``."""
    try:
        return decode(data)
    except msgspec.ValidationError as exc:
        raise DecodeError("bad_field", f"{what}: {exc}") from None
    except msgspec.DecodeError as exc:
        raise DecodeError("malformed", f"{what}: {exc}") from None


def decode_step(data: bytes) -> ClockStep:
    return _decoded(_decode_step, "clock_step", data)


def decode_done(data: bytes) -> ClockDone:
    return _decoded(_decode_done, "clock_done", data)


def participant(number: int) -> str:
    """The last segment of a participant's answer key: ``pool-<n>``, or ``world``."""
    return "world" if number == WORLD else f"pool-{number}"


def check_done_key(key: str, done: ClockDone) -> None:
    """An answer sits under the pool it names (``key_mismatch``): access control lets a pool put
    only its own ``clock/done/pool-<n>``, so a pool cannot answer for another."""
    check_key_names(key, participant(done.pool))


class _Mailbox:
    """What a subscriber hands over from Zenoh's thread, decoded; refusals counted by reason."""

    def __init__(self, decode: Any, size: int, check: Any = None):
        self._decode = decode
        self._check = check  # (key, item) -> None, or Rejected
        self._items: deque[Any] = deque(maxlen=size)
        self._cond = threading.Condition()
        self.rejected: dict[str, int] = {}

    def handler(self, sample: zenoh.Sample) -> None:
        try:
            item = self._decode(sample.payload.to_bytes())
            if self._check is not None:
                self._check(str(sample.key_expr), item)
        except Rejected as exc:
            with self._cond:
                self.rejected[exc.reason] = self.rejected.get(exc.reason, 0) + 1
                n = self.rejected[exc.reason]
            if n == 1 or n % 1000 == 0:
                log.warning("lock-step clock: %s refused (%d so far): %s", sample.key_expr, n, exc.detail)
            return
        with self._cond:
            self._items.append(item)
            self._cond.notify_all()

    def take(self, timeout: float) -> list[Any]:
        """Everything received so far, waiting up to ``timeout`` s for the first of it."""
        with self._cond:
            if not self._items:
                self._cond.wait(timeout)
            out = list(self._items)
            self._items.clear()
            return out


class LockstepFollower:
    """A pool's end of the clock, on the pool's session (``pool`` :data:`WORLD`: the world service's,
    stepped on a key of its own once the pools have run the tick)."""

    def __init__(self, session: zenoh.Session, keys: SwarmKeys, pool: int):
        self.pool = pool
        self._box = _Mailbox(decode_step, 64)
        world = pool == WORLD
        self._sub = session.declare_subscriber(keys.clock_world_step if world else keys.clock_step, self._box.handler)
        self._pub = session.declare_publisher(keys.clock_done_world if world else keys.clock_done(pool), **CLOCK_QOS)
        self._pending: deque[ClockStep] = deque()
        self.last: ClockStep | None = None
        self.steps = 0  # steps taken
        self.duplicates = 0  # steps the leader put again (it asked a second time): answered, not run again

    @property
    def rejected(self) -> dict[str, int]:
        return dict(self._box.rejected)

    def next_step(self, timeout: float) -> ClockStep | None:
        """The next step to run (None: none within ``timeout`` s). Before the first one, the pool
        says it is ready every half second (the leader may start listening after the pool)."""
        deadline = time.monotonic() + timeout
        while True:
            while self._pending:
                step = self._pending.popleft()
                last = self.last
                if last is not None and step.k <= last.k:
                    self.duplicates += 1  # answered again: its first answer may be what the leader missed
                    self.done(step)
                    continue
                self.last = step
                self.steps += 1
                return step
            left = deadline - time.monotonic()
            if left <= 0.0:
                return None
            if self.last is None:
                self._pub.put(_encode(ClockDone(self.pool, -1)))
                left = min(left, 0.5)
            self._pending.extend(self._box.take(left))

    def follow(self, stopped: Callable[[], bool], idle_timeout: float = IDLE_S, poll_s: float = 1.0,
              gone: Callable[[], bool] = lambda: False) -> Iterator[ClockStep]:
        """Each step as it comes, until ``stopped()``, or no step came for ``idle_timeout`` s of wall
        time (the leader is gone: logged), or ``gone()`` says the follower's owner is (looked at every
        ``poll_s`` s while no step comes). Answer each with :meth:`done`."""
        waiting = time.monotonic()
        while not stopped():
            step = self.next_step(min(poll_s, idle_timeout))
            if step is None:
                if time.monotonic() - waiting > idle_timeout:
                    log.error("no lock-step step for %.0f s: the run's leader is gone; %s stops", idle_timeout,
                              "the world" if self.pool == WORLD else f"pool {self.pool}")
                    return
                if gone():
                    return
                continue
            yield step
            waiting = time.monotonic()

    def done(self, step: ClockStep) -> None:
        self._pub.put(_encode(ClockDone(self.pool, step.k)))

    def close(self) -> None:
        for x in (self._sub, self._pub):
            try:
                x.undeclare()
            except zenoh.ZError as exc:
                log.debug("lock-step follower close: %s", exc)


class LockstepLeader:
    """The runner's end: puts each step and waits for every pool's answer.

    ``period`` is the UAVs' tick (s of simulated time); the first instant is ``epoch`` (s since the
    Unix epoch: :data:`LOCKSTEP_EPOCH` for a run). Each tick waits at most ``step_timeout`` s of
    wall time for the pools. With ``world``, the world service runs each tick after the pools, alone:
    it sees the swarm as the pools left it at the instant, and what it sends reaches them before the
    next step.
    """

    def __init__(self, session: zenoh.Session, keys: SwarmKeys, pools: Iterable[int], period: float,
                 epoch: float = LOCKSTEP_EPOCH, step_timeout: float = 20.0, world: bool = False):
        self.pools = frozenset(pools)
        if not self.pools or WORLD in self.pools:
            raise ValueError("a lock-step clock needs at least one pool, numbered from 1")
        self.world = world
        self.period = period
        self.epoch = epoch
        self.step_timeout = step_timeout
        self._box = _Mailbox(decode_done, 4096, check_done_key)
        self._sub = session.declare_subscriber(keys.all_clock_done, self._box.handler)
        self._pub = session.declare_publisher(keys.clock_step, **CLOCK_QOS)
        self._world_pub = session.declare_publisher(keys.clock_world_step, **CLOCK_QOS) if world else None
        self.k = -1  # the last tick whose both halves every pool ran
        self.now = epoch  # simulated time: the last step's
        self.wall_started: float | None = None
        self.wall_waiting = 0.0  # wall s spent waiting for the pools' answers
        self.resends = 0

    @property
    def rejected(self) -> dict[str, int]:
        return dict(self._box.rejected)

    def clock(self) -> float:
        """Simulated time now (s since the Unix epoch), for the runner's own timing."""
        return self.now

    def sim_elapsed(self) -> float:
        return (self.k + 1) * self.period

    def wait_ready(self, timeout: float) -> None:
        """Until every pool said it is ready for the first step (LockstepStalled after ``timeout`` s)."""
        ready: set[int] = set()
        every = self.pools | ({WORLD} if self.world else set())
        deadline = time.monotonic() + timeout
        while not every <= ready:
            left = deadline - time.monotonic()
            if left <= 0.0:
                missing = every - ready
                raise LockstepStalled(f"{_names(missing)} not ready for lock-step time within {timeout:g} s", missing)
            ready.update(d.pool for d in self._box.take(min(left, 0.5)) if d.k == -1)
        self.wall_started = time.monotonic()

    def tick(self) -> None:
        """The next tick, every pool's answer awaited."""
        k = self.k + 1
        step = ClockStep(k, self.epoch + k * self.period)
        self._step(step, self._pub, self.pools)
        if self._world_pub is not None:
            self._step(step, self._world_pub, frozenset({WORLD}))
        self.k = k

    def advance(self, seconds: float) -> None:
        """Ticks until ``seconds`` more of simulated time have passed (at least one)."""
        ticks = max(1, round(seconds / self.period))  # whole ticks: no float drift over a long run
        for _ in range(ticks):
            self.tick()

    def _step(self, step: ClockStep, pub: Any, who: frozenset[int]) -> None:
        self.now = step.t
        payload = _encode(step)
        pub.put(payload)
        waiting: set[int] = set(who)
        t0 = time.monotonic()
        deadline = t0 + self.step_timeout
        resend = t0 + 1.0
        while waiting:
            now = time.monotonic()
            if now >= deadline:
                self.wall_waiting += now - t0
                raise LockstepStalled(f"tick {step.k}: no answer within {self.step_timeout:g} s from {_names(waiting)}",
                                      waiting)
            if now >= resend:  # an answer lost (a pool's session reconnected): ask again, it answers again
                self.resends += 1
                pub.put(payload)
                resend = now + 1.0
            for d in self._box.take(min(deadline, resend) - now):
                if d.k == step.k:
                    waiting.discard(d.pool)
        self.wall_waiting += time.monotonic() - t0

    def drop(self, pools: Iterable[int]) -> None:
        """Pools gone (their process ended): the clock goes on without them."""
        self.pools = self.pools - frozenset(pools)

    def stats(self) -> dict[str, Any]:
        wall = time.monotonic() - self.wall_started if self.wall_started is not None else 0.0
        sim = self.sim_elapsed()
        return {"ticks": self.k + 1, "sim_s": round(sim, 3), "wall_s": round(wall, 3),
                "speedup": round(sim / wall, 2) if wall > 0 else None, "waiting_s": round(self.wall_waiting, 3),
                "resends": self.resends, "rejected": self.rejected, "pools": sorted(self.pools), "world": self.world}

    def close(self) -> None:
        for x in (self._sub, self._pub, self._world_pub):
            try:
                if x is not None:
                    x.undeclare()
            except zenoh.ZError as exc:
                log.debug("lock-step leader close: %s", exc)


def _names(numbers: Iterable[int]) -> str:
    """``pool(s) 1, 2`` and/or ``the world service``, for messages."""
    ns = sorted(numbers)
    pools = [str(n) for n in ns if n != WORLD]
    parts = ([f"pool(s) {', '.join(pools)}"] if pools else []) + (["the world service"] if WORLD in ns else [])
    return " and ".join(parts)
