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

from discovery.options import DiscoveryService, ProxyOptions, pose_feed_argv
from swarmnet.security.credentials import Credentials
from uav_stack.config import NetworkConfig, PoseFeed, ZenohMode

ROUTER_PORT = 7447  # Zenoh's registered port
UAV_PORT = 7447  # each UAV container listens on its own IP
DISCOVERY_PORT = 7450  # discovery server (UDP beacons, docs/discovery.md)
# where a container finds its credentials (docs/security.md): its bundle mounted read-only by the
# container runtime, or the stack's secrets on Docker Swarm; never in the image
KEYS_IN_CONTAINER = "/run/secrets"


def edge_service(host: str, edges: tuple[str, ...]) -> str:
    """The router service a UAV on server ``host`` uses, given the servers with an edge router of
    their own (the manager's first): ``router`` on the manager or with one router for all,
    else ``router-<host>`` (``deploy/swarm.py``)."""
    return "router" if not edges or host == edges[0] or host not in edges else f"router-{host}"


@dataclass(frozen=True)
class Service:
    name: str  # container/service name suffix and the key of its address
    argv: tuple[str, ...]  # command inside the image
    port: int
    proto: str = "tcp"  # tcp: the runtime waits until it accepts connections
    identity: str | None = None  # the swarm identity whose credentials it is handed ("edge"), if any


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


def network_plan(connectivity: str = "rendezvous", mode: ZenohMode = "peer", pose_feed: PoseFeed = "direct",
                 swarm: str = "*", discovery: DiscoveryService | None = None, with_router: bool = False,
                 secured: bool = False, feed_window: float | None = None) -> NetworkPlan:
    """The services and the UAVs' network config for a connectivity.

    ``discovery`` (for ``connectivity: discovery``) must carry a key: the runtime draws one
    per run if the scenario has none. ``with_router``
    also runs the edge router beside the discovery server, and every UAV keeps one link to
    it: the way in for ground stations and runners outside the UAVs' network (they join as
    Zenoh clients of the router). UAV-to-UAV data still flows peer to peer.
    ``secured``: every Zenoh link mutual TLS under the roster's access control, each container
    reading its credentials from :data:`KEYS_IN_CONTAINER` (the runtime puts them there).
    ``feed_window``: the edge pose feed's batch window, s (None: the router's default).
    """
    scheme = "tls" if secured else "tcp"
    creds = Credentials(keys=KEYS_IN_CONTAINER) if secured else None  # each UAV speaks as its own uav-<id>
    router_argv = ["python3", "-m", "discovery.rendezvous", "--listen", f"{scheme}/0.0.0.0:{ROUTER_PORT}"]
    router_argv += ["--keys", KEYS_IN_CONTAINER] if secured else ["--insecure"]
    if pose_feed == "edge":
        router_argv += pose_feed_argv(swarm, feed_window)
    router = Service("router", tuple(router_argv), ROUTER_PORT, identity="edge" if secured else None)
    if connectivity == "rendezvous":

        def make(addr: dict[str, str]) -> NetworkConfig:
            return NetworkConfig(connectivity="rendezvous", endpoints=(f"{scheme}/{addr['router']}:{ROUTER_PORT}",), mode=mode,
                                 listen=(f"{scheme}/0.0.0.0:{UAV_PORT}",), pose_feed=pose_feed, security=creds)

        return NetworkPlan((router,), make)
    if connectivity == "discovery":
        service = discovery or DiscoveryService()
        key = service.key
        if not key:
            raise ValueError("discovery needs a key (the runtime draws one per run if the scenario sets none)")
        server_argv = ("python3", "-m", "discovery.server", "--listen", f"0.0.0.0:{DISCOVERY_PORT}", "--key", f"{swarm}={key}",
                       "--ttl", str(service.ttl), "--rate", "5000")
        # secured: beacons bound to identities, checked with the edge's bundle (its roster and the beacon key)
        server = Service("discovery", server_argv + (("--identities", KEYS_IN_CONTAINER) if secured else ()),
                         DISCOVERY_PORT, proto="udp", identity="edge" if secured else None)
        routed = pose_feed == "edge" or with_router
        services = (server, router) if routed else (server,)

        def make_d(addr: dict[str, str]) -> NetworkConfig:
            # UAVs listen on their own address; the proxy drops loopback locators since the
            # server is remote, so peers dial each other's container (or task) address
            return NetworkConfig(
                connectivity="discovery",
                endpoints=(f"{scheme}/{addr['router']}:{ROUTER_PORT}",) if routed else (),
                mode="peer", listen=(f"{scheme}/0.0.0.0:{UAV_PORT}",), pose_feed=pose_feed,
                discovery=ProxyOptions(server=f"{addr['discovery']}:{DISCOVERY_PORT}", key=key, period=service.period),
                security=creds,
            )

        return NetworkPlan(services, make_d)
    raise ValueError(f"connectivity {connectivity!r} has no container deployment (deploy/services.py)")
