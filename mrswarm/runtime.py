"""Where the virtual UAVs run: the :class:`Runtime` interface the runner drives, and the choice of one.

``deploy/`` provides the runtimes (``ProcessRuntime``: one OS process per UAV;
``DockerRuntime``: one container per UAV); the runner (``mrswarm.experiment``) depends only
on this interface, and :func:`make_runtime` picks one from the scenario, handing each runtime
its own typed settings.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from discovery.options import DiscoveryService
from swarmnet.interest import Interest
from uav_stack.config import AgentConfig, NetworkConfig, PoseFeed, VirtualUavConfig, ZenohMode

if TYPE_CHECKING:
    from mrswarm.scenario import Scenario


class Runtime(Protocol):
    """Starts a swarm's network services, its virtual UAVs and the agents of its external ones, and stops them all."""

    name: str  # "process" or "docker"

    def start_network(self, mode: ZenohMode = "peer", pose_feed: PoseFeed = "direct", swarm: str = "*",
                      connectivity: str = "rendezvous", discovery: DiscoveryService | None = None,
                      keys: Path | None = None, extra_keys: dict[str, str] | None = None,
                      interest: Interest | None = None, feed_window: float | None = None,
                      extra_identities: dict[str, Path] | None = None) -> NetworkConfig:
        """Start what the connectivity needs (router, discovery server); return how UAVs reach it.

        ``keys``: the swarm's key directory (mutual TLS and access control on every link,
        docs/security.md; the discovery server binds beacons to its identities); None: plain TCP.
        ``extra_keys``: the discovery keys of more swarms sharing the airspace (swarm -> key;
        docs/world.md), ``extra_identities`` their key directories. ``interest``: spatial interest of
        the edge pose feed (docs/scale.md; only with ``pose_feed`` edge). ``feed_window``: the
        edge pose feed's batch window, s (None: the router's default, ``swarmnet.feed.DEFAULT_WINDOW``).
        """
        ...

    def add_swarm(self, swarm: str, net: NetworkConfig, discovery_key: str | None, keys: Path | None) -> NetworkConfig:
        """Another swarm in the same airspace: its own edge router (under its own key directory,
        ``keys``), the discovery server of ``net`` with its own discovery key; how its UAVs reach it."""
        ...

    def start_world(self, config: Path) -> None:
        """Start the world service (``python -m world``) with this configuration file (docs/world.md)."""
        ...

    def start_uav(self, cfg: VirtualUavConfig) -> None:
        """Start one virtual UAV (FCU + agent) with this configuration."""
        ...

    def start_agent(self, cfg: AgentConfig) -> None:
        """Start the agent of a UAV whose flight controller is external (``mrswarm agent`` against
        ``cfg.fcu``, named ``uav<id>`` like a virtual UAV), on this machine."""
        ...

    def pids(self) -> dict[str, int]:
        """Host process ids by name (uav3, router, ...)."""
        ...

    def exited(self) -> dict[str, int]:
        """What has exited, with its return code."""
        ...

    def stop(self, grace: float = 5.0) -> dict[str, int]:
        """Stop everything (SIGTERM, then SIGKILL after ``grace`` s); the return codes by name."""
        ...

    def signal(self, name: str, sig: int) -> bool:
        """Send a real signal to one child (``uav3``, ``router``, ``discovery``); False if it is not running."""
        ...

    def restart(self, name: str, grace: float = 3.0) -> None:
        """Start one child again as it was first started (stopping it first if it still runs)."""
        ...


def make_runtime(scn: Scenario, run_dir: Path, log_level: str = "INFO") -> Runtime:
    """The runtime the scenario asks for (``runtime: process | docker``)."""
    if scn.runtime == "docker":
        from deploy.docker_runtime import DockerRuntime

        return DockerRuntime(run_dir, log_level=log_level, settings=scn.docker, swarm=scn.swarm)
    from deploy.process_runtime import ProcessRuntime

    return ProcessRuntime(run_dir, log_level=log_level)
