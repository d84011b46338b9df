"""``mrswarm deploy``: images, containers of `mrswarm run --runtime docker`, Docker Swarm stacks.

    mrswarm deploy base-image                 # Debian bookworm + Python 3.11 by debootstrap (cached)
    mrswarm deploy build                      # the stack image from a host-built wheelhouse
    mrswarm deploy ps                         # everything mrswarm runs in docker, by label
    mrswarm deploy logs uav3 [--run RUN]      # a container's log (short name, full name or id)
    mrswarm deploy down [--run RUN]           # remove run containers, networks and multicast rules
    mrswarm deploy swarm up --uavs 20         # the stack on Docker Swarm mode (several edge servers)
    mrswarm deploy swarm seal                 # on each other edge server: drop multicast there
    mrswarm deploy swarm down
    mrswarm deploy cluster up --nodes 3       # a test cluster: N swarm nodes in network namespaces here
    mrswarm deploy cluster exec 1 -- CMD      # run CMD on node 1 (its network, its dockerd)
    mrswarm deploy cluster seal --swarm alpha # the swarm's overlay sealed on every node
    mrswarm deploy cluster down
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from deploy.dockerutil import L_ROLE, L_RUN, L_UAV, DeployError, client


def _base_image(args: argparse.Namespace) -> int:
    from deploy.images import make_base_image

    print(make_base_image(args.tag, args.suite, args.mirror, force=args.force))
    return 0


def _build(args: argparse.Namespace) -> int:
    from deploy.images import build_image

    info = build_image(args.tag, args.base, full=args.full)
    print(f"{info.tag}  {info.size_mb:.0f} MB  (FROM {info.base}, source {info.source})")
    return 0


def _ps(args: argparse.Namespace) -> int:
    cl = client()
    rows = []
    for c in cl.containers.list(all=True, filters={"label": L_RUN}):
        lb = c.labels
        nets = c.attrs["NetworkSettings"]["Networks"]
        ip = next(iter(nets.values()))["IPAddress"] if nets else ""
        rows.append((lb.get(L_RUN, ""), lb.get(L_ROLE, ""), lb.get(L_UAV, ""), c.name, c.status, ip))
    ns = "com.docker.stack.namespace"
    for c in cl.containers.list(all=True, filters={"label": ns}):
        if L_RUN not in c.labels:
            rows.append((c.labels[ns], "task", "", c.name, c.status, ""))
    if not rows:
        print("no mrswarm containers")
    else:
        w = [max(len(str(r[i])) for r in rows + [("RUN", "ROLE", "UAV", "NAME", "STATUS", "IP")]) for i in range(6)]
        for r in [("RUN", "ROLE", "UAV", "NAME", "STATUS", "IP")] + sorted(rows):
            print("  ".join(str(v).ljust(w[i]) for i, v in enumerate(r)).rstrip())
    for s in _services(cl):
        tasks = [t for t in s.tasks() if t["DesiredState"] == "running"]
        up = sum(1 for t in tasks if t["Status"]["State"] == "running")
        print(f"service {s.name}: {up}/{len(tasks)} running")
    for n in cl.networks.list(filters={"label": L_RUN}):
        print(f"network {n.name} ({n.attrs.get('Driver')})")
    return 0


def _services(cl: Any) -> list[Any]:
    """mrswarm's swarm services, or none when this engine is not a swarm manager."""
    import docker.errors
    try:
        return list(cl.services.list(filters={"label": L_RUN}))
    except docker.errors.APIError as e:
        if "not a swarm manager" in str(e) or "swarm" in str(e).lower():
            return []
        raise


def _find(cl: Any, name: str, run: str | None) -> Any:
    filters: dict[str, Any] = {"label": [L_RUN] + ([f"{L_RUN}={run}"] if run else [])}
    cands = [c for c in cl.containers.list(all=True, filters=filters)
             if c.name == name or c.id.startswith(name) or c.name.endswith(f"-{name}")]
    if not cands:
        raise DeployError(f"no mrswarm container matches {name!r}" + (f" in run {run}" if run else "")
                          + " (see `mrswarm deploy ps`)")
    if len(cands) > 1:
        raise DeployError(f"{name!r} matches {len(cands)} containers ({', '.join(c.name for c in cands)}): add --run")
    return cands[0]


def _logs(args: argparse.Namespace) -> int:
    cl = client()
    try:
        c = _find(cl, args.name, args.run)
        sys.stdout.write(c.logs(stdout=True, stderr=True, tail=args.tail if args.tail else "all").decode(errors="replace"))
        return 0
    except DeployError:
        if args.run:
            raise
    # a swarm service (e.g. `uav` of mrswarm-alpha)
    for s in _services(cl):
        if s.name == args.name or s.name.endswith(f"_{args.name}"):
            for chunk in s.logs(stdout=True, stderr=True, tail=args.tail or "all"):
                sys.stdout.write(chunk.decode(errors="replace"))
            return 0
    raise DeployError(f"no mrswarm container or service matches {args.name!r} (see `mrswarm deploy ps`)")


def _down(args: argparse.Namespace) -> int:
    from deploy import multicast

    cl = client()
    sel = [f"{L_RUN}={args.run}"] if args.run else [L_RUN]
    removed = 0
    for c in cl.containers.list(all=True, filters={"label": sel}):
        if c.labels.get(L_ROLE) == "sentinel" and not args.run:
            continue  # a swarm stack's: `mrswarm deploy swarm down` removes it
        c.remove(force=True)
        removed += 1
    nets = 0
    for n in cl.networks.list(filters={"label": sel}):
        if n.attrs.get("Driver") == "bridge":
            multicast.unseal(n.name)
            n.remove()
            nets += 1
    swept = multicast.sweep({n.name for n in cl.networks.list()})
    print(f"removed {removed} containers, {nets} networks, {swept} stale multicast rules")
    return 0


def _swarm_up_needs_mrswarm(args: argparse.Namespace) -> int:
    raise DeployError("`swarm up` builds its fleet from a scenario: run it as `mrswarm deploy swarm up`")


def _swarm_down(args: argparse.Namespace) -> int:
    from deploy import swarm

    print(json.dumps(swarm.down(args.swarm or "alpha", wait=args.wait, volumes=args.volumes)))
    return 0


def _swarm_seal(args: argparse.Namespace) -> int:
    from deploy import swarm
    from deploy.images import image_tag

    print(swarm.seal_node(client(), args.swarm or "alpha", args.image or image_tag()))
    return 0


def _cluster_root(args: argparse.Namespace) -> Path:
    return Path(args.root)


def _cluster_up(args: argparse.Namespace) -> int:
    from deploy import cluster
    from deploy.images import image_tag

    images = args.image or [image_tag()]
    cl = cluster.up(args.nodes, _cluster_root(args), args.prefix, images, log=lambda m: print(m, file=sys.stderr),
                    timeout=args.wait)
    print(json.dumps(cluster.status(Path(cl.root)), indent=2))
    print(f"manager: export DOCKER_HOST={cl.manager.docker_host}   (or: mrswarm deploy cluster exec 1 -- CMD)",
          file=sys.stderr)
    return 0


def _cluster_down(args: argparse.Namespace) -> int:
    from deploy import cluster

    out = cluster.down(_cluster_root(args), args.prefix)
    print(json.dumps(out, indent=2))
    return 1 if any(out["left"].values()) else 0


def _cluster_status(args: argparse.Namespace) -> int:
    from deploy import cluster

    print(json.dumps(cluster.status(_cluster_root(args)), indent=2))
    return 0


def _cluster_exec(args: argparse.Namespace) -> int:
    import subprocess

    from deploy import cluster

    argv = args.argv[1:] if args.argv[:1] == ["--"] else args.argv
    if not argv:
        raise DeployError("cluster exec: name the command after --")
    node = cluster.node_by_name(cluster.load(_cluster_root(args)), args.node)
    return subprocess.run(cluster.exec_argv(node, argv)).returncode


def _cluster_seal(args: argparse.Namespace) -> int:
    import subprocess

    from deploy import cluster
    from deploy.images import image_tag

    cl = cluster.load(_cluster_root(args))
    for node in cl.nodes:  # the manager first: it makes the overlay the workers' sentinels attach to
        cmd = [sys.executable, "-m", "deploy.cli", "swarm", "seal", "--swarm", args.swarm, "--image", args.image or image_tag()]
        res = subprocess.run(cluster.exec_argv(node, cmd), capture_output=True, text=True, timeout=120)
        if res.returncode != 0:
            raise DeployError(f"sealing {args.swarm} on {node.name} failed: {res.stderr.strip()}")
        print(f"{node.name}: {res.stdout.strip()}")
    return 0


def parser(swarm_up: Callable[[argparse.Namespace], int] | None = None) -> argparse.ArgumentParser:
    """The commands; ``swarm_up`` is the handler of ``swarm up``, given by the layer that reads scenarios."""
    from deploy.images import BASE_TAG, DEFAULT_MIRROR

    ap = argparse.ArgumentParser(prog="mrswarm deploy", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="COMMAND")
    p = sub.add_parser("base-image", help="make a Debian base image with debootstrap + docker import (skips if present)")
    p.add_argument("--tag", default=BASE_TAG)
    p.add_argument("--suite", default="bookworm", help="Debian suite; its python3 must be 3.11 (bookworm)")
    p.add_argument("--mirror", default=DEFAULT_MIRROR)
    p.add_argument("--force", action="store_true", help="remake it even if present")
    p.set_defaults(func=_base_image)
    p = sub.add_parser("build", help="build the stack image from a host-built wheelhouse (no network in the build)")
    p.add_argument("--tag", default=None, help="default mrswarm:<version>")
    p.add_argument("--base", default=None, help="BASE_IMAGE (default python:3.11-slim if present, else the debootstrap base)")
    p.add_argument("--full", action="store_true", help="also install matplotlib (plots inside the image)")
    p.set_defaults(func=_build)
    p = sub.add_parser("ps", help="containers, services and networks mrswarm runs, by label")
    p.set_defaults(func=_ps)
    p = sub.add_parser("logs", help="the log of one container (or swarm service)")
    p.add_argument("name", help="short name (uav3, router), full container name, id, or swarm service (uav)")
    p.add_argument("--run", default=None, help="run id (see `mrswarm deploy ps`) when several runs match")
    p.add_argument("--tail", type=int, default=0, help="only the last N lines")
    p.set_defaults(func=_logs)
    p = sub.add_parser("down", help="remove the containers and networks of runs (default: every run)")
    p.add_argument("--run", default=None, help="only this run")
    p.set_defaults(func=_down)

    p = sub.add_parser("swarm", help="the stack on Docker Swarm mode: up, seal, down")
    ssub = p.add_subparsers(dest="swarm_cmd", required=True, metavar="ACTION")
    q = ssub.add_parser("up", help="deploy router + N virtual UAV replicas as a stack")
    q.add_argument("--uavs", type=int, required=True, help="number of virtual UAV replicas")
    q.add_argument("--scenario", default="scenarios/coverage.yaml", help="scenario for swarm, origin, mission, fleet layout")
    q.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="scenario override (repeatable)")
    q.add_argument("--swarm", default=None, help="swarm name (default: the scenario's)")
    q.add_argument("--image", default=None)
    q.add_argument("--port", type=int, default=7447, help="router port published on the manager")
    q.add_argument("--max-per-node", type=int, default=0, help="at most this many UAV replicas per edge server")
    q.add_argument("--edge-per-node", action="store_true", help="an edge router on every edge server, linked to the "
                   "manager's; each UAV uses its own server's (docs/deploy.md)")
    q.add_argument("--autostart", action="store_true", help="take off and fly without waiting for commands")
    q.add_argument("--log-level", default="INFO")
    q.add_argument("--out", default=None, help="where stack.yml and fleet.json go (default build/swarm/<stack>)")
    q.add_argument("--init", action="store_true", help="`docker swarm init` first if this engine is in no swarm")
    q.add_argument("--dry-run", action="store_true", help="only write stack.yml and fleet.json")
    q.add_argument("--wait", type=float, default=180.0, help="seconds to wait for every replica to run")
    q.set_defaults(func=swarm_up or _swarm_up_needs_mrswarm)
    q = ssub.add_parser("seal", help="on another edge server: keep a sentinel of the overlay and drop multicast there")
    q.add_argument("--swarm", default=None)
    q.add_argument("--image", default=None)
    q.set_defaults(func=_swarm_seal)
    q = ssub.add_parser("down", help="remove the stack, its network, configs and this server's sentinel")
    q.add_argument("--swarm", default=None, help="swarm name (default alpha)")
    q.add_argument("--volumes", action="store_true", help="also remove the recorded data volume")
    q.add_argument("--wait", type=float, default=120.0)
    q.set_defaults(func=_swarm_down)

    from deploy.cluster import DEFAULT_PREFIX, DEFAULT_ROOT

    p = sub.add_parser("cluster", help="a test cluster on this machine: swarm nodes in network namespaces (needs root)")
    csub = p.add_subparsers(dest="cluster_cmd", required=True, metavar="ACTION")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--root", default=str(DEFAULT_ROOT), help="state, data roots and sockets of the nodes")
    common.add_argument("--prefix", default=DEFAULT_PREFIX, help="names of the namespaces (<prefix>n1.., <prefix>hub)")
    q = csub.add_parser("up", parents=[common], help="N docker engines in namespaces, one swarm, images loaded")
    q.add_argument("--nodes", type=int, default=3)
    q.add_argument("--image", action="append", default=[], help="image to load into every node (repeatable; "
                   "default mrswarm:<version>)")
    q.add_argument("--wait", type=float, default=60.0, help="seconds to wait for the engines and the swarm")
    q.set_defaults(func=_cluster_up)
    q = csub.add_parser("down", parents=[common], help="stop the nodes and remove everything (also after a failed up)")
    q.set_defaults(func=_cluster_down)
    q = csub.add_parser("status", parents=[common], help="the nodes, their docker sockets and swarm state")
    q.set_defaults(func=_cluster_status)
    q = csub.add_parser("exec", parents=[common], help="run a command on a node (its namespaces, DOCKER_HOST set)")
    q.add_argument("node", help="node number (1 is the manager) or name")
    q.add_argument("argv", nargs=argparse.REMAINDER, help="-- COMMAND ...")
    q.set_defaults(func=_cluster_exec)
    q = csub.add_parser("seal", parents=[common], help="a sentinel and no multicast on the swarm's overlay, every node")
    q.add_argument("--swarm", default="alpha")
    q.add_argument("--image", default=None)
    q.set_defaults(func=_cluster_seal)
    return ap


def main(argv: list[str] | None = None, swarm_up: Callable[[argparse.Namespace], int] | None = None) -> int:
    args = parser(swarm_up).parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except DeployError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
