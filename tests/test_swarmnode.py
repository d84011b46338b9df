"""SwarmNode between real Zenoh sessions on 127.0.0.1 (router rendezvous, peer mesh)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import msgpack
import pytest
import zenoh

from swarmnet.connectivity import Rendezvous, to_zenoh
from swarmnet.keyspace import SwarmKeys
from swarmnet.messages import Command, Kind, Pose, Realm, Telemetry, encode_command, encode_pose, encode_telemetry, tag
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.observer import SwarmObserver
from tests.conftest import wait_for


def see_each_other(*ns: SwarmNode) -> bool:
    """Wait until every node holds every other's liveliness token: declarations travel in order, so
    each node then also knows the others' subscribers and a single pose is not dropped for want of a route."""
    want = {n.identity.uav for n in ns}
    return wait_for(lambda: all((n.poll(), want <= n.alive_uavs() | {n.identity.uav})[1] for n in ns), 5.0)


@pytest.fixture
def nodes(rendezvous: Rendezvous) -> Iterator[list[SwarmNode]]:
    ns = [SwarmNode(NodeIdentity("alpha", i), rendezvous).open() for i in (1, 2, 3)]
    assert wait_for(lambda: all(len(n.peers()) >= 2 for n in ns), 5.0), "peers did not mesh"
    assert see_each_other(*ns)
    yield ns
    for n in ns:
        n.close()


def publish_round(ns: list[SwarmNode], k: int) -> None:
    for i, n in enumerate(ns):
        n.publish_pose(t_sim=k * 0.1, x=float(i), y=float(k), z=10.0, vx=0.0, vy=1.0, vz=0.0, yaw=0.0)


def test_poses_flow_between_all_nodes_and_fill_the_neighbour_table(nodes: list[SwarmNode]) -> None:
    for k in range(10):
        publish_round(nodes, k)
        time.sleep(0.05)
    for n in nodes:
        assert wait_for(lambda n=n: (n.poll(), len(n.neighbours) == 2 and all(x.received == 10 for x in n.neighbours))[1], 3.0)
        for nb in n.neighbours:
            assert nb.lost == 0 and nb.uav != n.identity.uav
            assert nb.pose.y == 9.0
            assert 10 <= nb.rate <= 40  # published every 50 ms
        assert n.stats.ages.transport.n == 20
        assert n.stats.ages.transport.percentile(99) < 1.0
        assert not n.stats.ages.negative  # one host, one clock: a pose never arrives before it was sent
    # the mesh is direct: every node links to the other two (plus the router)
    assert all(len(n.peers()) >= 2 for n in nodes)


def test_sequence_gaps_count_as_loss(nodes: list[SwarmNode]) -> None:
    a, b = nodes[0], nodes[1]
    for k in range(6):
        a.publish_pose(t_sim=0.0, x=0, y=0, z=0, vx=0, vy=0, vz=0, yaw=0)
        if k in (2, 3):  # pretend two poses were lost in the network: skip their seq numbers
            a._seq["pose"] += 1
        time.sleep(0.02)
    assert wait_for(lambda: (b.poll(), (nb := b.neighbours.get(1)) is not None and nb.received == 6)[1], 3.0)
    nb = b.neighbours.get(1)
    assert nb is not None and nb.lost == 2 and nb.loss == pytest.approx(2 / 8)


def test_swarms_are_isolated(rendezvous: Rendezvous) -> None:
    with SwarmNode(NodeIdentity("alpha", 1), rendezvous) as a, SwarmNode(NodeIdentity("beta", 1), rendezvous) as b, \
            SwarmNode(NodeIdentity("alpha", 2), rendezvous) as a2:
        assert see_each_other(a, a2)
        time.sleep(0.3)  # beta's UAV has no token of alpha's to wait for: give its links the same time
        for _ in range(5):
            a.publish_pose(t_sim=0, x=1, y=1, z=1, vx=0, vy=0, vz=0, yaw=0)
            b.publish_pose(t_sim=0, x=2, y=2, z=2, vx=0, vy=0, vz=0, yaw=0)
            a.send("chat", "for alpha")
            b.send("chat", "for beta")
            time.sleep(0.02)
        time.sleep(0.3)
        inbox_a2 = a2.poll()
        inbox_b = b.poll()
        assert [nb.uav for nb in a2.neighbours] == [1] and a2.neighbours.get(1).pose.x == 1.0  # type: ignore[union-attr]
        assert len(b.neighbours) == 0  # beta's only UAV hears nobody from alpha
        assert {m.body for m in inbox_a2.messages} == {"for alpha"}
        assert inbox_b.messages == []
        assert a2.alive_uavs() == {1, 2} and b.alive_uavs() == {1}


def test_broadcast_and_unicast(nodes: list[SwarmNode]) -> None:
    a, b, c = nodes
    a.send("task/claim", {"cell": [3, 4]})
    a.send("direct", [1, 2, 3], to=2)
    time.sleep(0.3)
    ib, ic = b.poll(), c.poll()
    assert sorted(m.topic for m in ib.messages) == ["direct", "task/claim"]
    assert [m.topic for m in ic.messages] == ["task/claim"]
    direct = next(m for m in ib.messages if m.topic == "direct")
    assert (direct.src, direct.dst, direct.body) == (1, 2, [1, 2, 3])


def test_commands_reach_one_uav_or_the_whole_swarm(nodes: list[SwarmNode], rendezvous: Rendezvous) -> None:
    keys = SwarmKeys("alpha")
    with zenoh.open(to_zenoh(rendezvous.zenoh_config())) as gcs:
        time.sleep(0.3)
        gcs.put(keys.cmd(2), encode_command(Command("gcs", 1, 2, "hold", {}, time.time())))
        gcs.put(keys.swarm_cmd, encode_command(Command("gcs", 2, 0, "land", {}, time.time())))
        time.sleep(0.3)
        got = {n.identity.uav: [c.verb for c in n.poll().commands] for n in nodes}
    assert got == {1: ["land"], 2: ["hold", "land"], 3: ["land"]}


def test_bad_input_is_counted_not_raised(nodes: list[SwarmNode], rendezvous: Rendezvous) -> None:
    keys = SwarmKeys("alpha")
    victim = nodes[0]
    good = encode_pose(Pose(2, Realm.VIRTUAL, 1, 0.0, time.time(), 0, 0, 0, 0, 0, 0, 0))
    with zenoh.open(to_zenoh(rendezvous.zenoh_config())) as attacker:
        time.sleep(0.3)
        attacker.put(keys.pose(5), b"\xc1garbage")  # not msgpack
        attacker.put(keys.pose(5), bytes(200))  # oversized
        attacker.put(keys.pose(5), msgpack.packb([tag(Kind.POSE, 9)] + [1] * 12))  # future version
        attacker.put(keys.pose(5), good)  # payload claims UAV 2 on UAV 5's key: spoofing
        attacker.put(keys.pose(1), encode_pose(Pose(1, Realm.VIRTUAL, 1, 0.0, time.time(), 0, 0, 0, 0, 0, 0, 0)))  # our own id
        attacker.put(keys.swarm_cmd, b"\x00\x01")
        attacker.put(keys.broadcast(2, "x"), msgpack.packb([1, 2, 3]))
        time.sleep(0.3)
        inbox = victim.poll()
    r = victim.stats.rejected
    assert r["malformed"] == 2 and r["oversized"] == 1 and r["wrong_version"] == 1
    assert r["key_mismatch"] == 1 and r["own_id"] == 1 and r["wrong_type"] == 1
    assert len(victim.neighbours) == 0 and inbox.commands == [] and inbox.messages == []
    # and the node keeps working
    nodes[1].publish_pose(t_sim=0, x=0, y=0, z=0, vx=0, vy=0, vz=0, yaw=0)
    assert wait_for(lambda: (victim.poll(), 2 in victim.neighbours)[1], 3.0)


def test_a_node_that_stops_polling_loses_old_data_but_never_stalls_the_link(rendezvous: Rendezvous) -> None:
    with (SwarmNode(NodeIdentity("alpha", 1), rendezvous, ring_size=64) as slow,
          SwarmNode(NodeIdentity("alpha", 2), rendezvous) as fast):
        assert see_each_other(slow, fast)
        for i in range(3000):  # flood broadcasts while nobody drains them
            fast.send("flood", i)
        for _ in range(5):
            fast.publish_pose(t_sim=0, x=0, y=0, z=0, vx=0, vy=0, vz=0, yaw=0)
            time.sleep(0.02)
        time.sleep(0.3)
        inbox = slow.poll()
        assert len(inbox.messages) <= 256  # bounded ring: only the newest survive
        assert inbox.messages[-1].body == 2999
        assert slow.neighbours.get(2) is not None and slow.neighbours.get(2).received == 5  # type: ignore[union-attr]


def test_liveliness_tracks_join_and_leave(rendezvous: Rendezvous) -> None:
    with SwarmNode(NodeIdentity("alpha", 1), rendezvous) as watcher:
        other = SwarmNode(NodeIdentity("alpha", 2), rendezvous).open()
        assert wait_for(lambda: (watcher.poll(), 2 in watcher.alive_uavs())[1], 5.0)
        other.close()
        assert wait_for(lambda: (watcher.poll(), 2 not in watcher.alive_uavs())[1], 5.0)


def test_stale_neighbours_are_hidden_then_forgotten(rendezvous: Rendezvous) -> None:
    with SwarmNode(NodeIdentity("alpha", 1), rendezvous, stale_after=0.3, forget_after=0.8) as a, \
            SwarmNode(NodeIdentity("alpha", 2), rendezvous) as b:
        assert see_each_other(a, b)
        b.publish_pose(t_sim=0, x=0, y=0, z=0, vx=0, vy=0, vz=0, yaw=0)
        assert wait_for(lambda: (a.poll(), 2 in a.neighbours)[1], 3.0)
        now = time.time()
        assert [n.uav for n in a.neighbours.fresh(now)] == [2]
        time.sleep(0.4)
        assert a.neighbours.fresh(time.time()) == [] and 2 in a.neighbours
        time.sleep(0.5)
        a.poll()
        assert 2 not in a.neighbours


def test_poll_drains_at_most_max_samples_per_stream_and_keeps_the_rest_in_order(nodes: list[SwarmNode]) -> None:
    a, b = nodes[0], nodes[1]
    for i in range(50):
        a.send("count", i)
    time.sleep(0.3)
    got = [m.body for m in b.poll(max_samples=20).messages]
    assert got == list(range(20))  # one call never drains more than its budget
    sizes: list[int] = []

    def drained() -> bool:
        batch = b.poll(max_samples=20).messages
        sizes.append(len(batch))
        got.extend(m.body for m in batch)
        return len(got) >= 50

    assert wait_for(drained, 3.0)
    assert got == list(range(50)) and max(sizes) <= 20  # nothing lost, nothing reordered


def test_the_observer_applies_the_same_key_rule_to_telemetry(rendezvous: Rendezvous) -> None:
    keys = SwarmKeys("alpha")

    def telemetry(uav: int) -> bytes:
        return encode_telemetry(Telemetry(uav, Realm.VIRTUAL, 1, time.time(), "GUIDED", True, 0.5, 12.0, 1.0, 2.0, 3.0, 1.0))

    with SwarmObserver("alpha", rendezvous) as obs, zenoh.open(to_zenoh(rendezvous.zenoh_config())) as attacker:
        time.sleep(0.4)
        attacker.put(keys.telemetry(5), telemetry(2))  # UAV 2's telemetry on UAV 5's key: spoofing
        attacker.put(keys.telemetry(5), b"\xc1")
        attacker.put(keys.telemetry(6), telemetry(6))
        assert wait_for(lambda: (obs.poll(), 6 in obs.uavs)[1], 3.0)
        assert sorted(obs.uavs) == [6] and obs.uavs[6].telemetry is not None
        assert obs.stats.rejected["key_mismatch"] == 1 and obs.stats.rejected["malformed"] == 1
        assert obs.stats.received["telemetry"] == 1


def test_members_follow_the_swarms_tokens(rendezvous: Rendezvous) -> None:
    """A cooperative mission splits its work by ``members()`` every tick: the UAVs whose token is
    there and the node's own, in order, kept between ticks and new as soon as a UAV joins or leaves."""
    a = SwarmNode(NodeIdentity("alpha", 5), rendezvous).open()
    b = SwarmNode(NodeIdentity("alpha", 2), rendezvous).open()
    c = SwarmNode(NodeIdentity("alpha", 9), rendezvous).open()
    try:
        assert wait_for(lambda: (a.poll(), a.members() == (2, 5, 9))[1], 10.0), a.members()
        assert a.members() is a.members()  # the same tuple while nobody joins or leaves
        c.close()
        assert wait_for(lambda: (a.poll(), a.members() == (2, 5))[1], 10.0), a.members()
        b.close()
        assert wait_for(lambda: (a.poll(), a.members() == (5,))[1], 10.0), a.members()
    finally:
        for n in (a, b, c):
            n.close()
