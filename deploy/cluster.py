"""A multi-node Docker Swarm on one machine: N edge servers as network namespaces.

``mrswarm deploy cluster up --nodes 3`` gives tests and users a real swarm of several edge
servers without several machines. Each node is

* a network namespace ``<prefix>n<i>`` whose only link, ``eth0`` (``10.213.0.1<i>/24``), is a
  veth into a hub namespace ``<prefix>hub`` holding the bridge ``br0``: the nodes' traffic never
  touches the host's interfaces (no default route), and the host's firewall never sees it;
* its own ``dockerd`` started inside that namespace in a private mount and UTS namespace:
  host name ``<prefix>n<i>``, tmpfs over ``/etc/docker`` (its own engine id), ``/run/containerd``
  (its own containerd) and ``/sys/fs/cgroup`` (the host's controllers mounted again, since
  ``ip netns exec`` hides them), its own data root, exec root, pidfile and socket under
  ``<root>/n<i>/``, and a cgroup ``/<prefix>n<i>`` per controller that holds the daemon, its
  containerd, shims and containers, so that teardown finds every process. Its iptables rules
  land in its own namespace's tables;
* a swarm member: node 1 is the manager (``swarm init`` with an address pool that does not
  overlap the nodes' subnet), the others join as workers;
* loaded with the images the host engine has (``docker save`` once, ``docker load`` per node;
  there is no registry).

The kernel here has no IPVS: services must use ``endpoint_mode: dnsrr`` and host-mode ports
(``deploy/swarm.py`` does). :func:`down` removes everything, also after a failed ``up`` or a
killed process: it works from the state file and, without one, from the names alone. Needs
root, ``ip`` (iproute2), ``unshare``/``nsenter`` (util-linux) and ``dockerd``.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import subprocess
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from deploy.dockerutil import DeployError
from groundfloor.files import write_json_atomic

DEFAULT_ROOT = Path("/var/tmp/mrswarm-cluster")
DEFAULT_PREFIX = "mrsc"
SUBNET = "10.213.0"  # node i is SUBNET.1<i> (i = 1..9)
ADDRESS_POOL = "10.214.0.0/16"  # swarm overlay subnets (Docker's default 10.0.0.0/8 would hold the nodes' own)
CGROUP_ROOT = Path("/sys/fs/cgroup")
STATE = "cluster.json"
MAX_NODES = 9


class ClusterError(DeployError):
    pass


@dataclass
class Node:
    index: int
    name: str  # namespace and host name, also the swarm node's hostname (placement constraints)
    address: str  # eth0 address inside the hub's subnet
    dir: str  # data root, exec root, pidfile and socket live here
    pid: int = 0  # dockerd

    @property
    def socket(self) -> str:
        return f"{self.dir}/docker.sock"

    @property
    def docker_host(self) -> str:
        return f"unix://{self.socket}"

    @property
    def exec_root(self) -> str:
        return f"{self.dir}/exec"


@dataclass
class Cluster:
    root: str
    prefix: str
    nodes: list[Node] = field(default_factory=list)
    images: list[str] = field(default_factory=list)

    @property
    def hub(self) -> str:
        return f"{self.prefix}hub"

    @property
    def manager(self) -> Node:
        return self.nodes[0]

    def save(self) -> None:
        Path(self.root).mkdir(parents=True, exist_ok=True)
        write_json_atomic(Path(self.root) / STATE, asdict(self), indent=1)


def load(root: Path = DEFAULT_ROOT) -> Cluster:
    path = root / STATE
    try:
        raw = json.loads(path.read_text())
    except FileNotFoundError:
        raise ClusterError(f"no cluster at {root} (`mrswarm deploy cluster up` makes one)") from None
    return Cluster(raw["root"], raw["prefix"], [Node(**n) for n in raw["nodes"]], raw.get("images", []))


def _run(argv: Sequence[str], timeout: float = 30.0, check: bool = True) -> subprocess.CompletedProcess[str]:
    res = subprocess.run(list(argv), capture_output=True, text=True, timeout=timeout)
    if check and res.returncode != 0:
        raise ClusterError(f"`{shlex.join(argv)}` failed: {res.stderr.strip() or res.stdout.strip()}")
    return res


def _check_host() -> None:
    if os.geteuid() != 0:
        raise ClusterError("a cluster of network namespaces needs root (ip netns, dockerd)")
    for exe in ("ip", "unshare", "nsenter", "dockerd", "docker"):
        if shutil.which(exe) is None:
            raise ClusterError(f"{exe} is not installed (iproute2, util-linux, docker.io)")


def netns_names() -> set[str]:
    res = _run(["ip", "netns", "list"], check=False)
    return {line.split()[0] for line in res.stdout.splitlines() if line.strip()}


def _cgroup_mounts() -> list[tuple[str, str, str]]:
    """(type, options, mount point) of the host's cgroup hierarchies, to mount again in a node."""
    out = []
    for line in Path("/proc/self/mounts").read_text().splitlines():
        dev, mnt, fstype, opts, *_ = line.split()
        if fstype in ("cgroup", "cgroup2") and mnt.startswith(f"{CGROUP_ROOT}/"):
            out.append((fstype, opts, mnt))
    return out


def _cgroup_dirs(name: str) -> list[Path]:
    """The node's cgroup in every hierarchy that exists (one directory per controller mount)."""
    return [Path(mnt) / name for _, _, mnt in _cgroup_mounts()]


def _daemon_script(node: Node) -> str:
    """The shell run in the node's namespaces: private mounts, own cgroup, then ``exec dockerd``."""
    mounts = [f"hostname {node.name}", "mount --make-rprivate /",
              "mount -t tmpfs tmpfs /run/containerd", "mount -t tmpfs tmpfs /etc/docker",
              f"mount -t tmpfs -o mode=755 tmpfs {CGROUP_ROOT}"]
    for fstype, opts, mnt in _cgroup_mounts():
        keep = ",".join(o for o in opts.split(",") if o not in ("rw", "relatime", "nosuid", "nodev", "noexec"))
        mounts.append(f"mkdir -p {mnt} && mount -t {fstype} {'-o ' + keep + ' ' if keep else ''}{fstype} {mnt}")
    cg = node.name
    # the pids hierarchy tracks the daemon and everything it starts (shims outlive it, re-parented to PID 1)
    join = [f"mkdir -p {mnt}/{cg} && echo $$ > {mnt}/{cg}/cgroup.procs" for fstype, opts, mnt in _cgroup_mounts()
            if fstype == "cgroup" and "pids" in opts.split(",")]
    dockerd = ["dockerd", "--data-root", f"{node.dir}/data", "--exec-root", node.exec_root, "--pidfile", f"{node.dir}/docker.pid",
               "-H", node.docker_host, "--storage-driver", "overlay2", "--cgroup-parent", f"/{cg}/containers",
               "--userland-proxy=false", "--shutdown-timeout", "2", "--log-level", "warn"]
    return " && ".join([*mounts, *join, f"exec {shlex.join(dockerd)}"])


def _wait(what: str, ok: Any, timeout: float, step: float = 0.2) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        got = ok()
        if got:
            return got
        if time.monotonic() > deadline:
            raise ClusterError(f"{what}: not after {timeout:.0f} s")
        time.sleep(step)


def node_client(node: Node, timeout: int = 120) -> Any:
    import docker

    return docker.DockerClient(base_url=node.docker_host, timeout=timeout)


def _ping(node: Node) -> bool:
    try:
        return bool(node_client(node, timeout=5).ping())
    except Exception:  # noqa: BLE001 - not up yet
        return False


def up(nodes: int = 3, root: Path = DEFAULT_ROOT, prefix: str = DEFAULT_PREFIX, images: Sequence[str] = (),
       log: Any = print, timeout: float = 60.0) -> Cluster:
    """Bring up ``nodes`` edge servers as one swarm; on any failure, remove what was made and raise."""
    if not 1 <= nodes <= MAX_NODES:
        raise ClusterError(f"--nodes must be in 1..{MAX_NODES}, got {nodes}")
    if root.exists() and not _ours(root):  # the arguments first: this needs neither root nor docker to tell
        raise ClusterError(f"--root {root} exists and holds other files: name a new or empty directory")
    _check_host()
    if (root / STATE).exists() or f"{prefix}hub" in netns_names():
        raise ClusterError(f"a cluster already runs at {root} (prefix {prefix}): `mrswarm deploy cluster down` first")
    cl = Cluster(str(root.resolve()), prefix, [Node(i, f"{prefix}n{i}", f"{SUBNET}.1{i}", str(root.resolve() / f"n{i}"))
                                               for i in range(1, nodes + 1)], list(images))
    try:
        _network(cl)
        cl.save()
        for n in cl.nodes:
            _start_daemon(cl, n)
            cl.save()
        for n in cl.nodes:
            _wait(f"dockerd of {n.name}", lambda n=n: _ping(n), timeout)
        log(f"{nodes} docker engines up")
        _form_swarm(cl, timeout)
        log(f"swarm formed: manager {cl.manager.name} ({cl.manager.address}), {nodes - 1} workers")
        if images:
            load_images(cl, images, log)
        return cl
    except BaseException:
        down(root, prefix)
        raise


def _network(cl: Cluster) -> None:
    hub = cl.hub
    _run(["ip", "netns", "add", hub])
    _run(["ip", "-n", hub, "link", "set", "lo", "up"])
    _run(["ip", "-n", hub, "link", "add", "br0", "type", "bridge"])
    _run(["ip", "-n", hub, "link", "set", "br0", "up"])
    for n in cl.nodes:
        _run(["ip", "netns", "add", n.name])
        _run(["ip", "link", "add", f"{cl.prefix}v{n.index}", "netns", hub, "type", "veth", "peer", "name", "eth0",
              "netns", n.name])
        _run(["ip", "-n", hub, "link", "set", f"{cl.prefix}v{n.index}", "master", "br0", "up"])
        _run(["ip", "-n", n.name, "addr", "add", f"{n.address}/24", "dev", "eth0"])
        _run(["ip", "-n", n.name, "link", "set", "eth0", "up"])
        _run(["ip", "-n", n.name, "link", "set", "lo", "up"])


def _start_daemon(cl: Cluster, n: Node) -> None:
    d = Path(n.dir)
    d.mkdir(parents=True, exist_ok=True)
    logf = open(d / "dockerd.log", "ab")  # noqa: SIM115 - handed to the daemon
    try:
        proc = subprocess.Popen(["ip", "netns", "exec", n.name, "unshare", "--uts", "--mount", "sh", "-c",
                                 _daemon_script(n)],
                                stdin=subprocess.DEVNULL, stdout=logf, stderr=logf, start_new_session=True)
    finally:
        logf.close()
    n.pid = proc.pid  # ip, unshare and sh all exec: this is dockerd's pid


def _form_swarm(cl: Cluster, timeout: float) -> None:
    m = node_client(cl.manager)
    m.swarm.init(advertise_addr=cl.manager.address, listen_addr=f"{cl.manager.address}:2377",
                 default_addr_pool=[ADDRESS_POOL], subnet_size=24)
    token = m.swarm.attrs["JoinTokens"]["Worker"]
    for n in cl.nodes[1:]:
        node_client(n).swarm.join(remote_addrs=[f"{cl.manager.address}:2377"], join_token=token,
                                  listen_addr=f"{n.address}:2377", advertise_addr=n.address)

    def ready() -> bool:
        states = [x.attrs["Status"]["State"] for x in m.nodes.list()]
        return len(states) == len(cl.nodes) and all(s == "ready" for s in states)

    _wait("every node ready in the swarm", ready, timeout, 0.5)


def load_images(cl: Cluster, images: Sequence[str], log: Any = print) -> None:
    """Copy images from the host engine into every node (no registry): one ``docker save``, a ``load`` per node."""
    tar = Path(cl.root) / "images.tar"
    try:
        with open(tar, "wb") as f:
            res = subprocess.run(["docker", "save", *images], stdout=f, stderr=subprocess.PIPE, timeout=300)
        if res.returncode != 0:
            raise ClusterError(f"docker save {' '.join(images)} failed: {res.stderr.decode().strip()}")
        for n in cl.nodes:
            with open(tar, "rb") as f:
                res = subprocess.run(["docker", "-H", n.docker_host, "load", "-q"], stdin=f, capture_output=True,
                                     timeout=300)
            if res.returncode != 0:
                raise ClusterError(f"docker load into {n.name} failed: {res.stderr.decode().strip()}")
        log(f"loaded {', '.join(images)} into {len(cl.nodes)} nodes")
    finally:
        tar.unlink(missing_ok=True)
    cl.images = sorted(set(cl.images) | set(images))
    cl.save()


def exec_argv(node: Node, argv: Sequence[str], cwd: str | None = None) -> list[str]:
    """``argv`` run on ``node``: in its network, mount and UTS namespaces, talking to its dockerd.

    ``MRSWARM_DOCKER_EXEC_ROOT`` tells ``deploy/multicast.py`` where this dockerd keeps the
    overlay namespaces it seals."""
    if not node.pid:
        raise ClusterError(f"node {node.name} has no dockerd")
    return ["nsenter", f"--target={node.pid}", "--mount", "--net", "--uts", f"--wd={cwd or os.getcwd()}", "--",
            "env", f"DOCKER_HOST={node.docker_host}", f"MRSWARM_DOCKER_EXEC_ROOT={node.exec_root}", *argv]


def node_by_name(cl: Cluster, which: str) -> Node:
    for n in cl.nodes:
        if which in (str(n.index), n.name):
            return n
    raise ClusterError(f"no node {which!r} in the cluster (have {', '.join(n.name for n in cl.nodes)})")


def _pids_in(dirs: list[Path]) -> set[int]:
    pids: set[int] = set()
    for d in dirs:
        if d.is_dir():
            for procs in d.rglob("cgroup.procs"):
                try:
                    pids |= {int(p) for p in procs.read_text().split()}
                except OSError:
                    pass
    return pids


def _kill(pids: set[int], sig: signal.Signals) -> None:
    for p in pids:
        try:
            os.kill(p, sig)
        except ProcessLookupError:
            pass


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def _rmdir_tree(d: Path) -> None:
    if not d.is_dir():
        return
    for sub in sorted((p for p in d.rglob("*") if p.is_dir()), key=lambda p: len(p.parts), reverse=True):
        try:
            sub.rmdir()
        except OSError:
            pass
    try:
        d.rmdir()
    except OSError:
        pass


def down(root: Path = DEFAULT_ROOT, prefix: str = DEFAULT_PREFIX, timeout: float = 20.0) -> dict[str, Any]:
    """Stop every node and remove namespaces, links, cgroups, mounts and files: idempotent, bounded in time.

    Works from the state file if there is one, and from the names alone if not (a killed ``up``)."""
    try:
        cl: Cluster | None = load(root)
        prefix = cl.prefix if cl else prefix
    except (ClusterError, ValueError, KeyError):
        cl = None
    names = {n for n in netns_names() if n.startswith(prefix)}
    node_names = sorted(n for n in names if n != f"{prefix}hub") or ([x.name for x in cl.nodes] if cl else [])
    cgroups = {name: _cgroup_dirs(name) for name in node_names}
    daemons = [x.pid for x in cl.nodes if x.pid] if cl else []
    for pidfile in root.glob("n*/docker.pid"):
        try:
            daemons.append(int(pidfile.read_text().strip()))
        except (OSError, ValueError):
            pass
    daemons = [p for p in set(daemons) if _alive(p) and _in_cgroup_of(p, prefix)]
    _kill(set(daemons), signal.SIGTERM)  # dockerd stops its containers (grace 2 s) and containerd
    deadline = time.monotonic() + timeout
    while any(_alive(p) for p in daemons) and time.monotonic() < deadline:
        time.sleep(0.2)
    all_cg = [d for ds in cgroups.values() for d in ds]
    killed = 0
    while (left := _pids_in(all_cg)) and time.monotonic() < deadline + 10:
        killed += len(left)
        _kill(left, signal.SIGKILL)  # shims re-parented to PID 1, a stuck daemon
        time.sleep(0.2)
    for ns in names:
        res = _run(["ip", "netns", "pids", ns], check=False)
        _kill({int(p) for p in res.stdout.split()}, signal.SIGKILL)
    for d in all_cg:
        _rmdir_tree(d)
    for ns in sorted(names):
        _run(["ip", "netns", "del", ns], check=False)  # takes its veth ends and the hub's bridge with it
    for line in reversed(Path("/proc/self/mounts").read_text().splitlines()):  # nothing should be here: all were private
        mnt = line.split()[1]
        if mnt.startswith(f"{root.resolve()}/"):
            _run(["umount", "-l", mnt], check=False)
    if _ours(root):
        shutil.rmtree(root, ignore_errors=True)
    return {"namespaces": sorted(names), "processes_killed": killed, "left": leftovers(root, prefix)}


def _ours(root: Path) -> bool:
    """Whether ``root`` holds only what :func:`up` puts there (never remove a directory of someone else's)."""
    if not root.is_dir():
        return False
    names = {p.name for p in root.iterdir()}
    return all(n in (STATE, "images.tar") or (n.startswith(f".{STATE}.") and n.endswith(".tmp"))
               or (n[:1] == "n" and n[1:].isdigit()) for n in names)


def _in_cgroup_of(pid: int, prefix: str) -> bool:
    """Only ever signal a pid from a state file if it still is one of our nodes' (pids get reused)."""
    try:
        return f"/{prefix}n" in Path(f"/proc/{pid}/cgroup").read_text() or _netns_of(pid, prefix)
    except OSError:
        return False


def _netns_of(pid: int, prefix: str) -> bool:
    res = _run(["ip", "netns", "identify", str(pid)], check=False)
    return res.stdout.strip().startswith(prefix)


def leftovers(root: Path = DEFAULT_ROOT, prefix: str = DEFAULT_PREFIX) -> dict[str, list[str]]:
    """What a cluster could leave behind on the host; every list is empty after :func:`down`."""
    links = _run(["ip", "-o", "link", "show"], check=False).stdout
    procs = []
    for p in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            cmd = p.read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if str(root.resolve()) in cmd and p.parent.name != str(os.getpid()):  # not this `down` itself
            procs.append(f"{p.parent.name}: {cmd[:80]}")
    return {
        "namespaces": sorted(n for n in netns_names() if n.startswith(prefix)),
        "links": [ln.split(":")[1].strip() for ln in links.splitlines() if f"{prefix}v" in ln or f"{prefix}br" in ln],
        "processes": procs,
        "mounts": [ln.split()[1] for ln in Path("/proc/self/mounts").read_text().splitlines()
                   if str(root.resolve()) in ln.split()[1]],
        "cgroups": [str(d) for d in _cgroup_dirs_glob(prefix)],
        "files": [str(root)] if root.exists() else [],
    }


def _cgroup_dirs_glob(prefix: str) -> list[Path]:
    return [d for _, _, mnt in _cgroup_mounts() for d in Path(mnt).glob(f"{prefix}n*") if d.is_dir()]


def status(root: Path = DEFAULT_ROOT) -> dict[str, Any]:
    cl = load(root)
    out: dict[str, Any] = {"root": cl.root, "images": cl.images, "nodes": []}
    try:
        swarm_nodes = {x.attrs["Description"]["Hostname"]: x for x in node_client(cl.manager, 10).nodes.list()}
    except Exception:  # noqa: BLE001 - the manager is down: report what we know
        swarm_nodes = {}
    for n in cl.nodes:
        sn = swarm_nodes.get(n.name)
        out["nodes"].append({"name": n.name, "address": n.address, "docker_host": n.docker_host, "dockerd": n.pid,
                             "running": _alive(n.pid), "role": sn.attrs["Spec"]["Role"] if sn else None,
                             "state": sn.attrs["Status"]["State"] if sn else None})
    return out
