"""In-process datagram links: ``inproc:<name>``, a UDP socket pair's behaviour without a socket.

A pool of virtual UAVs (:mod:`uav_stack.pool`) hosts each agent and its vehicle of the virtual
FCU in one process. Their MAVLink link carries the same datagrams as over UDP (the same frames,
signing, the FCU link's pinning, acknowledgements and counters), but handed over through two
bounded queues, one each way, instead of a socket pair on the loopback: no system call, no
selector, no copy through the kernel.

The two ends behave as a UDP socket pair does:

* the **listening** end (the FCU's vehicle) registers a name while it is open; an agent reaches it
  with the FCU connection string ``inproc:<name>``, parsed where a UDP one is
  (:class:`~uav_stack.fcu_link.FcuLink.open`), so the agent does not know whether it is pooled;
* each end has an address (``("inproc:<name>", 0)`` for the listener, ``1`` for the connecting
  end), so that a receiver's sender checks (the FCU link's ``foreign_source``, the vehicle's owner)
  work as over UDP;
* a datagram that finds its receiver's queue full is dropped and counted there (``dropped``), as a
  UDP socket's full receive buffer drops it without the sender knowing; one sent to an end that
  is closed, or to an address that is not the peer's, goes nowhere and the send says so (False);
* datagrams keep their boundaries and their order.

Single-threaded by design (a pool's one loop); the queues' append and pop are atomic in CPython,
so a reader and a writer in two threads would not corrupt them either.
"""

from __future__ import annotations

import errno
import itertools
import threading
from collections import deque

from groundfloor.net import Addr

INPROC_SCHEME = "inproc"
# datagrams each way: more than a UDP socket's default receive buffer holds of the FCU link's
# datagrams (about 90 of 1400 bytes in 208 KiB), and far more than a tick of either side sends
DEFAULT_CAPACITY = 256

_channels: dict[str, InprocChannel] = {}  # name -> the listening channel, while it is open
_lock = threading.Lock()
_serial = itertools.count(1)


def parse_inproc_url(url: str) -> str | None:
    """The name of an ``inproc:<name>`` connection string, None for any other."""
    scheme, sep, name = url.partition(":")
    if not sep or scheme != INPROC_SCHEME:
        return None
    if not name:
        raise ValueError(f"FCU connection {url!r}: expected {INPROC_SCHEME}:NAME")
    return name


def unique_name(prefix: str) -> str:
    """A name no other channel of this process has had (``prefix`` and a serial number)."""
    return f"{prefix}.{next(_serial)}"


class DatagramQueue:
    """One direction: a bounded FIFO of datagrams, with what it carried and what it dropped."""

    __slots__ = ("_q", "capacity", "datagrams", "bytes", "dropped")

    def __init__(self, capacity: int = DEFAULT_CAPACITY):
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self._q: deque[bytes] = deque()
        self.capacity = capacity
        self.datagrams = 0  # queued (and so delivered, unless the receiver closes first)
        self.bytes = 0
        self.dropped = 0  # the queue was full

    def put(self, data: bytes) -> None:
        if len(self._q) >= self.capacity:
            self.dropped += 1
            return
        self._q.append(data)
        self.datagrams += 1
        self.bytes += len(data)

    def take(self, max_datagrams: int) -> list[bytes]:
        q = self._q
        if not q:
            return []
        if len(q) <= max_datagrams:
            out = list(q)
            q.clear()
            return out
        return [q.popleft() for _ in range(max_datagrams)]

    def clear(self) -> None:
        self._q.clear()

    def __len__(self) -> int:
        return len(self._q)

    def as_dict(self) -> dict[str, int]:
        return {"datagrams": self.datagrams, "bytes": self.bytes, "dropped": self.dropped, "queued": len(self._q)}


class InprocEnd:
    """One end of a channel: ``sendto`` the peer, ``recvfrom_all`` what it sent (with its address)."""

    def __init__(self, channel: InprocChannel, side: int):
        self.channel = channel
        self.address: Addr = (channel.host, side)
        self.peer: Addr = (channel.host, 1 - side)
        self._rx = channel.to_listener if side == 0 else channel.to_connector
        self._tx = channel.to_connector if side == 0 else channel.to_listener
        self.closed = False
        self._peer_end: InprocEnd | None = None

    def sendto(self, data: bytes, addr: Addr) -> bool:
        """Queue one datagram for ``addr``; False (nothing queued) when it cannot reach it: this end
        or the peer's is closed, or ``addr`` is not the peer. A full queue drops it, counted there."""
        peer = self._peer_end
        if self.closed or peer is None or peer.closed or addr != self.peer:
            return False
        self._tx.put(data)
        return True

    def recvfrom_all(self, max_datagrams: int = 256) -> list[tuple[bytes, Addr]]:
        """Every pending datagram (at most ``max_datagrams``), oldest first, each with its sender."""
        if self.closed:
            return []
        data = self._rx.take(max_datagrams)
        if not data:
            return []
        src = self.peer
        return [(d, src) for d in data]

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._rx.clear()  # what nobody will read is gone, as with a closed socket
            self.channel.ended(self)


class InprocChannel:
    """Both directions of one link and its two ends; registered under its name while the
    listening end is open (:func:`listen`, :func:`connect`)."""

    def __init__(self, name: str, capacity: int = DEFAULT_CAPACITY):
        self.name = name
        self.host = f"{INPROC_SCHEME}:{name}"  # the addresses' "host": what a log line shows
        self.to_listener = DatagramQueue(capacity)
        self.to_connector = DatagramQueue(capacity)
        self.listener = InprocEnd(self, 0)
        self.connector: InprocEnd | None = None

    @property
    def url(self) -> str:
        return self.host

    def ended(self, end: InprocEnd) -> None:
        if end is self.listener:
            with _lock:
                if _channels.get(self.name) is self:
                    del _channels[self.name]

    def as_dict(self) -> dict[str, object]:
        """Counters of both directions (the UAV's counters file)."""
        return {"name": self.name, "to_fcu": self.to_listener.as_dict(), "to_agent": self.to_connector.as_dict()}


def listen(name: str, capacity: int = DEFAULT_CAPACITY) -> InprocChannel:
    """Register a channel under ``name`` and return it (its listening end is ``channel.listener``).
    OSError (EADDRINUSE) if an open channel has the name already."""
    if not name or ":" in name:
        raise ValueError(f"in-process link name {name!r}: non-empty, without ':'")
    ch = InprocChannel(name, capacity)
    with _lock:
        if name in _channels:
            raise OSError(errno.EADDRINUSE, f"in-process link {name!r} is taken")
        _channels[name] = ch
    return ch


def connect(name: str) -> InprocEnd:
    """The connecting end of the channel listening under ``name``. OSError: ECONNREFUSED if
    nothing listens there, EISCONN if another end has connected already (a link has two ends)."""
    with _lock:
        ch = _channels.get(name)
        if ch is None:
            raise OSError(errno.ECONNREFUSED, f"no in-process link {name!r} in this process")
        if ch.connector is not None:
            raise OSError(errno.EISCONN, f"in-process link {name!r} has its other end already")
        end = ch.connector = InprocEnd(ch, 1)
    end._peer_end = ch.listener
    ch.listener._peer_end = end
    return end


def is_listening(name: str) -> bool:
    with _lock:
        return name in _channels


class InprocFcuSocket:
    """The agent's end of an in-process FCU link, with :class:`~uav_stack.fcu_udp.FcuUdpSocket`'s
    interface: what :class:`~uav_stack.fcu_link.FcuLink` reads, and ``write`` for its encoder."""

    def __init__(self, name: str):
        self.name = name
        self.end: InprocEnd | None = None
        self.fcu: Addr | None = None  # the listener's address: datagrams from elsewhere are not the FCU's
        self.write_errors = 0

    def open(self) -> InprocFcuSocket:
        self.end = connect(self.name)
        self.fcu = self.end.peer
        return self

    @property
    def channel(self) -> InprocChannel:
        assert self.end is not None
        return self.end.channel

    @property
    def local_address(self) -> Addr:
        assert self.end is not None
        return self.end.address

    def recv_all(self, max_datagrams: int = 64) -> list[tuple[bytes, Addr]]:
        assert self.end is not None
        return self.end.recvfrom_all(max_datagrams)

    def write(self, buf: bytes) -> None:
        """To the FCU; counted in ``write_errors`` when it cannot go (the FCU's end is closed)."""
        if self.end is None or self.fcu is None or not self.end.sendto(buf, self.fcu):
            self.write_errors += 1

    def close(self) -> None:
        if self.end is not None:
            self.end.close()
            self.end = None
