"""Typed settings of the discovery service: what a swarm runs, and how a node reaches it.

* :class:`DiscoveryService`: a scenario's ``network.discovery`` (the swarm's key, the beacon
  period, the server's TTL); the runtimes start the discovery server from it.
* :class:`ProxyOptions`: a node's side (``NetworkConfig.discovery`` of a UAV process, or the
  flags of ``mrswarm agent``): which server, which key, what to advertise. The node's
  :class:`~discovery.proxy.BeaconDiscovery` is built from it.
* the services' own options, each writing its command line (:meth:`argv`) for every runtime
  (``deploy/plan.py`` places them): :class:`RouterOptions` (``mrswarm router``,
  discovery/rendezvous.py) with its :class:`FeedOptions` (the edge pose feed: window, spatial
  interest, the pools of virtual UAVs each sent one near batch), and
  :class:`DiscoveryServerOptions` (discovery/server.py). Durations are seconds here; an
  ``argv`` converts to a flag's unit (``--feed-window-ms``), the one place that does.

Light imports only (msgspec, no zenoh): a scenario or a UAV config names these types.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from msgspec import Meta, field

from discovery.protocol import DEFAULT_PERIOD, MIN_KEY_LEN
from groundfloor.schema import Config, ConfigError
from swarmnet.interest import Interest, PoolMembers, pool_groups

Key = Annotated[str, Meta(min_length=MIN_KEY_LEN, description="a swarm's discovery key (`mrswarm discovery keygen`)")]
ServerAddress = Annotated[str, Meta(pattern=r"^\S+$", min_length=1, max_length=300, description="HOST:PORT (or HOST)")]


class DiscoveryService(Config, frozen=True):
    """The discovery service of a swarm (docs/discovery.md); the runtime starts the server."""

    key: Key | None = None  # None: the runtime draws a fresh one per run
    period: Annotated[float, Meta(ge=0.2, le=10.0, description="seconds between beacons")] = DEFAULT_PERIOD
    ttl: Annotated[float, Meta(gt=0.0, le=60.0, description="the server forgets nodes silent this long, s")] = 3.0

    def __post_init__(self) -> None:
        if self.ttl < 2 * self.period:
            raise ConfigError("ttl", f"must be at least two beacon periods (2 x {self.period:g} s), got {self.ttl:g}")


class ProxyOptions(Config, frozen=True):
    """How one node finds its swarm through a discovery server (:class:`discovery.proxy.BeaconDiscovery`)."""

    server: ServerAddress
    key: Key | None = None  # the swarm's key, or
    key_file: str | None = None  # a file holding it
    advertise: tuple[str, ...] = ()  # announce these addresses/locators instead of the listen ones (public IP)
    period: Annotated[float, Meta(ge=0.1, le=30.0, description="seconds between beacons")] = DEFAULT_PERIOD
    extra_swarms: dict[str, Key] = field(default_factory=dict)  # more swarms to join (a ground station): swarm -> key
    dial: Literal["greater-zid", "always"] = "greater-zid"  # who dials a pair: the larger Zenoh id only, or both
    zid: Annotated[str, Meta(pattern=r"^[0-9a-fA-F]{1,32}$")] | None = None  # pin the session's Zenoh id
    lanes: Annotated[int, Meta(ge=1, le=8, description="parallel dial lanes")] = 4

    def __post_init__(self) -> None:
        if self.key is None and self.key_file is None:
            raise ConfigError("key", "required: the swarm's discovery key, or key_file")

    def read_key(self) -> str:
        """The key, read from ``key_file`` if it is not given inline."""
        if self.key is not None:
            return self.key
        assert self.key_file is not None
        try:
            key = Path(self.key_file).read_text().strip()
        except OSError as exc:
            raise ConfigError("key_file", f"cannot read {self.key_file}: {exc.strerror}") from None
        if len(key.encode()) < MIN_KEY_LEN:
            raise ConfigError("key_file", f"{self.key_file} holds a key shorter than {MIN_KEY_LEN} characters")
        return key


class FeedOptions(Config, frozen=True):
    """The edge router's pose feed (swarmnet/feed.py) for one swarm: its batch window, spatial interest,
    and with it the pools of virtual UAVs of the run, each sent one near batch for all its UAVs."""

    swarm: str  # the swarm whose poses it batches ('*': every swarm)
    window_s: Annotated[float, Meta(ge=0.0, le=1.0)] | None = None  # s a pose may wait for others (None: the router's default)
    interest: Interest | None = None  # spatial interest (docs/scale.md); None: every pose to every UAV
    pools: tuple[PoolMembers, ...] = ()  # the pools sharing one session (uav_stack/pool.py); with interest only

    def __post_init__(self) -> None:
        if self.pools and self.interest is None:
            raise ConfigError("pools", "group the near feed of spatial interest: they need an interest")
        pool_groups(self.pools)

    def argv(self) -> list[str]:
        argv = ["--feed", self.swarm]
        if self.window_s is not None:
            argv += ["--feed-window-ms", f"{self.window_s * 1000.0:g}"]
        if self.interest is not None:
            argv += self.interest.argv()
        return argv + [a for p in self.pools for a in ("--pool", p.arg())]


class RouterOptions(Config, frozen=True):
    """``mrswarm router`` (discovery/rendezvous.py): a swarm's edge router, as a runtime starts it."""

    listen: tuple[str, ...]  # Zenoh endpoints it listens on, e.g. tls/127.0.0.1:7447
    keys: str | None = None  # its credentials (the swarm's key directory or edge's bundle) as it sees them; None: plain TCP
    stats: str | None = None  # its counters written to this file every second
    feed: FeedOptions | None = None  # the edge pose feed (pose_feed: edge)
    connect: tuple[str, ...] = ()  # other edge routers it links to (one edge per server)

    def argv(self) -> list[str]:
        argv = [a for endpoint in self.listen for a in ("--listen", endpoint)]
        argv += ["--keys", self.keys] if self.keys is not None else ["--insecure"]
        if self.stats is not None:
            argv += ["--stats", self.stats]
        if self.feed is not None:
            argv += self.feed.argv()
        return argv + [a for endpoint in self.connect for a in ("--connect", endpoint)]


class DiscoveryServerOptions(Config, frozen=True):
    """The discovery server (discovery/server.py) of the swarms of one airspace, as a runtime starts it."""

    listen: str  # UDP HOST:PORT
    keys: dict[str, Key]  # swarm -> its discovery key
    # the keys in this file (the runtime writes :meth:`keys_text` there), else on the command line
    keys_file: str | None = None
    ttl: Annotated[float, Meta(gt=0.0)] = 3.0  # s: the server forgets nodes silent this long
    rate: Annotated[float, Meta(gt=0.0)] = 100.0  # datagrams/s accepted per source address
    identities: tuple[str, ...] = ()  # key directories (or edge bundles) whose roster binds beacons to identities

    def argv(self) -> list[str]:
        argv = ["--listen", self.listen]
        if self.keys_file is not None:
            argv += ["--keys", self.keys_file]
        else:
            argv += [a for swarm, key in self.keys.items() for a in ("--key", f"{swarm}={key}")]
        argv += ["--ttl", str(self.ttl), "--rate", f"{self.rate:g}"]
        return argv + [a for d in self.identities for a in ("--identities", d)]

    def keys_text(self) -> str:
        """What :attr:`keys_file` holds: one ``SWARM KEY`` per line."""
        return "".join(f"{swarm} {key}\n" for swarm, key in self.keys.items())
