"""The process runtime: every virtual UAV is its own OS process on this machine.

Each UAV process runs a virtual FCU and the agent (``python -m uav_stack.virtual_uav``),
with its own Zenoh session and a real MAVLink/UDP link between the two. A UAV whose flight
controller is external (a real autopilot, a SITL) gets only its agent (``mrswarm agent``). The runtime also
starts the network plan's services on 127.0.0.1 (``deploy/plan.py``: the discovery server, each swarm's edge
router), as every runtime places that plan. Every child (UAVs,
edge router, discovery server) gets its own process group and ``PR_SET_PDEATHSIG`` (SIGTERM) before it execs, so
it dies with the runner even when the runner is killed with SIGKILL, and :meth:`ProcessRuntime.stop` escalates
from SIGTERM to SIGKILL, so nothing outlives the run. :meth:`ProcessRuntime.signal` and
:meth:`ProcessRuntime.restart` let a supervisor or a fault schedule act on one child.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from deploy.plan import LocalSite, NetworkPlan, PlacedService, SwarmPlan
from discovery.netutil import wait_tcp
from discovery.options import DiscoveryServerOptions, RouterOptions
from groundfloor.files import write_atomic
from groundfloor.process import die_with_parent_preexec
from uav_stack.config import AgentConfig, NetworkConfig, VirtualUavConfig

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


def _death_signal(name: str) -> int:
    """What a child gets when the runner dies: a UAV SIGTERM (it writes its last records, then exits,
    with a watchdog of its own), the edge services SIGKILL (nothing to save; a Zenoh router's
    shutdown can wait on its peers)."""
    return signal.SIGTERM if name.startswith(("uav", "pool")) else signal.SIGKILL


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
        self._py, self._env = child_python(python)
        (run_dir / "logs").mkdir(parents=True, exist_ok=True)
        (run_dir / "config").mkdir(parents=True, exist_ok=True)

    # ---- the network: routers, discovery server (deploy/plan.py) --------------------------------
    def start_network(self, plan: NetworkPlan) -> dict[str, NetworkConfig]:
        """Start the plan's services on 127.0.0.1 (:class:`~deploy.plan.LocalSite`), in its order, each
        waited for; return how each swarm's UAVs reach them.

        The discovery server (connectivity ``discovery``) gets every swarm's key in a file of the run
        (``config/discovery.keys``, not on a command line) and, secured, their key directories; each
        swarm's edge router (``router``, ``router-<swarm>``) its own key directory, and its counters go to
        ``logs/<name>.stats.json``, whose first write says it is up.
        """
        placed = plan.place(LocalSite(self.run_dir))
        for svc in placed.services:
            if isinstance(svc.options, DiscoveryServerOptions):
                self._start_discovery(svc, svc.options, plan.swarms[0])
            else:
                self._start_router(svc, svc.options)
        return placed.uav_networks({s.name: s.host for s in placed.services})

    def _start_router(self, svc: PlacedService, options: RouterOptions) -> None:
        self._spawn(svc.name, [*self._py, *svc.argv()])
        router = self.children[svc.name]
        if options.stats is not None:  # a bare TCP probe would count as a refused handshake: wait for its first counters
            wait_file(Path(options.stats), timeout=20.0, proc=router.proc)
        else:
            wait_tcp(svc.host, svc.port, timeout=20.0, alive=lambda: router.proc.poll() is None,
                     what=f"the router (log: {router.log_path})")

    def _start_discovery(self, svc: PlacedService, options: DiscoveryServerOptions, swarm: SwarmPlan) -> None:
        from discovery.client import QueryTimeout, query_registry

        if options.keys_file is not None:
            write_atomic(options.keys_file, options.keys_text(), private=True)
        # (no --die-with-parent: _spawn arranges SIGKILL on the runner's death for every service)
        self._spawn(svc.name, [*self._py, *svc.argv()])
        child = self.children[svc.name]
        deadline = time.monotonic() + 20.0
        while True:
            if child.proc.poll() is not None:
                raise RuntimeError(f"discovery server exited with code {child.proc.returncode} (see {child.log_path})")
            try:
                query_registry(options.listen, swarm.name, swarm.discovery_key or "", timeout=0.2, attempts=1)
                return
            except QueryTimeout:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"discovery server on {options.listen} does not answer after 20 s") from None

    # ---- the world service (docs/world.md) -----------------------------------------------------
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

    def start_pool(self, name: str, cfgs: list[VirtualUavConfig], number: int, lockstep_epoch: float | None = None) -> None:
        """Several virtual UAVs in one process (``python -m uav_stack.pool``): one virtual FCU, an agent
        each, one Zenoh session as ``pool-<number>``."""
        from uav_stack.pool import PoolConfig

        path = self.run_dir / "config" / f"{name}.json"
        write_atomic(path, PoolConfig(uavs=tuple(cfgs), number=number, lockstep_epoch=lockstep_epoch).to_json(), private=True)
        self._spawn(name, [*self._py, "-m", "uav_stack.pool", "--config", str(path), "--log-level", self.log_level])

    def start_agent(self, cfg: AgentConfig) -> None:
        """The agent of a UAV whose flight controller is external: ``mrswarm agent --config`` against
        ``cfg.fcu``, a child like a UAV process (``uav<id>``: its own process group, dies with the runner)."""
        path = self.run_dir / "config" / f"uav{cfg.uav}.json"
        write_atomic(path, cfg.to_json(), private=True)  # it holds the discovery key
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
        """SIGTERM every UAV and wait for them, then the world service, the routers and the discovery server (as the
        container runtime does: a UAV's last words, its final behaviour report, still reach the edge); SIGKILL
        whatever is left ``grace`` s after its own SIGTERM."""
        helpers = [n for n in self.children if n == "world" or n.startswith("router")] + \
            [n for n in ("discovery",) if n in self.children]
        uavs = [n for n in self.children if n not in helpers]
        for group in (uavs, helpers):
            for n in group:
                c = self.children[n]
                if c.proc.poll() is None:
                    try:
                        os.killpg(c.proc.pid, signal.SIGTERM)
                    except ProcessLookupError:
                        pass
            deadline = time.monotonic() + grace
            for n in group:
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
