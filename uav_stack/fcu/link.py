"""One vehicle's UDP MAVLink endpoint: a non-blocking socket, learned peers, datagram parsing.

Like a PX4 SITL / mavlink-router UDP server endpoint, the vehicle streams to every peer
that has sent it a datagram (at most ``max_peers``; the least recently heard one is
replaced, and peers silent for ``peer_timeout_s`` are forgotten) plus static ``remotes``.

One peer is the vehicle's **owner**, its companion (the agent): the one configured, or else
the first peer heard. The owner is never replaced nor forgotten, so datagrams from other
ports cannot churn it out of the table (they only replace each other, counted in
``peers_evicted``). With ``owner_only`` (a virtual UAV, whose agent is its only client: ground
stations go through the agent's router) datagrams from anyone else are dropped before they
are parsed, counted in ``foreign_datagrams``.

:class:`InprocLink` is the same endpoint without a socket, for a vehicle whose agent runs in the
FCU's process (a pool of virtual UAVs): its datagrams go through an in-process channel
(:mod:`uav_stack.inproc`), reached as ``inproc:<name>``; peers, owner and coalescing are the same.
"""

from __future__ import annotations

import socket
from dataclasses import dataclass, field

from groundfloor.net import Addr
from uav_stack import inproc
from uav_stack.fcu.stats import FcuStats
from uav_stack.mav import mavlink
from uav_stack.mavcodec import MAVLink
from uav_stack.udp import drain

MAX_DATAGRAM = 1400  # bytes: stays under a 1500-byte MTU with IP/UDP headers


@dataclass
class UdpLink:
    listen: Addr = ("127.0.0.1", 0)
    remotes: tuple[Addr, ...] = ()
    max_peers: int = 8
    peer_timeout_s: float = 30.0
    owner: Addr | None = None  # never evicted nor expired; None: the first peer heard becomes the owner
    owner_only: bool = False  # drop datagrams from anyone but the owner
    peers: dict[Addr, float] = field(default_factory=dict)  # addr -> wall time last heard
    sock: socket.socket | None = None
    stats: FcuStats | None = None  # datagrams_out / send_errors are counted here
    coalesce: bool = True  # queue() joins messages into datagrams of <= MAX_DATAGRAM bytes
    dirty: list[UdpLink] | None = None  # shared list this link joins when it has queued output
    targets: list[Addr] = field(default_factory=list)
    _pending: list[bytes] = field(default_factory=list)
    _pending_len: int = 0

    def __post_init__(self) -> None:
        self.remotes = tuple((str(h), int(p)) for h, p in self.remotes)
        self._rebuild()

    def open(self) -> Addr:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:  # no SO_REUSEADDR: no other process can bind this port beside us and take the owner's traffic
            s.bind(self.listen)
            s.setblocking(False)
        except OSError:
            s.close()
            raise
        self.sock = s
        host, port = s.getsockname()[:2]
        return host, port

    @property
    def address(self) -> Addr:
        """Where the vehicle listens (once open)."""
        assert self.sock is not None
        host, port = self.sock.getsockname()[:2]
        return str(host), int(port)

    @property
    def url(self) -> str:
        """The FCU connection string an agent reaches this vehicle with (once open)."""
        host, port = self.address
        return f"udpout:{host}:{port}"

    def fileno(self) -> int:
        return self.sock.fileno() if self.sock is not None else -1

    def close(self) -> None:
        self._pending.clear()
        self._pending_len = 0
        if self.sock is not None:
            self.sock.close()
            self.sock = None

    def set_owner(self, addr: Addr, owner_only: bool | None = None) -> None:
        """Make ``addr`` the owner (e.g. the agent's socket, known once it is bound)."""
        self.owner = (str(addr[0]), int(addr[1]))
        if owner_only is not None:
            self.owner_only = owner_only

    def admits(self, addr: Addr) -> bool:
        """May a datagram from ``addr`` be looked at? (Everyone's, unless ``owner_only``.)"""
        return not self.owner_only or self.owner is None or addr == self.owner

    def recv(self, max_datagrams: int = 256) -> list[tuple[bytes, Addr]]:
        """Every pending datagram (bounded), without blocking."""
        return drain(self.sock, max_datagrams)

    def note_peer(self, addr: Addr, wall: float) -> bool:
        """Remember a peer we heard from (a valid MAVLink datagram); True if it is new."""
        if self.owner is None:
            self.owner = addr
        known = addr in self.peers
        self.peers[addr] = wall
        if not known:
            if len(self.peers) > self.max_peers:
                oldest = min((a for a in self.peers if a != self.owner), key=self.peers.__getitem__, default=None)
                if oldest is not None:
                    del self.peers[oldest]
                    if self.stats is not None:
                        self.stats.peers_evicted += 1
            self._rebuild()
        return not known

    def expire_peers(self, wall: float) -> None:
        stale = [a for a, t in self.peers.items() if wall - t > self.peer_timeout_s and a != self.owner]
        if stale:
            for a in stale:
                del self.peers[a]
            self._rebuild()

    def _rebuild(self) -> None:
        self.targets = list(dict.fromkeys([*self.remotes, *self.peers]))

    def queue(self, buf: bytes) -> None:
        """Send one packed message now, or (coalescing) with the rest of this wake-up's output."""
        if not self.coalesce:
            self.send(buf)
            return
        if self._pending_len + len(buf) > MAX_DATAGRAM:
            self.flush()
        if not self._pending and self.dirty is not None:
            self.dirty.append(self)
        self._pending.append(buf)
        self._pending_len += len(buf)

    def flush(self) -> None:
        if self._pending:
            data = b"".join(self._pending)
            self._pending.clear()
            self._pending_len = 0
            self.send(data)

    def send(self, buf: bytes) -> None:
        s = self.sock
        if s is None:
            return
        ok = err = 0
        for addr in self.targets:
            try:
                s.sendto(buf, addr)
                ok += 1
            except OSError:  # full buffer, unreachable peer...: drop, like UDP
                err += 1
        if self.stats is not None:
            self.stats.datagrams_out += ok
            self.stats.send_errors += err


@dataclass
class InprocLink(UdpLink):
    """A vehicle's endpoint on an in-process channel (``inproc:<name>``) instead of a UDP socket:
    the one peer it can hear is the channel's other end (its agent). No descriptor (``fileno`` -1):
    the host's loop polls it (:meth:`VirtualFcu.poll_io`)."""

    name: str = ""  # "" : a name of its own (:func:`uav_stack.inproc.unique_name`)
    capacity: int = inproc.DEFAULT_CAPACITY
    channel: inproc.InprocChannel | None = None

    def open(self) -> Addr:
        if not self.name:
            self.name = inproc.unique_name("fcu")
        self.channel = inproc.listen(self.name, self.capacity)
        return self.channel.listener.address

    @property
    def address(self) -> Addr:
        assert self.channel is not None
        return self.channel.listener.address

    @property
    def url(self) -> str:
        assert self.channel is not None
        return self.channel.url

    def fileno(self) -> int:
        return -1

    def close(self) -> None:
        self._pending.clear()
        self._pending_len = 0
        if self.channel is not None:
            self.channel.listener.close()
            self.channel = None

    def recv(self, max_datagrams: int = 256) -> list[tuple[bytes, Addr]]:
        ch = self.channel
        return ch.listener.recvfrom_all(max_datagrams) if ch is not None else []

    def send(self, buf: bytes) -> None:
        ch = self.channel
        if ch is None:
            return
        ok = err = 0
        end = ch.listener
        for addr in self.targets:  # (a static remote or a stale peer is not on the channel: an error, as unreachable)
            if end.sendto(buf, addr):
                ok += 1
            else:
                err += 1
        if self.stats is not None:
            self.stats.datagrams_out += ok
            self.stats.send_errors += err


class DatagramParser:
    """Parses whole UDP datagrams with a MAVLink decoder whose state is reset per datagram."""

    def __init__(self) -> None:
        self.mav = MAVLink(None)
        self.mav.robust_parsing = True

    def parse(self, data: bytes) -> tuple[list[mavlink.MAVLink_message], bool]:
        """(good messages, datagram was clean)."""
        d = self.mav
        try:
            msgs = d.parse_datagram(data)
        except Exception:  # noqa: BLE001 - any decoder failure is a bad datagram
            return [], False
        bad = [m for m in msgs if isinstance(m, mavlink.MAVLink_bad_data)]
        # valid frames of messages outside our dialect are skipped, not counted as bad
        good = [m for m in msgs if not isinstance(m, (mavlink.MAVLink_bad_data, mavlink.MAVLink_unknown))]
        clean = not bad and d.buf_len() == 0 and bool(msgs)
        return good, clean
