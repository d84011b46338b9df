"""The network plan: what a run's network needs besides the UAVs, built once, placed by every runtime.

A :class:`NetworkPlan` is made once from the typed scenario (``Scenario.network_plan`` in the
runner; ``deploy`` never reads a scenario): the swarms of the airspace with their credentials
and discovery keys, the topology (connectivity, Zenoh mode, pose feed), the edge feed's window
and spatial interest (with the pools of virtual UAVs that share one session each, so that the
edge sends each pool one near batch), the discovery service's timing. :attr:`NetworkPlan.services` is the one
place that decides which services run: the discovery server (connectivity ``discovery``) and one
edge router per swarm (``router``, then ``router-<swarm>``), each with its identity.

A runtime places the plan on a :class:`Site`, the only part that differs between runtimes:
the address and port each service binds, where a service or a UAV finds its credentials, a
stats file, whether the discovery keys go into a file. :meth:`NetworkPlan.place` turns every
service into typed options that write their own command line (``discovery/options.py``:
:class:`RouterOptions`, :class:`FeedOptions`, :class:`DiscoveryServerOptions`), and, once the
runtime knows each service's host, :meth:`PlacedNetwork.uav_networks` gives every swarm's UAVs
their ``NetworkConfig``. Two sites cover today's runtimes: :class:`LocalSite` (processes on
this machine's loopback, ``deploy/process_runtime.py``) and :data:`CONTAINERS` (each service in a
network namespace of its own: Docker containers and Swarm stack services, ``deploy/docker_runtime.py``,
``deploy/swarm.py``). A new runtime reuses one or writes its own, then starts each
:class:`PlacedService`'s :meth:`~PlacedService.argv` wherever it runs things.
"""

from __future__ import annotations

import socket
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol

from discovery.netutil import free_port
from discovery.options import DiscoveryServerOptions, DiscoveryService, FeedOptions, ProxyOptions, RouterOptions
from groundfloor.net import Addr
from swarmnet.interest import Interest, PoolMembers
from swarmnet.keyspace import check_swarm
from swarmnet.security.credentials import Credentials
from swarmnet.security.identity import NodeName
from uav_stack.config import NetworkConfig, PoseFeed, ZenohMode, pool_shares_session

ROUTER_PORT = 7447  # Zenoh's registered port
UAV_PORT = 7447  # each UAV container listens on its own IP
DISCOVERY_PORT = 7450  # discovery server (UDP beacons, docs/discovery.md)
# datagrams/s the discovery server accepts per source address: every node of a run shares 127.0.0.1
# (or a NAT's address), so the server's per-source default (100) would drop their beacons
DISCOVERY_RATE = 5000.0
# where a container finds its credentials (docs/security.md): its bundle mounted read-only by the
# container runtime, or the stack's secrets on Docker Swarm; never in the image
KEYS_IN_CONTAINER = "/run/secrets"

Role = Literal["router", "discovery"]
MODULES: dict[Role, str] = {"router": "discovery.rendezvous", "discovery": "discovery.server"}


def edge_service(host: str, edges: tuple[str, ...]) -> str:
    """The router service a UAV on server ``host`` uses, given the servers with an edge router of
    their own (the manager's first): ``router`` on the manager or with one router for all,
    else ``router-<host>`` (``deploy/swarm.py``)."""
    return "router" if not edges or host == edges[0] or host not in edges else f"router-{host}"


@dataclass(frozen=True)
class SwarmPlan:
    """One swarm of the airspace: its name, its key directory on this machine, its discovery key."""

    name: str
    keys: Path | None = None  # the swarm's key directory (mutual TLS, docs/security.md); None: plain TCP
    discovery_key: str | None = None  # its key on the discovery server (required with connectivity discovery)

    def __post_init__(self) -> None:
        check_swarm(self.name)

    @property
    def scheme(self) -> str:
        return "tls" if self.keys is not None else "tcp"


@dataclass(frozen=True)
class Service:
    """One service of the plan, before a runtime places it."""

    name: str  # discovery, router, router-<swarm>: a process's or container's name, the key of its address
    role: Role
    swarm: str  # the swarm it serves (the discovery server: every swarm of the plan)
    port: int  # its port in a network namespace of its own (a container, a stack's task)
    proto: Literal["tcp", "udp"]  # tcp: a runtime can wait until it accepts connections
    identity: NodeName | None  # whose credentials it is handed (edge.<swarm>); None: plain TCP
    feed: FeedOptions | None = None  # a router's edge pose feed

    @property
    def module(self) -> str:
        return MODULES[self.role]


class Site(Protocol):
    """Where a runtime puts the plan's services and UAVs: the only parts of the plan that differ between runtimes."""

    @property
    def uav_listen(self) -> Addr:
        """The host and port a UAV listens on."""
        ...

    def bind(self, service: Service) -> Addr:
        """The host and port ``service`` listens on."""
        ...

    def keys(self, swarm: SwarmPlan) -> str:
        """Where a service or UAV of the secured ``swarm`` finds its credentials."""
        ...

    def stats(self, service: Service) -> str | None:
        """A file for the service's counters (None: none)."""
        ...

    def keys_file(self) -> str | None:
        """A file for the discovery server's keys, which the runtime writes (None: on its command line)."""
        ...


@dataclass(frozen=True)
class LocalSite:
    """Processes on this machine (``deploy/process_runtime.py``): every service on 127.0.0.1 at a free port,
    the swarms' key directories as they are, a secured router's counters and the discovery keys in the run folder."""

    run_dir: Path
    uav_listen: Addr = ("127.0.0.1", 0)

    def bind(self, service: Service) -> Addr:
        return "127.0.0.1", free_port(socket.SOCK_DGRAM if service.proto == "udp" else socket.SOCK_STREAM)

    def keys(self, swarm: SwarmPlan) -> str:
        assert swarm.keys is not None
        return str(swarm.keys)

    def stats(self, service: Service) -> str | None:
        # a secured router's first counters say it is up (a bare TCP probe would count as a refused handshake)
        if service.role == "router" and service.identity is not None:
            return str(self.run_dir / "logs" / f"{service.name}.stats.json")
        return None

    def keys_file(self) -> str | None:
        return str(self.run_dir / "config" / "discovery.keys")  # not on a command line other users can read


@dataclass(frozen=True)
class ContainerSite:
    """Each service and UAV in a network namespace of its own (a Docker container, a Swarm stack's task): fixed
    ports on every address of that namespace, credentials in :data:`KEYS_IN_CONTAINER`, keys on the command line."""

    uav_listen: Addr = ("0.0.0.0", UAV_PORT)

    def bind(self, service: Service) -> Addr:
        return "0.0.0.0", service.port

    def keys(self, swarm: SwarmPlan) -> str:
        return KEYS_IN_CONTAINER

    def stats(self, service: Service) -> str | None:
        return None

    def keys_file(self) -> str | None:
        return None


CONTAINERS = ContainerSite()


@dataclass(frozen=True)
class PlacedService:
    """One service as a runtime runs it: where it listens, and its options."""

    service: Service
    host: str  # the address it binds
    port: int
    options: RouterOptions | DiscoveryServerOptions

    @property
    def name(self) -> str:
        return self.service.name

    def argv(self) -> list[str]:
        """Its command line after the Python interpreter (each runtime names its own: ``python3``, ``python -S``)."""
        return ["-m", self.service.module, *self.options.argv()]


@dataclass(frozen=True)
class PlacedNetwork:
    """A plan placed on a site: the services to start, in order, and how the UAVs reach them."""

    plan: NetworkPlan
    services: tuple[PlacedService, ...]
    site: Site

    def service(self, name: str) -> PlacedService:
        for s in self.services:
            if s.name == name:
                return s
        raise KeyError(name)

    def uav_network(self, swarm: str, hosts: Mapping[str, str]) -> NetworkConfig:
        """How the UAVs of ``swarm`` reach it, given the host (IP address or DNS name) of each service by name."""
        missing = [s.name for s in self.services if s.name not in hosts]
        if missing:
            raise ValueError(f"no address for services {missing}")
        plan = self.plan
        sw = plan.swarm(swarm)
        router = self.service(plan.router_name(swarm))
        host, port = self.site.uav_listen
        discovery = None
        if plan.connectivity == "discovery":
            server = self.service("discovery")
            discovery = ProxyOptions(server=f"{hosts[server.name]}:{server.port}", key=sw.discovery_key,
                                     period=plan.discovery.period)
        # UAVs listen on their own address; with discovery the proxy drops loopback locators when the
        # server is remote, so peers dial each other's own (container or task) address
        return NetworkConfig(connectivity=plan.connectivity, endpoints=(f"{sw.scheme}/{hosts[router.name]}:{router.port}",),
                             mode=plan.mode, listen=(f"{sw.scheme}/{host}:{port}",), pose_feed=plan.pose_feed,
                             lease_s=plan.lease_s, interest=plan.interest, discovery=discovery,
                             security=Credentials(keys=self.site.keys(sw)) if sw.keys is not None else None)

    def uav_networks(self, hosts: Mapping[str, str]) -> dict[str, NetworkConfig]:
        """Every swarm's :meth:`uav_network`, the plan's first swarm first."""
        return {s.name: self.uav_network(s.name, hosts) for s in self.plan.swarms}


@dataclass(frozen=True)
class NetworkPlan:
    """A run's network, runtime-independent: the swarms of the airspace (the scenario's own first) and how they meet.

    The edge router always runs, with discovery too: every node keeps one link to it, the way in
    for ground stations and runners outside the UAVs' network (they join as its Zenoh clients),
    and the edge pose feed's home; UAV-to-UAV data still flows peer to peer.
    """

    swarms: tuple[SwarmPlan, ...]
    connectivity: Literal["discovery", "rendezvous"] = "rendezvous"
    mode: ZenohMode = "peer"
    pose_feed: PoseFeed = "direct"
    feed_window_s: float | None = None  # the edge feed's batch window, s (None: the router's default)
    interest: Interest | None = None  # spatial interest of every edge feed (docs/scale.md)
    discovery: DiscoveryService = field(default_factory=DiscoveryService)  # its beacon period and TTL (keys: per swarm)
    lease_s: float = 3.0  # a node silent this long is gone
    # swarm -> its pools of virtual UAVs (process runtime, fleet.pool): with spatial interest on a
    # connectivity where a pool shares one session, its edge sends each pool one near batch
    pools: Mapping[str, tuple[PoolMembers, ...]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        names = [s.name for s in self.swarms]
        if not names or len(set(names)) != len(names):
            raise ValueError(f"a network plan needs one or more swarms, each once; got {names}")
        if self.interest is not None and self.pose_feed != "edge":
            raise ValueError("spatial interest filters the edge pose feed: it needs pose_feed 'edge'")
        if self.connectivity == "discovery":
            if self.mode != "peer":
                raise ValueError("discovery connects peers directly; client mode needs connectivity 'rendezvous'")
            if unkeyed := [s.name for s in self.swarms if not s.discovery_key]:
                raise ValueError(f"discovery needs a key for swarms {unkeyed} (the runner draws one per run if the scenario "
                                 "sets none)")

    def swarm(self, name: str) -> SwarmPlan:
        for s in self.swarms:
            if s.name == name:
                return s
        raise KeyError(name)

    @property
    def grouped_near(self) -> bool:
        """The edge sends each pool of virtual UAVs one near batch: with spatial interest, where
        a pool's UAVs share its one session (every connectivity but discovery)."""
        return self.interest is not None and pool_shares_session(self.connectivity)

    def router_name(self, swarm: str) -> str:
        """``router`` for the plan's first swarm, ``router-<swarm>`` for every other."""
        return "router" if swarm == self.swarms[0].name else f"router-{swarm}"

    @property
    def services(self) -> tuple[Service, ...]:
        """What runs besides the UAVs, in the order to start it: the discovery server first (the routers'
        nodes beacon to it), then each swarm's edge router."""
        out = []
        first = self.swarms[0]
        if self.connectivity == "discovery":  # bound to the first swarm's edge identity; it checks every swarm's beacons
            out.append(Service("discovery", "discovery", first.name, DISCOVERY_PORT, "udp",
                               NodeName("edge", 0, first.name) if first.keys is not None else None))
        for s in self.swarms:
            feed = FeedOptions(swarm=s.name, window_s=self.feed_window_s, interest=self.interest,
                               pools=self.pools.get(s.name, ()) if self.grouped_near else ()) \
                if self.pose_feed == "edge" else None
            out.append(Service(self.router_name(s.name), "router", s.name, ROUTER_PORT, "tcp",
                               NodeName("edge", 0, s.name) if s.keys is not None else None, feed))
        return tuple(out)

    def place(self, site: Site) -> PlacedNetwork:
        """Every service with the options it runs with on ``site``."""
        placed = []
        for svc in self.services:
            host, port = site.bind(svc)
            options: RouterOptions | DiscoveryServerOptions
            if svc.role == "router":
                sw = self.swarm(svc.swarm)
                options = RouterOptions(listen=(f"{sw.scheme}/{host}:{port}",), feed=svc.feed, stats=site.stats(svc),
                                        keys=site.keys(sw) if sw.keys is not None else None)
            else:  # secured: every swarm's beacons bound to identities (its roster and beacon key)
                identities = tuple(dict.fromkeys(site.keys(s) for s in self.swarms if s.keys is not None))
                keys = {s.name: s.discovery_key or "" for s in self.swarms}
                options = DiscoveryServerOptions(listen=f"{host}:{port}", keys=keys, keys_file=site.keys_file(),
                                                 ttl=self.discovery.ttl, rate=DISCOVERY_RATE, identities=identities)
            placed.append(PlacedService(svc, host, port, options))
        return PlacedNetwork(self, tuple(placed), site)
