"""Beacon protocol and discovery server on 127.0.0.1: authentication, replay, registry, relay, bad input.

The server runs for real (its UDP socket and loop, in a thread); the "nodes" here are bare
UDP sockets speaking the protocol, so each test controls exactly what is sent.
"""

from __future__ import annotations

import os
import random
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from discovery.client import QueryTimeout, query_registry
from discovery.protocol import (
    MAX_DATAGRAM,
    Beacon,
    Envelope,
    MsgType,
    NodeEntry,
    ProtocolError,
    ReplayGuard,
    beacon_body,
    parse_beacon,
    parse_bye,
    parse_gone,
    parse_peers,
    parse_query,
    seal,
    unseal,
    view_digest,
)
from discovery.server import DiscoveryServer, ServerConfig, load_keys
from tests.conftest import wait_for

KA = "alpha-key-0123456789abcdef"
KB = "beta-key-0123456789abcdef0"


def entry(node: int, role: str = "uav", port: int | None = None) -> NodeEntry:
    return NodeEntry(role, node, "virtual", "test", os.urandom(16).rstrip(b"\0") or b"\1", 1,
                     (f"tcp/10.0.{node % 250}.2:{port or 7447}",))


class FakeNode:
    """A UDP socket that beacons like a proxy and collects what the server sends back."""

    def __init__(self, server: tuple[str, int], swarm: str, key: str, e: NodeEntry):
        self.server, self.swarm, self.key, self.entry = server, swarm, key.encode(), e
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.inbox: list[Envelope] = []
        self.view: list[NodeEntry] = []

    def beacon(self, view: bytes | None = None) -> None:
        v = view if view is not None else view_digest(self.view)
        self.sock.sendto(seal(MsgType.BEACON, self.swarm, self.key, beacon_body(Beacon(self.entry, v, 1.0))), self.server)

    def recv(self, wait: float = 0.5) -> list[Envelope]:
        deadline = time.monotonic() + wait
        got = []
        while time.monotonic() < deadline:
            try:
                data, _ = self.sock.recvfrom(MAX_DATAGRAM + 1)
            except TimeoutError:
                if got:
                    break
                continue
            env = unseal(data, lambda s: self.key if s == self.swarm else None)
            got.append(env)
            if env.type == MsgType.PEERS:
                p = parse_peers(env.body)
                for e in p.entries:
                    self.view = [x for x in self.view if x.key != e.key] + [e]
            elif env.type == MsgType.GONE:
                gone = set(parse_gone(env.body))
                self.view = [x for x in self.view if x.key not in gone]
        self.inbox += got
        return got

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def server() -> Iterator[DiscoveryServer]:
    srv = DiscoveryServer(ServerConfig(keys={"alpha": KA.encode(), "beta": KB.encode()}, ttl=1.0, rate=2000, burst=4000))
    srv.bind("127.0.0.1", 0)
    stop = threading.Event()
    th = threading.Thread(target=srv.serve, args=(stop,), daemon=True)
    th.start()
    yield srv
    stop.set()
    th.join(5)
    srv.close()


def addr(srv: DiscoveryServer) -> tuple[str, int]:
    assert srv.sock is not None
    return srv.sock.getsockname()[:2]


def types(envs: list[Envelope]) -> list[str]:
    return [e.type.name for e in envs]


# ---- envelope -----------------------------------------------------------------------------------------
def test_seal_unseal_round_trip_and_every_tampered_byte_is_rejected() -> None:
    e = entry(3)
    data = seal(MsgType.BEACON, "alpha", KA.encode(), beacon_body(Beacon(e, b"\0" * 8, 1.0)))
    env = unseal(data, {"alpha": KA.encode()}.get)
    assert env.type == MsgType.BEACON and env.swarm == "alpha" and abs(env.ts - time.time()) < 1
    for i in range(len(data)):
        b = bytearray(data)
        b[i] ^= 0x01
        with pytest.raises(ProtocolError) as exc:
            unseal(bytes(b), {"alpha": KA.encode(), "alphb": KA.encode()}.get)
        assert exc.value.reason in ("bad_mac", "malformed", "bad_version", "unknown_swarm")
    with pytest.raises(ProtocolError, match="bad_mac"):
        unseal(data, {"alpha": KB.encode()}.get)
    with pytest.raises(ProtocolError, match="unknown_swarm"):
        unseal(data, {"beta": KB.encode()}.get)
    with pytest.raises(ProtocolError, match="oversized"):
        unseal(data + b"\0" * MAX_DATAGRAM, {"alpha": KA.encode()}.get)


def test_replay_guard_rejects_old_timestamps_and_repeated_nonces() -> None:
    g = ReplayGuard(window=5.0)
    key = {"alpha": KA.encode()}.get
    fresh = unseal(seal(MsgType.QUERY, "alpha", KA.encode(), [1]), key)
    g.check(fresh)
    with pytest.raises(ProtocolError, match="replayed"):
        g.check(fresh)
    old = unseal(seal(MsgType.QUERY, "alpha", KA.encode(), [1], ts=time.time() - 30), key)
    with pytest.raises(ProtocolError, match="stale"):
        g.check(old)
    future = unseal(seal(MsgType.QUERY, "alpha", KA.encode(), [1], ts=time.time() + 30), key)
    with pytest.raises(ProtocolError, match="stale"):
        g.check(future)


@pytest.mark.parametrize("bad", [
    ["pilot", 1, "virtual", "x", b"\1", 1, ["tcp/1.2.3.4:1"]],  # unknown role
    ["uav", 0, "virtual", "x", b"\1", 1, ["tcp/1.2.3.4:1"]],  # id out of range
    ["uav", 1, "virtual", "x", b"\1", 2, ["tcp/1.2.3.4:1"]],  # a client cannot be dialled
    ["uav", 1, "virtual", "x", b"\1" * 17, 1, ["tcp/1.2.3.4:1"]],  # zid too long
    ["uav", 1, "virtual", "x", b"\1", 1, []],  # nowhere to dial
    ["uav", 1, "virtual", "x", b"\1", 1, ["tcp/1.2.3.4:1"] * 9],  # too many locators
    ["uav", 1, "virtual", "x", b"\1", 1, ["tcp/1.2.3.4:1 ; rm -rf"]],  # not a locator
    ["uav", 1, "mixed", "x", b"\1", 1, ["tcp/1.2.3.4:1"]],  # unknown realm
    ["uav", 1, "virtual", "x", b"\1", 1],  # short
])
def test_invalid_entries_are_rejected(bad: list[Any]) -> None:
    with pytest.raises(ProtocolError, match="invalid_entry"):
        NodeEntry.from_wire(bad)


def test_unseal_never_raises_anything_but_protocol_error_on_garbage() -> None:
    rng = random.Random(5)
    good = seal(MsgType.BEACON, "alpha", KA.encode(), beacon_body(Beacon(entry(1), b"\0" * 8, 1.0)))
    keys = {"alpha": KA.encode()}.get
    for i in range(4000):
        if i % 2:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 200)))
        else:
            b = bytearray(good)
            b[rng.randrange(len(b))] = rng.randrange(256)
            data = bytes(b[: rng.randrange(len(b) + 1)])
        try:
            unseal(data, keys)
        except ProtocolError:
            pass


def test_bodies_with_a_valid_mac_but_garbage_inside_raise_protocol_error_only() -> None:
    keys = {"alpha": KA.encode()}.get
    bodies = [None, 1, "x", [1, 2], {"a": 1}, [[1] * 7, b"", 0.5], [b"x" * 70], [[]] * 3, [[], b"\0" * 8, 1e9],
              [["uav", 1, "virtual", "s", b"\1", 1, [1]], b"\0" * 8, 1.0], [2 ** 40, 0, 1, []], [1, 5, 2, []]]
    for body in bodies:
        try:
            env = unseal(seal(MsgType.BEACON, "alpha", KA.encode(), body), keys)
        except ProtocolError as exc:  # e.g. a bin field longer than any valid one
            assert exc.reason == "malformed"
            continue
        for parse in (parse_beacon, parse_peers, parse_gone, parse_bye, parse_query):
            try:
                parse(env.body)
            except ProtocolError:
                pass


# ---- server -------------------------------------------------------------------------------------------
def test_new_member_is_pushed_to_the_others_and_gets_a_snapshot(server: DiscoveryServer) -> None:
    a = FakeNode(addr(server), "alpha", KA, entry(1))
    b = FakeNode(addr(server), "alpha", KA, entry(2))
    try:
        a.beacon()
        assert types(a.recv()) == ["ACK"]  # alone, and its (empty) view is right
        b.beacon()
        got_b = b.recv()
        assert types(got_b) == ["PEERS"] and parse_peers(got_b[0].body).snap != 0  # a snapshot with A
        assert [e.key for e in b.view] == [("uav", 1)]
        got_a = a.recv()
        assert types(got_a) == ["PEERS"] and parse_peers(got_a[0].body).snap == 0  # B pushed to A at once
        assert [e.key for e in a.view] == [("uav", 2)]
        b.beacon()
        assert types(b.recv()) == ["ACK"]  # B's view is current now: a 100-byte answer
        assert server.stats["pushes"] == 1 and server.stats["snapshots"] == 1
    finally:
        a.close()
        b.close()


def test_silent_member_expires_within_the_ttl_and_the_others_are_told(server: DiscoveryServer) -> None:
    a = FakeNode(addr(server), "alpha", KA, entry(1))
    b = FakeNode(addr(server), "alpha", KA, entry(2))
    try:
        a.beacon()
        b.beacon()
        a.recv()
        b.recv()
        t0 = time.monotonic()
        got: list[Envelope] = []
        while time.monotonic() - t0 < 3.0 and "GONE" not in types(got):
            a.beacon(view_digest(a.view))
            got += a.recv(0.3)
        assert "GONE" in types(got)
        assert time.monotonic() - t0 < 1.0 + 0.6  # ttl 1 s (+ sweep and beacon slack)
        assert a.view == [] and ("uav", 2) not in server.members["alpha"]
        assert server.stats["expired"] == 1
    finally:
        a.close()
        b.close()


def test_swarms_are_isolated_and_a_wrong_key_is_never_listed(server: DiscoveryServer) -> None:
    a = FakeNode(addr(server), "alpha", KA, entry(1))
    b = FakeNode(addr(server), "beta", KB, entry(1))
    intruder = FakeNode(addr(server), "alpha", KB, entry(66))  # beta's key, claims alpha
    try:
        for n in (a, b):
            n.beacon()
            n.recv()
        intruder.beacon()
        assert intruder.sock.gettimeout() and not _any_reply(intruder)
        b2 = FakeNode(addr(server), "beta", KB, entry(2))
        b2.beacon()
        b2.recv()
        b.recv()
        a.recv(0.3)
        assert [e.key for e in a.view] == []  # beta's members never reach alpha
        assert [e.key for e in b.view] == [("uav", 2)]
        rows, stats = query_registry("{}:{}".format(*addr(server)), "alpha", KA)
        assert [(r.entry.role, r.entry.node) for r in rows] == [("uav", 1)]
        assert stats["drop_bad_mac"] == 1
        with pytest.raises(QueryTimeout):  # a wrong key cannot even read the registry
            query_registry("{}:{}".format(*addr(server)), "alpha", KB, timeout=0.3, attempts=1)
        b2.close()
    finally:
        a.close()
        b.close()
        intruder.close()


def _any_reply(n: FakeNode) -> bool:
    try:
        n.sock.settimeout(0.3)
        n.sock.recvfrom(MAX_DATAGRAM)
        return True
    except TimeoutError:
        return False


def test_replayed_beacons_and_spoofed_byes_change_nothing(server: DiscoveryServer) -> None:
    a = FakeNode(addr(server), "alpha", KA, entry(1))
    try:
        data = seal(MsgType.BEACON, "alpha", KA.encode(), beacon_body(Beacon(a.entry, b"\0" * 8, 1.0)))
        a.sock.sendto(data, addr(server))
        a.recv()
        a.sock.sendto(data, addr(server))  # the same datagram again
        older = seal(MsgType.BEACON, "alpha", KA.encode(), beacon_body(Beacon(a.entry, b"\0" * 8, 1.0)), ts=time.time() - 2)
        a.sock.sendto(older, addr(server))  # a new nonce but older than the last beacon
        other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        other.sendto(seal(MsgType.BYE, "alpha", KA.encode(), ["uav", 1]), addr(server))  # BYE from another socket
        other.close()
        assert wait_for(lambda: server.stats["drop_replayed"] == 2 and server.stats["drop_bye_unknown"] == 1, 2.0), server.stats
        assert ("uav", 1) in server.members["alpha"]
        a.sock.sendto(seal(MsgType.BYE, "alpha", KA.encode(), ["uav", 1]), addr(server))
        assert wait_for(lambda: ("uav", 1) not in server.members["alpha"], 2.0)
    finally:
        a.close()


def test_server_survives_every_kind_of_bad_input_and_counts_it(server: DiscoveryServer) -> None:
    target = addr(server)
    rng = random.Random(11)
    valid = seal(MsgType.QUERY, "alpha", KA.encode(), [7])
    bad = [
        b"",
        b"\x00" * 3,
        b"MRSD",
        os.urandom(MAX_DATAGRAM + 100),  # oversized (truncated to MAX+1 on receive)
        b"MRSD\x09" + valid[5:],  # a future protocol version
        valid[:-1] + bytes([valid[-1] ^ 1]),  # bad MAC
        seal(MsgType.QUERY, "gamma", KA.encode(), [1]),  # a swarm the server has no key for
        seal(MsgType.QUERY, "alpha", KA.encode(), [1], ts=time.time() - 3600),  # stale
        seal(MsgType.BEACON, "alpha", KA.encode(), ["not", "a", "beacon"]),  # valid MAC, malformed body
        seal(MsgType.ACK, "alpha", KA.encode(), [b"\0" * 8]),  # a server->proxy type sent to the server
        seal(MsgType.BEACON, "alpha", KA.encode(), [["uav", 1, "virtual", "x", b"\1", 2, ["tcp/1.2.3.4:1"]], b"\0" * 8, 1.0]),
    ] + [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))) for _ in range(300)]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for d in bad:
            s.sendto(d, target)
        s.sendto(valid, target)
        s.sendto(valid, target)  # replay
    assert wait_for(lambda: server.stats["rx"] >= len(bad) + 2, 3.0)
    st = server.stats
    for reason in ("malformed", "oversized", "bad_version", "bad_mac", "unknown_swarm", "stale", "replayed",
                   "unexpected_type", "invalid_entry"):
        assert st["drop_" + reason] >= 1, (reason, dict(st))
    assert st["drop_internal_error"] == 0
    rows, stats = query_registry("{}:{}".format(*target), "alpha", KA)  # still serving
    assert rows == [] and stats["queries"] >= 1


def test_a_flood_from_one_address_is_rate_limited_and_service_resumes() -> None:
    srv = DiscoveryServer(ServerConfig(keys={"alpha": KA.encode()}, rate=20, burst=20))
    srv.bind("127.0.0.1", 0)
    stop = threading.Event()
    th = threading.Thread(target=srv.serve, args=(stop,), daemon=True)
    th.start()
    try:
        target = addr(srv)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for _ in range(500):
                s.sendto(b"flood", target)
        assert wait_for(lambda: srv.stats["rx"] >= 400, 3.0)
        # the server may still be draining its socket: rx >= 400 alone does not imply 400 drops yet
        assert wait_for(lambda: srv.stats["drop_rate_limited"] >= 400, 3.0), srv.stats
        time.sleep(1.0)  # the bucket refills
        rows, _ = query_registry("{}:{}".format(*target), "alpha", KA)
        assert rows == []
    finally:
        stop.set()
        th.join(5)
        srv.close()


def test_keys_file_formats(tmp_path: Any) -> None:
    p = tmp_path / "keys"
    p.write_text("# swarm keys\nalpha  0123456789abcdef0123\n\nbeta fedcba9876543210fedc  # second\n")
    assert load_keys(p) == {"alpha": "0123456789abcdef0123", "beta": "fedcba9876543210fedc"}
    p.write_text('{"alpha": "0123456789abcdef0123"}')
    assert load_keys(p) == {"alpha": "0123456789abcdef0123"}
    p.write_text("alpha\n")
    with pytest.raises(ValueError, match="SWARM KEY"):
        load_keys(p)
    with pytest.raises(ValueError, match="at least 16"):
        ServerConfig(keys={"alpha": b"short"})


def test_builtin_hmac_matches_the_standard_library() -> None:
    import hashlib
    import hmac

    from discovery.protocol import hmac_sha256

    # RFC 4231 test case 2
    assert hmac_sha256(b"Jefe", b"what do ya want for nothing?").hex() == \
        "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843"
    rng = random.Random(9)
    for n in range(300):
        key = bytes(rng.randrange(256) for _ in range(n % 140))
        msg = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 1500)))
        assert hmac_sha256(key, msg) == hmac.new(key, msg, hashlib.sha256).digest()


def test_discovery_in_a_uav_process_does_not_load_openssl() -> None:
    """hashlib/hmac pull in OpenSSL's libcrypto (~4 MB RSS in each of 50 UAV processes)."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    code = ("import sys, discovery.proxy, discovery.protocol, swarmnet.node; "
            "print(sorted(m for m in ('_hashlib', 'hashlib', 'hmac', 'ssl') if m in sys.modules))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, timeout=60,
                         env={**os.environ, "PYTHONPATH": str(root)})
    assert res.returncode == 0, res.stderr
    assert "_hashlib" not in res.stdout and "'hmac'" not in res.stdout, res.stdout
