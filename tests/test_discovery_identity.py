"""Discovery beacons bound to identities: one member's credentials speak only for that member.

The discovery server runs as a real process with the swarm's key directory (``--identities``);
UAVs 1 and 3 are real secured SwarmNodes. The attacker holds UAV 2's bundle (its certificate,
key and beacon token, and the swarm's discovery key), as a stolen UAV would, and beacons as UAV 3
with its own locator, then says UAV 3's goodbye. UAV 3's entry keeps its real locators in every
sample and is never removed; UAV 2 itself is still listed (its credentials are good for itself);
a revoked UAV 2 is refused once the roster says so. The same attack on a server without the key
directory succeeds: the positive control.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from discovery.client import query_registry
from discovery.protocol import Beacon, MsgType, NodeEntry, beacon_body, seal
from discovery.proxy import BeaconDiscovery
from discovery.wire import WHATAMI_PEER, zid_from_hex
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.security.beacon import read_token
from swarmnet.security.credentials import Credentials
from swarmnet.security.identity import NodeName
from swarmnet.security.pki import KeyDir
from tests.conftest import free_port, wait_for

ROOT = Path(__file__).resolve().parents[1]
SWARM = "alpha"
KEY = "alpha-key-0123456789abcdef"
ROGUE = "tls/127.0.0.1:9"


@pytest.fixture
def keys(tmp_path: Path) -> KeyDir:
    kd = KeyDir.init(tmp_path / "keys", SWARM)
    for n in ("uav-1", "uav-2", "uav-3"):
        kd.issue(NodeName.in_swarm(n, SWARM))
    return kd


def serve(keys: KeyDir | None) -> Iterator[str]:
    addr = f"127.0.0.1:{free_port(socket.SOCK_DGRAM)}"
    argv = [sys.executable, "-m", "discovery.server", "--listen", addr, "--key", f"{SWARM}={KEY}", "--rate", "5000"]
    argv += ["--identities", str(keys.path)] if keys is not None else []
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        assert wait_for(lambda: _answers(addr), 10.0), "the discovery server did not start"
        yield addr
    finally:
        proc.terminate()
        proc.wait(10)


def _answers(addr: str) -> bool:
    try:
        query_registry(addr, SWARM, KEY, timeout=0.2, attempts=1)
        return True
    except Exception:  # noqa: BLE001 - not up yet
        return False


@pytest.fixture
def bound_server(keys: KeyDir) -> Iterator[str]:
    yield from serve(keys)


@pytest.fixture
def open_server() -> Iterator[str]:
    yield from serve(None)


def uav(server: str, keys: KeyDir, n: int) -> SwarmNode:
    creds = Credentials(keys=str(keys.path), identity=NodeName.uav(n, SWARM).cn)
    return SwarmNode(NodeIdentity(SWARM, n), BeaconDiscovery(server=server, key=KEY, credentials=creds))


def registry(server: str) -> dict[int, NodeEntry]:
    rows, _ = query_registry(server, SWARM, KEY)
    return {r.entry.node: r.entry for r in rows if r.entry.role == "uav"}


class Thief:
    """Speaks to the discovery server with UAV 2's credentials (``token``), or none."""

    def __init__(self, server: str, token: bytes | None):
        host, port = server.rsplit(":", 1)
        self.server = (host, int(port))
        self.token = token
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def beacon_as(self, node: int, locator: str = ROGUE) -> None:
        entry = NodeEntry("uav", node, "virtual", "thief", zid_from_hex(os.urandom(8).hex()), WHATAMI_PEER, (locator,))
        self.sock.sendto(seal(MsgType.BEACON, SWARM, KEY.encode(), beacon_body(Beacon(entry, b"\0" * 8, 1.0)),
                              token=self.token), self.server)

    def bye_for(self, node: int) -> None:
        self.sock.sendto(seal(MsgType.BYE, SWARM, KEY.encode(), ["uav", node], token=self.token), self.server)

    def close(self) -> None:
        self.sock.close()


def test_a_second_uavs_credentials_cannot_replace_or_remove_another_uavs_entry(bound_server: str, keys: KeyDir) -> None:
    nodes = [uav(bound_server, keys, n).open() for n in (1, 3)]
    stolen = read_token(keys.path, NodeName.uav(2, SWARM).cn)
    thieves = [Thief(bound_server, stolen), Thief(bound_server, None)]  # UAV 2's token, and the swarm key alone
    try:
        assert wait_for(lambda: set(registry(bound_server)) == {1, 3}, 5.0)
        real = registry(bound_server)[3].locators
        samples = []
        for _ in range(40):  # 8 s: the attacker beacons as UAV 3 and says its goodbye, five times a second
            for t in thieves:
                t.beacon_as(3)
                t.bye_for(3)
            samples.append(registry(bound_server).get(3))
            time.sleep(0.2)
        assert all(e is not None and e.locators == real for e in samples), "UAV 3's entry was replaced or removed"
        rows, stats = query_registry(bound_server, SWARM, KEY)
        assert stats["drop_bad_identity"] >= 80 and stats["drop_untagged"] >= 80, stats
        assert stats.get("left", 0) == 0
        thieves[0].beacon_as(2, "tls/127.0.0.1:7")  # UAV 2's credentials still speak for UAV 2
        assert wait_for(lambda: 2 in registry(bound_server), 2.0)
        keys.revoke(NodeName.uav(2, SWARM))  # ... until it is revoked: the server reads the roster again
        time.sleep(1.5)
        before = query_registry(bound_server, SWARM, KEY)[1]["drop_bad_identity"]
        thieves[0].beacon_as(2, "tls/127.0.0.1:7")
        assert wait_for(lambda: query_registry(bound_server, SWARM, KEY)[1]["drop_bad_identity"] > before, 2.0)
    finally:
        for t in thieves:
            t.close()
        for n in nodes:
            n.close()


def test_the_same_attack_succeeds_on_a_server_without_identities_the_positive_control(open_server: str,
                                                                                   keys: KeyDir) -> None:
    node = uav(open_server, keys, 3).open()
    thief = Thief(open_server, None)
    try:
        assert wait_for(lambda: 3 in registry(open_server), 5.0)
        thief.beacon_as(3)
        assert wait_for(lambda: registry(open_server).get(3) is not None and registry(open_server)[3].locators == (ROGUE,),
                        2.0), "the forged beacon did not take: this test proves nothing"
    finally:
        thief.close()
        node.close()


def test_a_tagged_goodbye_of_the_node_itself_still_removes_it_at_once(bound_server: str, keys: KeyDir) -> None:
    a, b = uav(bound_server, keys, 1).open(), uav(bound_server, keys, 3).open()
    try:
        assert wait_for(lambda: set(registry(bound_server)) == {1, 3}, 5.0)
        b.close()
        assert wait_for(lambda: set(registry(bound_server)) == {1}, 1.0)
        assert query_registry(bound_server, SWARM, KEY)[1]["left"] == 1
    finally:
        a.close()
        b.close()
