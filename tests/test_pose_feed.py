"""The edge pose feed: batches of validated poses from the edge router, isolation, bad input."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import msgpack
import pytest
import zenoh

from discovery.rendezvous import serve
from swarmnet.connectivity import Rendezvous, to_zenoh
from swarmnet.keyspace import SwarmKeys
from swarmnet.messages import (
    BATCH_VERSION,
    MAX_BATCH_BYTES,
    Kind,
    Pose,
    PoseBatch,
    Realm,
    batched_pose_count,
    decode_pose_batch,
    encode_pose,
    encode_pose_batch,
    tag,
)
from swarmnet.node import NodeIdentity, SwarmNode
from tests.conftest import free_port, wait_for
from tests.pose_rounds import hear_a_round, publish_pose


@pytest.fixture
def edge() -> Iterator[Rendezvous]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    stop = threading.Event()
    th = threading.Thread(target=serve, args=([endpoint], stop, None, ["alpha", "beta"], 0.04), daemon=True)
    th.start()
    time.sleep(0.6)
    yield Rendezvous((endpoint,), mode="client")
    stop.set()
    th.join(5)


def test_batch_codec_round_trip_and_limits() -> None:
    p = encode_pose(Pose(3, Realm.VIRTUAL, 1, 1.0, time.time(), 1, 2, 3, 0, 0, 0, 0))
    b = decode_pose_batch(encode_pose_batch(PoseBatch(7, time.time(), [3, 4], [p, p])))
    assert b.seq == 7 and b.poses == [p, p] and b.senders == [3, 4]
    from swarmnet.messages import DecodeError
    v = BATCH_VERSION
    with pytest.raises(DecodeError):  # a 49-byte "pose" inside a batch
        decode_pose_batch(msgpack.packb([tag(Kind.POSE_BATCH, v), 1, 1, [3], [bytes(49)]], use_bin_type=True))
    with pytest.raises(DecodeError):
        decode_pose_batch(msgpack.packb([tag(Kind.POSE_BATCH, v), 1, 1, [3], ["not bytes"]], use_bin_type=True))
    with pytest.raises(DecodeError):  # a sender per pose
        decode_pose_batch(msgpack.packb([tag(Kind.POSE_BATCH, v), 1, 1, [], [p]], use_bin_type=True))
    with pytest.raises(DecodeError):
        decode_pose_batch(msgpack.packb([tag(Kind.POSE_BATCH, v), 1, 1, [0], [p]], use_bin_type=True))
    with pytest.raises(DecodeError):  # version 1 carried no senders
        decode_pose_batch(msgpack.packb([tag(Kind.POSE_BATCH, 1), 1, 1, [p]], use_bin_type=True))


def test_a_batch_is_counted_without_decoding_and_bad_input_counts_nothing() -> None:
    """What the edge-feed inlet's thread counts towards an instant's poses: the neighbours' poses
    in a batch, not the UAV's own; anything that is not a batch counts 0, never raises."""
    p = encode_pose(Pose(3, Realm.VIRTUAL, 1, 1.0, time.time(), 1, 2, 3, 0, 0, 0, 0))
    batch = encode_pose_batch(PoseBatch(7, time.time(), [3, 4, 5], [p, p, p]))
    assert batched_pose_count(batch) == 3
    assert batched_pose_count(batch, exclude=4) == 2
    for bad in (b"", b"\xc1", encode_pose(Pose(3, Realm.VIRTUAL, 1, 1.0, time.time(), 1, 2, 3, 0, 0, 0, 0)),
                msgpack.packb([tag(Kind.POSE_BATCH, BATCH_VERSION), 1, 1, 5, [p]], use_bin_type=True),
                msgpack.packb({"senders": [1, 2]}), bytes(MAX_BATCH_BYTES + 1), batch[:-3]):
        assert batched_pose_count(bad) == 0, bad


def test_edge_feed_delivers_every_pose_in_batches_per_swarm(edge: Rendezvous) -> None:
    nodes = [SwarmNode(NodeIdentity("alpha", i), edge, pose_feed="edge").open() for i in (1, 2, 3)]
    other = SwarmNode(NodeIdentity("beta", 1), edge, pose_feed="edge").open()
    try:
        assert wait_for(lambda: all((n.poll(), n.alive_uavs() == {1, 2, 3})[1] for n in nodes), 5.0)
        time.sleep(0.3)
        for k in range(10):
            for i, n in enumerate(nodes):
                n.publish_pose(t_sim=k * 0.1, x=float(i), y=float(k), z=5.0, vx=0, vy=0, vz=0, yaw=0)
            other.publish_pose(t_sim=0, x=99, y=99, z=5, vx=0, vy=0, vz=0, yaw=0)
            time.sleep(0.1)
        time.sleep(0.3)
        for n in nodes:
            n.poll()
            assert sorted(nb.uav for nb in n.neighbours) == sorted({1, 2, 3} - {n.identity.uav})
            assert all(nb.received == 10 and nb.lost == 0 and nb.pose.y == 9.0 for nb in n.neighbours)
            assert 5 <= n.stats.received["pose_batch"] <= 40  # batches, not a message per pose
            assert n.stats.rejected == {}  # our own pose in the batch is not a rejection
        other.poll()
        assert len(other.neighbours) == 0  # beta's feed carries only beta
    finally:
        for n in nodes + [other]:
            n.close()


def test_without_a_shim_batches_land_as_through_the_stages(edge: Rendezvous) -> None:
    """A UAV without a netem shim takes a batch's poses straight into its table (the fast path);
    one with a pass-through shim runs every stage. Fed the same batches, honest and forged,
    they end with the same neighbours, counters, rejections and number of transport ages."""
    keys = SwarmKeys("alpha")
    senders = [SwarmNode(NodeIdentity("alpha", i), edge, pose_feed="edge").open() for i in (1, 2)]
    fast = SwarmNode(NodeIdentity("alpha", 3), edge, pose_feed="edge").open()
    staged = SwarmNode(NodeIdentity("alpha", 4), edge, pose_feed="edge", netem={"preset": "none"}).open()
    forger = zenoh.open(to_zenoh(edge.zenoh_config()))
    try:
        assert fast.netem is None and staged.netem is not None
        assert wait_for(lambda: all((n.poll(), {1, 2} <= n.alive_uavs())[1] for n in (fast, staged)), 5.0)
        time.sleep(0.3)
        for k in range(10):
            for i, n in enumerate(senders):
                n.publish_pose(t_sim=k * 0.1, x=float(i), y=float(k), z=5.0, vx=0, vy=0, vz=0, yaw=0)
            time.sleep(0.1)
        p2 = encode_pose(Pose(2, Realm.VIRTUAL, 1, 0.0, time.time(), 0, 0, 0, 0, 0, 0, 0))
        p7 = encode_pose(Pose(7, Realm.VIRTUAL, 1, 0.0, time.time(), 7, 7, 7, 0, 0, 0, 0))
        forger.put(keys.pose_feed, encode_pose_batch(PoseBatch(1, time.time(), [5, 7], [p2, p7])))  # 1 of 2 forged
        time.sleep(0.4)
        outcome = []
        for n in (fast, staged):
            n.poll()
            table = sorted((nb.uav, nb.received, nb.lost, nb.pose.x, nb.pose.y) for nb in n.neighbours)
            outcome.append((table, n.stats.received["pose"], dict(n.stats.rejected), n.stats.ages.transport.n))
        assert outcome[0] == outcome[1]
        table, received, rejected, ages = outcome[0]
        assert table == [(1, 10, 0, 0.0, 9.0), (2, 10, 0, 1.0, 9.0), (7, 1, 0, 7.0, 7.0)]
        assert received == 21 and ages == 21 and rejected == {"key_mismatch": 1}
        assert fast.stats.received["pose_batch"] == staged.stats.received["pose_batch"] >= 5
    finally:
        forger.close()
        for n in senders + [fast, staged]:
            n.close()


def test_edge_feed_drops_invalid_and_spoofed_poses(edge: Rendezvous) -> None:
    keys = SwarmKeys("alpha")
    with SwarmNode(NodeIdentity("alpha", 1), edge, pose_feed="edge") as victim, \
            zenoh.open(to_zenoh(edge.zenoh_config())) as attacker:
        time.sleep(0.4)
        attacker.put(keys.pose(5), b"\xc1garbage")
        attacker.put(keys.pose(5), encode_pose(Pose(2, Realm.VIRTUAL, 1, 0.0, time.time(), 0, 0, 0, 0, 0, 0, 0)))  # spoofed
        attacker.put(keys.pose_feed, b"\x00junk")  # a forged batch straight on the feed key
        attacker.put(keys.pose(6), encode_pose(Pose(6, Realm.VIRTUAL, 1, 0.0, time.time(), 1, 1, 1, 0, 0, 0, 0)))  # valid
        assert wait_for(lambda: (victim.poll(), 6 in victim.neighbours)[1], 3.0)
        assert sorted(nb.uav for nb in victim.neighbours) == [6]
        assert victim.stats.rejected["malformed"] == 1  # the forged batch; the feed filtered the rest


def test_a_batched_pose_must_name_the_sender_the_batch_lists(edge: Rendezvous) -> None:
    """Receivers check the key rule inside batches too: a batch claiming UAV 5 sent UAV 2's pose is refused."""
    keys = SwarmKeys("alpha")
    p2 = encode_pose(Pose(2, Realm.VIRTUAL, 1, 0.0, time.time(), 0, 0, 0, 0, 0, 0, 0))
    p7 = encode_pose(Pose(7, Realm.VIRTUAL, 1, 0.0, time.time(), 1, 1, 1, 0, 0, 0, 0))
    with SwarmNode(NodeIdentity("alpha", 1), edge, pose_feed="edge") as victim, \
            zenoh.open(to_zenoh(edge.zenoh_config())) as forger:
        time.sleep(0.4)
        forger.put(keys.pose_feed, encode_pose_batch(PoseBatch(1, time.time(), [5, 7], [p2, p7])))
        assert wait_for(lambda: (victim.poll(), 7 in victim.neighbours)[1], 3.0)
        assert sorted(nb.uav for nb in victim.neighbours) == [7]  # the honest pose of the batch is kept
        assert victim.stats.rejected["key_mismatch"] == 1


def test_a_uav_on_the_edge_feed_wakes_once_the_poses_of_an_instant_are_in(edge: Rendezvous) -> None:
    """Aligned ticks on the edge feed: the UAV counts the neighbours' poses inside the batches as
    they arrive and is woken on the last one expected (one from each neighbour heard at the
    instant before), not by its own pose coming back in the swarm's batch."""
    a, b, c = (SwarmNode(NodeIdentity("alpha", uav), edge, pose_feed="edge").open() for uav in (1, 2, 3))
    pose = publish_pose
    try:
        hear_a_round(c, a, b, settle_s=0.3)  # each heard at the last instant, through the router's feed
        c.waker.clear()
        instant = time.time()
        assert c.expect_poses(instant) == 2
        pose(a)
        pose(c)  # its own, back in the swarm's batch: not a neighbour's
        assert not c.waker.wait(0.4) and not c.expected_poses_in()  # one of two: keep waiting
        pose(b)
        assert c.waker.wait(3.0) and c.expected_poses_in()
        c.poll()
        assert all(n.last_recv >= instant for n in c.neighbours)  # what woke it: both poses of the instant
        assert c.stats.received["pose_batch"] > 0
        c.stop_expecting_poses()
    finally:
        for n in (a, b, c):
            n.close()
