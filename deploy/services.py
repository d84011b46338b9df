"""What a swarm's network needs besides the UAVs, for runtimes that place things on hosts.

A scenario's connectivity decides which infrastructure services run next to the UAVs (a
rendezvous/edge router today; the discovery server of ``discovery/`` when it lands) and how a
UAV reaches them. The container runtime and the swarm-mode stack both take their services
from :func:`network_plan`, so a new connectivity is added here once and works in both.

Services listen on fixed ports inside their own network namespace (a container or a
swarm task has the port to itself); the runtime learns each service's address after it
starts and calls :meth:`NetworkPlan.uav_network` to build the UAVs' ``NetworkConfig``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from uav_stack.config import NetworkConfig

ROUTER_PORT = 7447  # Zenoh's registered port
UAV_PORT = 7447  # each UAV container listens on its own IP


@dataclass(frozen=True)
class Service:
    name: str  # container/service name suffix and the key of its address
    argv: tuple[str, ...]  # command inside the image
    port: int
    proto: str = "tcp"  # tcp: the runtime waits until it accepts connections


@dataclass(frozen=True)
class NetworkPlan:
    services: tuple[Service, ...]
    make: Callable[[dict[str, str]], NetworkConfig] = field(repr=False)

    def uav_network(self, addresses: dict[str, str]) -> NetworkConfig:
        """The UAVs' network config, given each service's host or IP address by name."""
        missing = [s.name for s in self.services if s.name not in addresses]
        if missing:
            raise ValueError(f"no address for services {missing}")
        return self.make(addresses)


def network_plan(connectivity: str = "rendezvous", mode: str = "peer", pose_feed: str = "direct",
                 swarm: str = "*") -> NetworkPlan:
    if connectivity == "rendezvous":
        argv = ["python3", "-m", "discovery.rendezvous", "--listen", f"tcp/0.0.0.0:{ROUTER_PORT}"]
        if pose_feed == "edge":
            argv += ["--feed", swarm]
        router = Service("router", tuple(argv), ROUTER_PORT)

        def make(addr: dict[str, str]) -> NetworkConfig:
            return NetworkConfig(connectivity="rendezvous", endpoints=(f"tcp/{addr['router']}:{ROUTER_PORT}",), mode=mode,
                                 listen=(f"tcp/0.0.0.0:{UAV_PORT}",), pose_feed=pose_feed)

        return NetworkPlan((router,), make)
    raise ValueError(f"connectivity {connectivity!r} has no container deployment yet (deploy/services.py)")
