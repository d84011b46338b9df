"""The lock-step clock under the swarm's access control (swarmnet/security/acl.py), on a real TLS
edge router: a pool answers only for itself and cannot step the clock; the runner (``ctl``) steps
it. What each identity may do is asserted by what arrives."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
import zenoh

from swarmnet.lockstep import LOCKSTEP_EPOCH, ClockDone, ClockStep, LockstepFollower, LockstepLeader
from swarmnet.security.acl import access_control
from swarmnet.security.identity import NodeName
from swarmnet.security.pki import KeyDir
from swarmnet.security.roster import Roster
from tests.conftest import wait_for
from tests.test_security import KEYS, SWARM, client, creds, router_process

enc = msgspec.msgpack.encode


@pytest.fixture
def clock_keys(tmp_path: Path) -> Path:
    kd = KeyDir.init(tmp_path / "keys", SWARM)
    for n in ("ctl", "edge", "gcs-1"):
        kd.issue(NodeName.in_swarm(n, SWARM))
    kd.issue(NodeName("pool", 1, SWARM), uavs=(1, 2))
    kd.issue(NodeName("pool", 2, SWARM), uavs=(3, 4))
    return kd.path


def test_the_rules_grant_the_clock_to_the_right_subjects(clock_keys: Path) -> None:
    rules = {r["id"]: r["key_exprs"] for r in access_control(Roster.load(clock_keys))["rules"]}
    assert KEYS.clock_done(1) in rules["pool-1.in"] and KEYS.clock_done(2) in rules["pool-2.in"]
    assert KEYS.clock_done(2) not in rules["pool-1.in"] and KEYS.all_clock_done not in rules["pool-1.in"]
    assert KEYS.clock_step not in rules["pool-1.in"] and KEYS.clock_step in rules["pool-1.out"]
    assert not any("clock/done" in k for k in rules["pool-1.out"])  # a pool hears no pool's answers
    assert KEYS.clock_step in rules["ctl.in"] and KEYS.clock_step not in rules["gcs.in"]


class Heard:
    """A subscriber's samples by key, from Zenoh's thread."""

    def __init__(self, session: zenoh.Session, key: str):
        self._lock = threading.Lock()
        self.keys: list[str] = []
        self.payloads: list[bytes] = []
        self._sub = session.declare_subscriber(key, self._take)

    def _take(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.keys.append(str(sample.key_expr))
            self.payloads.append(sample.payload.to_bytes())

    def count(self, key: str, payload: bytes | None = None) -> int:
        with self._lock:
            return sum(k == key and (payload is None or p == payload) for k, p in zip(self.keys, self.payloads, strict=True))


@pytest.fixture
def secured(clock_keys: Path, tmp_path: Path) -> Iterator[dict[str, zenoh.Session]]:
    with router_process(clock_keys, tmp_path) as (ep, _stats):
        opened = {n: client(ep, creds(clock_keys, n)) for n in ("ctl", "pool-1", "pool-2", "gcs-1")}
        try:
            yield opened
        finally:
            for s in opened.values():
                s.close()


def test_a_pool_answers_only_for_itself_and_only_ctl_steps_the_clock(secured: dict[str, zenoh.Session]) -> None:
    ctl, pool1, pool2, gcs = secured["ctl"], secured["pool-1"], secured["pool-2"], secured["gcs-1"]
    at_ctl = Heard(ctl, f"{KEYS.prefix}/clock/**")  # ctl receives everything of the swarm
    at_pool1 = Heard(pool1, f"{KEYS.prefix}/clock/**")
    at_pool2 = Heard(pool2, f"{KEYS.prefix}/clock/**")
    own, forged, pool2_own = enc(ClockDone(1, 7)), enc(ClockDone(2, 7)), enc(ClockDone(2, 8))
    by_ctl, by_pool, by_gcs = enc(ClockStep(1, LOCKSTEP_EPOCH)), enc(ClockStep(2, LOCKSTEP_EPOCH)), enc(ClockStep(3, 0.0))

    def put_all() -> None:
        pool1.put(KEYS.clock_done(1), own)  # its own answer: allowed
        pool1.put(KEYS.clock_done(2), forged)  # pool 2's: refused
        pool1.put(KEYS.clock_step, by_pool)  # a step: refused
        gcs.put(KEYS.clock_step, by_gcs)  # a ground station's step: refused
        ctl.put(KEYS.clock_step, by_ctl)  # the runner's step: allowed
        pool2.put(KEYS.clock_done(2), pool2_own)  # pool 2's own answer: allowed (for ctl: no pool hears answers)

    def allowed_arrived() -> bool:
        put_all()
        return (at_ctl.count(KEYS.clock_done(1), own) > 0 and at_ctl.count(KEYS.clock_done(2), pool2_own) > 0
                and at_pool1.count(KEYS.clock_step, by_ctl) > 0 and at_pool2.count(KEYS.clock_step, by_ctl) > 0)

    assert wait_for(allowed_arrived, 10.0, 0.1)
    deadline = time.monotonic() + 2.0  # a while longer: what is allowed keeps arriving, nothing refused does
    while time.monotonic() < deadline:
        put_all()
        time.sleep(0.05)
    assert at_ctl.count(KEYS.clock_done(1), own) >= 10 and at_ctl.count(KEYS.clock_done(2), pool2_own) >= 10
    assert at_pool1.count(KEYS.clock_step, by_ctl) >= 10 and at_pool2.count(KEYS.clock_step, by_ctl) >= 10
    assert at_ctl.count(KEYS.clock_done(2), forged) == 0  # pool 1 cannot answer for pool 2
    for heard in (at_ctl, at_pool2):  # (pool 1's own subscriber hears its put in the session, not from the router)
        assert heard.count(KEYS.clock_step, by_pool) == 0  # nor step the clock
    for heard in (at_ctl, at_pool1, at_pool2):
        assert heard.count(KEYS.clock_step, by_gcs) == 0  # nor can a ground station
    # no pool hears another's answers
    assert at_pool1.count(KEYS.clock_done(2), pool2_own) == 0 and at_pool2.count(KEYS.clock_done(1)) == 0


def test_the_clock_runs_through_the_secured_router(secured: dict[str, zenoh.Session]) -> None:
    """The leader on ctl's session, a follower on each pool's: ten ticks through access control."""
    leader = LockstepLeader(secured["ctl"], KEYS, (1, 2), 0.1, LOCKSTEP_EPOCH, step_timeout=5.0)
    followers = [LockstepFollower(secured[f"pool-{n}"], KEYS, n) for n in (1, 2)]
    seen: dict[int, list[int]] = {1: [], 2: []}

    def run(f: LockstepFollower) -> None:
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and len(seen[f.pool]) < 10:
            step = f.next_step(0.2)
            if step is not None:
                seen[f.pool].append(step.k)
                f.done(step)

    threads = [threading.Thread(target=run, args=(f,), daemon=True) for f in followers]
    try:
        for th in threads:
            th.start()
        leader.wait_ready(15.0)
        for _ in range(10):
            leader.tick()
        for th in threads:
            th.join(10.0)
            assert not th.is_alive()
        assert seen == {1: list(range(10)), 2: list(range(10))}
        assert leader.stats()["ticks"] == 10 and leader.rejected == {}
    finally:
        leader.close()
        for f in followers:
            f.close()
