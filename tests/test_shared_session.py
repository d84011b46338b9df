"""A pool's one Zenoh session (swarmnet/shared_session.py): real sessions, a real TLS router.

The members of a pool share a session speaking as ``pool-<n>``; each is still its own UAV to
the swarm (its pose under its own key, its own commands, unicasts and token), sees the others
but not itself, and the pool's certificate speaks for its roster's UAVs and for no other.
"""

from __future__ import annotations

import json
import random
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import pytest

from groundfloor.schema import ConfigError
from swarmnet.connectivity import Rendezvous
from swarmnet.interest import Interest
from swarmnet.messages import Command, Pose, Realm, decode_pose, encode_command
from swarmnet.neighbours import NeighbourTable
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.observer import SwarmObserver
from swarmnet.security.acl import access_control
from swarmnet.security.identity import NodeName
from swarmnet.security.pki import KeyDir, KeysError
from swarmnet.security.roster import Roster
from swarmnet.shared_session import NeighbourView, Positions, SharedSession
from tests.conftest import wait_for
from tests.test_security import KEYS, SWARM, creds, pose, router_process


@pytest.fixture
def pool_keys(tmp_path: Path) -> Path:
    kd = KeyDir.init(tmp_path / "keys", SWARM)
    for n in ("uav-1", "uav-2", "uav-3", "ctl", "edge", "gcs-1"):
        kd.issue(NodeName.in_swarm(n, SWARM))
    kd.issue(NodeName("pool", 1, SWARM), uavs=(1, 2))
    return kd.path


def fly(nodes: list[SwarmNode], t: float) -> None:
    for n in nodes:
        n.publish_pose(t_sim=t % 1000.0, x=10.0 * n.identity.uav, y=0.0, z=10.0, vx=0.0, vy=0.0, vz=0.0, yaw=0.0)
    for n in nodes:
        n.poll()


@pytest.fixture
def pool(pool_keys: Path, tmp_path: Path) -> Iterator[tuple[SharedSession, SwarmNode, SwarmNode, SwarmNode, SwarmObserver]]:
    with router_process(pool_keys, tmp_path) as (ep, _stats):
        share = SharedSession(SWARM, Rendezvous((ep,), mode="client", credentials=creds(pool_keys, "pool-1")))
        with share:
            m1 = SwarmNode(NodeIdentity(SWARM, 1), share.connectivity, shared=share)
            m2 = SwarmNode(NodeIdentity(SWARM, 2), share.connectivity, shared=share)
            u3 = SwarmNode(NodeIdentity(SWARM, 3), Rendezvous((ep,), mode="client", credentials=creds(pool_keys, "uav-3")))
            ctl = SwarmObserver(SWARM, Rendezvous((ep,), mode="client", credentials=creds(pool_keys, "ctl")), name="runner")
            with m1, m2, u3, ctl:
                yield share, m1, m2, u3, ctl


def test_pool_members_are_each_their_own_uav_on_one_session(pool: tuple[SharedSession, SwarmNode, SwarmNode, SwarmNode,
                                                                        SwarmObserver]) -> None:
    share, m1, m2, u3, ctl = pool
    assert m1.session is m2.session is share.session
    nodes = [m1, m2, u3]

    def everyone_sees_everyone() -> bool:
        fly(nodes, time.time())
        ctl.poll()
        return ({nb.uav for nb in m1.neighbours} == {2, 3} and {nb.uav for nb in m2.neighbours} == {1, 3}
                and {nb.uav for nb in u3.neighbours} == {1, 2} and {nb.uav for nb in ctl.node.neighbours} >= {1, 2, 3})
    assert wait_for(everyone_sees_everyone, 10.0, 0.1)
    # a member never sees itself, and its pose is under its own key for everyone outside
    assert 1 not in m1.neighbours and m1.neighbours.get(1) is None and len(m1.neighbours) == 2
    assert {n.pose.x for n in ctl.node.neighbours if n.uav in (1, 2)} == {10.0, 20.0}
    assert m1.alive_uavs() >= {1, 2, 3} and m1.members() == m2.members()
    # each pose reached the pool once, for both members
    assert share.stats.received["pose"] > 0 and m1.stats.received["pose"] == m2.stats.received["pose"]
    # each member's own age at use; its transport ages leave its own pose out
    m1.take_neighbours()
    assert set(m1.stats.ages.links) <= {2, 3} and set(m2.stats.ages.links) <= {1, 3}
    # the neighbours around a member come from the pool's index of positions: UAV 2 is 10 m
    # from UAV 1, UAV 3 20 m
    assert [n.uav for n in m1.take_neighbours(around=(10.0, 0.0, 15.0))] == [2]
    assert sorted(n.uav for n in m2.take_neighbours(around=(20.0, 0.0, 15.0))) == [1, 3]

    # commands: to one member, only it; to the swarm, each
    ctl.node.session.put(KEYS.cmd(2), encode_command(Command("ctl", 5, 2, "hold", {}, time.time())))  # type: ignore[union-attr]
    assert wait_for(lambda: [c.verb for c in m2.poll().commands] == ["hold"], 3.0)
    assert m1.poll().commands == []
    # messages: a unicast between pool-mates, a broadcast to all but its sender
    m1.send("hello", {"n": 1}, to=2)
    assert wait_for(lambda: [m.topic for m in m2.poll().messages] == ["hello"], 3.0)
    m2.send("all", {"n": 2})
    got1: list[str] = []
    got3: list[str] = []
    assert wait_for(lambda: (got1.extend(m.topic for m in m1.poll().messages),
                             got3.extend(m.topic for m in u3.poll().messages), got1 and got3)[-1], 3.0)
    assert got1 == ["all"] and got3 == ["all"] and m2.poll().messages == []


def test_a_pools_certificate_speaks_for_its_roster_only(pool: tuple[SharedSession, SwarmNode, SwarmNode, SwarmNode,
                                                                    SwarmObserver]) -> None:
    share, m1, m2, u3, ctl = pool
    assert share.session is not None
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:  # the pool's session forges UAV 3's pose and a command
        share.session.put(KEYS.pose(3), pose(3, x=77.0))
        share.session.put(KEYS.cmd(3), encode_command(Command("gcs", 7, 3, "kill", {}, time.time())))
        fly([m1, m2], time.time())
        ctl.poll()
        assert u3.poll().commands == []
        time.sleep(0.05)
    assert all(n.pose.x != 77.0 for n in ctl.node.neighbours)  # the router refused it: UAV 3 publishes nothing here
    assert {n.uav for n in ctl.node.neighbours} == {1, 2}  # its own UAVs' poses do pass


def test_poses_published_together_all_leave_when_it_ends_even_if_a_member_raises(
        pool: tuple[SharedSession, SwarmNode, SwarmNode, SwarmNode, SwarmObserver]) -> None:
    share, m1, m2, u3, ctl = pool

    def heard(x1: float, x2: float) -> bool:  # a UAV outside the pool has both members' latest poses
        u3.poll()
        n1, n2 = u3.neighbours.get(1), u3.neighbours.get(2)
        return n1 is not None and n2 is not None and (n1.pose.x, n2.pose.x) == (x1, x2)

    assert wait_for(lambda: (fly([m1, m2, u3], time.time()), heard(10.0, 20.0))[-1], 10.0, 0.1)
    with pytest.raises(RuntimeError, match="an agent failed"), share.together():
        for m, x in ((m1, 11.0), (m2, 22.0)):
            m.publish_pose(t_sim=1.0, x=x, y=0.0, z=10.0, vx=0.0, vy=0.0, vz=0.0, yaw=0.0)
        time.sleep(0.3)
        assert not heard(11.0, 22.0)  # held inside: none put yet
        raise RuntimeError("an agent failed")
    assert share.held is None
    assert wait_for(lambda: heard(11.0, 22.0), 5.0)  # both put as it ended, each under its own key
    # outside it, a pose leaves at once as ever
    m1.publish_pose(t_sim=2.0, x=12.0, y=0.0, z=10.0, vx=0.0, vy=0.0, vz=0.0, yaw=0.0)
    assert wait_for(lambda: heard(12.0, 22.0), 5.0)


def test_a_member_with_a_netem_shim_impairs_its_own_links(pool: tuple[SharedSession, SwarmNode, SwarmNode, SwarmNode,
                                                                      SwarmObserver]) -> None:
    share, m1, m2, u3, ctl = pool
    assert wait_for(lambda: (fly([m1, m2, u3], time.time()), len(m1.neighbours) == 2 and len(m2.neighbours) == 2)[-1], 10.0)
    m1.set_netem({"v2v": {"loss": {"model": "bernoulli", "p": 1.0}}})  # every pose to UAV 1 lost
    assert isinstance(m1.neighbours, NeighbourTable) and m1 in share.impaired
    before = {n.uav: n.received for n in m1.neighbours}
    for _ in range(20):
        fly([m1, m2, u3], time.time())
        time.sleep(0.05)
    assert {n.uav: n.received for n in m1.neighbours} == before  # none came through its shim
    assert all(n.received > before[n.uav] for n in m2.neighbours if n.uav == 3)  # its pool-mate's links are not impaired


def test_neighbour_view_leaves_the_member_out_and_counts_its_own_first_uses() -> None:
    table = NeighbourTable()
    for u in (1, 2, 3):
        table.update(decode_pose(pose(u)), 100.0)
    view = NeighbourView(table, 2)
    assert [n.uav for n in view.snapshot()] == [1, 3] and len(view) == 2 and 2 not in view and 1 in view
    assert view.first_uses(view.snapshot(), 100.5) == [0.5, 0.5]
    assert view.first_uses(view.snapshot(), 100.6) == []  # already used
    other = NeighbourView(table, 1)  # another member: its first use is its own
    assert other.first_uses(other.snapshot(), 100.7) == pytest.approx([0.7, 0.7])


def test_the_neighbours_around_a_member_are_those_within_the_radius_as_the_table_changes() -> None:
    rng = random.Random(7)
    table = NeighbourTable(forget_after=10.0)
    positions = Positions(capacity=4)  # grows as UAVs come
    view = NeighbourView(table, 1, positions)
    seq: dict[int, int] = {}

    def move(uavs: list[int], at: float) -> None:
        for u in uavs:
            seq[u] = seq.get(u, 0) + 1
            table.update(Pose(u, Realm.VIRTUAL, seq[u], 0.0, at, rng.uniform(-100, 100), rng.uniform(-100, 100),
                              10, 0, 0, 0, 0), at)
        positions.moved(table, uavs)

    def brute(x: float, y: float, r: float) -> set[int]:
        return {n.uav for n in table.snapshot() if n.uav != 1 and (n.pose.x - x) ** 2 + (n.pose.y - y) ** 2 <= r * r}

    move(list(range(1, 41)), 100.0)
    for step in range(20):
        at = 100.0 + step
        move(rng.sample(range(1, 61), 15), at)  # some move, some new ones come
        positions.forget(table.expire(at))  # the silent ones go
        for _ in range(5):
            x, y, r = rng.uniform(-100, 100), rng.uniform(-100, 100), rng.uniform(5, 80)
            assert {n.uav for n in view.around(x, y, r)} == brute(x, y, r)
    assert 1 not in {n.uav for n in view.around(0.0, 0.0, 1e6)}  # never the member itself


def test_a_pool_certificate_names_its_uavs_and_the_rules_grant_theirs(tmp_path: Path) -> None:
    kd = KeyDir.init(tmp_path / "k", SWARM)
    with pytest.raises(KeysError, match="speaks for"):
        kd.issue(NodeName("pool", 1, SWARM))  # no UAVs
    with pytest.raises(KeysError, match="only a pool"):
        kd.issue(NodeName.uav(4, SWARM), uavs=(4,))
    kd.issue(NodeName("pool", 1, SWARM), uavs=(5, 4))
    roster = Roster.load(kd.path)
    assert roster.speaks_for("pool-1.alpha") == (4, 5)
    rules = {r["id"]: r for r in access_control(roster)["rules"]}
    puts = rules["pool-1.in"]["key_exprs"]
    assert KEYS.pose(4) in puts and KEYS.pose(5) in puts and KEYS.cmd(4) not in puts
    assert not any(k.startswith(f"{KEYS.prefix}/1/") for k in puts)
    # the rotation keeps what a pool speaks for
    kd.rotate()
    assert Roster.load(kd.path).speaks_for("pool-1.alpha") == (4, 5)
    # a hand-edited roster that gives a UAV's certificate others to speak for is refused, naming the field
    data = json.loads(roster.to_json())
    data["nodes"]["uav-3.alpha"] = {"serial": "ab", "not_after": time.time() + 100, "issued": time.time(), "uavs": [3]}
    (tmp_path / "edited").mkdir()
    (tmp_path / "edited" / "roster.json").write_text(json.dumps(data))
    with pytest.raises(ConfigError, match=r"nodes.uav-3.alpha.uavs"):
        Roster.load(tmp_path / "edited")


def test_a_runs_own_key_directory_needs_its_pools_certificates(tmp_path: Path) -> None:
    from mrswarm.cli.keys import main as keys_main
    from mrswarm.run.keys import check_keys, run_identities

    d = tmp_path / "alpha"
    assert keys_main(["init", "--swarm", SWARM, "--dir", str(d)]) == 0
    assert keys_main(["issue", "--dir", str(d), "edge", "ctl", "gcs-1", "--uavs", "1-4"]) == 0
    names = run_identities(SWARM, [1, 2, 3, 4])
    with pytest.raises(KeysError, match=r"pool-1 speaking for UAVs 1,2 .*--speaks-for 1,2"):
        check_keys(d, SWARM, names, {1: (1, 2)})
    assert keys_main(["issue", "--dir", str(d), "pool-1", "--speaks-for", "1-2"]) == 0
    assert check_keys(d, SWARM, names, {1: (1, 2)}) == d.resolve()
    with pytest.raises(KeysError, match="pool-1 speaking for UAVs 1,2,3"):  # a larger pool than the certificate's
        check_keys(d, SWARM, names, {1: (1, 2, 3)})


class _Member:
    """What the pool's near-feed credit reads of a member and writes to it."""

    def __init__(self, uav: int, at: tuple[float, float] | None) -> None:
        self.identity = SimpleNamespace(uav=uav)
        self.near_feed = True
        self.own_position = None if at is None else (*at, 10.0)
        self.filed: list[tuple[int, float]] = []
        self.handed: list[tuple[Pose, float]] = []
        self.stats = SimpleNamespace(received=Counter(), ages=SimpleNamespace(
            arrived_many=lambda srcs, ages: self.filed.extend(zip(srcs, ages, strict=True))))

    def hand(self, poses: list[tuple[Pose, float]]) -> None:
        self.handed += poses


def test_a_pose_of_the_pools_near_batch_counts_for_the_members_within_reach_of_its_sender() -> None:
    """Radius 20 m + margin 5: members at x = 0 (1), 22 (2, within the margin of x = 0), 100 (3,
    with a netem shim) and one that has not flown yet (4). Each is credited the senders within
    25 m of it, never its own pose; the one with a shim is handed those poses, no ages."""
    share = SharedSession(SWARM, Rendezvous(("tcp/127.0.0.1:9",), mode="client"), pose_feed="edge", number=1,
                          interest=Interest(radius_m=20.0, margin_m=5.0))
    members = {1: _Member(1, (0.0, 0.0)), 2: _Member(2, (22.0, 0.0)), 3: _Member(3, (100.0, 0.0)), 4: _Member(4, None)}
    share.members.update(members)  # type: ignore[arg-type]
    share.impaired.append(members[3])  # type: ignore[arg-type]
    at = time.time()
    where = {1: 0.0, 2: 22.0, 7: 3.0, 8: 90.0, 9: 300.0}  # 7 near 1 and 2, 8 near 3 only, 9 near nobody
    srcs, ages, handed = list(where), [0.001 * u for u in where], []
    for u, x in where.items():
        p = Pose(u, Realm.VIRTUAL, 1, 0.0, at - 0.001 * u, x, 0.0, 10.0, 0, 0, 0, 0)
        assert share.neighbours.update(p, at)
        handed.append((p, at))
    share._credit_near(srcs, ages, handed)
    assert {u: m.stats.received["pose"] for u, m in members.items()} == {1: 2, 2: 2, 3: 1, 4: 0}
    assert members[1].filed == [(2, 0.002), (7, 0.007)] and members[2].filed == [(1, 0.001), (7, 0.007)]
    assert [p.uav for p, _ in members[3].handed] == [8] and members[3].filed == [] and members[4].filed == []
    with pytest.raises(ValueError, match="number"):
        SharedSession(SWARM, Rendezvous(("tcp/127.0.0.1:9",), mode="client")).add_near_feed(1)
