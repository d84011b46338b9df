"""Several edge servers: the stack on Docker Swarm mode.

``mrswarm deploy swarm up --uavs N`` turns a scenario into a :class:`Fleet` (in mrswarm's
CLI layer, which reads scenarios) and this module turns the fleet into a compose stack file
and deploys it with ``docker stack deploy``:

* the services of the scenario's network plan placed in containers (``deploy/plan.py``,
  :data:`~deploy.plan.CONTAINERS`: the discovery server, the edge router), with the same options
  as the other runtimes, DNS round-robin endpoints and their port published on the manager in
  host mode (no ingress mesh needed);
* with ``StackOptions.edges`` (``swarm up --edge-per-node``), an edge router per server:
  ``router-<host>`` pinned to each other server, dialling the manager's ``router``; each UAV
  replica uses its own server's (``deploy/swarm_uav.py``, ``MRSWARM_NODE``/``MRSWARM_EDGES``);
* ``uav``: a replicated service of N virtual UAVs. Every replica gets the same fleet file
  (a swarm config); replica k runs the k-th UAV config (``deploy/swarm_uav.py``);
* one attachable overlay network ``mrswarm-<swarm>`` that spans every edge server, created
  before the stack (external to it). Its multicast is dropped on every server that runs a
  sentinel container (``deploy/multicast.py``): ``up`` starts one on the manager, and
  ``mrswarm deploy swarm seal`` on each other edge server. Discovery can then only go through
  the rendezvous/discovery service, as on a cellular network;
* on a secured swarm (docs/security.md), the credentials as Swarm secrets from the swarm's key
  directory, mounted in ``/run/secrets`` (never in the image): the router gets the CA
  certificate, the roster and ``edge``'s key pair; the ``uav`` service every UAV's pair of the
  fleet, since Swarm hands secrets per service, not per replica (each replica uses its own), and
  the swarm's MAVLink signing key.

Other edge servers join with ``docker swarm join`` and replicas spread over them
(``docs/deploy.md``). The stack's name is ``mrswarm-<swarm>``; ``down`` runs ``docker stack rm``
and waits until its services, tasks, network and configs are gone.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import yaml
from msgspec import structs

from deploy.dockerutil import L_ROLE, L_RUN, L_SWARM, DeployError, client
from deploy.multicast import IPV6_OFF
from deploy.plan import ROUTER_PORT, PlacedNetwork, edge_service
from deploy.settings import ContainerSettings
from discovery.options import RouterOptions
from groundfloor.schema import to_builtins
from swarmnet.security.beacon import BEACON_KEY_FILE
from swarmnet.security.identity import NodeName
from swarmnet.security.roster import CA_CERT_FILE, MAVLINK_KEY_FILE, ROSTER_FILE
from uav_stack.config import VirtualUavConfig

FLEET_PATH = "/etc/mrswarm/fleet.json"
DATA_PATH = "/data"


@dataclass(frozen=True)
class StackOptions:
    image: str
    container: ContainerSettings = ContainerSettings()  # limits of each UAV replica, and the multicast policy
    port: int = ROUTER_PORT  # router port published on the manager (the GCS / runner connects there)
    max_per_node: int = 0  # 0: no limit; else at most this many UAV replicas on one edge server
    log_level: str = "INFO"
    # one edge router per server (host names, the manager's first): the manager's is `router`, the
    # others `router-<host>`, linked to it; each UAV uses its own server's. Empty: one router.
    edges: tuple[str, ...] = ()



@dataclass(frozen=True)
class Fleet:
    """What a stack runs: the swarm's network plan placed in containers (``deploy/plan.py``) and one
    config per UAV replica.

    Built from a scenario by ``mrswarm deploy swarm up`` (``mrswarm/cli/deploy.py``); the UAVs
    reach the services by their DNS names, so ``network.uav_network`` was called with those.
    """

    network: PlacedNetwork
    uavs: tuple[VirtualUavConfig, ...]

    @property
    def swarm(self) -> str:
        return self.network.plan.swarms[0].name

    @property
    def keys(self) -> Path | None:
        """The swarm's key directory, relative to the stack file's folder or absolute; None: plain TCP."""
        return self.network.plan.swarms[0].keys


def _secret(key_file: str) -> str:
    """A secret's name in the stack file: ``uav-3.alpha.key`` -> ``uav-3_alpha_key``."""
    return key_file.replace(".", "_")


def _secrets(fleet: Fleet, name: str, common_labels: dict[str, str]) -> tuple[dict[str, Any], dict[str, list[Any]]]:
    """The stack's secrets (name -> file) and each service's (service -> mounts), from the key directory."""
    assert fleet.keys is not None
    base = [CA_CERT_FILE, ROSTER_FILE]
    pairs: dict[str, list[str]] = {}
    for svc in fleet.network.services:
        if (ident := svc.service.identity) is not None:
            # the discovery server also holds the beacon key: it checks every node's beacon token
            extra = [BEACON_KEY_FILE] if svc.service.role == "discovery" else []
            pairs[svc.name] = [*base, f"{ident.cn}.pem", f"{ident.cn}.key", *extra]
    pairs["uav"] = [*base, *(f"{NodeName.uav(c.agent.uav, fleet.swarm).cn}.{ext}" for c in fleet.uavs
                             for ext in ("pem", "key", "beacon"))]
    # the MAVLink signing key: the stack's own directory always has one (ensure_keys); a swarm's, if it was made
    if not fleet.keys.is_absolute() or (fleet.keys / MAVLINK_KEY_FILE).is_file():
        pairs["uav"].append(MAVLINK_KEY_FILE)
    files = sorted({f for fs in pairs.values() for f in fs})
    top = {_secret(f): {"file": f"{fleet.keys / f}" if fleet.keys.is_absolute() else f"./{fleet.keys / f}",
                        "name": f"{name}-{f}", "labels": common_labels} for f in files}
    mounts = {svc: [{"source": _secret(f), "target": f, "mode": 0o400 if f.endswith((".key", ".beacon")) else 0o444}
                    for f in fs]
              for svc, fs in pairs.items()}
    return top, mounts


def stack_name(swarm: str) -> str:
    return f"mrswarm-{swarm}"


def stack_spec(fleet: Fleet, opts: StackOptions) -> tuple[dict[str, Any], str]:
    """The compose stack (as a dict) and the fleet file's JSON text."""
    fleet_json = json.dumps([to_builtins(c) for c in fleet.uavs], indent=1)
    digest = hashlib.sha256(fleet_json.encode()).hexdigest()[:10]
    name = stack_name(fleet.swarm)
    common_labels = {L_RUN: name, L_SWARM: fleet.swarm}
    sysctls = {k: int(v) for k, v in IPV6_OFF.items()}
    services: dict[str, Any] = {}
    for svc in fleet.network.services:
        services[svc.name] = {
            "image": opts.image,
            "command": ["python3", *svc.argv()],
            "networks": ["swarm"],
            "ports": [{"target": svc.port, "published": opts.port if svc.name == "router" else svc.port,
                       "protocol": svc.service.proto, "mode": "host"}],
            "sysctls": sysctls,
            "read_only": True,
            "tmpfs": ["/tmp"],
            "labels": {**common_labels, L_ROLE: svc.name},
            "deploy": {
                "replicas": 1,
                "endpoint_mode": "dnsrr",
                "placement": {"constraints": ["node.role == manager"]},
                "resources": {"limits": {"cpus": "1.0", "memory": "512M"}},
                "restart_policy": {"condition": "on-failure", "max_attempts": 5},
                "labels": {**common_labels, L_ROLE: svc.name},
            },
        }
        if svc.name == "router" and opts.edges and isinstance(svc.options, RouterOptions):
            services[svc.name]["deploy"]["placement"] = {"constraints": [f"node.hostname == {opts.edges[0]}"]}
            # an edge per other server, linked to the manager's (docs/deploy.md)
            scheme = fleet.network.plan.swarm(svc.service.swarm).scheme
            linked = replace(svc, options=structs.replace(svc.options, connect=(f"{scheme}/router:{svc.port}",)))
            for host in opts.edges[1:]:
                edge = json.loads(json.dumps(services[svc.name]))
                edge["command"] = ["python3", *linked.argv()]
                del edge["ports"]  # only the manager's router is published
                edge["deploy"]["placement"] = {"constraints": [f"node.hostname == {host}"]}
                services[edge_service(host, opts.edges)] = edge
    uav_deploy: dict[str, Any] = {
        "replicas": len(fleet.uavs),
        "endpoint_mode": "dnsrr",
        "resources": {"limits": {"cpus": f"{opts.container.cpus:g}", "memory": f"{opts.container.memory_mb}M"}},
        "restart_policy": {"condition": "on-failure", "max_attempts": 3},
        "labels": {**common_labels, L_ROLE: "uav"},
    }
    if opts.max_per_node:
        uav_deploy["placement"] = {"max_replicas_per_node": opts.max_per_node}
    services["uav"] = {
        "image": opts.image,
        "command": ["python3", "-m", "deploy.swarm_uav", "--fleet", FLEET_PATH, "--log-level", opts.log_level],
        "hostname": "uav{{.Task.Slot}}",
        "environment": {"MRSWARM_SLOT": "{{.Task.Slot}}"}
        | ({"MRSWARM_NODE": "{{.Node.Hostname}}", "MRSWARM_EDGES": ",".join(opts.edges)} if opts.edges else {}),
        "configs": [{"source": "fleet", "target": FLEET_PATH, "mode": 0o444}],
        "volumes": [{"type": "volume", "source": "data", "target": DATA_PATH}],
        "networks": ["swarm"],
        "sysctls": sysctls,
        "read_only": True,
        "tmpfs": ["/tmp"],
        "labels": {**common_labels, L_ROLE: "uav"},
        "depends_on": [s for s in services],
        "deploy": uav_deploy,
    }
    stack = {
        "version": "3.8",
        "services": services,
        "networks": {"swarm": {"external": True, "name": name}},
        "volumes": {"data": {"labels": common_labels}},
        "configs": {"fleet": {"name": f"{name}-fleet-{digest}", "file": "./fleet.json", "labels": common_labels}},
    }
    if fleet.keys is not None:  # the credentials, as Swarm secrets (docs/security.md)
        stack["secrets"], mounts = _secrets(fleet, name, common_labels)
        for service, m in mounts.items():
            services[service]["secrets"] = m
        for host in opts.edges[1:]:
            services[edge_service(host, opts.edges)]["secrets"] = mounts["router"]
    return stack, fleet_json


def write_stack(fleet: Fleet, opts: StackOptions, out: Path) -> Path:
    stack, fleet_json = stack_spec(fleet, opts)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fleet.json").write_text(fleet_json)
    name = stack_name(fleet.swarm)
    header = (f"# mrswarm stack for swarm '{fleet.swarm}' ({len(fleet.uavs)} virtual UAVs), made by `mrswarm deploy swarm up`\n"
              f"# (which also makes the network and drops multicast on it). By hand, on a swarm manager:\n"
              f"#   docker network create --driver overlay --attachable {name}\n"
              f"#   mrswarm deploy swarm seal --swarm {fleet.swarm}    # on every edge server: no multicast\n"
              f"#   docker stack deploy -c stack.yml {name}\n")
    path = out / "stack.yml"
    path.write_text(header + yaml.dump(stack, Dumper=_NoAliases, sort_keys=False))
    return path


class _NoAliases(yaml.SafeDumper):
    def ignore_aliases(self, data: Any) -> bool:
        return True


def ensure_network(cl: Any, swarm: str) -> Any:
    """The stack's attachable overlay network (made once, shared by every edge server)."""
    name = stack_name(swarm)
    for n in cl.networks.list(names=[name]):
        if n.name == name:
            return n
    return cl.networks.create(name, driver="overlay", attachable=True, scope="swarm", check_duplicate=True,
                              labels={L_RUN: name, L_SWARM: swarm, L_ROLE: "network"})


def seal_node(cl: Any, swarm: str, image: str) -> str:
    """Keep a sentinel container of the overlay on this server and drop multicast there."""
    import socket

    from deploy import multicast

    manager = bool(cl.info().get("Swarm", {}).get("ControlAvailable"))
    # a worker cannot create (or even list) a swarm network before a container of it runs there:
    # its sentinel attaches by name (the network is attachable) and brings it here
    net_name = ensure_network(cl, swarm).name if manager else stack_name(swarm)
    name = f"{stack_name(swarm)}-sentinel-{socket.gethostname()}"[:63]
    found = cl.containers.list(all=True, filters={"name": f"^{name}$"})
    box = found[0] if found else cl.containers.run(
        image, ["python3", "-c", SENTINEL], name=name, detach=True, network=net_name, read_only=True,
        labels={L_RUN: stack_name(swarm), L_SWARM: swarm, L_ROLE: "sentinel"}, restart_policy={"Name": "unless-stopped"},
        cap_drop=["ALL"], nano_cpus=int(0.05e9), mem_limit="32m")
    if box.status != "running":
        box.start()
    net = cl.networks.get(net_name)
    deadline = time.monotonic() + 20
    while not multicast.seal_overlay(net.id, net.name):
        if time.monotonic() > deadline:
            raise DeployError(f"the overlay {net.name} has no namespace on this server after 20 s")
        time.sleep(0.5)
    return name


SENTINEL = "import signal, sys; signal.signal(signal.SIGTERM, lambda *a: sys.exit(0)); signal.pause()"


def _docker_cli() -> str:
    exe = shutil.which("docker")
    if exe is None:
        raise DeployError("the docker CLI is not installed (apt-get install docker.io); `docker stack deploy` needs it")
    return exe


def _swarm_manager(cl: Any) -> None:
    info = cl.info().get("Swarm", {})
    if info.get("LocalNodeState") != "active":
        raise DeployError("this docker engine is not in a swarm: run `docker swarm init` on the first edge server "
                          "(see docs/deploy.md), or pass --init")
    if not info.get("ControlAvailable"):
        raise DeployError("this node is a swarm worker; run `mrswarm deploy swarm` on a manager")


def edge_hosts(cl: Any) -> tuple[str, ...]:
    """The swarm's ready servers by host name, this manager's first: one edge router each."""
    me = cl.info().get("Swarm", {}).get("NodeID")
    ready = [n for n in cl.nodes.list() if n.attrs["Status"]["State"] == "ready"
             and n.attrs["Spec"].get("Availability", "active") == "active"]
    ready.sort(key=lambda n: (n.id != me, n.attrs["Description"]["Hostname"]))
    return tuple(n.attrs["Description"]["Hostname"] for n in ready)


def init_swarm(cl: Any) -> bool:
    """``docker swarm init`` if this engine is in no swarm yet; True if it made one."""
    if cl.info().get("Swarm", {}).get("LocalNodeState") == "active":
        return False
    cl.swarm.init(advertise_addr=_default_address(), listen_addr="0.0.0.0:2377")
    return True


def _default_address() -> str:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # route lookup only, nothing is sent
            return str(s.getsockname()[0])
        except OSError:
            return "127.0.0.1"


def up(fleet: Fleet, opts: StackOptions, out: Path, wait: float = 120.0) -> dict[str, Any]:
    cl = client()
    _swarm_manager(cl)
    try:
        cl.images.get(opts.image)
    except Exception:  # noqa: BLE001
        raise DeployError(f"image {opts.image} is not on this node: `mrswarm deploy build` (and `docker save | docker load` "
                          "it on every other edge server)") from None
    path = write_stack(fleet, opts, out)
    name = stack_name(fleet.swarm)
    if opts.container.multicast == "drop":
        seal_node(cl, fleet.swarm, opts.image)  # before any task of the stack starts here
    else:
        ensure_network(cl, fleet.swarm)
    res = subprocess.run([_docker_cli(), "stack", "deploy", "--prune", "-c", path.name, name], cwd=out,
                         capture_output=True, text=True, timeout=120)
    if res.returncode != 0:
        raise DeployError(f"docker stack deploy failed: {res.stderr.strip() or res.stdout.strip()}")
    want = {f"{name}_{s}": 1 for s in stack_spec(fleet, opts)[0]["services"]}
    want[f"{name}_uav"] = len(fleet.uavs)
    running = wait_running(cl, want, wait)
    scheme = "tls" if fleet.keys is not None else "tcp"
    return {"stack": name, "file": str(path), "services": running, "router": f"{scheme}/<manager>:{opts.port}"}


def wait_running(cl: Any, want: dict[str, int], timeout: float) -> dict[str, int]:
    """Wait (bounded) until each service has its number of running tasks."""
    deadline = time.monotonic() + timeout
    counts: dict[str, int] = {}
    while True:
        counts = {}
        for s in cl.services.list(filters={"name": list(want)}):
            if s.name in want:
                counts[s.name] = sum(1 for t in s.tasks() if t["Status"]["State"] == "running"
                                     and t["DesiredState"] == "running")
        if all(counts.get(n, 0) >= k for n, k in want.items()):
            return counts
        if time.monotonic() > deadline:
            raise DeployError(f"services not running after {timeout:.0f} s: have {counts}, want {want} "
                              "(`docker service ps --no-trunc` tells why)")
        time.sleep(1.0)


def down(swarm: str, wait: float = 90.0, volumes: bool = False) -> dict[str, int]:
    """``docker stack rm`` and wait until its services, containers, network and configs are gone."""
    cl = client()
    name = stack_name(swarm)
    label = f"{L_RUN}={name}"
    ns = f"com.docker.stack.namespace={name}"
    if not cl.info().get("Swarm", {}).get("ControlAvailable"):  # a worker: only its sentinel is its own
        gone = 0
        for c in cl.containers.list(all=True, sparse=True, filters={"label": label}):
            c.remove(force=True)
            gone += 1
        removed = 0
        for v in cl.volumes.list(filters={"label": ns}) if volumes else []:
            try:
                v.remove(force=True)
                removed += 1
            except Exception:  # noqa: BLE001 - its UAVs still run here: the manager's `down` stops them first
                pass
        return {"sentinels_removed": gone, "volumes_removed": removed}
    res = subprocess.run([_docker_cli(), "stack", "rm", name], capture_output=True, text=True, timeout=120)
    if res.returncode != 0 and "Nothing found in stack" not in res.stderr:
        raise DeployError(f"docker stack rm failed: {res.stderr.strip()}")
    deadline = time.monotonic() + wait
    left: dict[str, int] = {}
    while True:
        left = {
            "services": len(cl.services.list(filters={"label": ns})),
            "containers": len(cl.containers.list(all=True, sparse=True, filters={"label": ns})),
            "networks": len(cl.networks.list(filters={"label": ns})),
            "configs": len(cl.configs.list(filters={"label": label})),
            "secrets": len(cl.secrets.list(filters={"label": label})),
        }
        if not any(left.values()):
            break
        if time.monotonic() > deadline:
            raise DeployError(f"stack {name} not gone after {wait:.0f} s: {left}")
        time.sleep(1.0)
    for c in cl.containers.list(all=True, sparse=True, filters={"label": label}):  # this server's sentinel
        try:
            c.remove(force=True)
        except Exception:  # noqa: BLE001 - already gone
            pass
    while nets := [n for n in cl.networks.list(names=[name]) if n.name == name]:
        try:
            nets[0].remove()
        except Exception as exc:  # noqa: BLE001
            if time.monotonic() > deadline:
                raise DeployError(f"network {name} still in use (a sentinel on another edge server? run "
                                  f"`mrswarm deploy swarm down --swarm {swarm}` there): {exc}") from None
        time.sleep(0.5)  # removal of a swarm-scoped network completes asynchronously
        if time.monotonic() > deadline + 30:
            raise DeployError(f"network {name} not gone after {wait:.0f} s")
    removed_volumes = 0
    if volumes:
        for v in cl.volumes.list(filters={"label": ns}):
            try:
                v.remove(force=True)
                removed_volumes += 1
            except Exception:  # noqa: BLE001 - a volume in use on another node stays
                pass
    return {"volumes_removed": removed_volumes}
