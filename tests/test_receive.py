"""Event-driven receive: arrival stamps, wake-ups, a command's round trip to a real agent, the edge feed's window."""

from __future__ import annotations

import random
import statistics
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

from discovery.rendezvous import serve
from groundfloor.histogram import LogHistogram
from swarmnet.connectivity import Rendezvous, to_zenoh
from swarmnet.keyspace import SwarmKeys
from swarmnet.messages import (
    Pose,
    PoseBatch,
    Realm,
    batched_pose_count,
    decode_pose,
    decode_pose_batch,
    encode_pose,
    encode_pose_batch,
)
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.observer import SwarmObserver
from swarmnet.receive import How, Inlet, Waker, subscribe
from swarmnet.stats import PoseAges
from tests.conftest import free_port, wait_for
from tests.gcs_helpers import start_virtual_uav, stop_process
from tests.pose_rounds import hear_a_round, publish_pose


@pytest.mark.parametrize("how", ["thread", "callback"])
def test_an_inlet_stamps_each_sample_on_arrival_and_wakes_its_owner(rendezvous: Rendezvous, how: How) -> None:
    with zenoh.open(to_zenoh(rendezvous.zenoh_config())) as s:
        waker = Waker()
        inlet = Inlet(4, waker, how=how)
        sub = subscribe(s, "t/x", inlet)
        got: list[float] = []
        woke = threading.Event()

        def owner() -> None:  # the owner sleeps on the waker, as a UAV's loop does between ticks
            if waker.wait(5.0):
                got.append(time.time())
                woke.set()

        th = threading.Thread(target=owner)
        th.start()
        time.sleep(0.3)
        t_put = time.time()
        s.put("t/x", b"1")
        th.join(5.0)
        assert woke.is_set()
        [(at, sample)] = list(inlet.drain())
        assert t_put <= at <= got[0] and sample.payload.to_bytes() == b"1"
        for k in range(10):  # bounded: the oldest are dropped
            s.put("t/x", str(k).encode())
        # a callback notifies per sample; the inlet's thread once per batch it empties from its channel
        # (and the last one in: the inlet's thread may hold 4 before the rest have come)
        assert wait_for(lambda: len(inlet) == 4 and inlet._q[-1][1].payload.to_bytes() == b"9"
                        and waker.notifications >= (11 if how == "callback" else 2), 3.0)
        assert [smp.payload.to_bytes() for _, smp in inlet.drain()] == [b"6", b"7", b"8", b"9"]
        assert waker.wait(0.0) and not waker.wait(0.05)  # notifications coalesce into one wake-up
        sub.undeclare()
        # the inlet's thread leaves Zenoh once its channel closed (one left inside at exit aborts the process)
        assert inlet.join(2.0)
        waker.close()


def test_ages_filed_when_read_make_the_histograms_one_by_one_adds_make() -> None:
    """Transport ages are noted as poses arrive and filed when read (a UAV of 50 takes in 500 a
    second): the histograms a user reads must be those that adding each age as it came gives."""
    rng = np.random.default_rng(11)
    ages = PoseAges()
    want, want_links = LogHistogram(), {}
    values = np.concatenate([rng.lognormal(np.log(0.003), 1.0, 3000), [0.0, 1e-6, 5e3, -0.2, -0.01, np.nan]])
    rng.shuffle(values)
    senders = rng.integers(1, 50, values.size)
    half = values.size // 2
    for u, v in zip(senders[:half].tolist(), values[:half].tolist(), strict=True):
        ages.arrived(u, v)  # a direct pose
    for k in range(half, values.size, 9):  # batches of nine, as the edge feed sends them
        ages.arrived_many(senders[k:k + 9].tolist(), values[k:k + 9].tolist())
    for u, v in zip(senders.tolist(), values.tolist(), strict=True):
        if not v < 0:  # a NaN too: add keeps it (bin 0)
            want.add(v)
            want_links.setdefault(u, LogHistogram()).add(v)
    got = ages.transport
    assert got.bins == want.bins and got.n == want.n == values.size - 2  # all but the two below zero
    assert got.total == pytest.approx(want.total) and got.max == want.max
    for q in (50, 90, 99, 100):
        assert got.percentile(q) == want.percentile(q)
    assert set(ages.links) == set(want_links)
    for u, h in want_links.items():
        assert ages.links[u].bins == h.bins and ages.links[u].n == h.n and ages.links[u].max == h.max
    assert ages.negative == {"transport": 2} and ages.most_negative == pytest.approx(-0.2)
    ages.used_many([0.001, 0.004, -0.001])  # the last: the wall clock stepped back
    ages.used(0.002)
    assert ages.use.n == 3 and ages.use.max == 0.004 and ages.negative == {"transport": 2, "use": 1}
    # a node nobody reads keeps a bounded backlog
    for _ in range(PoseAges.FILE_AT + 10):
        ages.arrived(7, 0.001)
        ages.used(0.001)
    assert len(ages._ages) < PoseAges.FILE_AT and len(ages._uses) < PoseAges.FILE_AT


def test_ages_below_zero_are_counted_apart_not_mixed_into_the_histograms() -> None:
    ages = PoseAges()
    ages.arrived(3, 0.002)
    ages.arrived(3, -0.05)  # a receiver whose clock is behind the sender's
    ages.used(0.03)
    assert ages.transport.n == 1 and ages.links[3].n == 1 and ages.transport.mean == pytest.approx(0.002)
    assert ages.negative == {"transport": 1} and ages.most_negative == pytest.approx(-0.05)
    d = ages.to_dict()
    assert d["negative_ages"] == {"transport": 1} and d["use_age"]["n"] == 1 and set(d["transport_age_links"]) == {"3"}


def test_the_age_at_use_counts_each_pose_once_from_its_arrival(rendezvous: Rendezvous) -> None:
    a = SwarmNode(NodeIdentity("alpha", 1), rendezvous).open()
    b = SwarmNode(NodeIdentity("alpha", 2), rendezvous).open()
    try:
        assert wait_for(lambda: (a.poll(), b.poll(), {1, 2} <= b.alive_uavs())[2], 10.0)

        def heard() -> bool:  # published until the peers' direct link carries it
            a.publish_pose(t_sim=0.0, x=0.0, y=0.0, z=5.0, vx=0.0, vy=0.0, vz=0.0, yaw=0.0)
            return (b.poll(), 1 in b.neighbours)[1]

        assert wait_for(heard, 10.0, period=0.1)
        time.sleep(0.3)
        b.poll()  # a pose sent while the last one was on its way
        time.sleep(0.05)  # the controller uses it a while after it arrived
        t_use = time.time()
        [nb] = b.take_neighbours(t_use)
        assert b.stats.ages.use.n == 1 and b.stats.ages.use.max == pytest.approx(t_use - nb.last_recv)
        assert t_use - nb.last_recv >= 0.05
        b.take_neighbours()  # the same pose again: not a new use
        assert b.stats.ages.use.n == 1
    finally:
        a.close()
        b.close()


def test_a_node_wakes_its_owner_once_the_poses_of_an_instant_are_in(rendezvous: Rendezvous) -> None:
    """Aligned ticks (``network.align_ticks``) act as soon as every neighbour heard at the last
    instant has sent its pose of this one: the waker fires on the last of them, not before."""
    a, b, c = (SwarmNode(NodeIdentity("alpha", uav), rendezvous).open() for uav in (1, 2, 3))
    pose = publish_pose
    try:
        assert c.expect_poses(time.time()) == 0  # nobody heard yet: nothing to wait for
        hear_a_round(c, a, b)  # each heard at the last instant, over the peers' direct links
        c.waker.clear()
        instant = time.time()
        assert c.expect_poses(instant) == 2
        pose(a)
        assert not c.waker.wait(0.3) and not c.expected_poses_in()  # one of two: keep waiting
        pose(b)
        assert c.waker.wait(3.0) and c.expected_poses_in()
        c.poll()
        assert all(n.last_recv >= instant for n in c.neighbours)  # what woke it: both poses of the instant

        # a pose that came before the owner asked, but after the instant, counts too
        c.stop_expecting_poses()
        assert not c.expected_poses_in()
        t_round = time.time()
        pose(a)
        pose(b)
        assert wait_for(lambda: (c.poll(), all(n.last_recv >= t_round for n in c.neighbours))[1], 3.0)
        instant = time.time()
        pose(a)
        assert wait_for(lambda: len(c._pose_inlet or []) == 1, 3.0)
        c.waker.clear()
        assert c.expect_poses(instant) == 2
        pose(b)
        assert c.waker.wait(3.0) and c.expected_poses_in()
        c.stop_expecting_poses()

        # through a netem shim a pose's arrival is not its delivery: due when the shim releases it
        with SwarmNode(NodeIdentity("alpha", 4), rendezvous, netem={"v2v": {"delay": {"ms": 200.0}}}) as d:
            assert wait_for(lambda: (pose(a), d.poll(), 1 in d.neighbours)[2], 10.0, period=0.1)
            time.sleep(0.3)
            d.poll()  # the last of those released
            t_round = time.time()
            pose(a)
            assert wait_for(lambda: (d.poll(), (nb := d.neighbours.get(1)) is not None and nb.last_recv >= t_round)[1], 3.0)
            instant = time.time()
            assert d.expect_poses(instant) == 1
            pose(a)
            assert d.waker.wait(3.0) and d.expected_poses_in()
            d.poll()  # the shim takes it in, and holds it
            due = d.expected_poses_due()
            assert due is not None and instant + 0.19 <= due <= instant + 0.4
            time.sleep(max(due - time.time(), 0.0) + 0.01)
            d.poll()
            nb = d.neighbours.get(1)
            assert d.expected_poses_due() is None and nb is not None and nb.last_recv == pytest.approx(due)
    finally:
        for n in (a, b, c):
            n.close()


def test_an_expectation_is_armed_safely_while_samples_pour_in(rendezvous: Rendezvous) -> None:
    """The owner arms an expectation (counting the samples already waiting) while the inlet's
    thread appends more: it must never fail ("deque mutated during iteration" once killed UAVs)."""
    with zenoh.open(to_zenoh(rendezvous.zenoh_config())) as s:
        waker = Waker()
        inlet = Inlet(512, None, how="thread")
        sub = subscribe(s, "t/flood", inlet)
        stop = threading.Event()

        def flood() -> None:
            pub = s.declare_publisher("t/flood")
            while not stop.is_set():
                for _ in range(50):
                    pub.put(b"x")
                time.sleep(0.0005)

        th = threading.Thread(target=flood)
        th.start()
        try:
            assert wait_for(lambda: len(inlet) > 100, 5.0)
            since, armed = time.time(), 0
            deadline = time.monotonic() + 1.5
            while time.monotonic() < deadline:
                inlet.expect(1_000_000, since, waker)  # scans the waiting samples while more come
                armed += 1
                for _ in inlet.drain(64):
                    pass
            assert armed > 100 and not inlet.expectation_met
            inlet.expect(1, since, waker)  # already met by what keeps coming
            assert waker.wait(2.0) and inlet.expectation_met
        finally:
            stop.set()
            th.join(5.0)
            sub.undeclare()
            assert inlet.join(2.0)
            waker.close()


def test_the_pose_inlet_counts_the_neighbours_poses_in_batches_and_wakes_at_the_last(rendezvous: Rendezvous) -> None:
    """On the edge feed the pose inlet's thread counts the poses in each batch of UAVs other than
    its owner's (as a UAV's node weighs them), a payload that is no batch as none, stamps with the
    inlet's clock, and wakes the owner on the batch that completes the instant; a count that
    fails counts nothing and the thread goes on."""
    me = 7

    def batch(*uavs: int) -> bytes:
        poses = [encode_pose(Pose(u, Realm.VIRTUAL, 1, 0.0, time.time(), 0.0, float(u), 5.0, 0.0, 0.0, 0.0, 0.0))
                 for u in uavs]
        return encode_pose_batch(PoseBatch(1, time.time(), list(uavs), poses))

    skew = 1000.0  # the inlet's own clock, a thousand seconds ahead of the wall's
    with zenoh.open(to_zenoh(rendezvous.zenoh_config())) as s:
        waker = Waker()
        inlet = Inlet(64, None, lambda: time.time() + skew, "thread",
                      weigh=lambda sample: batched_pose_count(sample.payload.to_bytes(), me))
        sub = subscribe(s, "t/feed", inlet)
        try:
            since = time.time() + skew
            inlet.expect(5, since, waker)  # five poses of others, as a UAV with five neighbours
            s.put("t/feed", batch(1, me, 2))  # two of others (its own pose is no neighbour's)
            s.put("t/feed", b"not a batch")  # none
            assert wait_for(lambda: len(inlet) == 2, 3.0)
            assert not waker.wait(0.2) and not inlet.expectation_met
            s.put("t/feed", batch(3, 4))  # four
            assert wait_for(lambda: len(inlet) == 3, 3.0)
            assert not waker.wait(0.2) and not inlet.expectation_met
            t_last = time.time()
            s.put("t/feed", batch(me, 5))  # five: the instant's last
            assert waker.wait(3.0) and inlet.expectation_met
            arrivals = list(inlet.drain())
            assert len(arrivals) == 4 and all(since <= at <= time.time() + skew for at, _ in arrivals)
            assert arrivals[-1][0] >= t_last + skew
            assert arrivals[1][1].payload.to_bytes() == b"not a batch"
            failing = Inlet(64, None, time.time, "thread", weigh=lambda sample: 1 // 0)
            sub2 = subscribe(s, "t/bad", failing)
            failing.expect(1, time.time(), waker)
            s.put("t/bad", batch(1))
            s.put("t/bad", batch(2))
            assert wait_for(lambda: len(failing) == 2, 3.0) and not failing.expectation_met
            sub2.undeclare()
            assert failing.join(2.0)
        finally:
            sub.undeclare()
            assert inlet.join(2.0)  # the thread leaves once its channel is closed
            waker.close()


def test_a_command_reaches_a_real_agent_and_is_acknowledged_within_10_ms(tmp_path: Path, router: str) -> None:
    """A virtual UAV process (its loop at 10 Hz) sleeps on its waker between ticks: a command is
    handled when it arrives, not at the next tick. Round trip measured 20 times; the p50 is asserted."""
    proc = start_virtual_uav(tmp_path, router, swarm="rtt")
    obs = SwarmObserver("rtt", Rendezvous((router,), mode="client"), name="test").open()
    try:
        assert wait_for(lambda: (obs.poll(), obs.phases().get(1) == "ready")[1], 60.0), "the UAV never became ready"
        rtts = []
        rng = random.Random(3)
        for _ in range(20):
            time.sleep(rng.uniform(0.02, 0.08))  # at any phase of the agent's 40 ms tick
            sent = time.time()
            p = obs.command("land", [1])  # on the ground: acknowledged ("on the ground"), nothing changes
            assert wait_for(lambda p=p: (obs.poll(), p.complete)[1], 5.0, period=0.001)
            assert p.acks[1].ok
            rtts.append(p.acked_at[1] - sent)
        assert statistics.median(rtts) <= 0.010, sorted(rtts)
    finally:
        obs.close()
        stop_process(proc)


@pytest.fixture
def edge_5ms() -> Iterator[Rendezvous]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    stop = threading.Event()
    th = threading.Thread(target=serve, args=([endpoint], stop, None, ["alpha"], 0.005), daemon=True)
    th.start()
    time.sleep(0.6)
    yield Rendezvous((endpoint,), mode="client")
    stop.set()
    th.join(5)


def test_the_edge_feed_forwards_each_pose_within_its_window_and_batches_those_that_share_it(edge_5ms: Rendezvous) -> None:
    keys = SwarmKeys("alpha")
    with zenoh.open(to_zenoh(edge_5ms.zenoh_config())) as s:
        feed = Inlet(1024)
        sub = subscribe(s, keys.pose_feed, feed)

        def flowing() -> bool:  # until the router's feed carries our poses
            s.put(keys.pose(1), encode_pose(Pose(1, Realm.VIRTUAL, 0, 0.0, time.time(), 0, 0, 0, 0, 0, 0, 0)))
            return len(feed) > 0

        assert wait_for(flowing, 10.0, period=0.1)
        time.sleep(0.1)
        list(feed.drain())
        waits, sizes = [], []
        for k in range(20):
            for uav in (1, 2, 3):  # three UAVs publish at once: their poses share a window
                pose = Pose(uav, Realm.VIRTUAL, k, 0.0, time.time(), 0, 0, 0, 0, 0, 0, 0)
                s.put(keys.pose(uav), encode_pose(pose))
            time.sleep(0.05)
            for _at, sample in feed.drain():
                batch = decode_pose_batch(sample.payload.to_bytes())
                sizes.append(len(batch.poses))
                waits += [batch.t_wall - decode_pose(p).t_wall for p in batch.poses]
        sub.undeclare()
    assert sum(sizes) == 60  # every pose, once
    assert len(sizes) < 60  # in fewer batches than poses
    assert statistics.median(waits) <= 0.005 + 0.005  # sent when its window closed, not 40 ms later


def _inlet_threads() -> int:
    return sum(1 for t in threading.enumerate() if t.name == "swarmnet-inlet" and t.is_alive())


def test_a_scenarios_feed_window_and_interest_reach_the_edge_router_of_its_run(tmp_path: Path) -> None:
    """``network.feed_window_ms`` and ``network.interest`` are planned once (``Scenario.network_plan``) and
    handed to the run's edge router (the process runtime), which says the window (ms) and interest it runs with."""
    from deploy.process_runtime import ProcessRuntime
    from mrswarm.scenario import load_scenario

    scn = load_scenario(Path(__file__).resolve().parents[1] / "scenarios" / "coverage.yaml",
                        ["network.security=off", "network.mode=client", "network.pose_feed=edge", "network.feed_window_ms=2.5",
                         "network.interest={radius_m: 30, far_rate_hz: 0.5}"])
    rt = ProcessRuntime(tmp_path)
    try:
        nets = rt.start_network(scn.network_plan({scn.swarm: None}))
        log = tmp_path / "logs" / "router.log"
        said = "window 2.5 ms), interest radius 30 m (+5), far 0.5 Hz"
        assert wait_for(lambda: said in (log.read_text() if log.exists() else ""), 20.0), \
            log.read_text() if log.exists() else "no router log"
        assert nets[scn.swarm].interest == scn.network.interest  # and the UAVs listen for their near feeds
    finally:
        rt.stop(grace=5.0)


def test_a_uav_alone_runs_no_receive_thread_until_another_uav_is_there(rendezvous: Rendezvous) -> None:
    """A blocked receive of zenoh-python wakes ten times a second, so a UAV's pose inlet starts
    its thread only with the first other UAV: alone, none runs. A UAV that joins starts it at its
    liveliness token, before its first pose; a pose that comes with no token (here a plain
    session's) starts it at the next poll, and is heard."""
    base = _inlet_threads()
    a = SwarmNode(NodeIdentity("alpha", 1), rendezvous).open()
    try:
        for _ in range(10):
            a.poll()
            time.sleep(0.05)
        assert a._pose_inlet is not None and not a._pose_inlet.started and _inlet_threads() == base
        with zenoh.open(to_zenoh(rendezvous.zenoh_config())) as s:
            pose = Pose(uav=7, realm=Realm.VIRTUAL, seq=1, t_sim=1.0, t_wall=time.time(), x=1.0, y=2.0, z=5.0,
                        vx=0.0, vy=0.0, vz=0.0, yaw=0.0)

            def heard() -> bool:
                pose.t_wall = time.time()
                s.put(SwarmKeys("alpha").pose(7), encode_pose(pose))
                time.sleep(0.05)
                a.poll()
                return 7 in a.neighbours

            assert wait_for(heard, 10.0, period=0.05)
        assert a._pose_inlet.started and _inlet_threads() == base + 1
    finally:
        a.close()
    assert wait_for(lambda: _inlet_threads() == base, 5.0)

    a = SwarmNode(NodeIdentity("alpha", 1), rendezvous).open()
    b = SwarmNode(NodeIdentity("alpha", 2), rendezvous).open()
    try:
        assert wait_for(lambda: (a.poll(), 2 in a.alive_uavs())[1], 10.0)
        assert a._pose_inlet is not None and a._pose_inlet.started  # at b's token, no pose yet
        assert 2 not in a.neighbours
        hear_a_round(a, b)
        assert a.stats.ages.transport.max < 1.0  # stamped as they arrived
    finally:
        a.close()
        b.close()
