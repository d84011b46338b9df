"""A virtual UAV as one replica of a Docker Swarm service (``deploy/stack.yml``).

Every replica runs this with the same fleet file: a JSON list of the per-UAV configs the
scenario produced (the same ``VirtualUavConfig`` JSON a UAV process or container gets).
Swarm numbers the replicas 1..N (``{{.Task.Slot}}``, passed as ``MRSWARM_SLOT``), so replica
``k`` flies the k-th config: unique UAV ids without any coordination. It then listens on its
own address on the overlay network (the one it uses to reach the router: gossip must
advertise a locator the other edge servers can reach) and runs the same loop as
``python -m uav_stack.virtual_uav``.
"""

from __future__ import annotations

import argparse
import logging
import os
import socket
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from msgspec.structs import replace

from deploy.plan import edge_service
from groundfloor.errors import MrswarmError
from groundfloor.net import Addr
from groundfloor.process import setup_logging
from groundfloor.schema import ConfigError, decode_json
from uav_stack.config import VirtualUavConfig
from uav_stack.runtime import StopFlag, run_virtual_uav

log = logging.getLogger(__name__)


class SlotError(ValueError, MrswarmError):
    pass


def load_fleet(path: str | Path) -> list[VirtualUavConfig]:
    """The fleet file: a JSON list of UAV configs (:class:`~groundfloor.schema.ConfigError` names a bad field)."""
    return decode_json(Path(path).read_bytes(), list[VirtualUavConfig])


def pick(fleet: Sequence[VirtualUavConfig], slot: int) -> VirtualUavConfig:
    if not 1 <= slot <= len(fleet):
        raise SlotError(f"task slot {slot} has no UAV: the fleet file holds {len(fleet)} (redeploy with --uavs to scale)")
    return fleet[slot - 1]


def endpoint_host(endpoint: str) -> Addr:
    """``tcp/router:7447`` -> ("router", 7447)."""
    addr = endpoint.split("/", 1)[1].split("#", 1)[0]
    host, _, port = addr.rpartition(":")
    return host.strip("[]"), int(port)


def own_address_towards(host: str, port: int, timeout: float, stop: StopFlag) -> str:
    """The local IP this replica uses to reach ``host`` (waits, bounded, for the DNS entry)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.connect((socket.gethostbyname(host), port))  # UDP connect: a route lookup, no packet
                return str(s.getsockname()[0])
        except OSError as exc:
            if time.monotonic() > deadline or stop.stopped:
                raise SlotError(f"cannot resolve or route to {host}: {exc}") from None
            time.sleep(0.5)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python3 -m deploy.swarm_uav", description=__doc__.splitlines()[0])
    ap.add_argument("--fleet", required=True, help="JSON list of VirtualUavConfig (one per task slot)")
    ap.add_argument("--slot", type=int, default=None, help="task slot (default: $MRSWARM_SLOT)")
    ap.add_argument("--listen-port", type=int, default=7447)
    ap.add_argument("--log-level", default="INFO")
    args = ap.parse_args(argv)
    stop = StopFlag().install()
    setup_logging(args.log_level)
    try:
        slot = args.slot if args.slot is not None else int(os.environ.get("MRSWARM_SLOT", ""))
        cfg = pick(load_fleet(args.fleet), slot)
        net = cfg.agent.network
        if not net.endpoints:
            raise SlotError("the fleet's network config names no endpoint")
        edges = tuple(e for e in os.environ.get("MRSWARM_EDGES", "").split(",") if e)
        edge = edge_service(os.environ.get("MRSWARM_NODE", ""), edges)
        if edge != "router":  # this server has an edge router of its own: use it (docs/deploy.md)
            net = replace(net, endpoints=tuple(e.replace("/router:", f"/{edge}:", 1) for e in net.endpoints))
            cfg = replace(cfg, agent=replace(cfg.agent, network=net))
        host, port = endpoint_host(net.endpoints[0])
        ip = own_address_towards(host, port, 60.0, stop)
    except (SlotError, ConfigError, ValueError, OSError) as exc:
        log.error("%s", exc)
        return 2
    if net.mode == "peer":
        cfg = replace(cfg, agent=replace(cfg.agent, network=replace(net, listen=(f"tcp/{ip}:{args.listen_port}",))))
    rec = cfg.agent.record_dir
    if rec:
        Path(rec).mkdir(parents=True, exist_ok=True)
    log.info("slot %d: UAV %d on %s, rendezvous %s", slot, cfg.agent.uav, ip, net.endpoints[0])
    return run_virtual_uav(cfg, stop)


if __name__ == "__main__":
    sys.exit(main())
