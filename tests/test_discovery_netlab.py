"""The namespace lab itself, and two properties of discovery nodes on it:

* the lab behaves like a cellular network: routed unicast works between hosts, multicast
  does not cross, and everything is gone afterwards;
* a discovery node never sends a multicast or broadcast packet (captured on every
  interface of its namespace, with a positive control);
* a node behind a NAT that forwards a public address is reachable once it advertises
  that address (``--advertise``), and is not without it.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from discovery.netlab import Netlab, NetlabError, cleanup_stale, list_namespaces
from tests.discovery_lab import ROOT, SwarmLab

pytestmark = pytest.mark.netns

KEY = "netlab-alpha-key-0123456789abcdef"

RECV_MCAST = """
import socket, struct, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
s.bind(("0.0.0.0", 7446))
s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, socket.inet_aton("224.0.0.224") + socket.inet_aton(sys.argv[1]))
u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
u.bind((sys.argv[1], 9999))
s.settimeout(3.0); u.settimeout(3.0)
got = []
for sock in (u, s):
    try:
        got.append(sock.recvfrom(100)[0].decode())
    except socket.timeout:
        got.append(None)
print(got)
"""

SEND = """
import socket, sys, time
time.sleep(0.5)
m = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
m.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 16)
m.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(sys.argv[2]))
u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
for _ in range(5):
    u.sendto(b"unicast", (sys.argv[1], 9999))
    m.sendto(b"multicast", ("224.0.0.224", 7446))
    time.sleep(0.1)
"""


def test_lab_routes_unicast_between_subnets_but_not_multicast_and_cleans_up() -> None:
    cleanup_stale()
    with Netlab(["edge", "h1", "h2"]) as lab:
        names = list_namespaces(f"mrsnl-{lab.owner}-")
        assert sorted(names) == sorted(lab.namespaces)
        assert lab["h1"].addr.rsplit(".", 2)[1] != lab["h2"].addr.rsplit(".", 2)[1]  # separate subnets
        fwd = lab.run("core", ["cat", "/proc/sys/net/ipv4/ip_forward"]).stdout.strip()
        assert fwd == "1"
        rx = lab.popen("h2", [sys.executable, "-c", RECV_MCAST, lab["h2"].addr], stdout=subprocess.PIPE, text=True)
        tx = lab.run("h1", [sys.executable, "-c", SEND, lab["h2"].addr, lab["h1"].addr])
        assert tx.returncode == 0, tx.stderr
        out, _ = rx.communicate(timeout=20)
        assert out.strip() == "['unicast', None]"  # unicast routed, multicast (even with TTL 16) is not
    assert not list_namespaces(f"mrsnl-{lab.owner}-")


def test_lab_is_deleted_when_building_fails_and_stale_labs_are_collected() -> None:
    lab = Netlab(["h1", "h2"])
    lab.hosts["h2"] = lab.hosts["h2"].__class__("h2", lab.hosts["h2"].ns, "10.66.999.2", "10.66.999.1")  # invalid
    with pytest.raises(NetlabError):
        lab.up()
    assert not list_namespaces(f"mrsnl-{lab.owner}-")
    # a lab whose owner died (here: a pid that cannot exist) is removed by cleanup_stale
    ghost = "mrsnl-t4194305x0000-h1"
    subprocess.run(["ip", "netns", "add", ghost], check=True)
    assert ghost in cleanup_stale()
    assert ghost not in list_namespaces()


CAPTURE = r"""
import json, socket, struct, sys, time
dur, own = float(sys.argv[1]), sys.argv[2]
s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x0003))
s.settimeout(0.1)
found, packets, tcp, control = [], 0, 0, False
end = time.time() + dur
sent = False
while time.time() < end + 1.0:
    if not sent and time.time() >= end:  # positive control: a multicast datagram we send ourselves
        m = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        m.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(own))
        m.sendto(b"control", ("224.0.0.251", 5353))
        sent = True
    try:
        data, addr = s.recvfrom(65535)
    except socket.timeout:
        continue
    packets += 1
    if addr[1] == 0x0800 and len(data) >= 34:
        ip = data[14:]
        proto, dst = ip[9], socket.inet_ntoa(ip[16:20])
        first = int(dst.split(".")[0])
        if proto == 6:
            tcp += 1
        if proto == 17 and (224 <= first <= 239 or dst.endswith(".255")):
            if dst == "224.0.0.251" and b"control" in data:
                control = True
            else:
                found.append([addr[0], dst])
    elif addr[1] == 0x86DD and len(data) >= 54:
        ip = data[14:]
        if ip[6] == 17 and ip[24] == 0xFF:
            found.append([addr[0], "ipv6 multicast"])
print(json.dumps({"found": found, "packets": packets, "tcp": tcp, "control": control}))
"""


def test_discovery_nodes_send_no_multicast_or_broadcast(tmp_path: Path) -> None:
    with SwarmLab(tmp_path, ["h1", "h2"], {"alpha": KEY}) as lab:
        lab.start_server()
        cap = lab.lab.popen("h1", [sys.executable, "-c", CAPTURE, "6", lab.addr("h1")], stdout=subprocess.PIPE, text=True)
        time.sleep(0.5)
        lab.start_probe("n1", "h1", "alpha", 1, extra_args=("--listen", "tcp/0.0.0.0:7448"))  # every interface
        lab.start_probe("n2", "h2", "alpha", 2)
        st = lab.wait_status(["n1", "n2"], lambda st: len(st["n1"]["peers"]) == 1, 10.0)
        assert len(st["n1"]["peers"]) == 1
        out, _ = cap.communicate(timeout=30)
    res = json.loads(out)
    assert res["control"], "the capture did not see the control multicast: it would not see zenoh's either"
    assert res["tcp"] > 10  # it did see the node's traffic
    assert res["found"] == [], res["found"]


NAT = "10.69.250.1"  # the "public" address the core router forwards to h1


def test_node_behind_a_nat_is_reachable_only_when_it_advertises_the_public_address(tmp_path: Path) -> None:
    with SwarmLab(tmp_path, ["h1", "h2", "h3"], {"alpha": KEY}, second_octet=69) as lab:
        h1 = lab.addr("h1")
        for rule in (["-t", "nat", "-A", "PREROUTING", "-d", NAT, "-p", "tcp", "--dport", "7447", "-j", "DNAT",
                      "--to-destination", f"{h1}:7447"],
                     # h1 accepts no connection addressed to its private address (only the forwarded ones)
                     ["-A", "FORWARD", "-p", "tcp", "-d", h1, "--dport", "7447", "-m", "conntrack", "--ctorigdst", h1,
                      "-j", "DROP"]):
            res = lab.lab.run("core", ["iptables", *rule])
            assert res.returncode == 0, f"iptables (installed by scripts/test) failed: {res.stderr}"
        lab.start_server()
        # Pinned ZIDs make the dialling order certain. Zenoh compares ZIDs byte by byte from the
        # least significant byte (its printed form's last two hex digits): a random ZID ending in
        # "00" is smaller than "1", and then h1 would dial it (1 run in ~128 did).
        lab.start_probe("n2", "h2", "alpha", 2, extra_args=("--zid", "a2"))
        lab.start_probe("n3", "h3", "alpha", 3, extra_args=("--zid", "a3"))
        # h1 gets the smallest ZID, so the others are the ones that dial it (greater-zid rule)
        lab.start_probe("n1", "h1", "alpha", 1, extra_args=("--zid", "1"))
        st = lab.wait_status(["n1", "n2", "n3"], lambda st: len(st["n2"]["peers"]) >= 1, 10.0)
        time.sleep(4.0)  # two dial attempts of 2 s each
        st = lab.statuses(["n1", "n2", "n3"])
        assert st["n1"]["peers"] == {}, "reached the private address through the NAT?"
        assert st["n1"]["discovery"]["locators"] == [f"tcp/{h1}:7447"]
        lab.kill("n1")
        lab.start_probe("n1b", "h1", "alpha", 1, extra_args=("--zid", "2", "--advertise", NAT))
        st = lab.wait_status(["n1b", "n2", "n3"], lambda st: len(st["n1b"]["peers"]) == 2, 15.0)
        assert len(st["n1b"]["peers"]) == 2, st["n1b"]
        assert st["n1b"]["discovery"]["locators"] == [f"tcp/{NAT}:7447"]
        # the peers may still be dialling the old, unreachable address (2 s open_timeout), and Zenoh
        # handles Hellos one at a time (docs/discovery.md): allow for one such attempt
        took = max(st["n1b"]["peers"].values()) - st["n1b"]["opened_at"]
        print(f"NAT'd node linked {took:.2f} s after its session opened")
        assert took <= 4.5
        nodes, _ = lab.query("alpha")
        assert {n["node"]: n["locators"] for n in nodes}[1] == [f"tcp/{NAT}:7447"]
        st = lab.wait_status(["n1b", "n2", "n3"], lambda st: all(st[n]["rx"].get("alpha/1", {}).get("n", 0) > 5
                                                                  for n in ("n2", "n3")), 10.0)
        assert all(st[n]["rx"].get("alpha/1", {}).get("n", 0) > 5 for n in ("n2", "n3"))


def test_netlab_cli_up_list_down() -> None:
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/sbin:/usr/bin:/sbin:/bin"}
    name = f"ci{int(time.time()) % 100000}"
    up = subprocess.run([sys.executable, "-m", "mrswarm", "netlab", "up", "--name", name, "--hosts", "2"], cwd=ROOT,
                        capture_output=True, text=True, env=env, timeout=60)
    try:
        assert up.returncode == 0, up.stderr
        assert "h2" in up.stdout and f"mrsnl-u{name}-edge" in up.stdout
        assert len(list_namespaces(f"mrsnl-u{name}-")) == 4
    finally:
        down = subprocess.run([sys.executable, "-m", "mrswarm", "netlab", "down", "--name", name], cwd=ROOT,
                              capture_output=True, text=True, env=env, timeout=60)
    assert down.returncode == 0, down.stderr
    assert not list_namespaces(f"mrsnl-u{name}-")
