"""The process runtime: every virtual UAV is its own OS process on this machine.

Each UAV process runs a virtual FCU and the agent (``python -m uav_stack.virtual_uav``),
with its own Zenoh session and a real MAVLink/UDP link between the two. The runtime also
starts what connectivity needs on 127.0.0.1 (a discovery server and/or a rendezvous router). Children get their own
process group and ``PR_SET_PDEATHSIG``, and :meth:`ProcessRuntime.stop` escalates from
SIGTERM to SIGKILL, so nothing outlives the run.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from discovery.netutil import free_port, wait_tcp
from discovery.options import DiscoveryService, ProxyOptions
from uav_stack.config import NetworkConfig, PoseFeed, VirtualUavConfig, ZenohMode

log = logging.getLogger(__name__)


def child_python(python: str = sys.executable) -> tuple[list[str], dict[str, str]]:
    """argv prefix and environment for lean child Python processes.

    ``-S`` skips ``site``: every ``.pth`` hook of the host's site-packages (a machine can
    carry several, each importing modules into every Python process; 5 MB of RSS on our
    machines) and the user site. The import path is handed over explicitly instead: the
    directory holding our packages (an editable checkout or site-packages) and the
    site-packages directories, in the parent's order.
    """
    import site

    import uav_stack

    roots = [str(Path(uav_stack.__file__).resolve().parents[1])]
    for d in site.getsitepackages() + [site.getusersitepackages()]:
        if d not in roots and Path(d).is_dir():
            roots.append(d)
    extra = os.environ.get("PYTHONPATH")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(([extra] if extra else []) + roots), PYTHONUNBUFFERED="1")
    return [python, "-S"], env


@dataclass
class Child:
    name: str
    proc: subprocess.Popen[bytes]
    log_path: Path


class ProcessRuntime:
    name = "process"

    def __init__(self, run_dir: Path, python: str = sys.executable, log_level: str = "INFO"):
        self.run_dir = run_dir
        self.python = python
        self.log_level = log_level
        self.children: dict[str, Child] = {}
        self._py, self._env = child_python(python)
        (run_dir / "logs").mkdir(parents=True, exist_ok=True)
        (run_dir / "config").mkdir(parents=True, exist_ok=True)

    # ---- connectivity ---------------------------------------------------------------------
    def start_network(self, mode: ZenohMode = "peer", pose_feed: PoseFeed = "direct", swarm: str = "*",
                      connectivity: str = "rendezvous", discovery: DiscoveryService | None = None,
                      extra_keys: dict[str, str] | None = None) -> NetworkConfig:
        """Start what the nodes need on 127.0.0.1 and return how they reach it.

        ``rendezvous``: a Zenoh router (gossip rendezvous; data router for client mode).
        ``discovery``: a discovery server (beacon relay, docs/discovery.md), plus the edge
        router (pose feed, and the way in for ground stations). ``extra_keys``: more swarms the
        discovery server serves (swarm -> key), for swarms sharing the airspace.
        """
        if connectivity == "discovery":
            return self._start_discovery(swarm, pose_feed, discovery or DiscoveryService(), extra_keys or {})
        endpoint = self._start_router(pose_feed, swarm)
        return NetworkConfig(connectivity="rendezvous", endpoints=(endpoint,), mode=mode, listen=("tcp/127.0.0.1:0",),
                             pose_feed=pose_feed)

    def _start_router(self, pose_feed: str, swarm: str) -> str:
        port = free_port()
        endpoint = f"tcp/127.0.0.1:{port}"
        argv = [*self._py, "-m", "discovery.rendezvous", "--listen", endpoint]
        if pose_feed == "edge":
            argv += ["--feed", swarm]
        self._spawn("router", argv)
        router = self.children["router"]
        wait_tcp("127.0.0.1", port, timeout=20.0, alive=lambda: router.proc.poll() is None,
                 what=f"the router (log: {router.log_path})")
        return endpoint

    def _start_discovery(self, swarm: str, pose_feed: PoseFeed, service: DiscoveryService,
                         extra_keys: dict[str, str]) -> NetworkConfig:
        from discovery.client import QueryTimeout, query_registry
        from discovery.protocol import new_key

        key = service.key or new_key()  # a fresh key per run unless the scenario sets one
        keys = self.run_dir / "config" / "discovery.keys"
        keys.write_text("".join(f"{s} {k}\n" for s, k in {swarm: key, **extra_keys}.items()))
        keys.chmod(0o600)
        server = f"127.0.0.1:{free_port(socket.SOCK_DGRAM)}"
        self._spawn("discovery", [self.python, "-m", "discovery.server", "--listen", server, "--keys", str(keys),
                                  "--ttl", str(service.ttl), "--rate", "5000",  # every node shares 127.0.0.1
                                  "--die-with-parent"])
        deadline = time.monotonic() + 20.0
        while True:
            proc = self.children["discovery"].proc
            if proc.poll() is not None:
                raise RuntimeError(f"discovery server exited with code {proc.returncode}"
                                   f" (see {self.children['discovery'].log_path})")
            try:
                query_registry(server, swarm, key, timeout=0.2, attempts=1)
                break
            except QueryTimeout:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"discovery server on {server} does not answer after 20 s") from None
        # The edge router runs beside the discovery server, and every node keeps one static link
        # to it: it carries the edge pose feed (if on) and is the way in for ground stations and
        # other tools (`mrswarm gcs`, `mrswarm netem set`), which join as its Zenoh clients.
        # Routing is interest-based, so it carries nothing until someone subscribes through it;
        # UAV-to-UAV data flows peer to peer over the links discovery introduced.
        endpoints = (self._start_router(pose_feed, swarm),)
        return NetworkConfig(connectivity="discovery", endpoints=endpoints, mode="peer", listen=("tcp/127.0.0.1:0",),
                             pose_feed=pose_feed, discovery=ProxyOptions(server=server, key=key, period=service.period))

    # ---- the world service (docs/world.md) ----------------------------------------------------
    def start_world(self, config: Path) -> None:
        """The world service beside the edge router; it joins the swarms as the router's client."""
        self._spawn("world", [*self._py, "-m", "world", "--config", str(config), "--log-level", self.log_level,
                              "--die-with-parent"])

    # ---- UAVs ------------------------------------------------------------------------------
    def start_uav(self, cfg: VirtualUavConfig) -> None:
        path = self.run_dir / "config" / f"uav{cfg.agent.uav}.json"
        path.write_text(cfg.to_json())
        self._spawn(
            f"uav{cfg.agent.uav}",
            [*self._py, "-m", "uav_stack.virtual_uav", "--config", str(path), "--log-level", self.log_level],
        )

    def _spawn(self, name: str, argv: list[str]) -> None:
        log_path = self.run_dir / "logs" / f"{name}.log"
        with open(log_path, "ab") as out:  # the child keeps its own descriptor
            proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                    start_new_session=True, env=self._env)
        self.children[name] = Child(name, proc, log_path)

    def exited(self) -> dict[str, int]:
        """Children that have exited, with their return codes."""
        return {n: c.proc.returncode for n, c in self.children.items() if c.proc.poll() is not None}

    def pids(self) -> dict[str, int]:
        return {n: c.proc.pid for n, c in self.children.items()}

    def stop(self, grace: float = 5.0) -> dict[str, int]:
        """SIGTERM every UAV, then the world service, the router and the discovery server; SIGKILL whatever is left
        after ``grace``."""
        helpers = [n for n in ("world", "router", "discovery") if n in self.children]
        order = [n for n in self.children if n not in helpers] + helpers
        for n in order:
            c = self.children[n]
            if c.proc.poll() is None:
                try:
                    os.killpg(c.proc.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + grace
        for n in order:
            c = self.children[n]
            try:
                c.proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("%s did not exit on SIGTERM; killing it", n)
                try:
                    os.killpg(c.proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                c.proc.wait(5)
        return {n: c.proc.returncode for n, c in self.children.items()}
