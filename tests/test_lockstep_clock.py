"""The lock-step clock (swarmnet/lockstep.py) on real Zenoh sessions through a router on 127.0.0.1.

The leader is the runner's end, each follower a pool's, each on a client session of its own as in
a run. Every wait is bounded: a follower thread ends by its deadline, the leader by its timeouts.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import msgspec
import pytest
import zenoh

from swarmnet.connectivity import Rendezvous, to_zenoh
from swarmnet.keyspace import SwarmKeys
from swarmnet.lockstep import (
    LOCKSTEP_EPOCH,
    ClockDone,
    ClockStep,
    LockstepFollower,
    LockstepLeader,
    LockstepStalled,
    decode_done,
    decode_step,
)
from swarmnet.messages import DecodeError
from tests.conftest import wait_for

SWARM = "clk"
KEYS = SwarmKeys(SWARM)
PERIOD = 0.1
TICKS = 50
enc = msgspec.msgpack.encode


def t_of(k: int, period: float = PERIOD) -> float:
    """Step k's instant, as the leader computes it (one float for every run)."""
    return LOCKSTEP_EPOCH + k * period


@pytest.fixture
def sessions(router: str) -> Iterator[list[zenoh.Session]]:
    """Four client sessions of the router: the leader's, two pools', and one for the tests' own puts."""
    with contextlib.ExitStack() as stack:
        out = []
        for _ in range(4):
            s = zenoh.open(to_zenoh(Rendezvous((router,), mode="client").zenoh_config()))
            stack.callback(s.close)
            out.append(s)
        yield out


@dataclass
class Pool:
    """A pool's loop, reduced to the clock: take a step, (maybe) run it, answer it."""

    follower: LockstepFollower
    until_k: int  # the last step it takes
    stop_answering_at: int | None = None  # from this step on it takes steps but never answers
    slow: dict[int, float] = field(default_factory=dict)  # step -> wall s it takes to run
    deadline_s: float = 30.0
    seen: list[tuple[int, float]] = field(default_factory=list)
    error: BaseException | None = None
    thread: threading.Thread | None = None

    def start(self) -> Pool:
        self.thread = threading.Thread(target=self._run, daemon=True, name=f"pool-{self.follower.pool}")
        self.thread.start()
        return self

    def _run(self) -> None:
        deadline = time.monotonic() + self.deadline_s
        try:
            while time.monotonic() < deadline:
                step = self.follower.next_step(0.2)
                if step is None:
                    continue
                self.seen.append((step.k, step.t))
                if self.stop_answering_at is not None and step.k >= self.stop_answering_at:
                    return
                time.sleep(self.slow.get(step.k, 0.0))
                self.follower.done(step)
                if step.k >= self.until_k:
                    return
        except BaseException as exc:  # noqa: BLE001 (handed to the test)
            self.error = exc

    def join(self, timeout: float = 10.0) -> None:
        assert self.thread is not None
        self.thread.join(timeout)
        assert not self.thread.is_alive(), f"pool {self.follower.pool} did not end"
        assert self.error is None, self.error


@contextlib.contextmanager
def clock(sessions: list[zenoh.Session], pools: tuple[int, ...] = (1, 2), step_timeout: float = 5.0,
          period: float = PERIOD) -> Iterator[tuple[LockstepLeader, list[LockstepFollower]]]:
    leader = LockstepLeader(sessions[0], KEYS, pools, period, LOCKSTEP_EPOCH, step_timeout=step_timeout)
    followers = [LockstepFollower(sessions[i], KEYS, n) for i, n in enumerate(pools, start=1)]
    try:
        yield leader, followers
    finally:
        leader.close()
        for f in followers:
            f.close()


def test_the_wire_structs_round_trip_and_refusals_say_why() -> None:
    step = ClockStep(7, t_of(7))
    assert decode_step(enc(step)) == step and decode_done(enc(ClockDone(3, -1))) == ClockDone(3, -1)
    assert enc(step) == enc([7, t_of(7)])  # an array on the wire
    for payload, reason in ((b"\xc1", "malformed"), (b"", "malformed"), (enc([-1, 0.0]), "bad_field"),
                            (enc([1, math.nan]), "bad_field"), (enc([1, math.inf]), "bad_field"),
                            (enc([1, 2.0, 3]), "bad_field"), (enc([True, 1.0]), "bad_field"),
                            (enc({"k": 1, "t": 2.0}), "bad_field"), (enc([2**62, 1.0]), "bad_field")):
        with pytest.raises(DecodeError) as ei:
            decode_step(payload)
        assert ei.value.reason == reason and ei.value.detail.startswith("clock_step: "), payload
    assert decode_done(enc([0, 1])) == ClockDone(0, 1)  # 0: the world service
    for payload, reason in ((enc([-1, 1]), "bad_field"), (enc([65536, 1]), "bad_field"), (enc([1, -2]), "bad_field"),
                            (b"\x92", "malformed")):
        with pytest.raises(DecodeError) as ei:
            decode_done(payload)
        assert ei.value.reason == reason and ei.value.detail.startswith("clock_done: "), payload
    with pytest.raises(ValueError, match="at least one pool"):
        LockstepLeader(None, KEYS, (), PERIOD)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="numbered from 1"):
        LockstepLeader(None, KEYS, (0, 1), PERIOD)  # type: ignore[arg-type]


def test_the_leader_steps_two_pools_through_fifty_ticks_in_order(sessions: list[zenoh.Session]) -> None:
    with clock(sessions) as (leader, followers):
        pools = [Pool(f, until_k=TICKS - 1).start() for f in followers]
        leader.wait_ready(10.0)
        for _ in range(TICKS):
            leader.tick()
        for p in pools:
            p.join()
        expected = [(k, t_of(k)) for k in range(TICKS)]
        for p in pools:
            assert p.seen == expected  # every step once, in order, each at epoch + k x period exactly
            assert p.follower.steps == TICKS and p.follower.last == ClockStep(TICKS - 1, t_of(TICKS - 1))
            assert p.follower.rejected == {}
        stats = leader.stats()
        assert stats["ticks"] == TICKS and stats["sim_s"] == pytest.approx(TICKS * PERIOD)
        assert stats["pools"] == [1, 2] and stats["rejected"] == {} and stats["wall_s"] > 0
        assert leader.k == TICKS - 1 and leader.clock() == t_of(TICKS - 1)


def test_advance_runs_ticks_until_that_much_simulated_time_has_passed(sessions: list[zenoh.Session]) -> None:
    with clock(sessions, pools=(1,)) as (leader, followers):
        pool = Pool(followers[0], until_k=11).start()
        leader.wait_ready(10.0)
        leader.advance(PERIOD)  # the first: the instant of the epoch
        assert leader.k == 0 and leader.clock() == t_of(0)
        leader.advance(3 * PERIOD)  # whole ticks, one per period
        assert leader.k == 3 and leader.clock() == t_of(3)
        for k in range(4, 12):  # one tick per period, as the runner's TICK of 0.1 s asks
            leader.advance(PERIOD)
            assert leader.k == k, k
        pool.join()
        assert [k for k, _ in pool.seen] == list(range(12))
        assert leader.sim_elapsed() == pytest.approx(12 * PERIOD)


def test_a_pool_that_stops_answering_stalls_the_leader_naming_it(sessions: list[zenoh.Session]) -> None:
    with clock(sessions, step_timeout=1.0) as (leader, followers):
        alive = Pool(followers[0], until_k=5).start()
        mute = Pool(followers[1], until_k=TICKS, stop_answering_at=5).start()
        leader.wait_ready(10.0)
        for _ in range(5):
            leader.tick()
        t0 = time.monotonic()
        with pytest.raises(LockstepStalled) as ei:
            leader.tick()
        waited = time.monotonic() - t0
        assert ei.value.missing == [2] and "tick 5" in str(ei.value) and "pool(s) 2" in str(ei.value)
        assert 1.0 <= waited < 3.0  # within step_timeout, not much later
        assert leader.k == 4  # the tick that stalled did not count
        alive.join()
        mute.join()
        assert [k for k, _ in alive.seen] == [0, 1, 2, 3, 4, 5] and [k for k, _ in mute.seen] == [0, 1, 2, 3, 4, 5]


def test_wait_ready_names_the_pool_that_never_came(sessions: list[zenoh.Session]) -> None:
    with clock(sessions) as (leader, followers):
        t0 = time.monotonic()
        with pytest.raises(LockstepStalled, match="not ready") as ei:
            leader.wait_ready(1.0)  # nobody came
        assert ei.value.missing == [1, 2] and time.monotonic() - t0 < 3.0
        first = Pool(followers[0], until_k=0).start()  # pool 1 says it is ready, pool 2 never does
        t0 = time.monotonic()
        with pytest.raises(LockstepStalled) as ei:
            leader.wait_ready(1.5)
        assert ei.value.missing == [2] and time.monotonic() - t0 < 3.5
        second = Pool(followers[1], until_k=0).start()  # it comes late: the clock starts
        leader.wait_ready(10.0)
        leader.tick()
        first.join()
        second.join()
        assert first.seen == second.seen == [(0, t_of(0))]


def test_a_malformed_step_is_counted_and_the_follower_goes_on(sessions: list[zenoh.Session]) -> None:
    spoiler = sessions[3]
    with clock(sessions) as (leader, followers):
        pools = [Pool(f, until_k=4).start() for f in followers]
        leader.wait_ready(10.0)
        leader.tick()
        for junk in (b"\xc1", enc([-3, 1.0]), enc([1, math.nan]), enc([1, t_of(1), "x"])):
            spoiler.put(KEYS.clock_step, junk)
        spoiler.put(KEYS.clock_done(1), b"\xc1")  # and on the leader's end
        assert wait_for(lambda: all(f.rejected == {"malformed": 1, "bad_field": 3} for f in followers), 5.0), \
            [f.rejected for f in followers]
        assert wait_for(lambda: leader.rejected == {"malformed": 1}, 5.0), leader.rejected
        for _ in range(4):
            leader.tick()
        for p in pools:
            p.join()
            assert p.seen == [(k, t_of(k)) for k in range(5)]  # nothing of the junk was taken as a step
        assert leader.stats()["rejected"] == {"malformed": 1} and leader.stats()["ticks"] == 5


def test_a_duplicate_step_is_answered_again_and_not_run_twice(sessions: list[zenoh.Session]) -> None:
    """A step put again (the leader asks again when an answer is late or lost) is answered again,
    and the pool does not run it a second time."""
    spy = sessions[3]
    answers: list[ClockDone] = []
    lock = threading.Lock()

    def heard(sample: zenoh.Sample) -> None:
        with lock:
            answers.append(decode_done(sample.payload.to_bytes()))

    sub = spy.declare_subscriber(KEYS.all_clock_done, heard)
    try:
        with clock(sessions) as (leader, followers):
            # pool 2 takes 1.6 s over step 2: the leader asks again after 1 s, its step_timeout is 5 s
            pools = [Pool(followers[0], until_k=6).start(), Pool(followers[1], until_k=6, slow={2: 1.6}).start()]
            leader.wait_ready(10.0)
            for _ in range(4):
                leader.tick()
            assert leader.resends >= 1 and leader.stats()["resends"] == leader.resends
            # and a step put again from outside the leader, as a resend whose first answer was lost
            spy.put(KEYS.clock_step, enc(ClockStep(1, t_of(1))))
            assert wait_for(lambda: sum(a == ClockDone(1, 1) for a in list(answers)) >= 2
                            and sum(a == ClockDone(2, 1) for a in list(answers)) >= 2, 5.0), answers
            for _ in range(3):
                leader.tick()
            for p in pools:
                p.join()
                assert p.seen == [(k, t_of(k)) for k in range(7)]  # each step taken once
                assert p.follower.steps == 7
            assert followers[0].duplicates >= 2 and followers[1].duplicates >= 2  # the resend of step 2, and step 1
            assert sum(a == ClockDone(2, 2) for a in list(answers)) >= 2  # pool 2 answered the resend of step 2 too
            assert leader.k == 6
    finally:
        sub.undeclare()


def test_an_answer_for_another_pool_under_a_pools_key_is_refused(sessions: list[zenoh.Session]) -> None:
    """A pool may put only its own ``clock/done/pool-<n>`` (access control); the leader reads the pool
    from the key, so an answer naming another pool under it is refused, not taken as that pool's."""
    rogue = sessions[3]
    with clock(sessions) as (leader, followers):
        pool1 = Pool(followers[0], until_k=0).start()
        deadline = time.monotonic() + 1.5
        with pytest.raises(LockstepStalled) as ei:
            while time.monotonic() < deadline:  # "pool 2 is ready", said under pool 1's key
                rogue.put(KEYS.clock_done(1), enc(ClockDone(2, -1)))
                time.sleep(0.1)
            leader.wait_ready(1.0)
        assert ei.value.missing == [2]
        assert leader.rejected.get("key_mismatch", 0) >= 1
        pool2 = Pool(followers[1], until_k=0).start()
        leader.wait_ready(10.0)
        leader.tick()
        pool1.join()
        pool2.join()


def test_the_world_service_runs_each_tick_after_every_pool_has(sessions: list[zenoh.Session]) -> None:
    """With a world, each tick's step reaches the world only once both pools answered it, and the
    next tick's only once the world did: it sees the swarm as the pools left it at the instant."""
    from swarmnet.lockstep import WORLD

    leader = LockstepLeader(sessions[0], KEYS, (1, 2), PERIOD, LOCKSTEP_EPOCH, step_timeout=5.0, world=True)
    followers = [LockstepFollower(sessions[1], KEYS, 1), LockstepFollower(sessions[2], KEYS, 2),
                 LockstepFollower(sessions[3], KEYS, WORLD)]
    order: list[tuple[str, int]] = []
    lock = threading.Lock()
    done = threading.Event()

    def run(f: LockstepFollower, name: str, slow: float) -> None:
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and not done.is_set():
            step = f.next_step(0.2)
            if step is None:
                continue
            time.sleep(slow)  # a slow pool: the world still comes after it
            with lock:
                order.append((name, step.k))
            f.done(step)

    threads = [threading.Thread(target=run, args=(f, n, s), daemon=True)
               for f, n, s in zip(followers, ("pool1", "pool2", "world"), (0.0, 0.01, 0.0), strict=True)]
    try:
        for t in threads:
            t.start()
        with pytest.raises(LockstepStalled) as ei:  # first without the world's readiness: it is named
            LockstepLeader(sessions[0], KEYS, (1, 2), PERIOD, world=True).wait_ready(0.0)
        assert "not ready" in str(ei.value)
        leader.wait_ready(10.0)
        for _ in range(10):
            leader.tick()
        done.set()
        for t in threads:
            t.join(5.0)
        assert leader.stats()["world"] is True and leader.k == 9
        for k in range(10):
            at = {name: order.index((name, k)) for name in ("pool1", "pool2", "world")}
            assert at["world"] > max(at["pool1"], at["pool2"]), (k, order)
            if k:
                assert at["pool1"] > order.index(("world", k - 1)) and at["pool2"] > order.index(("world", k - 1))
    finally:
        done.set()
        leader.close()
        for f in followers:
            f.close()
