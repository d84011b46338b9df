"""How a node finds its peers: one small interface, several strategies.

A :class:`Connectivity` produces the Zenoh configuration of a node's session and may run
something beside the session (the discovery proxy of ``discovery/`` does). SwarmNode only
talks to this interface, so strategies can be swapped without touching the data path.

Multicast scouting is always **off** in the configs built here: cellular networks carry no
multicast, and our test machines must not send any outside namespaces we create.

Every strategy takes the node's :class:`~swarmnet.security.credentials.Credentials`: with them,
every link is mutual TLS under the swarm's access control (docs/security.md); without them
(``None``, the library's insecure mode for tests and labs) links are plain TCP.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, runtime_checkable

import zenoh

if TYPE_CHECKING:
    from swarmnet.security.credentials import Credentials

log = logging.getLogger(__name__)


# All of Zenoh's runtimes (receive, transmit, network, accept) handed over to its application
# runtime, which has one worker thread: one Zenoh thread instead of five or more, for a process
# with one node of few links (a UAV: one link in client mode, a few dozen in a peer mesh). By
# default Zenoh runs two receive workers (tokio woke the second for nothing at each arriving
# batch) and a transmit thread that each put wakes. Side by side, a UAV of 50 cost 8 % less
# CPU with the receive runtime alone on one worker, and 5.5 % less again with everything on one
# (docs/benchmarks.md). Nothing of the UAV's runs Python on that thread that could wait (its
# subscriptions are ring channels or minimal callbacks, swarmnet/receive.py). Zenoh reads it
# (RON) when it first starts a runtime. A router, which reads from every UAV at once, keeps
# Zenoh's defaults.
LEAN_ZENOH_RUNTIME = "(rx: (handover: app), tx: (handover: app), net: (handover: app), acc: (handover: app))"


def lean_zenoh_runtime() -> None:
    """Give this process's Zenoh :data:`LEAN_ZENOH_RUNTIME`, unless ``ZENOH_RUNTIME`` is already
    set (``ZENOH_RUNTIME='()'`` keeps Zenoh's defaults). Call before the first session opens:
    later calls change nothing in a process whose Zenoh runtimes have started."""
    os.environ.setdefault("ZENOH_RUNTIME", LEAN_ZENOH_RUNTIME)


@runtime_checkable
class Connectivity(Protocol):
    """Strategy that connects a node's Zenoh session to its swarm."""

    @property
    def name(self) -> str:
        """A short label for logs and status ("rendezvous", "static", ...); read-only."""
        ...

    @property
    def credentials(self) -> Credentials | None:
        """Mutual TLS and access control for every link (None: plain TCP, no access control)."""
        ...

    def zenoh_config(self) -> dict[str, Any]:
        """The session configuration (a JSON-able dict)."""
        ...

    def attach(self, session: zenoh.Session) -> None:
        """Called right after the session opens (start helpers here)."""
        ...

    def detach(self) -> None:
        """Called before the session closes."""
        ...


@dataclass(frozen=True)
class TransportTuning:
    """Transport knobs shared by every strategy."""

    lease_ms: int = 3000  # a frozen/partitioned peer is declared gone after ~lease (liveliness drops)
    open_timeout_ms: int = 2000  # per-locator connect timeout (zenoh default 10 s stalls discovery)
    batch_size: int = 8192  # small messages; smaller batches keep per-link buffers small at 50 peers
    # batches a link may queue per priority before a message that may be dropped is (zenoh: 2, at
    # most 16). Express messages take a batch each, and Zenoh waits only 1 ms for room, so with 2 a
    # burst on a loaded machine was dropped: 10 UAVs acknowledging one command at once lost 4
    # acknowledgements on the edge router's link to the flight recorder, and about 1 % of the poses.
    # Batches are allocated only when used, so an idle link costs nothing more.
    queue_commands: int = 16  # interactive priorities: commands, acknowledgements (rare, bursty)
    queue_data: int = 8  # data priorities: poses, telemetry
    # Zenoh's shared-memory transport between processes of one host (on in Zenoh 1.x by default).
    # Off: a session with it on runs a task that wakes its process ten times a second (the SHM
    # "handoff" reactor) whatever the traffic, which cost a lone UAV about a tenth of its CPU side
    # by side; it carries only payloads of 3 kB or more (Zenoh's threshold; a pose is 48 bytes),
    # such as the edge feed's batches of more than about 60 poses, and with it on a UAV of 100 had
    # 19 MB more RSS and lost 3.5 times as many poses (docs/benchmarks.md); and a payload it
    # carries lies in a buffer in /dev/shm, outside the link's TLS.
    shared_memory: bool = False

    def apply(self, cfg: dict[str, Any]) -> dict[str, Any]:
        cfg.setdefault("transport", {})
        cfg["transport"]["unicast"] = {"open_timeout": self.open_timeout_ms}
        c, d = self.queue_commands, self.queue_data
        queue = {"size": {"control": 2, "real_time": 2, "interactive_high": c, "interactive_low": c, "data_high": d,
                          "data": d, "data_low": 2, "background": 2}}
        cfg["transport"]["link"] = {"tx": {"lease": self.lease_ms, "batch_size": self.batch_size, "queue": queue}}
        cfg["transport"]["shared_memory"] = {"enabled": self.shared_memory}
        return cfg


def base_config(mode: str, connect: tuple[str, ...], listen: tuple[str, ...], tuning: TransportTuning,
                credentials: Credentials | None = None) -> dict[str, Any]:
    cfg: dict[str, Any] = {
        "mode": mode,
        "scouting": {
            "multicast": {"enabled": False},
            "gossip": {
                "enabled": True,
                "multihop": False,
                "autoconnect": {"peer": ["router", "peer"], "router": []},
                "autoconnect_strategy": {"peer": {"to_router": "always", "to_peer": "greater-zid"}},
            },
        },
        "connect": {"endpoints": list(connect)},
        "listen": {"endpoints": list(listen)},
    }
    if mode == "client":
        cfg["listen"] = {"endpoints": []}
    return secured(tuning.apply(cfg), credentials)


def secured(cfg: dict[str, Any], credentials: Credentials | None) -> dict[str, Any]:
    """``cfg`` secured with ``credentials`` (TLS, tls/ endpoints, access control), or as is without."""
    return cfg if credentials is None else credentials.secure(cfg)


def to_zenoh(cfg: dict[str, Any]) -> zenoh.Config:
    return zenoh.Config.from_json5(json.dumps(cfg))


@dataclass(frozen=True)
class Rendezvous:
    """Meet through a Zenoh router used as a gossip rendezvous.

    ``mode="peer"``: Zenoh's gossip scouting runs over the links that already exist (no UDP,
    no multicast): the router sends every newcomer the locators of the nodes it knows and
    forwards the newcomer's own, and each peer dials the ones it learns (``greater-zid``: one
    link per pair). The nodes form a direct peer-to-peer mesh; data never goes through the
    router, which may even die. Two peers that cannot reach each other get no data at all:
    since the regions rework of Zenoh 1.9 (eclipse-zenoh/zenoh#2096) a router no longer relays
    between its peers.
    ``mode="client"``: every node keeps one link to the router, which forwards all data
    (for UAVs behind carrier NAT that cannot accept connections).
    """

    endpoints: tuple[str, ...]
    mode: str = "peer"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    tuning: TransportTuning = field(default_factory=TransportTuning)
    credentials: Credentials | None = None
    name: str = "rendezvous"

    def __post_init__(self) -> None:
        if self.mode not in ("peer", "client"):
            raise ValueError(f"mode must be 'peer' or 'client', not {self.mode!r}")
        if not self.endpoints:
            raise ValueError("a rendezvous needs at least one router endpoint")

    def zenoh_config(self) -> dict[str, Any]:
        return base_config(self.mode, self.endpoints, self.listen, self.tuning, self.credentials)

    def attach(self, session: zenoh.Session) -> None:
        return None

    def detach(self) -> None:
        return None


@dataclass(frozen=True)
class StaticPeers:
    """Connect to a fixed list of endpoints (small labs, tests); gossip still meshes the rest."""

    endpoints: tuple[str, ...] = ()
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    tuning: TransportTuning = field(default_factory=TransportTuning)
    credentials: Credentials | None = None
    name: str = "static"

    def zenoh_config(self) -> dict[str, Any]:
        return base_config("peer", self.endpoints, self.listen, self.tuning, self.credentials)

    def attach(self, session: zenoh.Session) -> None:
        return None

    def detach(self) -> None:
        return None


T = TypeVar("T")
BIND_RETRIES = 3  # opens tried again after "Address already in use"


def open_retrying(open_session: Callable[[], T], timeout: float, what: str,
                  stopped: Callable[[], bool] = lambda: False) -> T:
    """``open_session()``, tried again after 0.5, 1, 2, 4, 4 ... s while Zenoh says it could not
    reach any endpoint, for at most ``timeout`` s (or until ``stopped()``); then its error. A port
    already in use is tried again up to BIND_RETRIES times (a connectivity that picks its own free
    port, such as the discovery proxy's scouting port, picks another: the first may have been taken
    by another process between its pick and Zenoh's bind, as 50 UAVs starting at once showed).

    Why: when a whole swarm starts at once on a loaded machine (100 UAV processes on 2 cores), an
    edge router can take longer than Zenoh's connect timeout to accept one more client, and a
    session that fails once would end a UAV or the runner that had only to wait. Any other error
    (a bad certificate, a bad configuration) is raised at once. ``what`` names the node in the log.
    """
    deadline = time.monotonic() + timeout
    delay = 0.5
    binds = 0
    while True:
        try:
            return open_session()
        except zenoh.ZError as exc:
            in_use = "Address already in use" in str(exc)
            binds += in_use
            if (("Unable to connect" not in str(exc) and not in_use) or binds > BIND_RETRIES or stopped()
                    or time.monotonic() + delay > deadline):
                raise
            log.warning("%s: could not join the swarm yet (%s); again in %.1f s", what, exc, delay)
            time.sleep(delay)
            delay = min(2 * delay, 4.0)
