"""Typed settings of the discovery service: what a swarm runs, and how a node reaches it.

* :class:`DiscoveryService`: a scenario's ``network.discovery`` (the swarm's key, the beacon
  period, the server's TTL); the runtimes start the discovery server from it.
* :class:`ProxyOptions`: a node's side (``NetworkConfig.discovery`` of a UAV process, or the
  flags of ``mrswarm agent``): which server, which key, what to advertise. The node's
  :class:`~discovery.proxy.BeaconDiscovery` is built from it.
* :func:`pose_feed_argv`: the edge router's pose-feed arguments, as the runtimes start it.

Light imports only (msgspec, no zenoh): a scenario or a UAV config names these types.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from msgspec import Meta, field

from discovery.protocol import DEFAULT_PERIOD, MIN_KEY_LEN
from swarmnet.schema import Config, ConfigError

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


def pose_feed_argv(swarm: str, window: float | None = None) -> list[str]:
    """The edge router's arguments (``mrswarm router``, discovery/rendezvous.py) for the pose feed of
    ``swarm`` batching within ``window`` s (None: the router's default), for the runtimes that start it."""
    argv = ["--feed", swarm]
    if window is not None:
        argv += ["--feed-window-ms", f"{window * 1000.0:g}"]
    return argv
