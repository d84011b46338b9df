"""The per-node discovery proxy, as a :class:`~swarmnet.connectivity.Connectivity` strategy.

``BeaconDiscovery`` configures the node's Zenoh session to do *scouting on a unicast
loopback address* (``scouting.multicast.address = 127.0.0.1:P``): Zenoh binds its scouting
responder there, plus one scouting socket ``S_k`` per address 127.0.0.1..127.0.0.4 (zenoh
1.10.2 binds them to 0.0.0.0), and never sends a multicast packet: its own periodic scouts
go to ``127.0.0.1:P``, its own responder. Gossip is off: the discovery server is the only
source of peers' addresses.

Then a small thread in the same process (no root, no raw sockets):

1. sends a Scout to ``127.0.0.1:P`` from each 127.0.0.k; the session answers with its Hello
   (ZID, locators) from ``S_k``, which tells the proxy where to inject;
2. beacons that identity to the discovery server every period (1 s), authenticated
   with the swarm's key, and keeps the server's list of the swarm's other members;
3. sends each member's Hello to one of the ``S_k``, and Zenoh dials its locators
   directly, peer to peer, exactly as if it had scouted the member on a LAN.

The thread wakes once per period and when the server pushes news; it never touches the
agent's loop and costs well under 0.1 % of a core. A running Zenoh session cannot be told to
dial a new endpoint, but it dials what it scouts, which is why the proxy speaks scouting;
the protocol is in docs/discovery.md.
"""

from __future__ import annotations

import logging
import os
import select
import socket
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import zenoh

from discovery.netutil import free_port
from discovery.options import ProxyOptions
from discovery.protocol import (
    DEFAULT_PERIOD,
    DEFAULT_PORT,
    DEFAULT_WINDOW,
    MAX_DATAGRAM,
    ROLES,
    Beacon,
    MsgType,
    NodeEntry,
    PartAssembler,
    ProtocolError,
    ReplayGuard,
    beacon_body,
    check_key,
    parse_ack,
    parse_gone,
    parse_peers,
    seal,
    unseal,
    view_digest,
)
from discovery.scout_guard import GuardError, ScoutGuard
from discovery.wire import Hello, Locator, WireError, advertised_locators, decode_hello, encode_hello, encode_scout
from groundfloor.net import Addr
from swarmnet.connectivity import TransportTuning, base_config
from swarmnet.security.credentials import Credentials
from swarmnet.version import __version__

log = logging.getLogger(__name__)

LOCAL_HOST = "127.0.0.1"
SOFTWARE = f"mrswarm/{__version__}"


def parse_server(text: str) -> Addr:
    """``host:port`` (or a bare host, on the default port) of the discovery server."""
    host, sep, port = text.rpartition(":")
    if not sep or "]" in port:
        host, port = text, str(DEFAULT_PORT)
    host = host.strip("[]")
    try:
        p = int(port)
    except ValueError:
        raise ValueError(f"discovery server {text!r}: expected HOST:PORT") from None
    if not host or not 0 < p < 65536:
        raise ValueError(f"discovery server {text!r}: expected HOST:PORT")
    return host, p


def is_loopback_host(host: str) -> bool:
    return host in ("localhost", "::1") or host.startswith("127.")


def resolve(addr: Addr) -> Addr:
    """``(host, port)`` -> ``(ip, port)``, as datagrams from that address will show it."""
    family = socket.AF_INET6 if ":" in addr[0] else socket.AF_UNSPEC
    info = socket.getaddrinfo(addr[0], addr[1], family, socket.SOCK_DGRAM)
    return str(info[0][4][0]), int(info[0][4][1])


def source_address(server: Addr, family: int) -> str:
    """The local address the kernel sends to ``server`` from (the uplink binds to it, not to the wildcard)."""
    if is_loopback_host(server[0]):
        return LOCAL_HOST if family == socket.AF_INET else "::1"
    try:
        with socket.socket(family, socket.SOCK_DGRAM) as probe:
            probe.connect(server)  # no datagram: only picks the route
            return str(probe.getsockname()[0])
    except OSError:  # no route yet (no network at boot): the wildcard, for now
        return "::" if family == socket.AF_INET6 else "0.0.0.0"


@dataclass
class BeaconDiscovery:
    """Find the swarm through a discovery server; connect to every member directly.

    ``key`` authenticates this node's swarm; a ground station watching more swarms lists
    them in ``extra_swarms`` (swarm -> key). ``advertise`` replaces the announced
    addresses (whole locators, or hosts that replace the host of every listen locator),
    e.g. a public address. ``connect`` adds static endpoints (the edge router of the pose
    feed). The node's identity (swarm, id, role, realm) comes from the :class:`SwarmNode`
    that opens the session (``bind``), unless given here.
    """

    server: str
    key: str
    swarm: str | None = None
    node: int | None = None
    role: str | None = None
    realm: str | None = None
    extra_swarms: dict[str, str] = field(default_factory=dict)
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    connect: tuple[str, ...] = ()
    advertise: tuple[str, ...] = ()
    period: float = DEFAULT_PERIOD
    dial: str = "greater-zid"  # who dials a pair: only the larger ZID (one link per pair), or "always" both
    scout_port: int = 0  # 0: a free loopback UDP port, picked anew each time the config is built
    zid: str | None = None  # pin the session's Zenoh id (hex); default: random per session
    lanes: int = 4  # parallel dial lanes: scouting sockets on 127.0.0.1..127.0.0.K (see DiscoveryProxy.inject)
    tuning: TransportTuning = field(default_factory=TransportTuning)
    credentials: Credentials | None = None  # mutual TLS and access control (None: plain TCP)
    # the node's beacon token (tags its beacons and goodbye, docs/discovery.md); default: the one beside its certificate
    token: bytes | None = None
    name: str = "discovery"

    def __post_init__(self) -> None:
        self._pick_port = not self.scout_port  # picked here, so picked again for a retried open
        self.server_addr = parse_server(self.server)
        check_key(self.key)
        for s, k in self.extra_swarms.items():
            check_key(k, f"key of swarm {s!r}")
        if self.dial not in ("greater-zid", "always"):
            raise ValueError(f"dial must be 'greater-zid' or 'always', not {self.dial!r}")
        if not 1 <= self.lanes <= 8:
            raise ValueError("lanes must be 1..8")
        if not 0.1 <= self.period <= 30:
            raise ValueError("the beacon period must be within 0.1..30 s")
        if not self.listen:
            raise ValueError("a discovery node must listen on at least one endpoint (peers dial it)")
        self.proxy: DiscoveryProxy | None = None
        self.refused: Counter[str] = Counter()

    @classmethod
    def from_options(cls, opts: ProxyOptions, listen: tuple[str, ...], connect: tuple[str, ...] = (),
                     credentials: Credentials | None = None, tuning: TransportTuning | None = None) -> BeaconDiscovery:
        """From a node's :class:`~discovery.options.ProxyOptions` (``NetworkConfig.discovery``) and its endpoints."""
        return cls(server=opts.server, key=opts.read_key(), listen=tuple(listen), connect=tuple(connect),
                   advertise=opts.advertise, period=opts.period, extra_swarms=dict(opts.extra_swarms), dial=opts.dial,
                   zid=opts.zid, lanes=opts.lanes, credentials=credentials, tuning=tuning or TransportTuning())

    def bind(self, identity: Any, refused: Counter[str] | None = None) -> None:
        """Take the identity of the node that owns the session (fields not set explicitly), and the
        counter its refusals go into (``NodeStats.refused``: scouting datagrams its guard dropped,
        members' locators of another scheme than its own)."""
        if refused is not None:
            self.refused = refused
        self.swarm = self.swarm or identity.swarm
        self.node = self.node or identity.uav
        self.role = self.role or identity.role
        if self.realm is None:
            r = identity.realm
            self.realm = r.label if hasattr(r, "label") else str(r)

    def zenoh_config(self) -> dict[str, Any]:
        if self._pick_port:  # a fresh one: another process may have taken the last between its pick and the bind
            self.scout_port = free_port(socket.SOCK_DGRAM, LOCAL_HOST)
        cfg = base_config("peer", self.connect, self.listen, self.tuning, self.credentials)
        cfg["scouting"] = {
            # a *unicast loopback* "multicast" address: no packet ever leaves the host
            "multicast": {
                "enabled": True,
                "address": f"{LOCAL_HOST}:{self.scout_port}",
                "interface": ",".join(f"127.0.0.{k + 1}" for k in range(self.lanes)),
                "listen": True,
                "autoconnect": {"peer": ["router", "peer"]},
                "autoconnect_strategy": {"peer": {"to_router": "always", "to_peer": self.dial}},
            },
            # gossip off: a node linked to two swarms (a ground station) would otherwise hand
            # one swarm's addresses to the other, bypassing the server's per-swarm keys
            "gossip": {"enabled": False},
        }
        cfg["open"] = {"return_conditions": {"connect_scouted": False}}
        if self.zid:
            cfg["id"] = self.zid
        return cfg

    @property
    def schemes(self) -> tuple[str, ...]:
        """The link protocols this node speaks, so the only ones it dials: ``tls`` when secured."""
        from swarmnet.security.credentials import SECURE_SCHEMES

        if self.credentials is not None:
            return SECURE_SCHEMES
        return tuple(sorted({e.partition("/")[0] for e in self.listen}))

    def memberships(self) -> dict[str, bytes]:
        if self.swarm is None:
            raise ValueError("BeaconDiscovery has no swarm: pass swarm= or open it through a SwarmNode")
        out = {self.swarm: check_key(self.key)}
        out.update({s: check_key(k) for s, k in self.extra_swarms.items()})
        return out

    def attach(self, session: zenoh.Session) -> None:
        if self.node is None or self.role is None:
            raise ValueError("BeaconDiscovery needs the node id and role (pass them, or open it through a SwarmNode)")
        if self.role not in ROLES:
            raise ValueError(f"role must be one of {ROLES}")
        token = self.token
        if token is None and self.credentials is not None:
            token = self.credentials.beacon_token()
            if token is None:
                log.warning("discovery: no beacon token beside %s's certificate in %s: a server that binds beacons to "
                            "identities will not list this node (`mrswarm keys bundle` writes it)",
                            self.credentials.identity, self.credentials.keys)
        assert self.swarm is not None
        self.proxy = DiscoveryProxy(
            session=session, scout_port=self.scout_port, memberships=self.memberships(), role=self.role, node=self.node,
            tokens={self.swarm: token} if token else {},
            realm=self.realm or "virtual", server=self.server_addr, period=self.period, advertise=self.advertise,
            lanes=self.lanes, schemes=self.schemes, refused=self.refused, guard_required=self.credentials is not None,
        )
        self.proxy.start()

    def detach(self) -> None:
        if self.proxy is not None:
            self.proxy.stop()
            self.proxy = None

    def status(self) -> dict[str, Any]:
        return self.proxy.status() if self.proxy is not None else {}


class DiscoveryProxy:
    """The proxy's state and thread (one per session)."""

    def __init__(self, *, session: zenoh.Session, scout_port: int, memberships: dict[str, bytes], role: str, node: int,
                 realm: str, server: Addr, period: float = DEFAULT_PERIOD, advertise: tuple[str, ...] = (),
                 window: float = DEFAULT_WINDOW, retry_min: float = 1.0, retry_max: float = 30.0, lanes: int = 1,
                 schemes: tuple[str, ...] = ("tcp", "tls"), refused: Counter[str] | None = None, guard_required: bool = False,
                 tokens: dict[str, bytes] | None = None):
        self.session = session
        self.tokens = tokens or {}  # swarm -> this node's beacon token there: its beacons and goodbye carry the node tag
        self.schemes = schemes  # the link protocols this node dials: a member's locators of any other are never injected
        self.refused: Counter[str] = refused if refused is not None else Counter()
        for k in ("scouting", "foreign_scheme"):  # the keys exist before this thread counts (no resize while read)
            self.refused[k] += 0
        self.guard_required = guard_required  # a secured node does not run with unguarded scouting sockets
        self.scout_guard: ScoutGuard | None = None
        self._guard_dropped = 0
        self.scout_addr: Addr = (LOCAL_HOST, scout_port)
        self.keys = memberships
        self.role, self.node, self.realm = role, node, realm
        self.server_name = server
        try:  # a name that does not resolve yet (no network at boot) is retried at every beacon
            self.server: Addr | None = resolve(server)
        except OSError:
            self.server = None
        self.period = period
        self.advertise = advertise
        self.retry_min, self.retry_max = retry_min, retry_max
        self.guard = ReplayGuard(window)
        self.stats: Counter[str] = Counter()
        self.peers: dict[str, dict[tuple[str, int], NodeEntry]] = {s: {} for s in memberships}
        self._snaps: dict[str, PartAssembler] = {s: PartAssembler() for s in memberships}
        # zid -> (when we may hand its Hello to Zenoh again, the current retry delay)
        self._retry: dict[bytes, tuple[float, float]] = {}
        self.entry: NodeEntry | None = None
        self.lanes = lanes
        self.injectors: list[Addr] = []  # the session's scouting sockets (where Hellos are injected)
        self._rr = 0
        self.last_server_contact = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self.local = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.local.bind((LOCAL_HOST, 0))
        target = self.server or server
        fam = socket.AF_INET6 if ":" in target[0] else socket.AF_INET
        self.up = socket.socket(fam, socket.SOCK_DGRAM)
        wildcard = "::" if fam == socket.AF_INET6 else "0.0.0.0"  # only while the server's name does not resolve
        self.up.bind((source_address(self.server, fam) if self.server is not None else wildcard, 0))
        for s in (self.local, self.up):
            s.setblocking(False)

    # ---- lifecycle ------------------------------------------------------------------------------------
    def start(self, learn_timeout: float = 5.0) -> None:
        try:
            self.learn(learn_timeout)
            self.lock_scouting()
        except BaseException:
            self._close_sockets()
            raise
        self._thread = threading.Thread(target=self._run, name="mrswarm-discovery", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        try:  # wake the thread's select() now instead of at the next beacon
            self.local.sendto(b"", self.local.getsockname())
        except OSError:
            pass
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None
        if self.entry is not None:
            for swarm, key in self.keys.items():  # tell the server at once, so peers forget us now
                self._send_up(seal(MsgType.BYE, swarm, key, [self.role, self.node], token=self.tokens.get(swarm)))
        self._close_sockets()

    def lock_scouting(self) -> None:
        """From now on only this proxy (and the session itself) reach the session's scouting sockets
        (discovery/scout_guard.py): a Hello from anyone else is dropped by the kernel, and counted."""
        try:
            self.scout_guard = ScoutGuard.install([p for _, p in self.injectors], self.scout_addr[1], self.local.getsockname()[1])
        except GuardError as exc:
            if self.guard_required:
                raise RuntimeError(f"a secured node does not run with open scouting sockets: {exc}") from None
            log.warning("discovery: %s; any process that reaches them can make this node dial it", exc)

    def count_refused(self) -> None:
        """Scouting datagrams the guard dropped since the last look, into ``refused.scouting``."""
        if self.scout_guard is None:
            return
        total = self.scout_guard.dropped()
        if total > self._guard_dropped:
            if not self._guard_dropped:
                log.warning("discovery: scouting datagrams from another process than this node's proxy dropped "
                            "(a forged Hello?); counted in refused.scouting")
            self.refused["scouting"] += total - self._guard_dropped
            self._guard_dropped = total

    def dialable(self, e: NodeEntry) -> tuple[str, ...]:
        """The locators of ``e`` this node may dial: those of its own link protocols."""
        out = []
        for loc in e.locators:
            try:
                scheme = Locator.parse(loc).proto
            except ValueError:
                continue
            if scheme in self.schemes:
                out.append(loc)
        return tuple(out)

    def _close_sockets(self) -> None:
        if self.scout_guard is not None:
            self.scout_guard.close()
            self.scout_guard = None
        for s in (self.local, self.up):
            try:
                s.close()
            except OSError:
                pass

    # ---- the local Zenoh session ------------------------------------------------------------------------
    def _scout_once(self, sock: socket.socket, deadline: float) -> tuple[Hello, Addr] | None:
        """Scout our responder from ``sock``; the Hello and the scouting socket that sent it."""
        sock.sendto(encode_scout(), self.scout_addr)
        while True:
            ready, _, _ = select.select([sock], [], [], max(0.0, min(0.2, deadline - time.monotonic())))
            if not ready:
                return None
            try:
                data, src = sock.recvfrom(MAX_DATAGRAM)
            except BlockingIOError:
                continue
            try:
                return decode_hello(data), src[:2]
            except WireError as exc:
                self.stats["local_" + exc.reason] += 1

    def learn(self, timeout: float) -> NodeEntry:
        """Scout our own session: its Hello gives our locators, its source our injection address.

        With several lanes, the session has one scouting socket per loopback address
        127.0.0.1..127.0.0.K, and a scout from 127.0.0.k is answered from the k-th socket:
        scouting from each address finds every lane."""
        want = str(self.session.info.zid())
        deadline = time.monotonic() + timeout
        lanes: list[Addr] = []
        hello: Hello | None = None
        for k in range(self.lanes):
            src_ip = f"127.0.0.{k + 1}"
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
                try:
                    sock.bind((src_ip, 0))
                except OSError:
                    break  # no such loopback address here: fewer lanes
                got = None
                while got is None and time.monotonic() < deadline:
                    got = self._scout_once(sock, deadline)
                if got is None:
                    break
            h, src = got
            if h.zid_hex != want:
                raise RuntimeError(
                    f"scouting port {self.scout_addr[1]} answered by another Zenoh session (ZID {h.zid_hex}, "
                    f"ours {want}); two nodes picked the same port - restart this node")
            hello = hello or h
            if src not in lanes:
                lanes.append(src)
        if hello is None:
            raise RuntimeError(f"the Zenoh session does not answer scouts on {self.scout_addr[0]}:{self.scout_addr[1]} "
                               f"(is scouting.multicast configured by BeaconDiscovery?)")
        keep_lo = is_loopback_host((self.server or self.server_name)[0])
        locs = advertised_locators(hello.locators, self.advertise, keep_loopback=keep_lo)
        if not locs:
            raise RuntimeError(
                f"the session advertises no usable locator (listening on {', '.join(hello.locators) or 'nothing'}"
                f"{'' if keep_lo else ', loopback dropped: the server is remote'}); set network.listen or advertise")
        self.injectors = lanes
        self.entry = NodeEntry(self.role, self.node, self.realm, SOFTWARE, hello.zid, hello.whatami, locs)
        log.info("discovery: zid %s at %s; %d dial lane(s); beaconing to %s:%d", want, ", ".join(locs), len(lanes),
                 *self.server_name)
        return self.entry

    def inject(self, e: NodeEntry, now: float, delay: float | None = None) -> None:
        """Hand a member's Hello to our session, which dials it (if it is the one to dial).

        Zenoh handles the Hellos of one scouting socket one at a time, and a dial to an
        unreachable locator holds up every later Hello of that socket for ``open_timeout``
        (2 s). So first Hellos go round-robin to all lanes but the last (several dials run in
        parallel), retries go to the last lane (an unreachable member never delays a newcomer),
        and retries back off exponentially: ``delay`` is when to try again."""
        lanes = self.injectors
        assert lanes
        locators = self.dialable(e)
        if not locators:  # nothing of this node's scheme (counted once, when the entry came)
            self._retry[e.zid] = (now + self.retry_max, self.retry_max)
            return
        if delay is not None and len(lanes) > 1:
            lane = lanes[-1]
        else:
            fresh = lanes[:-1] or lanes
            lane = fresh[self._rr % len(fresh)]
            self._rr += 1
        try:
            self.local.sendto(encode_hello(Hello(e.zid, e.whatami, locators)), lane)
            self.stats["injected"] += 1
        except (OSError, ValueError) as exc:
            self.stats["inject_error"] += 1
            log.debug("inject %s failed: %s", e.zid_hex, exc)
        d = self.retry_min if delay is None else delay
        self._retry[e.zid] = (now + d, d)

    def linked(self) -> set[str]:
        try:
            return {str(z) for z in self.session.info.peers_zid()}
        except Exception:  # session closing under us
            return set()

    # ---- the loop -----------------------------------------------------------------------------------------
    def _run(self) -> None:
        next_beacon = 0.0
        while not self._stop.is_set():
            try:
                now_m = time.monotonic()
                if now_m >= next_beacon:
                    self.count_refused()
                    self.beacon()
                    self.reinject(time.time())
                    jitter = 0.9 + 0.2 * int.from_bytes(os.urandom(2), "big") / 65535.0  # no lock-step beacons
                    next_beacon = now_m + self.period * jitter
                try:
                    ready, _, _ = select.select([self.up, self.local], [], [], max(0.0, next_beacon - time.monotonic()))
                except (OSError, ValueError):  # sockets closed by stop()
                    return
                if self.up in ready:
                    self._drain_up()
                if self.local in ready:
                    self._drain_local()
            except Exception:  # a bug must not end discovery for the life of the process
                self.stats["internal_error"] += 1
                log.exception("discovery proxy error")
                self._stop.wait(self.period)

    def beacon(self) -> None:
        assert self.entry is not None
        for swarm, key in self.keys.items():
            with self._lock:
                view = view_digest(self.peers[swarm].values())
            self._send_up(seal(MsgType.BEACON, swarm, key, beacon_body(Beacon(self.entry, view, self.period)),
                               token=self.tokens.get(swarm)))
            self.stats["beacons"] += 1

    def _send_up(self, data: bytes) -> None:
        try:
            if self.server is None:
                self.server = resolve(self.server_name)
            self.up.sendto(data, self.server)
        except OSError as exc:  # no name resolution or route yet, network down: try again next period
            self.stats["send_error"] += 1
            log.debug("beacon to %s failed: %s", self.server_name, exc)

    def reinject(self, now: float) -> None:
        """Members we still have no link to get their Hello again (a dial may have failed),
        after 1, 2, 4, ... 30 s; the delay starts over when the member changes or links."""
        linked = self.linked()
        with self._lock:
            members = {e.zid: e for table in self.peers.values() for e in table.values()}
        for zid in [z for z in self._retry if z not in members]:
            del self._retry[zid]
        for zid, e in members.items():
            if e.zid_hex in linked:
                self._retry.pop(zid, None)
                continue
            due, d = self._retry.get(zid, (0.0, self.retry_min / 2))
            if now >= due:
                self.inject(e, now, min(2 * d, self.retry_max))
                self.stats["retries"] += 1

    def _drain_local(self) -> None:
        for _ in range(64):
            try:
                self.local.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, OSError):
                return
            self.stats["local_ignored"] += 1

    def _drain_up(self) -> None:
        for _ in range(256):
            try:
                data, src = self.up.recvfrom(MAX_DATAGRAM + 1)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                self.stats["recv_error"] += 1
                return
            self.handle(data, src[:2], time.time())

    def handle(self, data: bytes, src: Addr, now: float) -> None:
        """One datagram from the server. Never raises on bad input: drops and counts it."""
        if src != self.server:
            self.stats["drop_not_from_server"] += 1
            return
        try:
            env = unseal(data, self.keys.get)
            self.guard.check(env, now)
            if env.type == MsgType.PEERS:
                self._on_peers(env.swarm, parse_peers(env.body), now)
            elif env.type == MsgType.GONE:
                gone = parse_gone(env.body)
                with self._lock:
                    for k in gone:
                        self.peers[env.swarm].pop(k, None)
                self.stats["gone"] += len(gone)
            elif env.type == MsgType.ACK:
                parse_ack(env.body)
                self.stats["acks"] += 1
            else:
                raise ProtocolError("unexpected_type", env.type.name)
        except ProtocolError as exc:
            self.stats["drop_" + exc.reason] += 1
            log.debug("dropped a datagram from the server: %s", exc)
            return
        self.last_server_contact = now

    def _on_peers(self, swarm: str, p: Any, now: float) -> None:
        me = self.entry.key if self.entry is not None else None
        fresh = [e for e in p.entries if e.key != me]
        if p.snap == 0:  # a push: new or changed members
            self.stats["pushes"] += 1
            self._update(swarm, fresh, replace=False, now=now)
            return
        snaps = self._snaps[swarm]
        before = snaps.inconsistent
        whole = snaps.add(p.snap, p.part, p.parts, fresh)
        if snaps.inconsistent != before:  # parts that disagree on the snapshot's size: it starts over
            self.stats["drop_inconsistent_snapshot"] += 1
        if whole is not None:
            self.stats["snapshots"] += 1
            self._update(swarm, whole, replace=True, now=now)

    def _update(self, swarm: str, entries: list[NodeEntry], replace: bool, now: float) -> None:
        with self._lock:
            table = self.peers[swarm]
            new = [e for e in entries if table.get(e.key) != e]
            if replace:
                table.clear()
            for e in entries:
                table[e.key] = e
        for e in new:
            if len(self.dialable(e)) < len(e.locators):
                self.refused["foreign_scheme"] += 1
                log.warning("discovery: %s %d (zid %s) announces %s; this node dials only %s", e.role, e.node, e.zid_hex,
                            ", ".join(e.locators), "/".join(self.schemes))
        if new:
            linked = self.linked()
            for e in new:
                if e.zid_hex not in linked:
                    self.inject(e, now)

    def status(self) -> dict[str, Any]:
        with self._lock:
            members = {s: sorted(f"{r}{n}" for r, n in t) for s, t in self.peers.items()}
        return {
            "zid": self.entry.zid_hex if self.entry else None,
            "locators": list(self.entry.locators) if self.entry else [],
            "injectors": [f"{h}:{p}" for h, p in self.injectors],
            "scouting_guarded": self.scout_guard is not None,
            "refused": dict(self.refused),
            "server_contact_age": (time.time() - self.last_server_contact) if self.last_server_contact else None,
            "members": members,
            "stats": dict(self.stats),
        }
