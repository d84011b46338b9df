"""The docker SDK client, labels and names shared by the docker runtime and the CLI."""

from __future__ import annotations

from typing import Any

from groundfloor.errors import MrswarmError

LABEL = "org.mrswarm"  # every container, network, service and config we create carries org.mrswarm.* labels
L_RUN = f"{LABEL}.run"  # run id: one `mrswarm run` or one swarm-mode stack
L_SWARM = f"{LABEL}.swarm"
L_ROLE = f"{LABEL}.role"  # uav | router | discovery | probe
L_UAV = f"{LABEL}.uav"


class DeployError(RuntimeError, MrswarmError):
    """A deployment that cannot start; the message says what is wrong and how to fix it."""


class DockerUnavailable(DeployError):
    """No docker engine can be reached; the message says how to get one."""


def client(timeout: int = 120) -> Any:
    try:
        import docker
    except ImportError:
        raise DockerUnavailable("the docker Python SDK is missing: pip install 'mrswarm[docker]'") from None
    try:
        cl = docker.from_env(timeout=timeout)
        cl.ping()
    except Exception as exc:  # noqa: BLE001 - any failure means: no usable engine
        raise DockerUnavailable(
            f"cannot reach a docker engine ({exc.__class__.__name__}: {exc}). Install docker.io and start dockerd "
            "(`scripts/test` does both), or set DOCKER_HOST") from None
    return cl


def labels(run: str, swarm: str, role: str, uav: int | None = None) -> dict[str, str]:
    out = {L_RUN: run, L_SWARM: swarm, L_ROLE: role}
    if uav is not None:
        out[L_UAV] = str(uav)
    return out
