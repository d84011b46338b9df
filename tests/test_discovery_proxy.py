"""The discovery proxy inside real SwarmNodes, the server as a real process, the CLI; all on 127.0.0.1."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from discovery.client import query_registry
from discovery.protocol import MAX_DATAGRAM, MsgType, Peers, parse_beacon, peers_body, seal, unseal
from discovery.proxy import BeaconDiscovery
from discovery.server import DiscoveryServer, ServerConfig
from swarmnet.node import NodeIdentity, SwarmNode
from tests.conftest import free_port, wait_for

ROOT = Path(__file__).resolve().parents[1]
KEY = "alpha-key-0123456789abcdef"
OTHER = "other-key-0123456789abcdef"


@pytest.fixture
def server() -> Iterator[str]:
    srv = DiscoveryServer(ServerConfig(keys={"alpha": KEY.encode()}, rate=5000, burst=5000))
    host, port = srv.bind("127.0.0.1", 0)
    stop = threading.Event()
    th = threading.Thread(target=srv.serve, args=(stop,), daemon=True)
    th.start()
    yield f"{host}:{port}"
    stop.set()
    th.join(5)
    srv.close()


def node(server: str, uav: int, key: str = KEY, role: str = "uav") -> SwarmNode:
    return SwarmNode(NodeIdentity("alpha", uav, role=role), BeaconDiscovery(server=server, key=key))


def test_nodes_mesh_exchange_poses_and_a_wrong_key_stays_alone(server: str) -> None:
    nodes = [node(server, i).open() for i in (1, 2, 3)]
    intruder = node(server, 9, key=OTHER).open()
    try:
        zids = {n.zid for n in nodes}
        assert wait_for(lambda: all(set(n.peers()) == zids - {n.zid} for n in nodes), 5.0), [n.peers() for n in nodes]
        for _ in range(15):
            for i, n in enumerate(nodes):
                n.publish_pose(t_sim=0, x=float(i), y=0, z=5, vx=0, vy=0, vz=0, yaw=0)
            time.sleep(0.05)
            for n in nodes:
                n.poll()
        assert [sorted(x.uav for x in n.neighbours) for n in nodes] == [[2, 3], [1, 3], [1, 2]]
        time.sleep(1.5)  # more beacon rounds: the intruder still gets nowhere
        assert intruder.peers() == [] and all(intruder.zid not in n.peers() for n in nodes)
        rows, stats = query_registry(server, "alpha", KEY)
        assert sorted(r.entry.node for r in rows) == [1, 2, 3]
        assert stats["drop_bad_mac"] >= 2
        st = nodes[0].connectivity.status()  # type: ignore[attr-defined]
        assert st["members"] == {"alpha": ["uav2", "uav3"]} and st["server_contact_age"] < 2.5
        assert intruder.connectivity.status()["server_contact_age"] is None  # type: ignore[attr-defined]
    finally:
        for n in nodes + [intruder]:
            n.close()


def test_clean_exit_says_bye_and_peers_forget_the_node(server: str) -> None:
    a, b = node(server, 1).open(), node(server, 2).open()
    try:
        assert wait_for(lambda: len(a.peers()) == 1, 5.0)
        b.close()
        assert wait_for(lambda: ("uav", 2) not in {(r.entry.role, r.entry.node)
                                                   for r in query_registry(server, "alpha", KEY)[0]}, 1.0)
        assert wait_for(lambda: a.connectivity.status()["members"] == {"alpha": []}, 2.0)  # type: ignore[attr-defined]
    finally:
        a.close()
        b.close()


def test_proxy_survives_garbage_from_the_server_address_and_elsewhere() -> None:
    fake = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # plays the discovery server
    fake.bind(("127.0.0.1", 0))
    fake.settimeout(3)
    srv = "{}:{}".format(*fake.getsockname())
    a, b = node(srv, 1).open(), node(srv, 2).open()
    try:
        beacons = {}
        while len(beacons) < 2:
            data, src = fake.recvfrom(MAX_DATAGRAM)
            env = unseal(data, {"alpha": KEY.encode()}.get)
            assert env.type == MsgType.BEACON
            beacons[parse_beacon(env.body).entry.node] = (parse_beacon(env.body).entry, src)
        a_addr = beacons[1][1]
        junk = [b"", os.urandom(50), os.urandom(3000), seal(MsgType.PEERS, "alpha", OTHER.encode(), [0, 0, 1, []]),
                seal(MsgType.PEERS, "alpha", KEY.encode(), [0, 0, 1, [["bad"]]]),
                seal(MsgType.PEERS, "alpha", KEY.encode(), [0, 0, 1, []], ts=time.time() - 600),
                seal(MsgType.BEACON, "alpha", KEY.encode(), [1, 2, 3])]
        for d in junk:
            fake.sendto(d[:65000], a_addr)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as elsewhere:  # right key, wrong sender
            elsewhere.sendto(seal(MsgType.PEERS, "alpha", KEY.encode(), peers_body(Peers(0, 0, 1, (beacons[2][0],)))), a_addr)
        time.sleep(0.5)
        assert a.peers() == []
        stats = a.connectivity.status()["stats"]  # type: ignore[attr-defined]
        for reason in ("drop_not_from_server", "drop_bad_mac", "drop_invalid_entry", "drop_stale", "drop_unexpected_type"):
            assert stats.get(reason, 0) >= 1, (reason, stats)
        # the real thing from the real server address still works: A learns B and they link
        fake.sendto(seal(MsgType.PEERS, "alpha", KEY.encode(), peers_body(Peers(0, 0, 1, (beacons[2][0],)))), a_addr)
        fake.sendto(seal(MsgType.PEERS, "alpha", KEY.encode(), peers_body(Peers(0, 0, 1, (beacons[1][0],)))), beacons[2][1])
        assert wait_for(lambda: a.peers() == [b.zid], 5.0)
    finally:
        a.close()
        b.close()
        fake.close()


def test_discovery_node_refuses_bad_configuration() -> None:
    with pytest.raises(ValueError, match="at least 16"):
        BeaconDiscovery(server="127.0.0.1:7450", key="short")
    with pytest.raises(ValueError, match="HOST:PORT"):
        BeaconDiscovery(server="127.0.0.1:notaport", key=KEY)
    with pytest.raises(ValueError, match="dial"):
        BeaconDiscovery(server="127.0.0.1:7450", key=KEY, dial="sometimes")
    # remote server + loopback-only listener: nothing a remote peer could dial, said clearly at open()
    n = node("192.0.2.1:7450", 1)
    with pytest.raises(RuntimeError, match="no usable locator"):
        n.open()


# ---- the server process and the CLI ------------------------------------------------------------------------
def cli(*args: str, timeout: float = 30) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mrswarm", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)))


def test_cli_serve_nodes_keygen(tmp_path: Path) -> None:
    key = cli("discovery", "keygen").stdout.strip()
    assert len(key) == 64
    keys = tmp_path / "keys"
    keys.write_text(f"alpha {key}\n")
    (tmp_path / "alpha.key").write_text(key)
    port = free_port(socket.SOCK_DGRAM)
    proc = subprocess.Popen([sys.executable, "-m", "mrswarm", "discovery", "serve", "--listen", f"127.0.0.1:{port}",
                             "--keys", str(keys)], cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert proc.stdout is not None
        assert "discovery server on udp/127.0.0.1" in proc.stdout.readline()
        a = node(f"127.0.0.1:{port}", 4, key=key).open()
        try:
            res = cli("discovery", "nodes", "--server", f"127.0.0.1:{port}", "--swarm", "alpha",
                      "--key-file", str(tmp_path / "alpha.key"), "--json")
            assert res.returncode == 0, res.stderr
            d = json.loads(res.stdout)
            assert [(n["role"], n["node"], n["zid"]) for n in d["nodes"]] == [("uav", 4, a.zid)]
            assert d["server"]["registered"] == 1
            res = cli("discovery", "nodes", "--server", f"127.0.0.1:{port}", "--swarm", "alpha", "--key", OTHER,
                      "--timeout", "0.2")
            assert res.returncode == 1 and "no answer" in res.stderr
        finally:
            a.close()
    finally:
        proc.terminate()
        proc.wait(10)
    bad = tmp_path / "bad"
    bad.write_text("alpha\n")
    res = cli("discovery", "serve", "--listen", "127.0.0.1:0", "--keys", str(bad))
    assert res.returncode == 2 and "expected 'SWARM KEY'" in res.stderr
    res = cli("discovery", "serve", "--listen", "127.0.0.1:0", "--key", "alpha=short")
    assert res.returncode == 2 and "at least 16" in res.stderr


def test_server_given_by_name_works(server: str) -> None:
    port = server.rsplit(":", 1)[1]
    a, b = node(f"localhost:{port}", 1).open(), node(f"localhost:{port}", 2).open()
    try:
        assert wait_for(lambda: a.peers() == [b.zid], 5.0)
        assert query_registry(f"localhost:{port}", "alpha", KEY)[0]
    finally:
        a.close()
        b.close()


def test_network_config_and_agent_cli_build_a_discovery_node(server: str, tmp_path: Path) -> None:
    from discovery.options import ProxyOptions
    from uav_stack.config import AgentConfig, NetworkConfig
    from uav_stack.geo import GeoPoint
    from uav_stack.runtime import make_connectivity

    keyfile = tmp_path / "alpha.key"
    keyfile.write_text(KEY + "\n")
    net = NetworkConfig(connectivity="discovery", discovery=ProxyOptions(server=server, key_file=str(keyfile), period=0.5))
    conn = make_connectivity(net)
    assert isinstance(conn, BeaconDiscovery) and conn.key == KEY and conn.period == 0.5
    # the config survives the JSON hop to a UAV process
    path = tmp_path / "agent.json"
    path.write_text(AgentConfig(swarm="alpha", uav=5, origin=GeoPoint(0, 0, 0), fcu="", network=net).to_json())
    cfg = AgentConfig.load(path)
    n = SwarmNode(NodeIdentity("alpha", 5), make_connectivity(cfg.network)).open()
    other = node(server, 6).open()
    try:
        assert wait_for(lambda: n.peers() == [other.zid], 5.0)
    finally:
        n.close()
        other.close()
    with pytest.raises(ValueError, match="client mode"):
        make_connectivity(NetworkConfig(connectivity="discovery", mode="client", discovery=ProxyOptions(server=server, key=KEY)))
    res = cli("agent", "--help")
    assert "--discovery" in res.stdout and "--discovery-key-file" in res.stdout and "--advertise" in res.stdout
