"""Spatial interest (docs/scale.md): full-rate poses only within the radius, across its border, secured."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
import zenoh

from groundfloor.schema import ConfigError, convert
from mrswarm.scenario import ScenarioError, load_scenario
from swarmnet.connectivity import Rendezvous, to_zenoh
from swarmnet.interest import Interest, NearFilter
from swarmnet.keyspace import SwarmKeys
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.security.credentials import Credentials
from swarmnet.security.identity import NodeName
from swarmnet.security.pki import KeyDir
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


@pytest.fixture
def swarm_keys(tmp_path: Path) -> Path:
    kd = KeyDir.init(tmp_path / "keys", SWARM)
    for n in ("uav-1", "uav-2", "uav-3", "uav-4", "edge"):
        kd.issue(NodeName.in_swarm(n, SWARM))
    return kd.path


@contextlib.contextmanager
def edge_router(keys: Path, tmp_path: Path) -> Iterator[str]:
    """``mrswarm router`` with the pose feed and spatial interest, secured, as its own process."""
    port = free_port()
    stats = tmp_path / "router.stats.json"
    argv = [sys.executable, "-m", "discovery.rendezvous", "--listen", f"tcp/127.0.0.1:{port}", "--keys", str(keys),
            "--stats", str(stats), "--feed", SWARM, *Interest(radius_m=RADIUS, margin_m=MARGIN, far_rate_hz=FAR_HZ).argv()]
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
