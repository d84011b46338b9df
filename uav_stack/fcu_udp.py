"""The UDP socket of the agent's FCU link: bound to one address, and it knows who sent what.

pymavlink's UDP links cannot be locked to their FCU: ``udpout`` leaves the socket bound to
0.0.0.0 (any interface) and returns datagrams from any sender, ``udpin`` answers everyone
who ever sent it something. This socket instead

* binds to one local address: for ``udpout:HOST:PORT`` the address that routes to HOST
  (127.0.0.1 for a local FCU, or ``bind``), for ``udpin:HOST:PORT`` the HOST of the spec;
* reports each datagram's sender, so :class:`~uav_stack.fcu_link.FcuLink` can drop what does
  not come from its FCU (for ``udpout`` the FCU's address is known from the start; for
  ``udpin`` it is the sender of the first autopilot heartbeat, pinned by the link);
* writes only to that FCU.

Serial and TCP links stay pymavlink's (a serial line has no other sender; a TCP connection
is its own pin).
"""

from __future__ import annotations

import logging
import socket

from groundfloor.net import Addr
from uav_stack.udp import drain, source_address_for

log = logging.getLogger(__name__)

UDP_SCHEMES = ("udpout", "udpin", "udp")  # pymavlink: "udp:" listens, like "udpin:"


def parse_udp_url(url: str) -> tuple[str, str, int] | None:
    """``(mode, host, port)`` of a UDP FCU connection string (mode ``udpout`` or ``udpin``),
    or None for anything else (serial, TCP, broadcast: pymavlink's)."""
    scheme, sep, rest = url.partition(":")
    if not sep or scheme not in UDP_SCHEMES:
        return None
    host, sep, port_s = rest.rpartition(":")
    if not sep or not host:
        raise ValueError(f"FCU connection {url!r}: expected {scheme}:HOST:PORT")
    try:
        port = int(port_s)
    except ValueError:
        raise ValueError(f"FCU connection {url!r}: port {port_s!r} is not a number") from None
    if not 0 < port < 65536:
        raise ValueError(f"FCU connection {url!r}: port out of range")
    return ("udpout" if scheme == "udpout" else "udpin"), host, port


class FcuUdpSocket:
    """A non-blocking UDP socket for one FCU; ``write`` is what pymavlink's encoder calls."""

    def __init__(self, mode: str, host: str, port: int, bind: str | None = None):
        self.mode, self.host, self.port, self.bind = mode, host, port, bind
        self.sock: socket.socket | None = None
        self.fcu: Addr | None = None  # where the FCU is: datagrams from elsewhere are not its own
        self.write_errors = 0

    def open(self) -> FcuUdpSocket:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if self.mode == "udpout":
                self.fcu = (socket.gethostbyname(self.host), self.port)
                s.bind((self.bind or source_address_for(self.fcu[0]), 0))
            else:
                s.bind((self.host, self.port))
                if self.host in ("0.0.0.0", ""):
                    log.warning("FCU link listens on every interface (%s:%d); the first autopilot heartbeat pins "
                                "the FCU, so listen on the FCU's interface instead if you can", self.host, self.port)
            s.setblocking(False)
        except OSError:
            s.close()
            raise
        self.sock = s
        return self

    @property
    def local_address(self) -> Addr:
        assert self.sock is not None
        host, port = self.sock.getsockname()[:2]
        return str(host), int(port)

    def recv_all(self, max_datagrams: int = 64) -> list[tuple[bytes, Addr]]:
        """Every pending datagram (at most ``max_datagrams``) and its sender; errors for an
        earlier send (ECONNREFUSED while the FCU is not up yet) are skipped, not data."""
        assert self.sock is not None
        return drain(self.sock, max_datagrams)

    def write(self, buf: bytes) -> None:
        """To the FCU only; dropped (and counted) while it is unknown (udpin before its heartbeat)."""
        if self.sock is None or self.fcu is None:
            self.write_errors += 1
            return
        try:
            self.sock.sendto(buf, self.fcu)
        except OSError:  # full buffer, FCU not up yet: drop, like UDP
            self.write_errors += 1

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None
