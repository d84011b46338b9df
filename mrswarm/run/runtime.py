"""Where the virtual UAVs run: the :class:`Runtime` interface the runner drives, and the choice of one.

``deploy/`` provides the runtimes (``ProcessRuntime``: one OS process per UAV;
``DockerRuntime``: one container per UAV), each placing the same network plan
(``deploy/plan.py``, made by ``Scenario.network_plan``); the runner (``mrswarm.run.experiment``) depends only
on this interface, and :func:`make_runtime` picks one from the scenario, handing each runtime
its own typed settings.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from deploy.plan import NetworkPlan
from uav_stack.config import AgentConfig, NetworkConfig, VirtualUavConfig

if TYPE_CHECKING:
    from mrswarm.scenario import Scenario


class Runtime(Protocol):
    """Starts a swarm's network services, its virtual UAVs and the agents of its external ones, and stops them all."""

    name: str  # "process" or "docker"

    def start_network(self, plan: NetworkPlan) -> dict[str, NetworkConfig]:
        """Start the plan's services (``deploy/plan.py``: the discovery server, each swarm's edge router),
        placed as this runtime places things, and return how each swarm's UAVs reach them (by swarm,
        the plan's first swarm first)."""
        ...

    def start_world(self, config: Path) -> None:
        """Start the world service (``python -m world``) with this configuration file (docs/world.md)."""
        ...

    def start_uav(self, cfg: VirtualUavConfig) -> None:
        """Start one virtual UAV (FCU + agent) with this configuration."""
        ...

    def start_pool(self, name: str, cfgs: list[VirtualUavConfig], number: int, lockstep_epoch: float | None = None) -> None:
        """Start several virtual UAVs in one process named ``name``, pool ``number`` of the run (its
        identity ``pool-<number>``; ``fleet.pool``; the process runtime); with ``lockstep_epoch``, on the
        run's lock-step clock from that simulated time on (swarmnet/lockstep.py)."""
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
