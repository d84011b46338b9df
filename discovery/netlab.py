"""A routed "cellular" test network built from Linux network namespaces (needs root).

    core router namespace (ip_forward=1, no multicast routing)
      ├── v1 ── eth0  host "edge"  10.<b>.1.2/24, default via 10.<b>.1.1
      ├── v2 ── eth0  host "h1"    10.<b>.2.2/24, default via 10.<b>.2.1
      └── ...

Every host sits on its own subnet behind the core router, like devices on an LTE/5G
campus network: unicast between hosts is routed, multicast and broadcast never cross
(no multicast routing, TTL 1 scouting dies at the router). Nothing is connected to the
machine's real interfaces.

Namespaces are named ``mrsnl-<owner>-<host>``: ``t<pid>x<random>`` for labs of a test or
benchmark run (:func:`cleanup_stale` removes those whose process is gone), ``u<name>`` for
labs made with ``mrswarm netlab up --name NAME``. :meth:`Netlab.down` kills every process
left in the lab's namespaces (processes the lab's owner started there) and deletes them;
use the lab as a context manager so that happens on failures too.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
from dataclasses import dataclass
from typing import Any

from groundfloor.errors import MrswarmError

PREFIX = "mrsnl"
NAME_RE = re.compile(r"^[a-z0-9]{1,12}$")
_TEST_OWNER_RE = re.compile(rf"^{PREFIX}-t(\d+)x[0-9a-f]+-")


class NetlabError(RuntimeError, MrswarmError):
    pass


@dataclass(frozen=True)
class Host:
    name: str
    ns: str  # network namespace
    addr: str  # the host's address, e.g. 10.66.3.2
    gateway: str  # the core router's address on the host's subnet


def _ip(args: list[str], batch: str | None = None, check: bool = True) -> subprocess.CompletedProcess[str]:
    try:
        res = subprocess.run(["ip", *args], input=batch, capture_output=True, text=True, timeout=120)
    except FileNotFoundError:
        raise NetlabError("the `ip` command (iproute2) is missing; install iproute2") from None
    if check and res.returncode != 0:
        raise NetlabError(f"ip {' '.join(args)} failed: {res.stderr.strip()}")
    return res


def list_namespaces(prefix: str = PREFIX + "-") -> list[str]:
    res = _ip(["netns", "list"], check=False)
    names = [line.split()[0] for line in res.stdout.splitlines() if line.strip()]
    return [n for n in names if n.startswith(prefix)]


def kill_namespace_processes(namespaces: list[str]) -> int:
    """SIGKILL the processes still running inside these namespaces; returns how many."""
    n = 0
    for ns in namespaces:
        res = _ip(["netns", "pids", ns], check=False)
        for tok in res.stdout.split():
            if tok.isdigit():
                try:
                    os.kill(int(tok), signal.SIGKILL)
                    n += 1
                except ProcessLookupError:
                    pass
    return n


def delete_namespaces(namespaces: list[str]) -> None:
    if not namespaces:
        return
    kill_namespace_processes(namespaces)
    _ip(["-force", "-batch", "-"], batch="".join(f"netns del {ns}\n" for ns in namespaces), check=False)


def cleanup_stale() -> list[str]:
    """Delete test labs whose owning process has exited (left over by a killed run)."""
    stale = []
    for ns in list_namespaces():
        m = _TEST_OWNER_RE.match(ns)
        if m and not os.path.exists(f"/proc/{m.group(1)}"):
            stale.append(ns)
    delete_namespaces(stale)
    return stale


class Netlab:
    """``hosts`` names (the first is usually the edge server); ``second_octet`` picks 10.X.0.0/16."""

    def __init__(self, hosts: list[str], name: str | None = None, second_octet: int = 66):
        if not hosts or len(hosts) > 250:
            raise ValueError("a netlab has 1..250 hosts")
        if len(set(hosts)) != len(hosts) or not all(NAME_RE.match(h) for h in hosts) or "core" in hosts:
            raise ValueError("host names must be unique, 1-12 characters of [a-z0-9], not 'core'")
        if not 0 <= second_octet <= 255:
            raise ValueError("second_octet must be 0..255")
        if name is None:
            owner = f"t{os.getpid()}x{os.urandom(2).hex()}"
        elif NAME_RE.match(name):
            owner = f"u{name}"
        else:
            raise ValueError("a netlab name is 1-12 characters of [a-z0-9]")
        self.owner = owner
        self.core = f"{PREFIX}-{owner}-core"
        self.hosts = {h: Host(h, f"{PREFIX}-{owner}-{h}", f"10.{second_octet}.{i}.2", f"10.{second_octet}.{i}.1")
                      for i, h in enumerate(hosts, 1)}
        self.is_up = False

    @property
    def namespaces(self) -> list[str]:
        return [h.ns for h in self.hosts.values()] + [self.core]

    def __getitem__(self, host: str) -> Host:
        return self.hosts[host]

    def up(self) -> Netlab:
        if os.geteuid() != 0:
            raise NetlabError("building network namespaces needs root")
        exists = set(list_namespaces(f"{PREFIX}-{self.owner}-"))
        if exists:
            raise NetlabError(f"namespaces of lab {self.owner!r} exist already: {sorted(exists)}")
        self.is_up = True  # from here on, down() cleans whatever part was made
        try:
            _ip(["-batch", "-"], batch="".join(f"netns add {ns}\n" for ns in self.namespaces))
            core = ["link set lo up\n"]
            for i, h in enumerate(self.hosts.values(), 1):
                core.append(f"link add v{i} type veth peer name eth0 netns {h.ns}\n")
                core.append(f"addr add {h.gateway}/24 dev v{i}\n")
                core.append(f"link set v{i} up\n")
            _ip(["-n", self.core, "-batch", "-"], batch="".join(core))
            for h in self.hosts.values():
                _ip(["-n", h.ns, "-batch", "-"], batch=(
                    "link set lo up\n"
                    f"addr add {h.addr}/24 dev eth0\n"
                    "link set eth0 up\n"
                    f"route add default via {h.gateway}\n"))
            res = subprocess.run(["ip", "netns", "exec", self.core, "sh", "-c", "echo 1 > /proc/sys/net/ipv4/ip_forward"],
                                 capture_output=True, text=True, timeout=30)
            if res.returncode != 0:
                raise NetlabError(f"cannot enable forwarding in {self.core}: {res.stderr.strip()}")
        except BaseException:
            self.down()
            raise
        return self

    def down(self) -> None:
        if self.is_up:
            delete_namespaces([ns for ns in self.namespaces if ns in set(list_namespaces(f"{PREFIX}-{self.owner}-"))])
            self.is_up = False

    def __enter__(self) -> Netlab:
        return self.up()

    def __exit__(self, *exc: object) -> None:
        self.down()

    def argv(self, host: str, argv: list[str]) -> list[str]:
        """``argv`` run inside ``host``'s namespace (``"core"``: the router's)."""
        ns = self.core if host == "core" else self.hosts[host].ns
        return ["ip", "netns", "exec", ns, *argv]

    def popen(self, host: str, argv: list[str], **kw: Any) -> subprocess.Popen[Any]:
        return subprocess.Popen(self.argv(host, argv), **kw)

    def run(self, host: str, argv: list[str], timeout: float = 30.0, **kw: Any) -> subprocess.CompletedProcess[str]:
        return subprocess.run(self.argv(host, argv), capture_output=True, text=True, timeout=timeout, **kw)


# ---- CLI: mrswarm netlab up|down|list ------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mrswarm netlab", description="routed network-namespace lab: one subnet per host, "
                                 "no multicast between hosts (like an LTE/5G campus network); needs root")
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("up", help="create a lab")
    p.add_argument("--name", default="lab", help="lab name (1-12 of [a-z0-9])")
    p.add_argument("--hosts", type=int, default=4, help="number of UAV hosts h1..hN (plus one 'edge' host)")
    p.add_argument("--octet", type=int, default=66, help="addresses 10.OCTET.<host>.2")
    p = sub.add_parser("down", help="delete a lab (kills what still runs in it)")
    p.add_argument("--name", default="lab")
    sub.add_parser("list", help="list lab namespaces")
    args = ap.parse_args(argv)
    try:
        if args.cmd == "up":
            lab = Netlab(["edge"] + [f"h{i}" for i in range(1, args.hosts + 1)], name=args.name, second_octet=args.octet)
            lab.up()
            print(f"lab {args.name!r}: core router namespace {lab.core}")
            for h in lab.hosts.values():
                print(f"  {h.name:6s} {h.addr:15s} ip netns exec {h.ns} <command>")
            print(f"delete with: mrswarm netlab down --name {args.name}")
        elif args.cmd == "down":
            names = list_namespaces(f"{PREFIX}-u{args.name}-")
            if not names:
                print(f"no lab named {args.name!r}", file=sys.stderr)
                return 1
            delete_namespaces(names)
            print(f"deleted {len(names)} namespaces")
        else:
            for ns in list_namespaces():
                print(ns)
    except (NetlabError, ValueError) as exc:
        print(f"mrswarm netlab: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
