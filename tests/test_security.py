"""Credentials and access control on real Zenoh sessions (docs/security.md).

A secured edge router runs as its own process (``python -m discovery.rendezvous --keys``), as
in a run; the swarm's members and the intruders are real sessions in this process. What each
identity may do is asserted by what arrives, never by a flag.
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
import zenoh

from groundfloor.schema import ConfigError
from mrswarm.gcs.session import GcsError, resolve_target
from mrswarm.scenario import ScenarioError, load_scenario
from swarmnet.connectivity import Rendezvous, to_zenoh
from swarmnet.keyspace import SwarmKeys
from swarmnet.messages import Command, Pose, Realm, encode_command, encode_pose
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.observer import SwarmObserver
from swarmnet.security.acl import access_control
from swarmnet.security.credentials import Credentials, secure_endpoint
from swarmnet.security.identity import NodeName
from swarmnet.security.pki import KeyDir, KeysError
from swarmnet.security.roster import Roster
from swarmnet.security.zenoh_log import is_refused_handshake
from tests.conftest import free_port, wait_for

ROOT = Path(__file__).resolve().parents[1]
SWARM = "alpha"
KEYS = SwarmKeys(SWARM)


def creds(keys: Path, name: str) -> Credentials:
    return Credentials(keys=str(keys), identity=NodeName.in_swarm(name, SWARM).cn)


# ---- identities, key directory ---------------------------------------------------------------
def test_names_say_role_id_and_swarm() -> None:
    assert NodeName.parse("uav-3.alpha") == NodeName("uav", 3, "alpha")
    assert NodeName.in_swarm("ctl", "alpha").cn == "ctl.alpha" and NodeName.in_swarm("gcs-2", "b").cn == "gcs-2.b"
    for bad in ("uav.alpha", "uav-0.alpha", "edge-1.alpha", "pilot-1.alpha", "uav-3", "uav-3.al pha"):
        with pytest.raises(ValueError):
            NodeName.parse(bad)
    with pytest.raises(ValueError, match="belongs to swarm"):
        NodeName.in_swarm("uav-3.beta", "alpha")


def test_key_directory_issue_revoke_rotate(tmp_path: Path) -> None:
    kd = KeyDir.init(tmp_path / "k", SWARM)
    assert stat.S_IMODE(os.stat(kd.path).st_mode) == 0o700
    uav3 = NodeName.uav(3, SWARM)
    kd.issue(uav3)
    for f in (kd.path / "ca.key", kd.key_path(uav3)):
        assert stat.S_IMODE(os.stat(f).st_mode) == 0o600, f  # private keys: owner only
    assert kd.roster.is_member("uav-3.alpha")
    with pytest.raises(KeysError, match="already"):
        kd.issue(uav3)
    kd.issue(uav3, renew=True)
    with pytest.raises(KeysError, match="holds a CA"):
        KeyDir.init(kd.path, SWARM)
    kd.revoke(uav3)
    assert not kd.roster.is_member("uav-3.alpha") and "uav-3.alpha" in kd.roster.revoked
    assert not kd.key_path(uav3).exists()
    with pytest.raises(KeysError, match="revoked"):  # the old certificate would come back with the name
        kd.issue(uav3)
    kd.issue(NodeName("edge", 0, SWARM))
    old_ca = (kd.path / "ca.pem").read_bytes()
    assert kd.rotate() == [NodeName("edge", 0, SWARM)]
    assert (kd.path / "ca.pem").read_bytes() != old_ca and kd.roster.revoked == {}
    kd.issue(uav3)  # a new CA: the name is free again
    bundle = kd.bundle(uav3, tmp_path / "b3")
    assert sorted(p.name for p in bundle.iterdir()) == ["ca.pem", "mavlink.key", "roster.json", "uav-3.alpha.beacon",
                                                        "uav-3.alpha.key", "uav-3.alpha.pem"]
    for private in ("uav-3.alpha.key", "uav-3.alpha.beacon", "mavlink.key"):
        assert stat.S_IMODE(os.stat(bundle / private).st_mode) == 0o600
    assert "beacon.key" in {p.name for p in kd.bundle(NodeName("edge", 0, SWARM), tmp_path / "be").iterdir()}
    with pytest.raises(KeysError, match="no CA"):  # a bundle cannot issue
        KeyDir(bundle).issue(NodeName.uav(4, SWARM))


def test_credentials_name_what_is_missing(tmp_path: Path) -> None:
    kd = KeyDir.init(tmp_path / "k", SWARM)
    with pytest.raises(ConfigError, match="uav-1.alpha.pem missing"):
        Credentials(keys=str(kd.path), identity="uav-1.alpha").files()
    with pytest.raises(ConfigError, match="identity"):
        Credentials(keys=str(kd.path)).files()  # nobody filled in who speaks
    assert secure_endpoint("tcp/10.0.0.1:7447") == "tls/10.0.0.1:7447" and secure_endpoint("tls/h:1") == "tls/h:1"
    with pytest.raises(ValueError, match="udp"):
        secure_endpoint("udp/10.0.0.1:7447")
    with pytest.raises(ConfigError, match="roster"):
        Roster.load(tmp_path)


def test_rules_bind_every_uav_to_its_own_keys(tmp_path: Path) -> None:
    kd = KeyDir.init(tmp_path / "k", SWARM)
    for n in ("uav-1", "uav-2", "gcs-1", "ctl", "edge", "uav-9"):
        kd.issue(NodeName.in_swarm(n, SWARM))
    kd.revoke(NodeName.uav(9, SWARM))
    acl = access_control(kd.roster)
    assert acl["default_permission"] == "deny"
    subjects = {cn for s in acl["subjects"] for cn in s["cert_common_names"]}
    assert subjects == {"uav-1.alpha", "uav-2.alpha", "gcs-1.alpha", "ctl.alpha", "edge.alpha"}  # not the revoked one
    rules = {r["id"]: r for r in acl["rules"]}
    assert "mrs/alpha/1/pose" in rules["uav-1.in"]["key_exprs"] and "mrs/alpha/2/pose" not in rules["uav-1.in"]["key_exprs"]
    assert not any("cmd" in k or "netem" in k for k in rules["uav-1.in"]["key_exprs"])
    assert "mrs/alpha/netem/set" in rules["ctl.in"]["key_exprs"] and "mrs/alpha/netem/set" not in rules["gcs.in"]["key_exprs"]


def test_scenario_security_section() -> None:
    cov = ROOT / "scenarios" / "coverage.yaml"
    assert load_scenario(cov).network.secured.mode == "mtls"  # secure by default
    assert load_scenario(cov, ["network.security=off"]).network.secured.mode == "off"  # YAML's off is false
    assert load_scenario(cov, ["network.security.mode=off"]).network.secured.mode == "off"
    assert load_scenario(cov, ["network.security.keys=keys/alpha"]).network.secured.keys == "keys/alpha"
    with pytest.raises(ScenarioError, match="network.security.keys"):
        load_scenario(cov, ["network.security.mode=off", "network.security.keys=k"])
    with pytest.raises(ScenarioError, match="network.security.mode"):
        load_scenario(cov, ["network.security.mode=tls"])


def test_keys_cli(tmp_path: Path) -> None:
    def keys(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "mrswarm", "keys", *args], cwd=tmp_path, capture_output=True,
                              text=True, timeout=60, env=dict(os.environ, PYTHONPATH=str(ROOT)))

    assert keys("init", "--swarm", "alpha").returncode == 0
    res = keys("issue", "--swarm", "alpha", "edge", "ctl", "--uavs", "1-3")
    assert res.returncode == 0 and res.stdout.count("valid until") == 5, res.stderr
    assert keys("revoke", "--swarm", "alpha", "uav-2").returncode == 0
    res = keys("issue", "--swarm", "alpha", "uav-2")
    assert res.returncode == 2 and "revoked" in res.stderr and "Traceback" not in res.stderr
    listed = json.loads(keys("list", "--swarm", "alpha", "--json").stdout)
    assert sorted(listed["nodes"]) == ["ctl.alpha", "edge.alpha", "uav-1.alpha", "uav-3.alpha"]
    assert list(listed["revoked"]) == ["uav-2.alpha"]
    assert keys("bundle", "--swarm", "alpha", "uav-3", "--out", "b3").returncode == 0
    assert (tmp_path / "b3" / "uav-3.alpha.key").exists()
    res = keys("issue", "uav-1")
    assert res.returncode == 2 and "--swarm" in res.stderr


def test_a_ground_station_needs_credentials_for_a_tls_router(tmp_path: Path) -> None:
    with pytest.raises(GcsError, match="--keys"):
        resolve_target(None, ["tls/127.0.0.1:7447"], SWARM)
    assert resolve_target(None, ["tcp/127.0.0.1:7447"], SWARM).credentials is None  # an insecure swarm's router
    kd = KeyDir.init(tmp_path / "k", SWARM)
    kd.issue(NodeName("gcs", 1, SWARM))
    (tmp_path / "network.json").write_text(json.dumps({"swarm": SWARM, "endpoints": ["tls/127.0.0.1:7447"],
                                                       "security": {"mode": "mtls", "keys": str(kd.path)}}))
    t = resolve_target(str(tmp_path), [], None)
    assert t.credentials is not None and t.credentials.identity == "gcs-1.alpha"  # the run's keys, as gcs-1
    with pytest.raises(GcsError, match="gcs-2.alpha.pem missing"):
        resolve_target(str(tmp_path), [], None, identity="gcs-2")


def test_zenohs_refused_handshake_lines_are_recognised() -> None:
    refused = (b"\x1b[2m2026-11-23T22:08:51.037820Z\x1b[0m \x1b[33m WARN\x1b[0m acc-0 ThreadId(05) "
               b"\x1b[2mzenoh_link_tls::unicast\x1b[0m\x1b[2m:\x1b[0m peer sent no certificates.")
    assert is_refused_handshake(refused)
    assert not is_refused_handshake(b"2026 WARN zenoh::net::runtime::orchestrator: Unable to connect")


# ---- the rules at work: a secured router process and real sessions ---------------------------------
@pytest.fixture
def swarm_keys(tmp_path: Path) -> Path:
    kd = KeyDir.init(tmp_path / "keys", SWARM)
    for n in ("uav-1", "uav-2", "uav-3", "gcs-1", "ctl", "edge", "uav-9"):
        kd.issue(NodeName.in_swarm(n, SWARM))
    stolen = tmp_path / "stolen"
    stolen.mkdir()
    for suffix in ("pem", "key"):  # what a thief copied off UAV 9 before it was revoked
        (stolen / f"uav-9.alpha.{suffix}").write_bytes(kd.path.joinpath(f"uav-9.alpha.{suffix}").read_bytes())
    (stolen / "ca.pem").write_bytes((kd.path / "ca.pem").read_bytes())
    kd.revoke(NodeName.uav(9, SWARM))
    (stolen / "roster.json").write_bytes((kd.path / "roster.json").read_bytes())
    other = KeyDir.init(tmp_path / "other", SWARM)  # another swarm's CA, same names
    other.issue(NodeName.uav(1, SWARM))
    return kd.path


@contextlib.contextmanager
def router_process(keys: Path, tmp_path: Path, name: str = "router") -> Iterator[tuple[str, Path]]:
    """``mrswarm router --keys`` as its own process; yields its endpoint and its counters file."""
    port = free_port()
    stats = tmp_path / f"{name}.stats.json"
    with open(tmp_path / f"{name}.log", "wb") as out:
        proc = subprocess.Popen([sys.executable, "-m", "discovery.rendezvous", "--listen", f"tcp/127.0.0.1:{port}",
                                 "--keys", str(keys), "--stats", str(stats)], cwd=ROOT, stdout=out, stderr=subprocess.STDOUT,
                                env=dict(os.environ, PYTHONPATH=str(ROOT)))
    try:
        assert wait_for(stats.exists, 20.0), (tmp_path / f"{name}.log").read_text()
        yield f"tls/127.0.0.1:{port}", stats
    finally:
        proc.terminate()
        proc.wait(10)


@pytest.fixture
def secured_router(swarm_keys: Path, tmp_path: Path) -> Iterator[tuple[str, Path]]:
    with router_process(swarm_keys, tmp_path) as r:
        yield r


def client(endpoint: str, credentials: Credentials | None = None, tls: dict | None = None) -> zenoh.Session:
    """A client session of the router: with credentials, or with a hand-made TLS section (intruders)."""
    cfg = Rendezvous((endpoint,), mode="client", credentials=credentials).zenoh_config()
    if tls is not None:
        cfg["connect"]["endpoints"] = [endpoint.replace("tcp/", "tls/") if tls else endpoint.replace("tls/", "tcp/")]
        cfg["transport"]["link"]["tls"] = tls
    return zenoh.open(to_zenoh(cfg))


def pose(uav: int, x: float = 0.0) -> bytes:
    return encode_pose(Pose(uav, Realm.VIRTUAL, 1, 0.0, time.time(), x, 0, 10, 0, 0, 0, 0))


def test_each_identity_may_do_what_its_role_allows_and_nothing_else(secured_router: tuple[str, Path], swarm_keys: Path,
                                                                     tmp_path: Path) -> None:
    ep, stats_file = secured_router
    conn = {n: Rendezvous((ep,), mode="client", credentials=creds(swarm_keys, n)) for n in ("uav-1", "uav-2", "ctl")}
    with SwarmNode(NodeIdentity(SWARM, 1), conn["uav-1"]) as u1, SwarmNode(NodeIdentity(SWARM, 2), conn["uav-2"]) as u2, \
            SwarmObserver(SWARM, conn["ctl"], name="runner") as ctl, \
            client(ep, creds(swarm_keys, "uav-3")) as rogue, client(ep, creds(swarm_keys, "gcs-1")) as gcs, \
            client(ep, Credentials(keys=str(tmp_path / "stolen"), identity="uav-9.alpha")) as revoked:
        nodes = (u1, u2)
        assert wait_for(lambda: (ctl.poll(), ctl.alive_uavs() >= {1, 2})[1], 5.0)

        def attack() -> None:
            for who in (rogue, revoked):
                who.put(KEYS.pose(1), pose(1, x=50.0))  # speak for UAV 1
                who.put(KEYS.cmd(1), encode_command(Command("gcs", 7, 1, "kill", {}, time.time())))
                who.put(KEYS.swarm_cmd, encode_command(Command("gcs", 8, 0, "land", {}, time.time())))
                who.put(KEYS.netem_set, b"{}")
            revoked.put(KEYS.pose(9), pose(9))  # even its own key: the roster no longer lists it
            rogue.put(KEYS.pose(3), pose(3, x=99.0))  # its own key: allowed
        tokens = [rogue.liveliness().declare_token(KEYS.alive("uav", u)) for u in (3, 10, 11)]
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            attack()
            for n in nodes:
                n.poll()
            ctl.poll()
            time.sleep(0.05)
        # the ground station commands, and is obeyed
        gcs.put(KEYS.cmd(2), encode_command(Command("gcs", 9, 2, "hold", {}, time.time())))
        assert wait_for(lambda: [c.verb for c in u2.poll().commands] == ["hold"], 3.0)
        got_cmds = [c.verb for n in nodes for c in n.poll().commands]
        assert got_cmds == []  # no kill, no land from the rogue or the revoked certificate
        # UAV 3's pose on its own key passes; the forged "UAV 1" (which publishes nothing here) never arrives
        assert sorted(nb.uav for nb in u2.neighbours) == [3]
        assert all(n.stats.received["netem_set"] == 0 and n.netem is None for n in nodes)
        assert ctl.alive_uavs() == {1, 2, 3}  # its own token only, not 10 and 11
        del tokens
        for n in nodes:
            assert n.stats.rejected == {}  # access control stopped it all before the application checks
    # links of a certificate the roster does not list are counted (the router's file is written every second)
    assert wait_for(lambda: json.loads(stats_file.read_text())["refused"].get("non_member_link", 0) >= 1, 3.0)


def test_intruders_without_a_swarm_certificate_cannot_connect(secured_router: tuple[str, Path], swarm_keys: Path,
                                                              tmp_path: Path) -> None:
    ep, stats_file = secured_router
    ca = str(swarm_keys / "ca.pem")
    other = tmp_path / "other"
    intruders = {
        "no certificate": {"root_ca_certificate": ca, "verify_name_on_connect": False},
        "another CA": {"root_ca_certificate": ca, "enable_mtls": True, "verify_name_on_connect": False,
                       "connect_certificate": str(other / "uav-1.alpha.pem"),
                       "connect_private_key": str(other / "uav-1.alpha.key")},
        "plain TCP": {},
    }
    for what, tls in intruders.items():
        with pytest.raises(zenoh.ZError):
            client(ep, tls=tls).close()
            pytest.fail(f"{what}: connected")
    refused = lambda: json.loads(stats_file.read_text())["refused"].get("tls_handshake", 0)  # noqa: E731
    assert wait_for(lambda: refused() >= 3, 3.0), refused()  # each refused handshake counted by the router


def junk_connections(port: int, other: tuple[Path, Path], each: int) -> int:
    """Connections a TLS listener refuses, ``each`` of four kinds: HTTP bytes, nothing (connect, close), TLS without a
    client certificate, TLS with ``other``, another CA's (certificate, key); the number made."""
    import socket
    import ssl

    made = 0
    for kind in ("bytes", "nothing", "no certificate", "another CA"):
        for _ in range(each):
            with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
                if kind == "bytes":
                    s.sendall(b"GET / HTTP/1.1\r\nHost: uav\r\n\r\n")
                elif kind != "nothing":
                    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
                    ctx.check_hostname, ctx.verify_mode = False, ssl.CERT_NONE
                    if kind == "another CA":
                        ctx.load_cert_chain(*other)
                    try:
                        with ctx.wrap_socket(s) as t:
                            t.recv(1)
                    except (OSError, ssl.SSLError):
                        pass
            made += 1
    return made


def test_every_refused_handshake_is_counted_once(secured_router: tuple[str, Path], swarm_keys: Path, tmp_path: Path) -> None:
    """Zenoh refuses at most 10 handshakes a second (a fixed 100 ms pause after each); the count catches up, exactly."""
    ep, stats_file = secured_router
    other = (tmp_path / "other" / "uav-1.alpha.pem", tmp_path / "other" / "uav-1.alpha.key")
    made = junk_connections(int(ep.rsplit(":", 1)[1]), other, each=10)
    refused = lambda: json.loads(stats_file.read_text())["refused"]  # noqa: E731
    assert wait_for(lambda: refused().get("tls_handshake", 0) >= made, 15.0), (refused(), made)
    with client(ep, creds(swarm_keys, "uav-1")):  # a member's link is no refusal
        time.sleep(2.0)
    assert refused()["tls_handshake"] == made == 40 and refused()["accept_queue_full"] == 0, refused()


def test_a_connection_flood_beyond_the_accept_queue_is_counted_there(secured_router: tuple[str, Path]) -> None:
    import socket

    ep, stats_file = secured_router
    port = int(ep.rsplit(":", 1)[1])
    for _ in range(3000):  # far more than the 1,024 connections the listener's queue holds, in well under a second
        s = socket.socket()
        s.setblocking(False)
        with contextlib.suppress(BlockingIOError):
            s.connect(("127.0.0.1", port))
        s.close()
    refused = lambda: json.loads(stats_file.read_text())["refused"]  # noqa: E731
    assert wait_for(lambda: refused().get("accept_queue_full", 0) > 0, 5.0), refused()
    assert refused().get("tls_handshake", 0) < 100  # Zenoh's pace: 10 a second


def test_a_rotated_ca_refuses_every_older_certificate_at_the_handshake(swarm_keys: Path, tmp_path: Path) -> None:
    kd = KeyDir(swarm_keys)
    old = kd.bundle(NodeName.uav(1, SWARM), tmp_path / "old-uav-1")
    kd.rotate()
    with router_process(swarm_keys, tmp_path, "rotated") as (ep, stats_file):
        with pytest.raises(zenoh.ZError):
            client(ep, Credentials(keys=str(old), identity="uav-1.alpha")).close()
        with client(ep, creds(swarm_keys, "uav-1")):  # its new bundle
            pass
        assert wait_for(lambda: json.loads(stats_file.read_text())["refused"].get("tls_handshake", 0) >= 1, 3.0)


def test_a_plain_node_is_the_librarys_insecure_mode(router: str) -> None:
    """Without credentials a connectivity builds plain TCP links: the library's explicit insecure mode,
    which the tests of other concerns use (the runs they start are secured by default)."""
    cfg = Rendezvous((router,)).zenoh_config()
    assert "access_control" not in cfg and "tls" not in json.dumps(cfg) and router.startswith("tcp/")
    secured = Rendezvous((router,), credentials=Credentials(keys="k", identity="uav-1.alpha"))
    with pytest.raises(ConfigError, match="keys"):
        secured.zenoh_config()


def test_roster_round_trip(tmp_path: Path) -> None:
    kd = KeyDir.init(tmp_path, SWARM)
    kd.issue(NodeName.uav(1, SWARM))
    data = msgspec.json.decode((tmp_path / "roster.json").read_bytes())
    data["nodes"]["uav-1.beta"] = data["nodes"]["uav-1.alpha"]
    (tmp_path / "roster.json").write_bytes(msgspec.json.encode(data))
    with pytest.raises(ConfigError, match="uav-1.beta"):
        Roster.load(tmp_path)
