"""The discovery server and proxy under attack, on loopback: spoofed-source floods, bloated
counters, inconsistent multi-part answers.

The server runs as a real process (``mrswarm discovery serve``); the members are real UDP
sockets, one source address each (127.0.2.x and up), beaconing with the swarm's key once a
second like proxies do; the attacker is another process sending from forged source
addresses in 127.1.0.0/16 (tests/spoof_flood.py).
"""

from __future__ import annotations

import os
import resource
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from discovery.client import QueryTimeout, query_registry
from discovery.protocol import (
    MAX_DATAGRAM,
    Beacon,
    MsgType,
    NodeEntry,
    PartAssembler,
    Peers,
    beacon_body,
    digest_of,
    entry_hash,
    parse_beacon,
    peers_body,
    seal,
    unseal,
)
from discovery.proxy import BeaconDiscovery
from discovery.server import DiscoveryServer, ServerConfig
from swarmnet.node import NodeIdentity, SwarmNode
from tests.conftest import free_port, wait_for

ROOT = Path(__file__).resolve().parents[1]
KEY = "alpha-key-0123456789abcdef"
TTL = 3.0


def big_entry(node: int, locators: int = 8) -> NodeEntry:
    """As large as an entry may be: 8 locators of about 100 characters."""
    locs = tuple(f"tcp/[2001:db8:{node:x}::{k:x}]:{7447 + k}?iface=" + "x" * 60 for k in range(locators))
    return NodeEntry("uav", node, "physical", "mrswarm/0.1.0+" + "b" * 30, os.urandom(16).rstrip(b"\0") or b"\1", 1, locs)


class Members:
    """N members, each a UDP socket on its own loopback address, beaconing every second.

    Each beacon carries the view a proxy that keeps up would hold: every member that beaconed
    before it. Newcomers beacon first in a round, so the members already there hold the
    newcomers (which the server pushed to them) by the time their own beacons arrive.
    """

    def __init__(self, server: tuple[str, int]):
        self.server = server
        self.key = KEY.encode()
        self.entries: list[NodeEntry] = []
        self.socks: list[socket.socket] = []
        self.joined = 0  # entries[:joined] have beaconed at least once
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def enroll(self, n: int) -> None:
        with self.lock:
            for _ in range(n):
                i = len(self.entries)
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # pushes and acks are not read here
                s.bind((f"127.0.{2 + i // 250}.{1 + i % 250}", 0))
                s.setblocking(False)
                self.entries.append(big_entry(i + 1, locators=1 + i % 3))
                self.socks.append(s)

    def _beacon(self, i: int, view: bytes) -> None:
        try:
            self.socks[i].sendto(seal(MsgType.BEACON, "alpha", self.key, beacon_body(Beacon(self.entries[i], view, 1.0))),
                                 self.server)
        except OSError:
            pass

    def _run(self) -> None:
        hashes: list[int] = []
        while not self.stop.is_set():
            t0 = time.monotonic()
            with self.lock:
                n = len(self.entries)
            total = sum(hashes)
            for i in range(self.joined, n):  # newcomers first: each one's view is everyone before it
                self._beacon(i, digest_of(total))
                hashes.append(entry_hash(self.entries[i]))
                total += hashes[-1]
            old, self.joined = self.joined, n
            for i in range(old):
                self._beacon(i, digest_of(total - hashes[i]))
            self.stop.wait(max(0.0, 1.0 - (time.monotonic() - t0)))

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        for s in self.socks:
            s.close()


@pytest.fixture
def server_process(tmp_path: Path) -> Iterator[tuple[str, int]]:
    keys = tmp_path / "keys"
    keys.write_text(f"alpha {KEY}\n")
    port = free_port(socket.SOCK_DGRAM)
    proc = subprocess.Popen([sys.executable, "-m", "mrswarm", "discovery", "serve", "--listen", f"127.0.0.1:{port}",
                             "--keys", str(keys), "--ttl", str(TTL), "--log-level", "WARNING", "--die-with-parent"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        assert proc.stdout is not None
        assert "discovery server on udp/" in proc.stdout.readline()
        yield ("127.0.0.1", port)
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def registry(server: tuple[str, int]) -> tuple[list, dict]:
    return query_registry(f"{server[0]}:{server[1]}", "alpha", KEY, timeout=2.0, attempts=3)


def count(server: tuple[str, int]) -> int:
    try:
        return len(registry(server)[0])
    except QueryTimeout:
        return -1


def enough_descriptors(n: int = 4096) -> None:
    """1000 member sockets need more than the usual soft limit of 1024 descriptors."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < n:
        resource.setrlimit(resource.RLIMIT_NOFILE, (n if hard == resource.RLIM_INFINITY else min(n, hard), hard))


@pytest.mark.e2e
def test_spoofed_source_flood_expires_no_member_and_the_registry_stays_complete_at_12_100_1000(
        server_process: tuple[str, int]) -> None:
    enough_descriptors()
    members = Members(server_process)
    members.thread.start()
    try:
        for n in (12, 100, 1000):
            while len(members.entries) < n:  # joins in steps: each one is pushed to every member
                members.enroll(min(100, n - len(members.entries)))
                target = len(members.entries)
                assert wait_for(lambda t=target: count(server_process) == t, 30, 0.5), f"registry never reached {target} members"
            _, before = registry(server_process)
            flood = subprocess.run([sys.executable, "-m", "tests.spoof_flood", "--target", "{}:{}".format(*server_process),
                                    "--count", "100000", "--first", str(n * 100_000)],
                                   cwd=ROOT, capture_output=True, text=True, timeout=300)
            assert flood.returncode == 0, flood.stderr
            sent = int(flood.stdout.split()[1])
            assert sent == 100_000, flood.stdout
            time.sleep(TTL + 0.5)  # a member silenced by the flood would have expired by now
            rows, stats = registry(server_process)
            # every member listed once, exactly as it announced itself, from its own address
            got = {r.entry.node: r for r in rows}
            assert len(rows) == n and sorted(got) == list(range(1, n + 1)), (n, sorted(got)[:20])
            for e, s in zip(members.entries, members.socks, strict=True):
                r = got[e.node]
                assert r.entry == e and r.address == "{}:{}".format(*s.getsockname())
            assert stats.get("expired", 0) == 0 and stats.get("left", 0) == 0, stats
            assert stats.get("drop_internal_error", 0) == 0, stats
            # the junk was seen (or dropped by the kernel on a full queue) and rejected, none of it registered
            junk = sum(stats.get(k, 0) - before.get(k, 0) for k in
                       ("drop_bad_mac", "drop_malformed", "drop_rate_limited", "drop_rx_queue_full"))
            assert junk >= 0.99 * sent, (junk, stats)
            assert stats["registered"] == n, stats
            # the per-source table stayed bounded: every new source past 4096 cost one O(1) eviction, not a rebuild
            looked_at = sum(stats.get(k, 0) - before.get(k, 0) for k in ("drop_bad_mac", "drop_malformed", "drop_rate_limited"))
            assert stats["sources"] <= 4096 + n + 1, stats
            assert stats["sources_evicted"] - before["sources_evicted"] >= looked_at - 4096, stats
    finally:
        members.close()


def test_registry_answers_fit_the_datagram_budget_at_every_size_with_many_counters() -> None:
    srv = DiscoveryServer(ServerConfig(keys={"alpha": KEY.encode()}, rate=5000, burst=5000))
    host, port = srv.bind("127.0.0.1", 0)
    stop = threading.Event()
    th = threading.Thread(target=srv.serve, args=(stop,), daemon=True)
    th.start()
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            # junk of every kind first: each drop reason is one more counter in the answer
            for d in [b"", os.urandom(7), b"MRSD\x07" + os.urandom(40), seal(MsgType.ACK, "alpha", KEY.encode(), [b"\0" * 8]),
                      seal(MsgType.QUERY, "nosuch", KEY.encode(), [1]), os.urandom(MAX_DATAGRAM + 10),
                      seal(MsgType.QUERY, "alpha", KEY.encode(), [1], ts=time.time() - 600),
                      seal(MsgType.BEACON, "alpha", KEY.encode(), [1, 2, 3])] * 100:
                s.sendto(d, (host, port))
            entries = []
            for i in range(1, 41):  # entries of 1..8 locators: the last datagram of an answer fills to every level
                entries.append(big_entry(i, locators=1 + (i * 5) % 8))
                s.sendto(seal(MsgType.BEACON, "alpha", KEY.encode(), beacon_body(Beacon(entries[-1], b"\0" * 8, 1.0))),
                         (host, port))
                assert wait_for(lambda n=i: len(srv.registry("alpha")) == n, 5.0)
                rows, stats = query_registry(f"{host}:{port}", "alpha", KEY)
                assert {r.entry for r in rows} == set(entries) and len(rows) == i
        assert stats["drop_malformed"] >= 100 and stats["drop_oversized"] >= 100 and stats["drop_unknown_swarm"] >= 100
        assert srv.stats["drop_internal_error"] == 0
    finally:
        stop.set()
        th.join(5)
        srv.close()


def test_registry_query_works_from_a_process_with_more_than_1024_descriptors() -> None:
    """select() cannot watch a descriptor above 1023; a busy ground station has them."""
    enough_descriptors()
    srv = DiscoveryServer(ServerConfig(keys={"alpha": KEY.encode()}))
    host, port = srv.bind("127.0.0.1", 0)
    stop = threading.Event()
    th = threading.Thread(target=srv.serve, args=(stop,), daemon=True)
    th.start()
    filler = []
    try:
        while not filler or filler[-1] < 1100:
            filler.append(os.dup(0))
        rows, stats = query_registry(f"{host}:{port}", "alpha", KEY)
        assert rows == [] and stats["queries"] == 1
    finally:
        for fd in filler:
            os.close(fd)
        stop.set()
        th.join(5)
        srv.close()


def test_part_assembler_restarts_on_parts_that_disagree_and_never_raises() -> None:
    a = PartAssembler()
    assert a.add(7, 0, 3, ["a"]) is None
    assert a.add(7, 4, 5, ["x"]) is None  # same id, another count: start over
    assert a.add(7, 3, 4, ["y"]) is None  # and again
    assert a.add(7, 9, 4, ["z"]) is None  # a part beyond the count
    assert a.inconsistent == 3
    assert a.add(8, 1, 2, ["b"]) is None and a.add(8, 0, 2, ["a"]) == ["a", "b"]
    assert a.add(9, 0, 1, []) == []


def test_proxy_survives_a_snapshot_whose_parts_disagree_and_applies_the_next_good_one() -> None:
    fake = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # plays the discovery server
    fake.bind(("127.0.0.1", 0))
    fake.settimeout(3)
    srv = "{}:{}".format(*fake.getsockname())
    a = SwarmNode(NodeIdentity("alpha", 1), BeaconDiscovery(server=srv, key=KEY)).open()
    b = SwarmNode(NodeIdentity("alpha", 2), BeaconDiscovery(server=srv, key=KEY)).open()
    try:
        beacons: dict[int, tuple[NodeEntry, tuple[str, int]]] = {}
        while len(beacons) < 2:
            data, src = fake.recvfrom(MAX_DATAGRAM)
            e = parse_beacon(unseal(data, {"alpha": KEY.encode()}.get).body).entry
            beacons[e.node] = (e, src)
        eb = beacons[2][0]
        k = KEY.encode()
        # parts of snapshot 7 that disagree on how many parts there are: this made the proxy raise KeyError
        for part, parts in ((0, 3), (4, 5), (3, 4)):
            fake.sendto(seal(MsgType.PEERS, "alpha", k, peers_body(Peers(7, part, parts, (eb,)))), beacons[1][1])
        assert wait_for(lambda: a.connectivity.status()["stats"].get("drop_inconsistent_snapshot", 0) >= 2, 3.0)  # type: ignore[attr-defined]
        stats = a.connectivity.status()["stats"]  # type: ignore[attr-defined]
        assert stats.get("internal_error", 0) == 0 and a.peers() == [], stats
        # a consistent snapshot afterwards is applied: A learns B and they link
        fake.sendto(seal(MsgType.PEERS, "alpha", k, peers_body(Peers(8, 0, 1, (eb,)))), beacons[1][1])
        fake.sendto(seal(MsgType.PEERS, "alpha", k, peers_body(Peers(0, 0, 1, (beacons[1][0],)))), beacons[2][1])
        assert wait_for(lambda: a.peers() == [b.zid], 5.0)
    finally:
        a.close()
        b.close()
        fake.close()
