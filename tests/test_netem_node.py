"""The netem shim inside real SwarmNodes: real Zenoh sessions on 127.0.0.1, real delays and drops."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

from swarmnet.connectivity import Rendezvous, to_zenoh
from swarmnet.keyspace import SwarmKeys
from swarmnet.messages import Realm, decode_ack
from swarmnet.netem.control import NetemSet, encode_netem_set
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.observer import SwarmObserver
from tests.conftest import wait_for

TICK = 0.04  # the UAV loop's poll period


def node(rdv: Rendezvous, uav: int, realm: Realm = Realm.VIRTUAL, netem: dict[str, Any] | None = None) -> SwarmNode:
    return SwarmNode(NodeIdentity("alpha", uav, realm), rdv, netem=netem).open()


@pytest.fixture
def opened() -> Iterator[list[Any]]:
    things: list[Any] = []
    yield things
    for t in things:
        t.close()


def meshed(nodes: list[SwarmNode], ids: set[int]) -> None:
    assert wait_for(lambda: all((n.poll(), ids <= n.alive_uavs())[1] for n in nodes), 10.0), "nodes did not see each other"


def settle(nodes: list[SwarmNode], seconds: float) -> None:
    """Poll every TICK for ``seconds``, as the UAV loop does, ending with a poll."""
    end = time.time() + seconds
    while time.time() < end:
        for n in nodes:
            n.poll(time.time())
        time.sleep(TICK)
    for n in nodes:
        n.poll(time.time())


def fly(pubs: list[SwarmNode], subs: list[SwarmNode], seconds: float, rate_hz: float = 10.0, drain: float = 1.0) -> None:
    """Publishers send poses at ``rate_hz``; receivers poll at the UAV tick; then drain ``drain`` s more."""
    t0 = time.time()
    next_pub = t0
    k = 0
    while time.time() < t0 + seconds + drain:
        now = time.time()
        if now >= next_pub and now < t0 + seconds:
            for i, p in enumerate(pubs):
                p.publish_pose(t_sim=k * 0.1, x=10.0 * i, y=float(k), z=10.0, vx=0.0, vy=1.0, vz=0.0, yaw=0.0)
            k += 1
            next_pub += 1.0 / rate_hz
        for s in subs:
            s.poll(time.time())
        time.sleep(TICK)


def link_stats(n: SwarmNode, src: int) -> dict[str, Any]:
    st = n.netem_stats()
    assert st is not None
    return st["links"][str(src)]


def test_a_delayed_link_delays_and_an_unimpaired_one_does_not(rendezvous: Rendezvous, opened: list[Any]) -> None:
    a = node(rendezvous, 1)
    b = node(rendezvous, 2, netem={"v2v": {"delay": {"ms": 250}}})
    c = node(rendezvous, 3)
    opened += [a, b, c]
    meshed([a, b, c], {1, 2, 3})
    fly([a], [b, c], 3.0)
    ls = link_stats(b, 1)
    assert ls["sent"] == ls["delivered"] == c.neighbours.get(1).received >= 25  # type: ignore[union-attr]
    age_b, age_c = b.stats.ages.transport, c.stats.ages.transport
    assert age_c.percentile(50) < 0.15  # the same poses without the shim
    # the shim adds 250 ms; the arrival instant is estimated within the 40 ms poll period
    assert 0.25 - TICK <= age_b.percentile(50) <= 0.25 + 0.3
    assert age_b.percentile(50) - age_c.percentile(50) == pytest.approx(0.25, abs=0.1)
    assert ls["delay"]["total"] / ls["delay"]["n"] == pytest.approx(0.25)


def test_transport_age_shows_a_fixed_netem_delay_exactly(rendezvous: Rendezvous, opened: list[Any]) -> None:
    """A 20 ms +- 0 profile: the transport age of the same poses is the unshimmed one plus 20 ms,
    within 1 ms at p50, however late the receiver polls (each pose is stamped on arrival and the
    shim delivers it at arrival + 20 ms)."""
    a = node(rendezvous, 1)
    b = node(rendezvous, 2, netem={"v2v": {"delay": {"ms": 20.0}}})
    c = node(rendezvous, 3)
    opened += [a, b, c]
    meshed([a, b, c], {1, 2, 3})
    ages: dict[int, dict[int, float]] = {2: {}, 3: {}}  # receiver -> pose seq -> transport age, s (exact, per pose)

    def take(n: SwarmNode) -> None:
        n.poll(time.time())
        nb = n.neighbours.get(1)
        if nb is not None:
            ages[n.identity.uav].setdefault(nb.pose.seq, nb.last_recv - nb.pose.t_wall)

    for k in range(60):
        a.publish_pose(t_sim=k * 0.1, x=0.0, y=float(k), z=10.0, vx=0.0, vy=0.0, vz=0.0, yaw=0.0)
        end = time.time() + 0.1
        while time.time() < end:  # poll more often than poses come, so each one is seen
            take(b)
            take(c)
            time.sleep(0.004)
    both = sorted(set(ages[2]) & set(ages[3]))
    assert len(both) >= 50
    shimmed = sorted(ages[2][q] for q in both)
    plain = sorted(ages[3][q] for q in both)
    assert min(plain) >= 0.0 and min(shimmed) >= 0.020
    p50 = len(both) // 2
    assert shimmed[p50] - plain[p50] == pytest.approx(0.020, abs=0.001)


def test_a_lossy_link_drops_and_the_neighbour_table_sees_the_gaps(rendezvous: Rendezvous, opened: list[Any]) -> None:
    a = node(rendezvous, 1)
    b = node(rendezvous, 2, netem={"seed": 5, "v2v": {"loss": {"model": "bernoulli", "p": 0.5}}})
    opened += [a, b]
    meshed([a, b], {1, 2})
    fly([a], [b], 4.0, rate_hz=20.0, drain=0.5)
    ls = link_stats(b, 1)
    assert ls["sent"] >= 60
    assert ls["delivered"] + ls["dropped"]["loss"] == ls["sent"]
    assert 0.3 < ls["dropped"]["loss"] / ls["sent"] < 0.7
    nb = b.neighbours.get(1)
    assert nb is not None and nb.received == ls["delivered"]
    assert nb.lost >= ls["dropped"]["loss"] - 3  # seq gaps (drops after the last delivered pose are not gaps yet)


def publish_set(rdv: Rendezvous, msg: NetemSet | bytes) -> None:
    s = zenoh.open(to_zenoh(Rendezvous(rdv.endpoints, mode="client").zenoh_config()))
    try:
        time.sleep(0.5)  # let the subscriber declarations reach this session
        s.put(SwarmKeys("alpha").netem_set, msg if isinstance(msg, bytes) else encode_netem_set(msg))
        time.sleep(0.2)
    finally:
        s.close()


def test_runtime_change_over_the_control_key_is_validated_counted_and_acked(rendezvous: Rendezvous, opened: list[Any]) -> None:
    a = node(rendezvous, 1)
    b = node(rendezvous, 2)  # starts without any shim
    obs = SwarmObserver("alpha", Rendezvous(rendezvous.endpoints, mode="client"), name="test").open()
    opened += [a, b, obs]
    meshed([a, b], {1, 2})
    assert wait_for(lambda: (obs.poll(), {1, 2} <= obs.alive_uavs())[1], 10.0)
    assert b.netem is None
    publish_set(rendezvous, NetemSet(id=77, sender="test", t_wall=time.time(), config={"v2v": {"delay": {"ms": 300}}}))
    assert wait_for(lambda: (b.poll(), b.netem is not None)[1], 5.0)
    assert b.stats.received["netem_set"] == 1
    assert b.netem_changes[-1]["id"] == 77 and b.netem_changes[-1]["t"] - b.netem_changes[-1]["t_sent"] < 1.0
    # the ack, as for a command
    acks = obs._subs["ack"]
    got: list[Any] = []

    def ack_seen(cmd_id: int, ok: bool) -> bool:
        for _at, s in acks.drain():
            got.append(decode_ack(s.payload.to_bytes()))
        return any(x.cmd_id == cmd_id and x.uav == 2 and x.ok is ok for x in got)

    assert wait_for(lambda: ack_seen(77, True), 5.0)
    assert "delay 300ms" in [x for x in got if x.cmd_id == 77][0].message
    fly([a], [b], 2.0)
    assert b.stats.ages.transport.percentile(50) >= 0.3 - TICK
    # an invalid config: refused, counted, nacked; the old one stays
    publish_set(rendezvous, NetemSet(id=78, sender="test", t_wall=time.time(),
                                     config={"v2v": {"loss": {"model": "bernoulli", "p": 2}}}))
    assert wait_for(lambda: (b.poll(), b.stats.rejected["bad_netem_config"] == 1)[1], 5.0)
    assert wait_for(lambda: ack_seen(78, False), 5.0)
    assert "v2v.loss.p" in [x for x in got if x.cmd_id == 78][0].message
    assert "delay 300ms" in b.netem.config.describe()  # type: ignore[union-attr]
    # garbage on the key and a change for someone else
    publish_set(rendezvous, b"{not json")
    publish_set(rendezvous, NetemSet(id=79, sender="test", t_wall=time.time(), targets=(1,), config={"preset": "none"}))
    assert wait_for(lambda: (b.poll(), a.poll(),
                             b.stats.rejected["malformed"] == 1 and a.stats.received["netem_set"] == 2)[2], 5.0)
    assert b.stats.received["netem_set"] == 1 and "delay 300ms" in b.netem.config.describe()  # type: ignore[union-attr]
    assert a.netem is not None and a.netem.config.preset == "none"


def test_commands_are_exempt_by_default_and_delayed_when_not(rendezvous: Rendezvous, opened: list[Any]) -> None:
    ground = {"ground": {"delay": {"ms": 400}}}
    exempt = node(rendezvous, 1, netem=ground)
    impaired = node(rendezvous, 2, netem={**ground, "exempt_commands": False})
    obs = SwarmObserver("alpha", Rendezvous(rendezvous.endpoints, mode="client"), name="gcs").open()
    opened += [exempt, impaired, obs]
    meshed([exempt, impaired], {1, 2})
    assert wait_for(lambda: (obs.poll(), {1, 2} <= obs.alive_uavs())[1], 10.0)
    settle([exempt, impaired], 0.3)
    sent = time.time()
    obs.command("land", [1, 2])
    arrived: dict[int, float] = {}
    deadline = time.time() + 5.0
    while time.time() < deadline and len(arrived) < 2:
        for n in (exempt, impaired):
            if n.poll(time.time()).commands:
                arrived[n.identity.uav] = time.time()
        time.sleep(TICK)
    assert set(arrived) == {1, 2}
    assert arrived[1] - sent < 0.3
    assert arrived[2] - sent >= 0.4 - TICK
    ls = impaired.netem_stats()["links"]["gcs:gcs"]  # type: ignore[index]
    assert ls["class"] == "ground" and ls["delivered"] == 1


def test_physical_links_are_impaired_only_on_the_virtual_side(rendezvous: Rendezvous, opened: list[Any]) -> None:
    cfg = {"v2v": {"delay": {"ms": 300}}, "v2p": {"delay": {"ms": 300}}}
    virt = node(rendezvous, 1)
    phys_tx = node(rendezvous, 2, Realm.PHYSICAL)
    phys_rx = node(rendezvous, 3, Realm.PHYSICAL, netem=cfg)
    opened += [virt, phys_tx, phys_rx]
    meshed([virt, phys_tx, phys_rx], {1, 2, 3})
    fly([virt, phys_tx], [phys_rx], 2.5)
    links = phys_rx.netem_stats()["links"]  # type: ignore[index]
    assert links["1"]["class"] == "v2p" and links["1"]["delay"]["total"] / links["1"]["delay"]["n"] == pytest.approx(0.3)
    assert links["2"]["class"] is None and links["2"]["delay"]["total"] == 0.0  # physical <-> physical: untouched
    n1, n2 = phys_rx.neighbours.get(1), phys_rx.neighbours.get(2)
    assert n1 is not None and n2 is not None
    assert n1.age(time.time()) > n2.age(time.time())


def test_stats_are_json_and_the_node_keeps_a_history_of_changes(rendezvous: Rendezvous, opened: list[Any]) -> None:
    b = node(rendezvous, 2, netem={"preset": "lte"})
    opened.append(b)
    b.set_netem({"preset": "degraded"}, source="test")
    st = b.netem_stats()
    assert st is not None and [c["source"] for c in st["changes"]] == ["config", "test"]
    assert st["preset"] == "degraded" and st["seed"] == 0
    json.dumps(st)
    b.set_netem(None)
    assert b.netem is None and b.netem_stats()["config"] == "off"  # type: ignore[index]


@pytest.fixture
def edge() -> Iterator[Rendezvous]:
    import threading

    from discovery.rendezvous import serve
    from tests.conftest import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    stop = threading.Event()
    th = threading.Thread(target=serve, args=([endpoint], stop, None, ["alpha"], 0.04), daemon=True)
    th.start()
    time.sleep(0.6)
    yield Rendezvous((endpoint,), mode="client")
    stop.set()
    th.join(5)


def test_edge_feed_batches_are_impaired_per_sender_with_link_overrides(edge: Rendezvous, opened: list[Any]) -> None:
    """One batch carries both neighbours' poses; only the link 1 -> 3 is slowed down."""
    pubs = [SwarmNode(NodeIdentity("alpha", i), edge, pose_feed="edge").open() for i in (1, 2)]
    rx = SwarmNode(NodeIdentity("alpha", 3), edge, pose_feed="edge",
                   netem={"links": [{"src": 1, "dst": 3, "delay": {"ms": 300}}]}).open()
    opened += [*pubs, rx]
    meshed([*pubs, rx], {1, 2, 3})
    fly(pubs, [rx], 3.0)
    links = rx.netem_stats()["links"]  # type: ignore[index]
    assert links["1"]["delay"]["total"] / links["1"]["delay"]["n"] == pytest.approx(0.3)
    assert links["2"]["delay"]["total"] == 0.0 and links["2"]["sent"] == links["2"]["delivered"] >= 25
    assert rx.stats.received["pose_batch"] >= 25
    n1, n2 = rx.neighbours.get(1), rx.neighbours.get(2)
    assert n1 is not None and n2 is not None and n1.received == links["1"]["delivered"]
    now = time.time()
    assert n1.age(now) > n2.age(now)


def test_swarm_messages_go_through_the_same_link_as_poses(rendezvous: Rendezvous, opened: list[Any]) -> None:
    a = node(rendezvous, 1)
    b = node(rendezvous, 2, netem={"v2v": {"delay": {"ms": 300}}})
    opened += [a, b]
    meshed([a, b], {1, 2})
    settle([a, b], 0.3)
    sent = time.time()
    a.send("chat", {"hello": 1})
    a.send("direct", "hi", to=2)
    got: dict[str, float] = {}
    deadline = time.time() + 5.0
    while time.time() < deadline and len(got) < 2:
        for m in b.poll(time.time()).messages:
            got[m.topic] = time.time()
        time.sleep(TICK)
    assert set(got) == {"chat", "direct"}
    assert min(got.values()) - sent >= 0.3 - TICK
    ls = link_stats(b, 1)
    assert ls["sent"] == ls["delivered"] == 2 and b.stats.received["broadcast"] == b.stats.received["unicast"] == 1


def test_a_ground_station_impairs_the_uav_that_shares_its_node_id(rendezvous: Rendezvous, opened: list[Any]) -> None:
    """Node ids of different roles are separate: a gcs with id 1 still hears UAV 1 through the shim."""
    uav = node(rendezvous, 1)
    gcs = SwarmObserver("alpha", rendezvous, node_id=1, role="gcs", name="gcs").open()
    opened += [uav, gcs]
    gcs.node.set_netem({"ground": {"delay": {"ms": 300}}}, source="test")
    assert wait_for(lambda: (gcs.poll(), 1 in gcs.alive_uavs())[1], 10.0)
    fly([uav], [gcs.node], 2.0)
    ls = link_stats(gcs.node, 1)
    assert ls["class"] == "ground" and ls["sent"] == ls["delivered"] >= 15
    assert ls["delay"]["total"] / ls["delay"]["n"] == pytest.approx(0.3)
    assert gcs.stats.rejected == {}  # the same id in another role is not our own id
