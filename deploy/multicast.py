"""Make multicast impossible on a container network, as on a cellular (LTE/5G) network.

A cellular network delivers unicast only: no device hears another's multicast or
broadcast, so discovery must go through a server. On a Docker bridge network containers
share one Ethernet segment and multicast just works, which would let a misconfigured Zenoh
node discover its neighbours by scouting and hide a broken discovery path. ``seal`` closes
that door before the first container starts, with iptables rules on the host for the
network's bridge (Docker's ``br_netfilter`` passes bridged IPv4 frames through them):

* ``DOCKER-USER`` (FORWARD): drop IPv4 multicast (224.0.0.0/4) and link-layer broadcast
  between the containers;
* ``INPUT`` / ``OUTPUT``: the same between the containers and the host.

The runtime also makes such a network ``internal`` (no route out of the host); Docker's
isolation rules for internal networks already drop traffic to destinations outside the
subnet, multicast included, and the rules above cover broadcast and the host as well.
Every container also runs with IPv6 disabled (a sysctl set by the runtime), so there is no
IPv6 multicast either. Loopback inside each container is untouched: a node may still scout
its own namespace (the discovery proxy does). Each rule carries the comment
``mrswarm-seal:<network>``; :func:`unseal` removes a network's rules and :func:`sweep` removes
those of networks that no longer exist.

Docker's overlay networks (swarm mode) carry no multicast *between* edge servers (VXLAN
without a multicast underlay), but containers on the same server share one bridge (``br0``
in the overlay's own network namespace) and do multicast to each other. ``seal_overlay``
puts the same drop rules into that namespace (``FORWARD``; ``br_netfilter`` is on there
too). The namespace exists on a server only while a container of the network runs there,
so the stack keeps a small sentinel container per server (``deploy/swarm.py``).
``tests/test_docker_multicast.py`` and ``tests/test_docker_swarm.py`` check both kinds.
"""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
from pathlib import Path

from deploy.dockerutil import DeployError

COMMENT = "mrswarm-seal:"
IPV6_OFF = {"net.ipv6.conf.all.disable_ipv6": "1", "net.ipv6.conf.default.disable_ipv6": "1"}


class SealError(DeployError):
    pass


def _rules(bridge: str, network: str, between_containers: bool = True) -> list[tuple[str, list[str]]]:
    tag = ["-m", "comment", "--comment", f"{COMMENT}{network}"]
    mc = ["-d", "224.0.0.0/4"]
    bc = ["-m", "pkttype", "--pkt-type", "broadcast"]
    forward = [
        ("DOCKER-USER", ["-i", bridge, *mc, *tag, "-j", "DROP"]),
        ("DOCKER-USER", ["-i", bridge, *bc, *tag, "-j", "DROP"]),
    ] if between_containers else []
    return forward + [
        ("INPUT", ["-i", bridge, *mc, *tag, "-j", "DROP"]),
        ("INPUT", ["-i", bridge, *bc, *tag, "-j", "DROP"]),
        ("OUTPUT", ["-o", bridge, *mc, *tag, "-j", "DROP"]),
    ]


def _iptables(args: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["iptables", "-w", "10", *args], capture_output=True, text=True)


def check_available() -> None:
    if shutil.which("iptables") is None:
        raise SealError("iptables is not installed (it comes with docker.io); cannot drop multicast on the container "
                        "network. Set docker.multicast: allow in the scenario to run on a LAN-like network instead")
    res = _iptables(["-S", "DOCKER-USER"])
    if res.returncode != 0:
        raise SealError(f"cannot read iptables' DOCKER-USER chain ({res.stderr.strip()}); sealing multicast needs root and "
                        "dockerd's iptables chains. Run as root, or set docker.multicast: allow in the scenario")


def seal(bridge: str, network: str, between_containers: bool = True) -> None:
    """Drop multicast and broadcast on ``bridge`` (the host side of Docker network ``network``).

    ``between_containers=False`` keeps multicast among the containers (a LAN) and only keeps
    it away from the host, so no host process ever hears a container's scouting."""
    check_available()
    if not Path(f"/sys/class/net/{bridge}").exists():
        raise SealError(f"network {network}: no bridge device {bridge} on this host")
    for chain, spec in _rules(bridge, network, between_containers):
        res = _iptables(["-I", chain, "1", *spec])
        if res.returncode != 0:
            unseal(network)
            raise SealError(f"iptables -I {chain} failed: {res.stderr.strip()}")


EXEC_ROOT_ENV = "MRSWARM_DOCKER_EXEC_ROOT"  # dockerd's --exec-root if not the default (a node of deploy/cluster.py)


def overlay_netns(network_id: str) -> Path:
    """Where dockerd keeps an overlay network's namespace on this server."""
    return Path(os.environ.get(EXEC_ROOT_ENV) or "/var/run/docker") / "netns" / f"1-{network_id[:10]}"


def seal_overlay(network_id: str, network: str) -> bool:
    """Drop multicast and broadcast on the overlay's bridge on this server; False if the
    namespace is not here (no container of the network runs on this server)."""
    ns = overlay_netns(network_id)
    if not ns.exists():
        return False
    if shutil.which("nsenter") is None or shutil.which("iptables") is None:
        raise SealError("nsenter and iptables are needed to seal an overlay network (util-linux, iptables)")
    tag = ["-m", "comment", "--comment", f"{COMMENT}{network}"]
    pre = ["nsenter", f"--net={ns}", "iptables", "-w", "10"]
    if f"{COMMENT}{network}" in subprocess.run([*pre, "-S", "FORWARD"], capture_output=True, text=True).stdout:
        return True
    for spec in (["-i", "br0", "-d", "224.0.0.0/4", *tag, "-j", "DROP"],
                 ["-i", "br0", "-m", "pkttype", "--pkt-type", "broadcast", *tag, "-j", "DROP"]):
        res = subprocess.run([*pre, "-I", "FORWARD", "1", *spec], capture_output=True, text=True)
        if res.returncode != 0:
            raise SealError(f"cannot add a rule in {ns}: {res.stderr.strip()} (needs root)")
    return True


def _listed(network: str | None) -> list[tuple[str, list[str]]]:
    """(chain, rule spec) of every seal rule, optionally only one network's."""
    out = []
    for chain in ("DOCKER-USER", "INPUT", "OUTPUT"):
        res = _iptables(["-S", chain])
        for line in res.stdout.splitlines():
            if COMMENT not in line or not line.startswith(f"-A {chain} "):
                continue
            toks = shlex.split(line)  # iptables -S quotes the comment
            if network is not None and f"{COMMENT}{network}" not in toks:
                continue
            out.append((chain, toks[2:]))
    return out


def _network_of(spec: list[str]) -> str:
    for tok in spec:
        if tok.startswith(COMMENT):
            return tok[len(COMMENT):]
    return ""


def unseal(network: str) -> int:
    """Remove the rules of ``network``; returns how many were removed."""
    if shutil.which("iptables") is None:
        return 0
    n = 0
    for chain, spec in _listed(network):
        if _iptables(["-D", chain, *spec]).returncode == 0:
            n += 1
    return n


def sweep(existing_networks: set[str]) -> int:
    """Remove seal rules whose network is gone (a run killed with SIGKILL leaves them)."""
    if shutil.which("iptables") is None:
        return 0
    n = 0
    for chain, spec in _listed(None):
        if _network_of(spec) not in existing_networks and _iptables(["-D", chain, *spec]).returncode == 0:
            n += 1
    return n
