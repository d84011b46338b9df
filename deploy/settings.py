"""Typed settings of the container runtime (a scenario's ``docker:`` section)."""

from __future__ import annotations

from typing import Annotated, Literal

from msgspec import Meta

from groundfloor.schema import Config

ImageName = Annotated[str, Meta(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.:/@-]{0,199}$", description="docker image reference")]


class ContainerSettings(Config, frozen=True):
    """Per-UAV containers of ``runtime: docker`` (and the replicas of ``mrswarm deploy swarm up``)."""

    image: ImageName | None = None  # default mrswarm:<version> (`mrswarm deploy build`)
    cpus: Annotated[float, Meta(gt=0.0, le=64.0, description="CPU limit per UAV container, cores")] = 0.5
    memory_mb: Annotated[int, Meta(ge=64, le=65536, description="memory limit per UAV container, MB")] = 256
    # drop: no multicast or broadcast between containers, like a cellular network; allow: a plain LAN bridge
    multicast: Literal["drop", "allow"] = "drop"
