"""Zenoh's scouting wire format, pinned against live zenoh sessions on 127.0.0.1.

The discovery proxy relies on zenoh 1.10 details (its scouting orchestrator,
``zenoh/src/net/runtime/orchestrator.rs``, and the Scout/Hello codec): a session
whose scouting address is a *unicast loopback* address answers a Scout sent there with
its Hello, from its scouting socket, and dials the locators of any Hello it receives on
that socket. If a zenoh upgrade changes any of this, these tests fail first.
"""

from __future__ import annotations

import json
import random
import socket
import time

import pytest
import zenoh

from discovery.proxy import BeaconDiscovery
from discovery.wire import (
    Hello,
    Locator,
    WireError,
    advertised_locators,
    decode_hello,
    encode_hello,
    encode_scout,
    zid_from_hex,
    zid_to_hex,
)
from tests.conftest import wait_for

KEY = "test-key-0123456789abcdef"


def open_session(dial: str = "always", listen: str = "tcp/127.0.0.1:0", lanes: int = 1) -> tuple[zenoh.Session, int]:
    bd = BeaconDiscovery(server="127.0.0.1:9", key=KEY, swarm="wire", node=1, role="uav", listen=(listen,), dial=dial,
                         lanes=lanes)
    cfg = bd.zenoh_config()
    return zenoh.open(zenoh.Config.from_json5(json.dumps(cfg))), bd.scout_port


def scout(port: int, timeout: float = 3.0, src: str = "127.0.0.1") -> tuple[bytes, tuple[str, int]]:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((src, 0))
        s.settimeout(0.3)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            s.sendto(encode_scout(), ("127.0.0.1", port))
            try:
                data, src = s.recvfrom(65535)
                return data, src[:2]
            except TimeoutError:
                continue
    raise AssertionError(f"no Hello from 127.0.0.1:{port}")


def test_session_answers_a_unicast_scout_with_its_hello_from_its_scouting_socket() -> None:
    s, port = open_session()
    try:
        data, src = scout(port)
        hello = decode_hello(data)
        assert hello.zid_hex == str(s.info.zid())
        assert hello.whatami == 1  # peer
        assert len(hello.locators) == 1 and hello.locators[0].startswith("tcp/127.0.0.1:")
        assert encode_hello(hello) == data  # our codec writes exactly what zenoh writes
        assert src[0] == "127.0.0.1" and src[1] != port  # the answer comes from the scouting socket S, not P
    finally:
        s.close()


def test_loopback_scout_sees_loopback_locators_and_the_proxy_drops_them_for_remote_servers() -> None:
    s, port = open_session(listen="tcp/0.0.0.0:0")
    try:
        hello = decode_hello(scout(port)[0])
        hosts = {Locator.parse(loc).host for loc in hello.locators}
        assert "127.0.0.1" in hosts  # zenoh includes loopback locators only for scouts from loopback
        remote_view = advertised_locators(hello.locators, keep_loopback=False)
        assert all(not Locator.parse(loc).is_loopback for loc in remote_view)
        assert set(remote_view) == {loc for loc in hello.locators if "127.0.0.1" not in loc}
    finally:
        s.close()


def test_injected_hello_makes_the_session_dial_the_locators() -> None:
    a, pa = open_session()
    b, pb = open_session()
    try:
        _, a_scouter = scout(pa)
        hello_b, _ = scout(pb)
        assert str(b.info.zid()) not in {str(z) for z in a.info.peers_zid()}
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
            u.sendto(hello_b, a_scouter)
        assert wait_for(lambda: str(b.info.zid()) in {str(z) for z in a.info.peers_zid()}, 5.0)
    finally:
        a.close()
        b.close()


def test_greater_zid_rule_gives_one_link_per_pair() -> None:
    sessions = [open_session(dial="greater-zid") for _ in range(3)]
    try:
        info = [(s, *scout(p)) for s, p in sessions]  # (session, hello, scouter)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
            for s, _, scouter in info:
                for s2, hello2, _ in info:
                    if s2 is not s:
                        u.sendto(hello2, scouter)
        assert wait_for(lambda: all(len(list(s.info.peers_zid())) == 2 for s, *_ in info), 5.0)
        time.sleep(0.3)
        assert [len(list(s.info.links())) for s, *_ in info] == [2, 2, 2]  # nobody dialled twice
    finally:
        for s, _ in sessions:
            s.close()


def test_zid_text_and_wire_forms_round_trip() -> None:
    for text in ("1", "ff", "100", "a1b2c3d4e5f60001", "f" * 32, "577da07fe94487b9fe4caca49fa5a7d"):
        wire = zid_from_hex(text)
        assert zid_to_hex(wire) == text
        assert wire[-1] != 0 or len(wire) == 1
    with pytest.raises(ValueError):
        zid_from_hex("1" + "0" * 32)


def test_hello_codec_round_trips_and_rejects_garbage_with_wire_error_only() -> None:
    h = Hello(zid_from_hex("a1b2c3"), 1, ("tcp/10.0.0.1:7447", "udp/[fe80::1]:7448", "tcp/host.example:1?x=1#y=2"))
    assert decode_hello(encode_hello(h)) == h
    assert decode_hello(encode_hello(Hello(b"\x01", 0))) == Hello(b"\x01", 0)
    rng = random.Random(3)
    good = encode_hello(h)
    for i in range(3000):
        if i % 2:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 80)))
        else:
            b = bytearray(good)
            for _ in range(rng.randrange(1, 4)):
                b[rng.randrange(len(b))] = rng.randrange(256)
            data = bytes(b[: rng.randrange(len(b) + 1)])
        try:
            decode_hello(data)
        except WireError:
            pass


def test_locators_parse_rewrite_and_advertise() -> None:
    loc = Locator.parse("tcp/[::1]:7447#iface=lo")
    assert (loc.proto, loc.host, loc.port, loc.tail) == ("tcp", "::1", "7447", "#iface=lo")
    assert loc.is_loopback and str(loc) == "tcp/[::1]:7447#iface=lo"
    listen = ["tcp/127.0.0.1:7447", "tcp/10.0.3.2:7447", "tcp/172.17.0.1:7447"]
    assert advertised_locators(listen) == ("tcp/10.0.3.2:7447", "tcp/172.17.0.1:7447")
    assert advertised_locators(listen, keep_loopback=True) == tuple(listen)
    # a public address in front of a NAT: one locator per listen port, with the public host
    assert advertised_locators(listen, ("203.0.113.5",)) == ("tcp/203.0.113.5:7447",)
    assert advertised_locators(listen, ("tls/uav7.example.org:443",)) == ("tls/uav7.example.org:443",)


def test_discovery_config_never_points_zenoh_at_a_multicast_group() -> None:
    cfg = BeaconDiscovery(server="10.0.0.2:7450", key=KEY, swarm="s", node=1, role="uav").zenoh_config()
    mc = cfg["scouting"]["multicast"]
    host, port = mc["address"].rsplit(":", 1)
    assert host == "127.0.0.1" and int(port) > 0
    assert mc["interface"] == "127.0.0.1,127.0.0.2,127.0.0.3,127.0.0.4"  # loopback only: the dial lanes
    assert cfg["scouting"]["gossip"]["enabled"] is False


def test_hellos_of_one_scouting_socket_are_dialled_one_at_a_time_and_lanes_run_in_parallel() -> None:
    """Why the proxy injects through several lanes: zenoh 1.10 handles the Hellos of one scouting
    socket serially, so a dial that hangs (here: a TCP server that never answers the zenoh
    handshake) holds up the next Hello for open_timeout (2 s). A second scouting socket,
    found by scouting from 127.0.0.2, is not held up."""
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(16)
    hang = encode_hello(Hello(zid_from_hex("abc123"), 1, (f"tcp/127.0.0.1:{silent.getsockname()[1]}",)))
    a, pa = open_session(lanes=2)
    b, pb = open_session()
    c, pc = open_session()
    try:
        lane1, lane2 = scout(pa)[1], scout(pa, src="127.0.0.2")[1]
        assert lane1 != lane2
        linked = lambda s: {str(z) for z in a.info.peers_zid()} >= {str(s.info.zid())}  # noqa: E731
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
            u.sendto(hang, lane1)
            time.sleep(0.1)
            t0 = time.monotonic()
            u.sendto(scout(pb)[0], lane2)  # another lane: dialled at once
            assert wait_for(lambda: linked(b), 1.0)
            assert time.monotonic() - t0 < 1.0
            u.sendto(scout(pc)[0], lane1)  # behind the hanging dial
            assert wait_for(lambda: linked(c), 5.0)
            assert time.monotonic() - t0 > 1.5
    finally:
        for s in (a, b, c):
            s.close()
        silent.close()
