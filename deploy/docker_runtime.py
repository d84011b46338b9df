"""The container runtime: every virtual UAV is its own Docker container.

It mirrors :class:`deploy.process_runtime.ProcessRuntime` (``start_network``, ``start_uav``,
``exited``, ``pids``, ``stop``), so the experiment runner drives either. Per run it creates:

* one user-defined bridge network ``mrs-<run>-net``, internal (no route out of the host) and
  with multicast and broadcast made impossible (``deploy/multicast.py``), unless the
  scenario says ``docker.multicast: allow`` (a plain LAN bridge);
* the services of the run's network plan (``deploy/plan.py``: the discovery server, the edge
  router), one container each, with the same options as the process runtime's;
* one container per virtual UAV, running ``python3 -m uav_stack.virtual_uav --config ...``
  with the same config JSON as a UAV process, on its own IP, with the scenario's CPU and
  memory limits, no capabilities, a read-only root file system, and IPv6 off.

The run folder is bind-mounted at the same path in every UAV container, so the recorded
trajectories and counters land where the runner analyses them, owned by the invoking
user. On a secured run (docs/security.md) each container gets only its own credentials: a
bundle (CA certificate, roster, its key pair) made per container in ``<run>/secrets/`` and
bind-mounted read-only at ``/run/secrets``; the run's key directory and the other bundles are
hidden from the UAV containers (an empty tmpfs over them). Nothing is baked into the image.
Containers and network carry ``org.mrswarm.*`` labels (run, swarm, role, UAV) and names
``mrs-<run>-<name>``. :meth:`DockerRuntime.stop` saves every container's log into ``<run>/logs/``
and removes containers, network and rules, also after Ctrl-C; for a runner killed outright,
``mrswarm deploy down`` removes whatever carries the labels.
"""

from __future__ import annotations

import json
import logging
import os
import re
import secrets
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from msgspec.structs import replace

from deploy import multicast
from deploy.dockerutil import L_RUN, DeployError, client, labels
from deploy.plan import CONTAINERS, KEYS_IN_CONTAINER, NetworkPlan
from deploy.settings import ContainerSettings
from discovery.netutil import wait_tcp
from discovery.options import DiscoveryServerOptions
from groundfloor.schema import to_builtins
from swarmnet.security.credentials import Credentials
from swarmnet.security.identity import NodeName
from uav_stack.config import AgentConfig, NetworkConfig, VirtualUavConfig

log = logging.getLogger(__name__)

EXITED_POLL_S = 1.0  # exited() asks the engine at most this often


def popen_exit_code(code: int) -> int:
    """A container's exit code in Popen's convention, as the process runtime reports it: the
    engine says 128 + N for a main process that signal N ended (137 for SIGKILL), Popen -N."""
    if 128 < code < 128 + 65:
        try:
            return -signal.Signals(code - 128).value
        except ValueError:
            pass
    return code


def wait_discovery(server: str, swarm: str, key: str, timeout: float, alive: Callable[[], bool]) -> None:
    """Wait until the discovery server answers a registry query (bounded)."""
    from discovery.client import QueryTimeout, query_registry

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not alive():
            raise RuntimeError(f"the discovery server on {server} exited before answering")
        try:
            query_registry(server, swarm, key, timeout=0.3, attempts=1)
            return
        except QueryTimeout:
            continue
    raise RuntimeError(f"the discovery server on {server} does not answer after {timeout:.0f} s")


PIDS_LIMIT = 256  # per container
SERVICE_CPUS = 1.0  # limit of each infrastructure container (router, discovery), cores
SERVICE_MEMORY_MB = 512


@dataclass
class Box:
    name: str  # short name: router, uav3
    container: Any
    role: str
    ip: str = ""


def run_id_for(run_dir: Path) -> str:
    base = re.sub(r"[^a-zA-Z0-9_.-]", "-", run_dir.name)[-40:].strip("-.") or "run"
    return f"{base}-{secrets.token_hex(2)}"


class DockerRuntime:
    name = "docker"

    def __init__(self, run_dir: Path, log_level: str = "INFO", settings: ContainerSettings | None = None,
                 swarm: str = "*"):
        self.run_dir = run_dir.resolve()
        self.log_level = log_level
        self.settings = settings or ContainerSettings()
        self.swarm = swarm
        self.run = run_id_for(run_dir)
        self.docker = client()
        from deploy.images import image_tag

        self.image = self.settings.image or image_tag()
        self._check_image()
        self._warn_if_stale()
        ncpu = int(self.docker.info().get("NCPU", 0) or 0)
        for what, cpus in (("docker.cpus", self.settings.cpus), ("service cpus", SERVICE_CPUS)):
            if ncpu and cpus > ncpu:
                raise DeployError(f"{what} = {cpus} but the docker host has {ncpu} CPUs")
        if self.settings.multicast == "drop":
            multicast.check_available()
        self.boxes: dict[str, Box] = {}
        self.keys: Path | None = None  # the swarm's key directory (host side); None: plain TCP
        self.network: Any = None
        self.sealed = False
        self._exited: dict[str, int] = {}
        self._exited_at = 0.0
        (self.run_dir / "logs").mkdir(parents=True, exist_ok=True)
        (self.run_dir / "config").mkdir(parents=True, exist_ok=True)

    def _check_image(self) -> None:
        import docker

        try:
            self.docker.images.get(self.image)
        except docker.errors.ImageNotFound:
            raise DeployError(f"image {self.image} not found: build it with `mrswarm deploy build`") from None

    def _warn_if_stale(self) -> None:
        """A checkout whose code differs from what the image was built from gets a warning."""
        from deploy.images import ROOT, source_hash

        if self.settings.image is None and (ROOT / "pyproject.toml").exists():
            built = (self.docker.images.get(self.image).labels or {}).get("org.mrswarm.source")
            if built and built != source_hash():
                print(f"warning: {self.image} was built from other sources than this checkout; "
                      "`mrswarm deploy build` updates it", file=sys.stderr)

    def _name(self, short: str) -> str:
        return f"mrs-{self.run}-{short}"

    # ---- the network: routers, discovery server (deploy/plan.py) --------------------------------
    def start_network(self, plan: NetworkPlan) -> dict[str, NetworkConfig]:
        """Create the run's network, start the plan's services as containers (:data:`~deploy.plan.CONTAINERS`),
        and return how the UAVs reach them.

        The runner on the host joins through the edge router. Each secured container is handed its
        own bundle of the swarm's key directory. One swarm per run: more swarms in one airspace run
        with the process runtime.
        """
        if len(plan.swarms) > 1:
            raise DeployError("more swarms in one airspace (other_swarms) run with the process runtime (docs/world.md)")
        self.swarm = plan.swarms[0].name
        self.keys = plan.swarms[0].keys
        # internal: no route out of the host. (Docker's isolation rules for internal networks
        # also drop traffic to addresses outside the subnet, multicast included, so a LAN-like
        # network with multicast must not be internal.)
        self.network = self.docker.networks.create(
            self._name("net"), driver="bridge", internal=self.settings.multicast == "drop", check_duplicate=True,
            labels=labels(self.run, self.swarm, "network"),
        )
        bridge = f"br-{self.network.id[:12]}"
        if self.settings.multicast == "drop":
            multicast.seal(bridge, self.network.name)
            self.sealed = True
        else:  # a LAN among the containers; still keep its multicast away from the host if we can
            try:
                multicast.seal(bridge, self.network.name, between_containers=False)
            except multicast.SealError as exc:
                log.warning("multicast between containers and host not blocked: %s", exc)
        placed = plan.place(CONTAINERS)
        hosts: dict[str, str] = {}
        for svc in placed.services:
            box = self._run(svc.name, svc.service.role, ["python3", *svc.argv()], uav=None, cpus=SERVICE_CPUS,
                            memory_mb=SERVICE_MEMORY_MB, mounts=False, identity=svc.service.identity)
            hosts[svc.name] = box.ip
            if isinstance(svc.options, DiscoveryServerOptions):
                wait_discovery(f"{box.ip}:{svc.port}", self.swarm, svc.options.keys[self.swarm], 30.0,
                               alive=partial(self._running, box))
            else:
                wait_tcp(box.ip, svc.port, 30.0, alive=partial(self._running, box), period=0.2)
        nets = placed.uav_networks(hosts)
        self._write_manifest()
        return nets

    # ---- the world service (docs/world.md) -----------------------------------------------------
    def start_world(self, config: Path) -> None:
        """The world service in its own container on the run's network: the run folder mounted (its
        configuration in, its records out) and, in a secured run, the edge's credentials as its own."""
        from world.config import WorldServiceConfig

        cfg = WorldServiceConfig.load(config)
        if self.keys is not None:  # the container sees its own bundle at KEYS_IN_CONTAINER, not the host's directory
            swarms = tuple(replace(s, network=replace(s.network, security=Credentials(keys=KEYS_IN_CONTAINER)))
                           for s in cfg.swarms)
            config = config.with_name("world.container.json")
            config.write_text(replace(cfg, swarms=swarms).to_json())
        self._run("world", "world", ["python3", "-m", "world", "--config", str(config.resolve()), "--log-level", self.log_level],
                  uav=None, cpus=SERVICE_CPUS, memory_mb=SERVICE_MEMORY_MB, mounts=True,
                  identity=NodeName("edge", 0, cfg.swarms[0].name))

    # ---- UAVs ------------------------------------------------------------------------------
    def start_pool(self, name: str, cfgs: list[VirtualUavConfig], number: int, lockstep_epoch: float | None = None) -> None:
        """Pools are the process runtime's: here every virtual UAV is a container of its own."""
        raise RuntimeError("fleet.pool: pools of virtual UAVs run with the process runtime; a container per UAV here")

    def start_uav(self, cfg: VirtualUavConfig) -> None:
        rec = cfg.agent.record_dir
        if rec is not None:
            cfg = replace(cfg, agent=replace(cfg.agent, record_dir=str(Path(rec).resolve())))
        path = self.run_dir / "config" / f"uav{cfg.agent.uav}.json"
        path.write_text(cfg.to_json())
        from deploy.behaviour_mounts import behaviour_mounts

        try:  # a behaviour of one's own (docs/sdk.md): its package mounted read-only, on the container's PYTHONPATH
            extra = behaviour_mounts(cfg.agent.mission.behaviour)
        except ValueError as exc:
            raise DeployError(str(exc)) from None
        self._run(f"uav{cfg.agent.uav}", "uav",
                  ["python3", "-m", "uav_stack.virtual_uav", "--config", str(path), "--log-level", self.log_level],
                  uav=cfg.agent.uav, cpus=self.settings.cpus, memory_mb=self.settings.memory_mb, mounts=True,
                  identity=NodeName.uav(cfg.agent.uav, cfg.agent.swarm), extra_mounts=extra)

    def start_agent(self, cfg: AgentConfig) -> None:
        """Not here: the containers' network has no way out to a flight controller on the host (a scenario with
        an external one is refused with runtime docker)."""
        raise RuntimeError(f"UAV {cfg.uav}'s flight controller is external ({cfg.fcu}): the container runtime runs "
                           "virtual UAVs only; use runtime: process")

    def _bundle(self, identity: NodeName) -> Path:
        """The credentials of one container: a bundle of the run's key directory, in <run>/secrets/<cn>."""
        from swarmnet.security.pki import KeyDir

        assert self.keys is not None
        secrets_dir = self.run_dir / "secrets"
        secrets_dir.mkdir(mode=0o700, exist_ok=True)
        return KeyDir(self.keys).bundle(identity, secrets_dir / identity.cn)

    def _run(self, short: str, role: str, argv: list[str], uav: int | None, cpus: float, memory_mb: int,
             mounts: bool, identity: NodeName | None = None, extra_mounts: dict[str, str] | None = None) -> Box:
        from docker.types import LogConfig

        kwargs: dict[str, Any] = {}
        volumes: dict[str, dict[str, str]] = {}
        tmpfs = {"/tmp": "size=16m"}
        if mounts:  # the run folder at the same path: config in, recorded data out
            volumes[str(self.run_dir)] = {"bind": str(self.run_dir), "mode": "rw"}
            for private in (self.run_dir / "secrets", self.keys):  # ... but no other node's credentials
                if private is not None and private.resolve().is_relative_to(self.run_dir):
                    tmpfs[str(private.resolve())] = "size=64k,mode=0700"
        if self.keys is not None and identity is not None:
            volumes[str(self._bundle(identity))] = {"bind": KEYS_IN_CONTAINER, "mode": "ro"}
        environment = {"PYTHONUNBUFFERED": "1"}
        if extra_mounts:  # read-only, and on the import path (deploy/behaviour_mounts.py)
            from deploy.behaviour_mounts import BEHAVIOURS_IN_CONTAINER

            volumes.update({host: {"bind": inside, "mode": "ro"} for host, inside in extra_mounts.items()})
            environment["PYTHONPATH"] = BEHAVIOURS_IN_CONTAINER
        if volumes:
            kwargs["volumes"] = volumes
        name = self._name(short)
        container = self.docker.containers.create(
            self.image, argv, name=name, hostname=short, labels=labels(self.run, self.swarm, role, uav),
            network=self.network.name, user=f"{os.getuid()}:{os.getgid()}",
            nano_cpus=int(cpus * 1e9), mem_limit=f"{memory_mb}m", memswap_limit=f"{memory_mb}m",
            pids_limit=PIDS_LIMIT, cap_drop=["ALL"], security_opt=["no-new-privileges"],
            read_only=True, tmpfs=tmpfs, sysctls=dict(multicast.IPV6_OFF),
            environment=environment,
            log_config=LogConfig(type="json-file", config={"max-size": "20m", "max-file": "1"}),
            **kwargs,
        )
        box = Box(short, container, role)
        self.boxes[short] = box  # tracked before start: stop() removes it whatever happens next
        container.start()
        container.reload()
        box.ip = container.attrs["NetworkSettings"]["Networks"][self.network.name]["IPAddress"]
        return box

    def start_container(self, short: str, argv: list[str], role: str = "probe") -> Box:
        """Any other container of the stack image on the run's network (tests, probes)."""
        return self._run(short, role, argv, uav=None, cpus=SERVICE_CPUS, memory_mb=SERVICE_MEMORY_MB, mounts=False)

    def _running(self, box: Box) -> bool:
        box.container.reload()
        return box.container.status in ("created", "running")

    # ---- status ----------------------------------------------------------------------------
    def exited(self) -> dict[str, int]:
        """Containers that have exited, with their exit codes (asks the engine at most 1/s). The
        log of a container seen exited for the first time is saved into ``<run>/logs/`` at once."""
        now = time.monotonic()
        if now - self._exited_at >= EXITED_POLL_S and self.boxes:
            self._exited_at = now
            by_id = {b.container.id: n for n, b in self.boxes.items()}
            for c in self.docker.containers.list(all=True, filters={"label": f"{L_RUN}={self.run}", "status": "exited"}):
                if c.id in by_id:
                    name = by_id[c.id]
                    if name not in self._exited:  # its log now, not only at the end: the supervisor reads why it failed
                        try:
                            self._save_log(name)
                        except OSError as exc:  # a full disk: the run goes on, the reason stays in the engine
                            log.warning("%s: cannot save its log: %s", name, exc.strerror or exc)
                    self._exited[name] = popen_exit_code(int(c.attrs["State"]["ExitCode"]))
        return dict(self._exited)

    def signal(self, name: str, sig: int) -> bool:
        """Send ``sig`` to one container's main process; False if it is not running."""
        box = self.boxes.get(name)
        if box is None or not self._running(box):
            return False
        box.container.kill(signal=int(sig))
        return True

    def restart(self, name: str, grace: float = 3.0) -> None:
        """Restart one container (its command and network as first started)."""
        self.boxes[name].container.restart(timeout=max(1, int(grace)))
        self._exited.pop(name, None)

    def pids(self) -> dict[str, int]:
        """Host PIDs of each container's main process (psutil can measure them like processes)."""
        out = {}
        for n, b in self.boxes.items():
            b.container.reload()
            out[n] = int(b.container.attrs["State"]["Pid"])
        return out

    def containers(self) -> dict[str, dict[str, Any]]:
        return {n: {"name": b.container.name, "id": b.container.id[:12], "ip": b.ip, "role": b.role}
                for n, b in self.boxes.items()}

    def _write_manifest(self, exit_codes: dict[str, int] | None = None) -> None:
        data = {"runtime": "docker", "run": self.run, "image": self.image, "settings": to_builtins(self.settings),
                "network": self.network.name if self.network is not None else None, "multicast_sealed": self.sealed,
                "containers": self.containers()}
        if exit_codes is not None:
            data["exit_codes"] = exit_codes
        (self.run_dir / "containers.json").write_text(json.dumps(data, indent=2))

    # ---- shutdown --------------------------------------------------------------------------
    def stop(self, grace: float = 5.0) -> dict[str, int]:
        """SIGTERM every UAV and wait for them, then the services; SIGKILL whatever is left
        ``grace`` seconds after its own SIGTERM; save the logs; remove containers, network and multicast rules.
        A second Ctrl-C cannot cut it short."""
        old = signal.signal(signal.SIGINT, signal.SIG_IGN) if _main_thread() else None
        try:
            return self._stop(grace)
        finally:
            if old is not None:
                signal.signal(signal.SIGINT, old)

    def _stop(self, grace: float) -> dict[str, int]:
        import docker

        uavs = [n for n, b in self.boxes.items() if b.role == "uav"]
        services = [n for n, b in self.boxes.items() if b.role != "uav"]
        codes: dict[str, int] = {}
        # The UAVs first, and only then the services: a router told to stop while every
        # UAV is closing its session at the same moment may not close its own in time.
        for group in (uavs, services):
            for n in group:
                try:
                    self.boxes[n].container.kill(signal="SIGTERM")
                except docker.errors.APIError:
                    pass  # not running
            deadline = time.monotonic() + grace
            for n in group:
                codes[n] = self._wait(self.boxes[n].container, max(0.5, deadline - time.monotonic()))
        for n in uavs + services:
            self._save_log(n)
        self._write_manifest(codes)
        self._remove_all()
        return codes

    def _wait(self, c: Any, timeout: float) -> int:
        import docker
        import requests

        try:
            return int(c.wait(timeout=timeout)["StatusCode"])
        except (requests.exceptions.RequestException, docker.errors.APIError):
            pass
        log.warning("%s did not exit on SIGTERM; killing it", c.name)
        try:
            c.kill()
            return int(c.wait(timeout=10)["StatusCode"])
        except (requests.exceptions.RequestException, docker.errors.APIError):
            return -9

    def _save_log(self, short: str) -> None:
        try:
            data = self.boxes[short].container.logs(stdout=True, stderr=True)
        except Exception as exc:  # noqa: BLE001 - a missing log must not stop the clean-up
            data = f"(log unavailable: {exc})\n".encode()
        (self.run_dir / "logs" / f"{short}.log").write_bytes(data)

    def _remove_all(self) -> None:
        import docker

        # every container of the run, also one created by a call that Ctrl-C interrupted
        leftovers = {c.id: c for c in self.docker.containers.list(all=True, filters={"label": f"{L_RUN}={self.run}"})}
        for b in self.boxes.values():
            leftovers.setdefault(b.container.id, b.container)
        for c in leftovers.values():
            try:
                c.remove(force=True)
            except docker.errors.NotFound:
                pass
            except docker.errors.APIError as exc:
                log.warning("could not remove %s: %s", c.name, exc)
        if self.network is not None:
            multicast.unseal(self.network.name)
            self.sealed = False
            try:
                self.network.remove()
            except docker.errors.NotFound:
                pass
            except docker.errors.APIError as exc:
                log.warning("could not remove network %s: %s", self.network.name, exc)
        for n in self.docker.networks.list(filters={"label": f"{L_RUN}={self.run}"}):
            n.remove()


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()
