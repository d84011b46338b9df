"""The process runtime: every virtual UAV is its own OS process on this machine.

Each UAV process runs a virtual FCU and the agent (``python -m uav_stack.virtual_uav``),
with its own Zenoh session and a real MAVLink/UDP link between the two. A UAV whose flight
controller is external (a real autopilot, a SITL) gets only its agent (``mrswarm agent``). The runtime also
starts what connectivity needs on 127.0.0.1 (a discovery server and/or a rendezvous router). Every child (UAVs,
edge router, discovery server) gets its own process group and ``PR_SET_PDEATHSIG`` (SIGTERM) before it execs, so
it dies with the runner even when the runner is killed with SIGKILL, and :meth:`ProcessRuntime.stop` escalates
from SIGTERM to SIGKILL, so nothing outlives the run. :meth:`ProcessRuntime.signal` and
:meth:`ProcessRuntime.restart` let a supervisor or a fault schedule act on one child.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from msgspec.structs import replace

from discovery.netutil import free_port, wait_tcp
from discovery.options import DiscoveryService, ProxyOptions, pose_feed_argv
from swarmnet.interest import Interest
from swarmnet.security.credentials import Credentials
from uav_stack.config import AgentConfig, NetworkConfig, PoseFeed, VirtualUavConfig, ZenohMode

log = logging.getLogger(__name__)

_PR_SET_PDEATHSIG = 1
try:  # resolved once in the parent: the child between fork and exec only calls it
    _prctl = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None
except (OSError, AttributeError):
    _prctl = None


def die_with_parent_preexec(parent: int, sig: int = signal.SIGTERM) -> Callable[[], None]:
    """A ``preexec_fn`` that makes the child get ``sig`` when ``parent`` (this process) dies.

    Runs in the child between fork and exec, so no start-up race: if the parent is already gone
    by then, the child exits at once instead of running as an orphan.
    """

    def set_pdeathsig() -> None:
        if _prctl is not None:
            _prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
        if os.getppid() != parent:
            os._exit(1)

    return set_pdeathsig


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


def _death_signal(name: str) -> int:
    """What a child gets when the runner dies: a UAV SIGTERM (it writes its last records, then exits,
    with a watchdog of its own), the edge services SIGKILL (nothing to save; a Zenoh router's
    shutdown can wait on its peers)."""
    return signal.SIGTERM if name.startswith("uav") else signal.SIGKILL


def wait_file(path: Path, timeout: float, proc: subprocess.Popen[bytes] | None = None) -> None:
    """Wait until ``path`` exists (a service's sign of life; bounded)."""
    deadline = time.monotonic() + timeout
    while not path.exists():
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"router exited with code {proc.returncode} before writing {path.name}")
        if time.monotonic() > deadline:
            raise RuntimeError(f"no {path} after {timeout:.0f} s")
        time.sleep(0.05)


@dataclass
class Child:
    name: str
    proc: subprocess.Popen[bytes]
    log_path: Path
    argv: list[str]
    starts: int = 1


class ProcessRuntime:
    name = "process"

    def __init__(self, run_dir: Path, python: str = sys.executable, log_level: str = "INFO"):
        self.run_dir = run_dir
        self.python = python
        self.log_level = log_level
        self.children: dict[str, Child] = {}
        self.keys: Path | None = None
        self.identities: dict[str, Path] = {}  # other swarms' key directories (the discovery server checks their tokens)
        self.interest: Interest | None = None
        self.feed_window: float | None = None  # s, the edge routers' pose-feed window (None: their default)
        self._py, self._env = child_python(python)
        (run_dir / "logs").mkdir(parents=True, exist_ok=True)
        (run_dir / "config").mkdir(parents=True, exist_ok=True)

    # ---- connectivity ---------------------------------------------------------------------
    def start_network(self, mode: ZenohMode = "peer", pose_feed: PoseFeed = "direct", swarm: str = "*",
                      connectivity: str = "rendezvous", discovery: DiscoveryService | None = None,
                      keys: Path | None = None, extra_keys: dict[str, str] | None = None,
                      interest: Interest | None = None, feed_window: float | None = None,
                      extra_identities: dict[str, Path] | None = None) -> NetworkConfig:
        """Start what the nodes need on 127.0.0.1 and return how they reach it.

        ``rendezvous``: a Zenoh router (gossip rendezvous; data router for client mode).
        ``discovery``: a discovery server (beacon relay, docs/discovery.md), plus the edge
        router (pose feed, and the way in for ground stations).
        ``keys``: the swarm's key directory: every link mutual TLS under the roster's access
        control (docs/security.md); None: plain TCP. ``extra_keys``: more swarms the discovery
        server serves (swarm -> key), for swarms sharing the airspace (:meth:`add_swarm`), and
        ``extra_identities`` their key directories (their beacons bound to identities too).
        """
        self.keys = keys
        self.identities = dict(extra_identities or {})
        self.interest = interest  # spatial interest of every edge router's pose feed (docs/scale.md)
        self.feed_window = feed_window
        if connectivity == "discovery":
            net = self._start_discovery(swarm, pose_feed, discovery or DiscoveryService(), extra_keys or {})
            return replace(net, interest=interest)
        endpoint = self._start_router(pose_feed, swarm)
        return NetworkConfig(connectivity="rendezvous", endpoints=(endpoint,), mode=mode, listen=(f"{self._scheme}/127.0.0.1:0",),
                             pose_feed=pose_feed, security=self._credentials(), interest=interest)

    @property
    def _scheme(self) -> str:
        return "tls" if self.keys is not None else "tcp"

    def _credentials(self, keys: Path | None = None) -> Credentials | None:
        """What every UAV process is given (each speaks as its own uav-<id>.<swarm>)."""
        keys = keys or self.keys
        return Credentials(keys=str(keys)) if keys is not None else None

    def _start_router(self, pose_feed: str, swarm: str, name: str = "router", keys: Path | None = None) -> str:
        keys = keys or self.keys
        port = free_port()
        endpoint = f"{'tls' if keys is not None else 'tcp'}/127.0.0.1:{port}"
        argv = [*self._py, "-m", "discovery.rendezvous", "--listen", endpoint]
        stats = self.run_dir / "logs" / f"{name}.stats.json"
        if keys is not None:  # as edge.<swarm>; counts what it refuses in logs/<name>.stats.json
            argv += ["--keys", str(keys), "--stats", str(stats)]
        else:
            argv += ["--insecure"]
        if pose_feed == "edge":
            argv += pose_feed_argv(swarm, self.feed_window)
            if self.interest is not None:
                argv += self.interest.argv()
        self._spawn(name, argv)
        router = self.children[name]
        if keys is not None:  # a bare TCP probe would count as a refused handshake: wait for its first counters
            wait_file(stats, timeout=20.0, proc=router.proc)
        else:
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
        # secured: every swarm's beacons bound to identities (its key directory's roster and beacon key)
        dirs = ([self.keys] if self.keys else []) + list(self.identities.values())
        identities = [a for d in dirs for a in ("--identities", str(d))]
        self._spawn("discovery", [self.python, "-m", "discovery.server", "--listen", server, "--keys", str(keys),
                                  "--ttl", str(service.ttl), "--rate", "5000", *identities])  # every node shares 127.0.0.1
        # (no --die-with-parent: _spawn arranges SIGKILL on the runner's death for every service)
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
        return NetworkConfig(connectivity="discovery", endpoints=endpoints, mode="peer", listen=(f"{self._scheme}/127.0.0.1:0",),
                             pose_feed=pose_feed, discovery=ProxyOptions(server=server, key=key, period=service.period),
                             security=self._credentials())

    # ---- more swarms, the world service (docs/world.md) -----------------------------------------
    def add_swarm(self, swarm: str, net: NetworkConfig, discovery_key: str | None, keys: Path | None) -> NetworkConfig:
        """Another swarm in the same airspace: its own edge router (``router-<swarm>``, under its own
        key directory ``keys``) and, with discovery, the run's discovery server with its own key
        (given to :meth:`start_network` in ``extra_keys``). Returns how its UAVs reach it."""
        endpoint = self._start_router(net.pose_feed, swarm, name=f"router-{swarm}", keys=keys)
        scheme = "tls" if keys is not None else "tcp"
        d = net.discovery
        return replace(net, endpoints=(endpoint,), listen=(f"{scheme}/127.0.0.1:0",), security=self._credentials(keys),
                       discovery=replace(d, key=discovery_key, key_file=None) if d is not None and discovery_key else d)

    def start_world(self, config: Path) -> None:
        """The world service beside the edge routers; it joins each swarm as its router's client."""
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

    def start_agent(self, cfg: AgentConfig) -> None:
        """The agent of a UAV whose flight controller is external: ``mrswarm agent --config`` against
        ``cfg.fcu``, a child like a UAV process (``uav<id>``: its own process group, dies with the runner)."""
        path = self.run_dir / "config" / f"uav{cfg.uav}.json"
        path.write_text(cfg.to_json())
        path.chmod(0o600)  # it holds the discovery key
        argv = [*self._py, "-m", "mrswarm", "agent", "--config", str(path), "--log-level", self.log_level]
        if cfg.network.security is None:  # the run asked for it by name (network.security: off)
            argv.append("--insecure")
        self._spawn(f"uav{cfg.uav}", argv)

    def _spawn(self, name: str, argv: list[str]) -> None:
        log_path = self.run_dir / "logs" / f"{name}.log"
        with contextlib.ExitStack() as stack:  # the child keeps its own descriptor
            try:
                out: Any = stack.enter_context(open(log_path, "ab"))
            except OSError as exc:  # a full or read-only disk must not stop a flight process from starting
                log.warning("%s: cannot open %s (%s); its output is discarded", name, log_path, exc.strerror)
                out = subprocess.DEVNULL
            proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                                    env=self._env, preexec_fn=die_with_parent_preexec(os.getpid(), _death_signal(name)))
        old = self.children.get(name)
        self.children[name] = Child(name, proc, log_path, argv, old.starts + 1 if old else 1)

    # ---- acting on one child (supervisor, fault schedule) --------------------------------------
    def signal(self, name: str, sig: int) -> bool:
        """Send ``sig`` to one child's process group; False if it is not running."""
        c = self.children.get(name)
        if c is None or c.proc.poll() is not None:
            return False
        try:
            os.killpg(c.proc.pid, sig)
        except ProcessLookupError:
            return False
        return True

    def restart(self, name: str, grace: float = 3.0) -> None:
        """Start ``name`` again with its first command line (stopping it first if it still runs)."""
        c = self.children[name]
        if c.proc.poll() is None:
            self._terminate(c, grace)
        self._spawn(name, c.argv)

    def exited(self) -> dict[str, int]:
        """Children that have exited, with their return codes."""
        return {n: c.proc.returncode for n, c in self.children.items() if c.proc.poll() is not None}

    def pids(self) -> dict[str, int]:
        return {n: c.proc.pid for n, c in self.children.items()}

    def stop(self, grace: float = 5.0) -> dict[str, int]:
        """SIGTERM every UAV, then the world service, the routers and the discovery server; SIGKILL whatever is
        left after ``grace``."""
        helpers = [n for n in self.children if n == "world" or n.startswith("router")] + \
            [n for n in ("discovery",) if n in self.children]
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
            if c.proc.poll() is None:
                try:
                    os.killpg(c.proc.pid, signal.SIGCONT)  # a stopped child cannot act on SIGTERM
                except ProcessLookupError:
                    pass
            try:
                c.proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("%s did not exit on SIGTERM; killing it", n)
                self._kill(c)
        return {n: c.proc.returncode for n, c in self.children.items()}

    def _terminate(self, c: Child, grace: float) -> None:
        for sig in (signal.SIGTERM, signal.SIGCONT):
            try:
                os.killpg(c.proc.pid, sig)
            except ProcessLookupError:
                return
        try:
            c.proc.wait(grace)
        except subprocess.TimeoutExpired:
            self._kill(c)

    @staticmethod
    def _kill(c: Child) -> None:
        try:
            os.killpg(c.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        try:
            c.proc.wait(5)
        except subprocess.TimeoutExpired:
            log.error("%s (pid %d) does not die on SIGKILL", c.name, c.proc.pid)
