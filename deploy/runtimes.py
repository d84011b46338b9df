"""Choose the runtime a scenario asks for: OS processes or Docker containers."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mrswarm.scenario import Scenario


def make_runtime(scn: Scenario, run_dir: Path, log_level: str = "INFO") -> Any:
    if scn.runtime == "docker":
        from deploy.docker_runtime import ContainerSettings, DockerRuntime

        d = scn.docker
        settings = ContainerSettings(image=d.image, cpus=d.cpus, memory_mb=d.memory_mb, multicast=d.multicast)
        return DockerRuntime(run_dir, log_level=log_level, settings=settings, swarm=scn.swarm)
    from deploy.process_runtime import ProcessRuntime

    return ProcessRuntime(run_dir, log_level=log_level)
