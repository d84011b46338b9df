"""Spatial interest (docs/scale.md): full-rate poses only within the radius, across its border, secured."""

from __future__ import annotations

import contextlib
import os
import random
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import yaml
import zenoh

from discovery.options import FeedOptions
from discovery.rendezvous import main as router_main
from groundfloor.schema import ConfigError, convert
from mrswarm.scenario import ScenarioError, load_scenario
from swarmnet.connectivity import Rendezvous, to_zenoh
from swarmnet.feed import PoseFeed
from swarmnet.interest import Interest, NearFilter, PoolMembers, pool_groups
from swarmnet.keyspace import SwarmKeys
from swarmnet.messages import Pose, Realm, decode_pose_batch, encode_pose
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.security.acl import access_control
from swarmnet.security.credentials import Credentials
from swarmnet.security.identity import NodeName
from swarmnet.security.pki import KeyDir
from swarmnet.shared_session import SharedSession
from tests.conftest import free_port, wait_for

ROOT = Path(__file__).resolve().parents[1]
SWARM = "alpha"
RADIUS, MARGIN, FAR_HZ = 20.0, 5.0, 1.0


def test_interest_config_names_the_field(tmp_path: Path) -> None:
    assert convert({"radius_m": 30}, Interest) == Interest(radius_m=30.0, margin_m=5.0, far_rate_hz=1.0)
    with pytest.raises(ConfigError, match="margin_m"):
        convert({"radius_m": 3, "margin_m": 5}, Interest)
    with pytest.raises(ConfigError, match="far_rate_hz"):
        convert({"radius_m": 30, "far_rate_hz": -1}, Interest)
    base = yaml.safe_load((ROOT / "scenarios" / "coverage.yaml").read_text())
    scn = tmp_path / "s.yaml"

    def network(net: dict) -> Path:
        scn.write_text(yaml.safe_dump({**base, "network": net}))
        return scn

    with pytest.raises(ScenarioError, match=r"network\.interest.*pose_feed: edge"):
        load_scenario(network({"pose_feed": "direct", "interest": {"radius_m": 30}}))
    assert load_scenario(network({"interest": {"radius_m": 30}})).network.pose_feed == "edge"  # unset: the feed it needs
    with pytest.raises(ScenarioError, match=r"network\.interest\.radius_m"):
        load_scenario(network({"pose_feed": "edge", "interest": {"radius_m": 0}}))
    loaded = load_scenario(network({"pose_feed": "edge", "interest": {"radius_m": 30, "far_rate_hz": 0.5}}))
    assert loaded.network.interest == Interest(radius_m=30.0, far_rate_hz=0.5)

def test_near_filter_keeps_a_pair_at_full_rate_within_the_margin() -> None:
    """The border: in at radius, out only past radius + margin (no flapping), far senders on the shared feed."""
    f = NearFilter(Interest(radius_m=RADIUS, margin_m=MARGIN, far_rate_hz=FAR_HZ))
    t = 100.0
    f.seen(1, 0.0, 0.0, t)
    f.seen(2, RADIUS - 0.1, 0.0, t)
    f.seen(3, RADIUS + 0.1, 0.0, t)
    assert f.split([1, 2, 3], t) == ([1, 2, 3], {})  # everyone's first pose goes to the whole swarm
    t += 0.1
    far, near = f.split([1, 2, 3], t)
    assert far == [] and near == {2: [1, 3], 1: [2], 3: [2]}  # 3 is 20.1 m from 1: not near it; 0.2 m from 2
    f.seen(2, RADIUS + MARGIN - 0.1, 0.0, t)  # 2 drifts out past the radius, within the margin: stays near
    t += 0.1
    far, near = f.split([2], t)
    assert 1 in near and near[1] == [2]
    f.seen(2, RADIUS + MARGIN + 0.1, 0.0, t)  # past the margin: out
    t += 0.1
    far, near = f.split([2], t)
    assert 1 not in near
    f.seen(2, RADIUS + 1.0, 0.0, t)  # back inside the margin but not inside the radius: stays out
    t += 0.1
    assert 1 not in f.split([2], t)[1]
    t += 1.0  # a second later every sender is due on the shared feed again
    assert f.split([1, 2, 3], t)[0] == [1, 2, 3]


def test_a_pool_gets_one_near_batch_with_the_union_of_its_uavs_senders_each_once() -> None:
    """Pool 1 hosts UAVs 1 and 2: its one batch holds every sender near either, each once (UAV 6
    is near both); the UAVs outside any pool get what they got without pools."""
    interest = Interest(radius_m=RADIUS, margin_m=MARGIN, far_rate_hz=FAR_HZ)
    where = {1: (0.0, 0.0), 2: (10.0, 0.0), 3: (25.0, 0.0), 4: (40.0, 0.0), 5: (500.0, 0.0), 6: (5.0, 10.0)}
    plain, pooled = NearFilter(interest), NearFilter(interest, {1: "pool-1", 2: "pool-1"})
    t = 100.0
    for f in (plain, pooled):
        for u, (x, y) in where.items():
            f.seen(u, x, y, t)
        assert f.split(list(where), t)[0] == list(where)  # first poses: the shared feed, for everyone
    t += 0.1
    _, alone = plain.split(list(where), t)
    _, grouped = pooled.split(list(where), t)
    assert alone[1] == [2, 6] and alone[2] == [1, 3, 6]  # 6 near both pool-mates: twice without pools
    assert grouped["pool-1"] == [1, 2, 3, 6]  # once with them: the union, each sender once, in sending order
    assert 1 not in grouped and 2 not in grouped
    assert {d: s for d, s in grouped.items() if d != "pool-1"} == {d: s for d, s in alone.items() if d not in (1, 2)}
    assert grouped[3] == [2, 4] and 5 not in grouped  # a UAV outside the pool: as before, its own batch


def test_pooled_batches_are_the_union_of_the_members_batches_as_they_move() -> None:
    """Random swarms on the move, hysteresis included: each pool's batch is exactly the union of what
    its UAVs would get alone, without a repeat; everyone else's batch is unchanged."""
    rng = random.Random(7)
    interest = Interest(radius_m=RADIUS, margin_m=MARGIN, far_rate_hz=0.0)
    ids = list(range(1, 61))
    pools = [PoolMembers(number=k + 1, uavs=tuple(ids[10 * k:10 * k + 7])) for k in range(5)]  # 3 of each 10 alone
    groups = pool_groups(pools)
    plain, pooled = NearFilter(interest), NearFilter(interest, groups)
    xy = {u: [rng.uniform(0, 150), rng.uniform(0, 150)] for u in ids}
    t = 0.0
    for _ in range(30):
        t += 0.1
        for u in ids:
            xy[u][0] += rng.uniform(-3, 3)
            xy[u][1] += rng.uniform(-3, 3)
            plain.seen(u, *xy[u], t)
            pooled.seen(u, *xy[u], t)
        senders = rng.sample(ids, 40)
        _, alone = plain.split(senders, t)
        _, grouped = pooled.split(senders, t)
        for p in pools:
            union = {s for u in p.uavs for s in alone.get(u, [])}
            got = grouped.get(p.name, [])
            assert len(got) == len(set(got)) and set(got) == union
        assert {d: s for d, s in grouped.items() if isinstance(d, int)} == {d: s for d, s in alone.items() if d not in groups}


def test_pools_on_the_command_line_are_typed_and_checked(capsys: pytest.CaptureFixture[str]) -> None:
    p = PoolMembers.parse("pool-3=1-5,7,9-10")
    assert p == PoolMembers(number=3, uavs=(1, 2, 3, 4, 5, 7, 9, 10)) and p.arg() == "pool-3=1-5,7,9-10"
    assert PoolMembers(number=2, uavs=(9, 4, 5)).arg() == "pool-2=4-5,9" and SwarmKeys(SWARM).pool_near_feed(2) == \
        "mrs/alpha/feed/near/pool-2"
    for bad, what in (("pool-0=1", "number"), ("pool-1=", "expected"), ("pool-1=5-3", "a <= b"), ("pool-1=0", "1..65535"),
                      ("uav-1=1", "expected"), ("pool-1=1,1", "twice"), ("pool-1=1--2", "not a UAV id")):
        with pytest.raises(ConfigError, match=what):
            PoolMembers.parse(bad)
    with pytest.raises(ConfigError, match="UAV 2 in both pool-1 and pool-2"):
        pool_groups([PoolMembers(number=1, uavs=(1, 2)), PoolMembers(number=2, uavs=(2, 3))])
    with pytest.raises(ConfigError, match="pool-1 given twice"):
        pool_groups([PoolMembers(number=1, uavs=(1,)), PoolMembers(number=1, uavs=(2,))])
    interest = Interest(radius_m=RADIUS)
    feed = FeedOptions(swarm=SWARM, interest=interest, pools=(PoolMembers(number=1, uavs=(11, 12)), p))
    assert feed.argv() == ["--feed", SWARM, *interest.argv(), "--pool", "pool-1=11-12", "--pool", "pool-3=1-5,7,9-10"]
    with pytest.raises(ConfigError, match="UAV 1 in both"):
        FeedOptions(swarm=SWARM, interest=interest, pools=(PoolMembers(number=1, uavs=(1, 2)), p))
    with pytest.raises(ConfigError, match="pools"):
        FeedOptions(swarm=SWARM, pools=(PoolMembers(number=1, uavs=(1, 2)),))
    base = ["--insecure", "--feed", SWARM, "--duration", "0"]
    for argv, said in ((base + ["--pool", "pool-1=1-2"], "give --interest-radius-m"),
                       (base + [*interest.argv(), "--pool", "pool-1=1-2", "--pool", "pool-2=2-3"], "UAV 2 in both"),
                       (base + [*interest.argv(), "--pool", "pool-1=a"], "expected pool-<n>=<ids>")):
        with pytest.raises(SystemExit) as exc:
            router_main(argv)
        assert exc.value.code == 2 and said in capsys.readouterr().err


class _Session:
    """What a pose feed asks of a Zenoh session, recording the puts."""

    def __init__(self) -> None:
        self.puts: list[tuple[str, bytes]] = []

    def declare_subscriber(self, key: str, handler: Any) -> Any:
        return SimpleNamespace(handler=None, undeclare=lambda: None)

    def declare_publisher(self, key: str, **_: Any) -> Any:
        return SimpleNamespace(put=lambda payload: self.puts.append((key, payload)))


def test_the_edge_feed_puts_one_batch_per_pool_per_flush() -> None:
    """The feed itself (no Zenoh): UAVs 1-3 in pool 1, 4 and 5 each alone, all within the radius:
    a flush puts one batch on the pool's key with every sender once, and one on each lone UAV's."""
    clock = [100.0]
    session = _Session()
    feed = PoseFeed(session, [SWARM], 0.0, clock=lambda: clock[0], interest=Interest(radius_m=RADIUS, far_rate_hz=0.5),  # type: ignore[arg-type]
                    pools=[PoolMembers(number=1, uavs=(1, 2, 3))])
    keys = SwarmKeys(SWARM)
    latest: dict[str, dict[int, bytes]] = {}

    def instant(k: int) -> None:
        for u in (1, 2, 3, 4, 5):
            payload = encode_pose(Pose(u, Realm.VIRTUAL, k, k * 0.1, clock[0], float(u), 0.0, 10.0, 0, 0, 0, 0))
            feed._take(SimpleNamespace(key_expr=keys.pose(u), payload=SimpleNamespace(to_bytes=lambda p=payload: p)),  # type: ignore[arg-type]
                       latest)
        feed._flush(latest)

    instant(1)  # every sender's first pose: the shared feed only
    assert [k for k, _ in session.puts] == [keys.pose_feed]
    session.puts.clear()
    clock[0] += 0.1
    instant(2)
    batches = {k: decode_pose_batch(b) for k, b in session.puts}
    assert len(session.puts) == len(batches) == 3  # the pool's batch and one for each lone UAV
    assert set(batches) == {keys.pool_near_feed(1), keys.near_feed(4), keys.near_feed(5)}
    assert batches[keys.pool_near_feed(1)].senders == [1, 2, 3, 4, 5]  # each once, near any of its UAVs
    assert batches[keys.near_feed(4)].senders == [1, 2, 3, 5] and batches[keys.near_feed(5)].senders == [1, 2, 3, 4]
    assert feed.stats.sent["near_pose"] == 13


@pytest.fixture
def swarm_keys(tmp_path: Path) -> Path:
    kd = KeyDir.init(tmp_path / "keys", SWARM)
    for n in ("uav-1", "uav-2", "uav-3", "uav-4", "edge"):
        kd.issue(NodeName.in_swarm(n, SWARM))
    return kd.path


@contextlib.contextmanager
def edge_router(keys: Path, tmp_path: Path, pools: tuple[PoolMembers, ...] = ()) -> Iterator[str]:
    """``mrswarm router`` with the pose feed and spatial interest, secured, as its own process."""
    port = free_port()
    stats = tmp_path / "router.stats.json"
    feed = FeedOptions(swarm=SWARM, interest=Interest(radius_m=RADIUS, margin_m=MARGIN, far_rate_hz=FAR_HZ), pools=pools)
    argv = [sys.executable, "-m", "discovery.rendezvous", "--listen", f"tcp/127.0.0.1:{port}", "--keys", str(keys),
            "--stats", str(stats), *feed.argv()]
    with open(tmp_path / "router.log", "wb") as out:
        proc = subprocess.Popen(argv, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    try:
        assert wait_for(stats.exists, 20.0), (tmp_path / "router.log").read_text()
        yield f"tls/127.0.0.1:{port}"
    finally:
        proc.terminate()
        proc.wait(10)


def uav(keys: Path, endpoint: str, n: int) -> SwarmNode:
    creds = Credentials(keys=str(keys), identity=NodeName.uav(n, SWARM).cn)
    return SwarmNode(NodeIdentity(SWARM, n), Rendezvous((endpoint,), mode="client", credentials=creds),
                     pose_feed="edge", near_feed=True)


def fly(nodes: dict[int, SwarmNode], where: dict[int, float], seconds: float) -> None:
    """Every node publishes its pose at (where[n], 0) at 10 Hz for ``seconds``, polling as a UAV does."""
    end = time.monotonic() + seconds
    k = 0
    while time.monotonic() < end:
        for n, node in nodes.items():
            node.publish_pose(t_sim=k * 0.1, x=where[n], y=0.0, z=10.0, vx=0, vy=0, vz=0, yaw=0)
            node.poll()
        k += 1
        time.sleep(0.1)
    time.sleep(0.3)
    for node in nodes.values():
        node.poll()


def received(node: SwarmNode, sender: int) -> int:
    nb = node.neighbours.get(sender)
    return 0 if nb is None else nb.received


def test_full_rate_across_the_border_slow_beyond_and_nobody_reads_anothers_near_feed(swarm_keys: Path,
                                                                                     tmp_path: Path) -> None:
    """UAV 1 at x = 0, UAV 2 just inside the radius, UAV 3 just outside it, UAV 4 far away. Then 2
    crosses the border outwards (within the margin: still full rate; past it: slow)."""
    with edge_router(swarm_keys, tmp_path) as endpoint:
        nodes = {n: uav(swarm_keys, endpoint, n).open() for n in (1, 2, 3, 4)}
        spy_creds = Credentials(keys=str(swarm_keys), identity=NodeName.uav(4, SWARM).cn)
        spy = zenoh.open(to_zenoh(Rendezvous((endpoint,), mode="client", credentials=spy_creds).zenoh_config()))
        stolen: list[zenoh.Sample] = []
        spy.declare_subscriber(SwarmKeys(SWARM).near_feed(1), stolen.append)
        try:
            assert wait_for(lambda: all((n.poll(), n.alive_uavs() == {1, 2, 3, 4})[1] for n in nodes.values()), 10.0)
            where = {1: 0.0, 2: RADIUS - 1.0, 3: RADIUS + 1.0, 4: 500.0}
            fly(nodes, where, 3.0)  # ~30 poses each
            one, two = nodes[1], nodes[2]
            assert received(one, 2) >= 20  # across the border, full rate
            assert received(two, 1) >= 20 and received(two, 3) >= 20  # 2 is within the radius of both 1 and 3
            assert 1 <= received(one, 3) <= 6  # just outside: the far rate (1 Hz), never nothing
            assert 1 <= received(one, 4) <= 6
            assert 1 <= received(nodes[4], 1) <= 6
            before = received(one, 2)
            where[2] = RADIUS + MARGIN - 1.0  # drifts out, within the margin
            fly(nodes, where, 2.0)
            assert received(one, 2) - before >= 12
            before = received(one, 2)
            where[2] = RADIUS + MARGIN + 5.0  # past the margin
            fly(nodes, where, 3.0)
            assert received(one, 2) - before <= 8  # the far rate, plus poses sent before the edge saw it leave
            assert received(one, 2) - before >= 1
            assert stolen == []  # UAV 4 may not receive UAV 1's near feed (access control at the edge)
            assert all(n.stats.rejected == {} for n in nodes.values())
        finally:
            spy.close()
            for n in nodes.values():
                n.close()


def test_a_pool_takes_its_own_near_batch_counts_each_member_what_is_near_it_and_reads_no_other_pools(
        tmp_path: Path) -> None:
    """Pool 1 (UAVs 1 and 2, one shared session) and pool 2 (UAVs 3 and 4, a bare session of its
    certificate) near each other and near UAV 5, alone, through a real TLS edge router told the
    layout. Pool 2 reads its own near key and never pool 1's; each of pool 1's batches lists a
    sender once; a member of pool 1 is credited with the poses near it only."""
    kd = KeyDir.init(tmp_path / "keys", SWARM)
    for n in ("uav-5", "edge"):
        kd.issue(NodeName.in_swarm(n, SWARM))
    kd.issue(NodeName("pool", 1, SWARM), uavs=(1, 2))
    kd.issue(NodeName("pool", 2, SWARM), uavs=(3, 4))
    keys = SwarmKeys(SWARM)
    interest = Interest(radius_m=RADIUS, margin_m=MARGIN, far_rate_hz=FAR_HZ)
    rules = {r["id"]: r["key_exprs"] for r in access_control(kd.roster)["rules"]}
    assert keys.pool_near_feed(1) in rules["pool-1.out"] and keys.pool_near_feed(2) not in rules["pool-1.out"]

    def conn(name: str) -> Rendezvous:
        return Rendezvous((endpoint,), mode="client", credentials=Credentials(keys=str(kd.path), identity=NodeName.in_swarm(
            name, SWARM).cn))

    with edge_router(kd.path, tmp_path, (PoolMembers(number=1, uavs=(1, 2)), PoolMembers(number=2, uavs=(3, 4)))) as endpoint:
        share = SharedSession(SWARM, conn("pool-1"), pose_feed="edge", number=1, interest=interest).open()
        members = {n: SwarmNode(NodeIdentity(SWARM, n), share.connectivity, pose_feed="edge", near_feed=True,
                                shared=share).open() for n in (1, 2)}
        five = SwarmNode(NodeIdentity(SWARM, 5), conn("uav-5"), pose_feed="edge", near_feed=True).open()
        other = zenoh.open(to_zenoh(conn("pool-2").zenoh_config()))
        own: list[bytes] = []
        stolen: list[zenoh.Sample] = []
        other.declare_subscriber(keys.pool_near_feed(2), lambda s: own.append(s.payload.to_bytes()))
        other.declare_subscriber(keys.pool_near_feed(1), stolen.append)
        other.declare_subscriber(keys.near_feed(1), stolen.append)  # nor a member's own key
        spy = zenoh.open(to_zenoh(conn("pool-1").zenoh_config()))  # pool 1's certificate: may read its own batches
        mine: list[bytes] = []
        spy.declare_subscriber(keys.pool_near_feed(1), lambda s: mine.append(s.payload.to_bytes()))
        nodes = {**members, 5: five}
        try:
            assert wait_for(lambda: all((n.poll(), n.alive_uavs() >= {1, 2, 5})[1] for n in nodes.values()), 10.0)
            where = {1: 0.0, 2: 10.0, 5: 5.0}

            def fly_with_three(steps: int, k0: int) -> None:
                """10 Hz: pool 2 flies UAV 3 at x = 15 on its bare session, the others at ``where``."""
                for k in range(k0, k0 + steps):
                    other.put(keys.pose(3), encode_pose(Pose(3, Realm.VIRTUAL, k, k * 0.1, time.time(), 15.0, 0, 10, 0, 0, 0, 0)))
                    for n, node in nodes.items():
                        node.publish_pose(t_sim=k * 0.1, x=where[n], y=0.0, z=10.0, vx=0, vy=0, vz=0, yaw=0)
                        node.poll()
                    time.sleep(0.1)
                time.sleep(0.3)
                for node in nodes.values():
                    node.poll()

            fly_with_three(30, 0)
            m1, m2 = members[1], members[2]
            assert received(m1, 2) >= 20 and received(m1, 3) >= 20 and received(m1, 5) >= 20  # full rate, once decoded
            assert received(five, 1) >= 20 and received(five, 2) >= 20 and received(five, 3) >= 20  # its own key, as before
            assert own and stolen == []  # pool 2 gets its batch, never pool 1's (access control at the edge)
            assert {s for b in own for s in decode_pose_batch(b).senders} == {1, 2, 5}
            assert mine and all(len(set(b.senders)) == len(b.senders) for b in map(decode_pose_batch, mine))
            assert {s for b in mine for s in decode_pose_batch(b).senders} == {1, 2, 3, 5}
            # each member counts the poses near it: both are within reach of 1, 2, 3 and 5
            assert abs(m1.stats.received["pose"] - m2.stats.received["pose"]) <= 0.2 * m1.stats.received["pose"]
            before = {n: members[n].stats.received["pose"] for n in (1, 2)}
            where[2] = 500.0  # UAV 2 flies off: from now on only the far feed is meant for it
            fly_with_three(20, 30)
            got = {n: members[n].stats.received["pose"] - before[n] for n in (1, 2)}
            assert got[1] >= 30 and got[2] <= 12, got  # 1 still hears 3 and 5 at full rate; 2, the far rate and the tail
            assert all(n.stats.rejected == {} for n in nodes.values()) and share.stats.rejected == {}
        finally:
            spy.close()
            other.close()
            for n in nodes.values():
                n.close()
            share.close()
