"""Forged Hellos at a secured node's scouting sockets draw no connection, and are counted.

Real secured SwarmNodes (mutual TLS, discovery proxy) on 127.0.0.1 with a real discovery server;
the attacker is a rogue listener (plain TCP and TLS) and a UDP socket that sends Zenoh Hellos
pointing at it to every UDP socket the nodes' sessions hold. Without the guard, Zenoh dials the
rogue (the positive control); with it, the kernel drops every one of those datagrams before Zenoh
sees them, and the node counts them in ``refused.scouting``.
"""

from __future__ import annotations

import os
import select
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import psutil
import pytest
import zenoh

from discovery.protocol import MsgType, seal
from discovery.proxy import BeaconDiscovery
from discovery.scout_guard import loopback_ports_filter
from discovery.server import DiscoveryServer, ServerConfig
from discovery.wire import WHATAMI_PEER, WHATAMI_ROUTER, Hello, encode_hello, zid_from_hex
from swarmnet.connectivity import to_zenoh
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.security.credentials import Credentials
from swarmnet.security.identity import NodeName
from swarmnet.security.pki import KeyDir
from tests.conftest import wait_for

SWARM = "alpha"
KEY = "alpha-key-0123456789abcdef"


@pytest.fixture
def keys(tmp_path: Path) -> Path:
    kd = KeyDir.init(tmp_path / "keys", SWARM)
    for n in ("uav-1", "uav-2", "uav-3"):
        kd.issue(NodeName.in_swarm(n, SWARM))
    return kd.path


@pytest.fixture
def server() -> Iterator[DiscoveryServer]:
    srv = DiscoveryServer(ServerConfig(keys={SWARM: KEY.encode()}, rate=5000, burst=5000))
    srv.bind("127.0.0.1", 0)
    stop = threading.Event()
    th = threading.Thread(target=srv.serve, args=(stop,), daemon=True)
    th.start()
    yield srv
    stop.set()
    th.join(5)
    srv.close()


def address(srv: DiscoveryServer) -> str:
    assert srv.sock is not None
    host, port = srv.sock.getsockname()[:2]
    return f"{host}:{port}"


def secured_node(srv: DiscoveryServer, keys: Path, uav: int) -> SwarmNode:
    creds = Credentials(keys=str(keys), identity=NodeName.uav(uav, SWARM).cn)
    return SwarmNode(NodeIdentity(SWARM, uav), BeaconDiscovery(server=address(srv), key=KEY, credentials=creds))


class Rogue:
    """A listener that counts the connections it gets (plain TCP; a TLS client opens TCP first all the same)."""

    def __init__(self) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(64)
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]
        self.accepted = 0

    def count(self, wait: float) -> int:
        deadline = time.monotonic() + wait
        while (left := deadline - time.monotonic()) > 0:
            if select.select([self.sock], [], [], left)[0]:
                try:
                    conn, _ = self.sock.accept()
                    conn.close()
                    self.accepted += 1
                except BlockingIOError:
                    pass
        return self.accepted

    def close(self) -> None:
        self.sock.close()


def udp_ports() -> set[int]:
    """Every UDP port this process holds (the sessions' scouting sockets and responders among them)."""
    return {c.laddr.port for c in psutil.Process().net_connections(kind="udp4")}


def forge(ports: set[int], rogue: int, times: int = 1) -> int:
    """Hellos of a "router" at the rogue (tcp/ and tls/ locators) to each port; the datagrams sent."""
    hello = encode_hello(Hello(zid_from_hex(os.urandom(8).hex()), WHATAMI_ROUTER,
                               (f"tcp/127.0.0.1:{rogue}", f"tls/127.0.0.1:{rogue}")))
    sent = 0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for _ in range(times):
            for p in ports:
                s.sendto(hello, ("127.0.0.1", p))
                sent += 1
    return sent


def test_the_filter_program_accepts_only_loopback_sources_on_the_listed_ports() -> None:
    prog = loopback_ports_filter([7, 40000, 7])
    assert len(prog) % 8 == 0 and len(prog) // 8 == 4 + 2 + 2  # the loopback test, two ports, drop and accept
    with pytest.raises(ValueError):
        loopback_ports_filter([])


def test_an_unguarded_zenoh_session_dials_a_forged_hello_the_positive_control(keys: Path) -> None:
    """The attack as it worked before: a session configured as the proxy configures it, without the proxy's guard."""
    bd = BeaconDiscovery(server="127.0.0.1:1", key=KEY, swarm=SWARM, node=1, role="uav", realm="virtual")
    before = udp_ports()
    rogue = Rogue()
    s = zenoh.open(to_zenoh(bd.zenoh_config()))
    try:
        time.sleep(0.3)
        forge(udp_ports() - before, rogue.port)
        assert rogue.count(3.0) >= 1, "the unguarded session did not dial the forged Hello: the test proves nothing"
    finally:
        s.close()
        rogue.close()


def test_a_forged_hello_draws_no_connection_from_a_secured_node_and_is_counted(server: DiscoveryServer, keys: Path) -> None:
    before = udp_ports()
    nodes = [secured_node(server, keys, u).open() for u in (1, 2)]
    rogue = Rogue()
    try:
        assert wait_for(lambda: all(len(n.peers()) == 1 for n in nodes), 5.0), [n.peers() for n in nodes]
        ports = udp_ports() - before  # every UDP socket the two nodes' sessions and proxies hold
        st = [n.connectivity.status() for n in nodes]  # type: ignore[attr-defined]
        assert all(s["scouting_guarded"] for s in st)
        guarded = {int(a.rsplit(":", 1)[1]) for s in st for a in s["injectors"]}
        assert len(guarded) == 8 and guarded <= ports  # four scouting sockets per node
        sent = forge(guarded, rogue.port, times=25)  # 200 Hellos as a router at the rogue
        more = forge(ports - guarded, rogue.port, times=5)  # and to the responders and the proxies' own sockets
        assert rogue.count(4.0) == 0, "a secured node dialled a locator no discovery vouched for"
        total = lambda: sum(n.stats.refused["scouting"] for n in nodes)  # noqa: E731
        assert wait_for(lambda: total() >= sent, 3.0), (total(), sent)
        time.sleep(1.2)  # one more beacon period: nothing else was dropped than what was sent
        assert sent <= total() <= sent + more, (total(), sent, more)
        assert all(n.stats.refused["scouting"] >= 100 for n in nodes)
        assert all(len(n.peers()) == 1 for n in nodes)  # the mesh is untouched
    finally:
        for n in nodes:
            n.close()
        rogue.close()


def test_a_member_announcing_a_plaintext_locator_is_never_dialled_and_is_counted(server: DiscoveryServer, keys: Path) -> None:
    """A registry entry with a tcp/ locator (what a compromised member could announce) is refused by the scheme check."""
    from discovery.protocol import Beacon, NodeEntry, beacon_body

    node = secured_node(server, keys, 1).open()
    rogue = Rogue()
    try:
        assert wait_for(lambda: node.connectivity.status()["server_contact_age"] is not None, 5.0)  # type: ignore[attr-defined]
        entry = NodeEntry("uav", 3, "virtual", "rogue", zid_from_hex("abcdef0123456789"), WHATAMI_PEER,
                          (f"tcp/127.0.0.1:{rogue.port}",))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(seal(MsgType.BEACON, SWARM, KEY.encode(), beacon_body(Beacon(entry, b"\0" * 8, 1.0))),
                     server.sock.getsockname()[:2])  # type: ignore[union-attr]
        assert wait_for(lambda: node.stats.refused["foreign_scheme"] == 1, 3.0), dict(node.stats.refused)
        assert rogue.count(2.5) == 0
    finally:
        node.close()
        rogue.close()
