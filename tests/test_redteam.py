"""Red team: a real ``mrswarm run`` of head_on, attacked the ways issue 9 found open, flies as if nothing happened.

One run, many outcomes. The swarm runs as `mrswarm run` runs it (secured by default), with the
swarm's key directory made here (``network.security.keys``) so the attackers can hold what a
real attacker may: a certificate of the swarm's CA for UAV 3 (a compromised or stolen UAV that is
still a member), a revoked certificate (UAV 9), a certificate of another CA, or nothing. While
the two UAVs fly at each other they try to:

* connect without a certificate, with another CA's, in plain TCP (to the edge router and to a
  UAV's own listener);
* kill and land the UAVs (per UAV and swarm-wide), speak for UAV 1 and 2 with poses that place
  each far from where it is (what made them collide before), fake "done" states to end the
  experiment, fake liveliness tokens, a 100 % loss netem change, a fault injection, a forged
  edge-feed batch;
* as UAV 3, through the router (client) and peer to peer with the UAVs (peer, by the router's
  gossip);

while a ground station with its own certificate holds and resumes UAV 1, which obeys. The
assertions are the swarm's outcome (goals reached, no collision, not ended early, no netem
change, no kill) and the refusals the router and the UAVs counted.

A second secured run takes issue 43's probe: forged Hellos at every UAV's scouting sockets,
UAV 3's stolen beacon token speaking for UAVs 1 and 2, junk at a UAV's TLS listener. The rest
of that probe runs where its parts live: a full or read-only results disk in
tests/test_disk_e2e.py, the recorder killed and a UAV stopped mid-run in
tests/test_fault_probe_e2e.py, the killed runner's results in tests/test_run_signals_e2e.py,
the loader's duplicate keys and deep nesting in tests/test_inputs.py, exact handshake counts
and floods in tests/test_security.py, the scouting guard and identity-bound beacons on their
own in tests/test_scouting_guard.py and tests/test_discovery_identity.py.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh

from discovery.client import query_registry
from discovery.server import load_keys
from swarmnet.connectivity import Rendezvous, to_zenoh
from swarmnet.keyspace import SwarmKeys
from swarmnet.messages import (
    AgentState,
    Command,
    Pose,
    PoseBatch,
    Realm,
    decode_pose,
    encode_command,
    encode_pose,
    encode_pose_batch,
    encode_state,
)
from swarmnet.netem.control import NetemSet, encode_netem_set
from swarmnet.observer import SwarmObserver
from swarmnet.security.credentials import Credentials
from swarmnet.security.identity import NodeName
from swarmnet.security.pki import KeyDir
from tests.conftest import wait_for
from tests.gcs_helpers import start_run, stop_process

pytestmark = pytest.mark.e2e

ROOT = Path(__file__).resolve().parents[1]
HEAD_ON = ROOT / "scenarios" / "head_on.yaml"
SWARM = "headon"  # the scenario's swarm
KEYS = SwarmKeys(SWARM)
ATTACK_S = 8.0  # the UAVs meet about 4 s into the mission (40 m apart at 5 m/s)


def make_keys(tmp: Path) -> tuple[Path, Path, Path]:
    """The swarm's key directory, a thief's copy of UAV 9's credentials (revoked since), another CA."""
    kd = KeyDir.init(tmp / "keys", SWARM)
    for n in ("uav-1", "uav-2", "uav-3", "uav-9", "edge", "ctl", "gcs-1"):
        kd.issue(NodeName.in_swarm(n, SWARM))
    stolen = kd.bundle(NodeName.uav(9, SWARM), tmp / "stolen")
    kd.revoke(NodeName.uav(9, SWARM))
    other = KeyDir.init(tmp / "other", SWARM)
    other.issue(NodeName.uav(3, SWARM))
    return kd.path, stolen, other.path


def session(endpoints: str | list[str], mode: str, tls: dict[str, Any] | None) -> zenoh.Session:
    """A raw Zenoh session as an attacker would open one (``tls`` None: plain TCP)."""
    eps = [endpoints] if isinstance(endpoints, str) else endpoints
    cfg: dict[str, Any] = {"mode": mode, "connect": {"endpoints": [e if tls else e.replace("tls/", "tcp/") for e in eps]},
                           "scouting": {"multicast": {"enabled": False}}, "transport": {"unicast": {"open_timeout": 2000}}}
    if mode == "peer":
        cfg["listen"] = {"endpoints": ["tls/127.0.0.1:0" if tls else "tcp/127.0.0.1:0"]}
    if tls:
        cfg["transport"]["link"] = {"tls": tls}
    return zenoh.open(zenoh.Config.from_json5(json.dumps(cfg)))


def refused_at_connect(endpoint: str, tls: dict[str, Any] | None) -> bool:
    try:
        session(endpoint, "client", tls).close()
    except zenoh.ZError:
        return True
    return False


def as_member(keys: Path, name: str, endpoints: tuple[str, ...], mode: str) -> zenoh.Session:
    """A session with a certificate of the swarm's CA (but no access control of its own: it is the attacker's)."""
    creds = Credentials(keys=str(keys), identity=f"{name}.{SWARM}")
    cfg = Rendezvous(endpoints, mode=mode, credentials=creds).zenoh_config()
    cfg.pop("access_control")
    return zenoh.open(to_zenoh(cfg))


def forged_pose(uav: int, x: float, y: float, seq: int = 1) -> bytes:
    return encode_pose(Pose(uav, Realm.VIRTUAL, seq % 65536, 1.0, time.time(), x, y, 10.0, 0, 0, 0, 0))


class SeqTracker:
    """The real UAVs' pose sequence numbers, as an eavesdropper sees them: a forged pose numbered well ahead
    of the real stream wins every neighbour table (the real poses then look late), which is what made an
    unprotected head_on collide."""

    def __init__(self, s: zenoh.Session):
        self.seq: dict[int, int] = {1: 0, 2: 0}
        self._sub = s.declare_subscriber(KEYS.all_poses, zenoh.handlers.RingChannel(256), allowed_origin=zenoh.Locality.REMOTE)

    def ahead(self, uav: int) -> int:
        while (sample := self._sub.try_recv()) is not None:
            try:
                p = decode_pose(sample.payload.to_bytes())
            except ValueError:
                continue
            if p.uav in self.seq:
                self.seq[p.uav] = p.seq
        return self.seq[uav] + 20_000


def impersonate(s: zenoh.Session, seqs: SeqTracker) -> None:
    """Each UAV's pose, forged 300 m to the side of where it is: the other sees no one to avoid."""
    for uav in (1, 2):
        s.put(KEYS.pose(uav), forged_pose(uav, 0.0, 300.0 * (1 if uav == 1 else -1), seqs.ahead(uav)))


def attack(s: zenoh.Session, n: int, seqs: SeqTracker) -> None:
    """One round of everything a member certificate must not be able to do."""
    t = time.time()
    impersonate(s, seqs)
    for uav in (1, 2):
        s.put(KEYS.cmd(uav), encode_command(Command("gcs", 1000 + n, uav, "kill", {}, t)))
        s.put(KEYS.state(uav), encode_state(AgentState(uav, Realm.VIRTUAL, 10_000 + n, t, "done", "goto")))
        s.put(KEYS.fault(uav), b"\x01")
    s.put(KEYS.swarm_cmd, encode_command(Command("gcs", 2000 + n, 0, "land", {}, t)))
    s.put(KEYS.netem_set, encode_netem_set(NetemSet(3000 + n, "ctl", t, {"v2v": {"loss": {"model": "bernoulli", "p": 1.0}}})))
    s.put(KEYS.pose_feed, encode_pose_batch(PoseBatch(n, t, [1, 2], [forged_pose(1, 0, 300), forged_pose(2, 0, -300)])))


def test_an_attacked_head_on_flies_as_if_nothing_happened(tmp_path: Path) -> None:
    keys, stolen, other = make_keys(tmp_path)
    out = tmp_path / "results"
    out.mkdir()
    run = start_run(HEAD_ON, out, [f"network.security.keys={keys}"])
    seen_phases: dict[int, set[str]] = {1: set(), 2: set()}
    alive_seen: set[int] = set()
    rogue_links: list[str] = []
    try:
        assert wait_for(lambda: any(out.glob("*/network.json")) or run.poll() is not None, 60.0)
        run_dir = next(out.glob("*/network.json")).parent
        net = json.loads((run_dir / "network.json").read_text())
        (router,) = net["endpoints"]
        assert router.startswith("tls/") and net["security"] == {"mode": "mtls", "keys": str(keys)}
        ca = str(keys / "ca.pem")
        gcs = SwarmObserver(SWARM, Rendezvous((router,), mode="client", credentials=Credentials(keys=str(keys),
                                                                                             identity=f"gcs-1.{SWARM}")),
                            node_id=1, role="gcs", name="gcs")
        gcs.tap = lambda kind, msg: seen_phases.get(msg.uav, set()).add(msg.phase) if kind == "state" else None
        with gcs:
            def phases() -> dict[int, str]:
                gcs.poll()
                alive_seen.update(gcs.alive_uavs())
                return gcs.phases()
            assert wait_for(lambda: phases() == {1: "mission", 2: "mission"} or run.poll() is not None, 120.0, 0.05), \
                phases()

            # no certificate, another CA's, plain TCP: refused at the router
            intruders = {"no certificate": {"root_ca_certificate": ca, "verify_name_on_connect": False},
                         "another CA": {"root_ca_certificate": ca, "enable_mtls": True, "verify_name_on_connect": False,
                                        "connect_certificate": str(other / f"uav-3.{SWARM}.pem"),
                                        "connect_private_key": str(other / f"uav-3.{SWARM}.key")},
                         "plain TCP": None}
            for what, tls in intruders.items():
                assert refused_at_connect(router, tls), what

            # a ground station's certificate commands (UAV 1 holds, then resumes its mission)
            for verb in ("hold", "resume"):
                p = gcs.command(verb, [1])
                assert wait_for(lambda p=p: (gcs.poll(), p.complete)[1], 3.0) and p.acks[1].ok, verb
                if verb == "hold":  # ... and holds (its state says so) before it is told to resume
                    assert wait_for(lambda: (phases(), "hold" in seen_phases[1])[1], 5.0, 0.05), seen_phases[1]

            # UAV 3 is compromised: a member's certificate, and the swarm's discovery key, which gives it every
            # UAV's locators (the registry); it dials the router (as client and as peer) and the UAVs themselves.
            # UAV 9's certificate was revoked, but a thief kept a copy.
            disc = net["discovery"]
            members, _ = query_registry(disc["server"], SWARM, load_keys(run_dir / disc["key_file"])[SWARM])
            uav_locators = tuple(loc for m in members if m.entry.role == "uav" for loc in m.entry.locators)
            assert len(uav_locators) >= 2 and all(loc.startswith("tls/") for loc in uav_locators), uav_locators
            for tls in (intruders["no certificate"], None):  # straight at a UAV's own listener, without a certificate
                assert refused_at_connect(uav_locators[0], tls)
            with as_member(keys, "uav-3", (router, *uav_locators), "peer") as rogue_peer, \
                    as_member(keys, "uav-3", (router,), "client") as rogue_client, \
                    as_member(stolen, "uav-9", (router,), "client") as revoked:
                tokens = [rogue_peer.liveliness().declare_token(KEYS.alive("uav", u)) for u in (3, *range(10, 40))]
                assert wait_for(lambda: len(rogue_peer.info.links()) >= 3, 5.0)  # the router and both UAVs
                rogue_links = [str(link.auth_identifier) for link in rogue_peer.info.links()]
                seqs = SeqTracker(rogue_peer)  # a member may read the poses: it flies among them
                n = 0
                t_end = time.monotonic() + ATTACK_S
                while time.monotonic() < t_end:
                    for s in (rogue_peer, rogue_client, revoked):
                        attack(s, n, seqs)
                    rogue_peer.put(KEYS.pose(3), forged_pose(3, 500.0, 500.0))  # its own key: allowed, far away
                    n += 1
                    phases()
                    time.sleep(0.05)
                while run.poll() is None and time.monotonic() < t_end + 60.0:  # keep being a (harmless) neighbour
                    rogue_peer.put(KEYS.pose(3), forged_pose(3, 500.0, 500.0))
                    phases()
                    time.sleep(0.1)
                del tokens
        assert run.wait(60) == 0, (out / "run.stdout").read_text()[-3000:]
    finally:
        stop_process(run)
        shutil.rmtree(tmp_path / "stolen", ignore_errors=True)

    summary = json.loads((run_dir / "summary.json").read_text())
    info = json.loads((run_dir / "run.json").read_text())
    # the swarm's outcome: both reached their goals, no collision, the experiment was not cut short
    assert all(g["reached"] for g in summary["goals"].values()), summary["goals"]
    assert summary["separation"]["collisions"] == 0, summary["separation"]
    assert summary["separation"]["min_during_mission_m"] > summary["separation"]["collision_distance_m"]
    assert info["aborted"] is None and info["all_done_at"] is not None and info["all_done_at"] > 6.0, info
    # nobody was killed, landed or finished by a forged message; netem never changed
    for uav, phases_of in seen_phases.items():
        assert not phases_of & {"killed", "landing", "landed", "rtl"}, (uav, phases_of)
    assert "hold" in seen_phases[1]  # ... but the ground station's hold was obeyed
    uav_stats = {u: json.loads((run_dir / f"uav{u}.json").read_text()) for u in (1, 2)}
    for u, st in uav_stats.items():
        assert st["netem"] is None and st["net"]["received"].get("netem_set", 0) == 0, (u, st["netem"])
        assert "3" in st["neighbours"], (u, list(st["neighbours"]))  # a member's own pose passes ...
        assert st["net"]["rejected"] == {}, st["net"]["rejected"]  # ... everything forged was stopped before the app
    # fake liveliness: only the member's own token (3) ever showed up next to the real UAVs
    assert alive_seen == {1, 2, 3}, alive_seen
    assert {f"uav-1.{SWARM}", f"uav-2.{SWARM}"} <= set(rogue_links)  # the attacks reached the UAVs' own listeners
    # every refusal counted: handshakes at the router and at UAV 1's or 2's listener, the revoked certificate's link
    sec = summary["security"]
    assert sec["mode"] == "mtls"
    assert sec["refused_by_router"].get("tls_handshake", 0) >= 3, sec
    assert sec["refused_by_router"].get("non_member_link", 0) >= 1, sec
    assert sec["refused_by_uavs"].get("tls_handshake", 0) >= 2, sec


class Rogue:
    """A listener that counts the connections it gets: where forged Hellos and beacons point."""

    def __init__(self) -> None:
        import socket as so

        self.sock = so.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(64)
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]
        self.accepted = 0

    def count(self) -> int:
        while True:
            try:
                conn, _ = self.sock.accept()
            except BlockingIOError:
                return self.accepted
            conn.close()
            self.accepted += 1


def scouting_ports(pid: int) -> list[int]:
    """A UAV process's UDP sockets on the wildcard address: its Zenoh session's scouting sockets."""
    import psutil

    return [c.laddr.port for c in psutil.Process(pid).net_connections(kind="udp4") if c.laddr.ip == "0.0.0.0"]


def test_forged_hellos_stolen_beacons_and_junk_handshakes_draw_nothing_and_are_counted(tmp_path: Path) -> None:
    """Issue 43's probe on a real secured head_on: a forged Hello (a "router" at a rogue's tcp/ and tls/ locators)
    at every UAV's scouting sockets, UAV 3's stolen credentials beaconing as UAV 1 (at the rogue) and saying UAV 2's
    goodbye, and junk connections at a UAV's TLS listener. No UAV opens a connection to the rogue, the registry keeps
    every real entry, the run completes (exit 0), and every refusal is counted: each forged datagram, each junk
    connection, each stolen beacon."""
    import socket as so

    from discovery.protocol import Beacon, MsgType, NodeEntry, beacon_body, seal
    from discovery.wire import WHATAMI_PEER, WHATAMI_ROUTER, Hello, encode_hello, zid_from_hex
    from swarmnet.security.beacon import read_token
    from tests.test_security import junk_connections

    keys, _, other = make_keys(tmp_path)
    out = tmp_path / "results"
    out.mkdir()
    run = start_run(HEAD_ON, out, [f"network.security.keys={keys}"])
    rogue = Rogue()
    try:
        assert wait_for(lambda: any(out.glob("*/network.json")) or run.poll() is not None, 60.0)
        run_dir = next(out.glob("*/network.json")).parent
        net = json.loads((run_dir / "network.json").read_text())
        disc = net["discovery"]
        key = load_keys(run_dir / disc["key_file"])[SWARM]
        assert wait_for(lambda: {m.entry.node for m in query_registry(disc["server"], SWARM, key)[0]} >= {1, 2}, 60.0)
        real = {m.entry.node: m.entry.locators for m in query_registry(disc["server"], SWARM, key)[0]}
        pids = json.loads((run_dir / "run.json").read_text())["pids"]
        targets = {u: scouting_ports(pids[f"uav{u}"]) for u in (1, 2)}
        assert all(len(p) == 4 for p in targets.values()), targets
        hello = encode_hello(Hello(zid_from_hex("f0f0f0f0f0f0f0f0"), WHATAMI_ROUTER,
                                   (f"tcp/127.0.0.1:{rogue.port}", f"tls/127.0.0.1:{rogue.port}")))
        token = read_token(keys, f"uav-3.{SWARM}")
        host, port = disc["server"].rsplit(":", 1)
        server = (host, int(port))
        sent = {1: 0, 2: 0}
        entries = []
        with so.socket(so.AF_INET, so.SOCK_DGRAM) as attacker:
            for n in range(40):  # 4 s
                for u, ports in targets.items():
                    for p in ports:
                        attacker.sendto(hello, ("127.0.0.1", p))
                        sent[u] += 1
                forged = NodeEntry("uav", 1, "virtual", "rogue", zid_from_hex("abcd0123abcd0123"), WHATAMI_PEER,
                                   (f"tls/127.0.0.1:{rogue.port}",))
                attacker.sendto(seal(MsgType.BEACON, SWARM, key.encode(), beacon_body(Beacon(forged, b"\0" * 8, 1.0)),
                                     token=token), server)
                attacker.sendto(seal(MsgType.BYE, SWARM, key.encode(), ["uav", 2], token=token), server)
                if n % 5 == 0:
                    rows, stats = query_registry(disc["server"], SWARM, key)
                    entries.append({m.entry.node: m.entry.locators for m in rows})
                time.sleep(0.1)
        junk = junk_connections(int(real[1][0].rsplit(":", 1)[1]), (other / f"uav-3.{SWARM}.pem", other / f"uav-3.{SWARM}.key"),
                                each=5)
        rows, stats = query_registry(disc["server"], SWARM, key)
        assert run.wait(90) == 0, (out / "run.stdout").read_text()[-3000:]
    finally:
        stop_process(run)
        shutil.rmtree(tmp_path / "stolen", ignore_errors=True)
    assert rogue.count() == 0, "a secured UAV opened a connection to a locator no discovery vouched for"
    assert all(e.get(1) == real[1] and e.get(2) == real[2] for e in entries), entries  # never replaced, never removed
    assert stats["drop_bad_identity"] >= 80 and stats.get("left", 0) == 0, stats
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["degraded"] == [] and summary["separation"]["collisions"] == 0
    per_uav = {u: json.loads((run_dir / f"uav{u}.json").read_text())["net"]["refused"] for u in (1, 2)}
    for u in (1, 2):
        assert per_uav[u]["scouting"] >= sent[u], (u, per_uav[u], sent[u])  # every forged Hello dropped and counted
        assert per_uav[u]["foreign_scheme"] == 0  # ... none got as far as the proxy
    assert per_uav[1]["tls_handshake"] == junk == 20, per_uav  # each junk connection, once
    assert summary["security"]["refused_by_uavs"]["tls_handshake"] == junk


def test_without_security_the_same_impersonation_makes_them_collide(tmp_path: Path) -> None:
    """The control: with ``network.security: off`` the forged poses above land, and the head-on UAVs fly
    through each other. It shows the attacks of the secured run are real ones."""
    out = tmp_path / "results"
    out.mkdir()
    run = start_run(HEAD_ON, out, ["network.security=off"])
    try:
        assert wait_for(lambda: any(out.glob("*/network.json")) or run.poll() is not None, 60.0)
        run_dir = next(out.glob("*/network.json")).parent
        net = json.loads((run_dir / "network.json").read_text())
        assert net["security"] == {"mode": "off"} and net["endpoints"][0].startswith("tcp/")
        with SwarmObserver(SWARM, Rendezvous(tuple(net["endpoints"]), mode="client"), name="watch") as obs:
            assert wait_for(lambda: (obs.poll(), obs.phases() == {1: "mission", 2: "mission"})[1], 120.0, 0.05)
            disc = net["discovery"]
            members, _ = query_registry(disc["server"], SWARM, load_keys(run_dir / disc["key_file"])[SWARM])
            locators = [loc for m in members if m.entry.role == "uav" for loc in m.entry.locators]
            with session(locators, "peer", None) as attacker:  # any process that reaches the UAVs' ports
                assert wait_for(lambda: len(attacker.info.peers_zid()) >= 2, 5.0)
                seqs = SeqTracker(attacker)
                t_end = time.monotonic() + ATTACK_S
                while time.monotonic() < t_end:
                    impersonate(attacker, seqs)
                    obs.poll()
                    time.sleep(0.02)
        # 3: the run completed with a collision (docs/reliability.md, exit codes): what this attack causes
        assert run.wait(60) in (0, 3), (out / "run.stdout").read_text()[-3000:]
    finally:
        stop_process(run)
    sep = json.loads((run_dir / "summary.json").read_text())["separation"]
    assert sep["min_during_mission_m"] < sep["safety_distance_m"], sep  # avoidance was blinded
