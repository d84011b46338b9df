"""Typed settings of the runtimes: UAV processes (a scenario's ``process:`` section) and UAV
containers (its ``docker:`` section)."""

from __future__ import annotations

from typing import Annotated, Literal

from msgspec import Meta

from swarmnet.schema import Config

ImageName = Annotated[str, Meta(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.:/@-]{0,199}$", description="docker image reference")]


class ContainerSettings(Config, frozen=True):
    """Per-UAV containers of ``runtime: docker`` (and the replicas of ``mrswarm deploy swarm up``)."""

    image: ImageName | None = None  # default mrswarm:<version> (`mrswarm deploy build`)
    cpus: Annotated[float, Meta(gt=0.0, le=64.0, description="CPU limit per UAV container, cores")] = 0.5
    memory_mb: Annotated[int, Meta(ge=64, le=65536, description="memory limit per UAV container, MB")] = 256
    # drop: no multicast or broadcast between containers, like a cellular network; allow: a plain LAN bridge
    multicast: Literal["drop", "allow"] = "drop"


class ProcessSettings(Config, frozen=True):
    """UAV processes of ``runtime: process`` (the default).

    ``cpu_affinity``: ``spread`` (default) pins each UAV process, with all its threads, to one of
    the CPUs the runner may use, round-robin in the order the UAVs start (a restarted UAV keeps
    its CPU). A UAV wakes ten times a second for a millisecond; between two wake-ups the other
    processes evict its code and data from the CPU caches, and a UAV the scheduler moves to
    another core finds even less of it there. Pinned, a UAV costs about 4 % less CPU in a fleet
    of 50 on two cores, and a lone one about 3 % less (docs/benchmarks.md). ``none``: the
    scheduler places every process, as for any program; choose it when other work shares the
    machine unevenly, since a pinned UAV cannot move off a core that other work keeps busy.
    The runner, the edge router and the discovery server are never pinned.
    """

    cpu_affinity: Literal["spread", "none"] = "spread"
