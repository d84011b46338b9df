"""Non-blocking UDP helpers shared by the virtual FCU's links and the agent's MAVLink router."""

from __future__ import annotations

import socket
import sys
from collections.abc import Callable

from groundfloor.net import Addr

_IP_RECVERR = 11  # <linux/in.h>; Python's socket module does not export it

def drain(sock: socket.socket | None, max_datagrams: int,
          refused: Callable[[], None] | None = None) -> list[tuple[bytes, Addr]]:
    """Every datagram pending on a non-blocking socket (at most ``max_datagrams``), with its sender.

    Errors the kernel reports for an earlier send (ECONNREFUSED from a peer that is not
    listening) are skipped, not raised; ``refused``, if given, is called on each ECONNREFUSED.
    """
    out: list[tuple[bytes, Addr]] = []
    if sock is None:
        return out
    for _ in range(max_datagrams):
        try:
            data, addr = sock.recvfrom(65535)
        except (BlockingIOError, InterruptedError):
            break
        except ConnectionRefusedError:
            if refused is not None:
                refused()
            continue
        except OSError:
            continue
        out.append((data, (addr[0], addr[1])))
    return out


def report_refusals(sock: socket.socket) -> bool:
    """Ask Linux to report ICMP errors (port unreachable) for an unconnected UDP socket's sends:
    the next receive or send then fails with ECONNREFUSED. False where it cannot (not Linux).

    Why: a sender can then tell that nobody listens at a destination and stop sending there.
    The errors also queue on the socket's error queue: empty it with :func:`clear_errors`."""
    if not sys.platform.startswith("linux"):
        return False
    sock.setsockopt(socket.IPPROTO_IP, getattr(socket, "IP_RECVERR", _IP_RECVERR), 1)
    return True


def clear_errors(sock: socket.socket, max_errors: int = 64) -> int:
    """Empty the error queue of a socket set up by :func:`report_refusals` (its entries count
    against the receive buffer); returns how many were there."""
    n = 0
    for _ in range(max_errors):
        try:
            sock.recvmsg(512, 512, socket.MSG_ERRQUEUE)
        except OSError:  # EAGAIN: empty
            break
        n += 1
    return n


def source_address_for(host: str, port: int = 9) -> str:
    """The local IPv4 address the kernel would send from to reach ``host`` (127.0.0.1 for a
    loopback host): a socket bound there is reachable only on that interface, never on all of
    them as one bound to 0.0.0.0 would be. No datagram is sent (a UDP connect only routes)."""
    dest = socket.gethostbyname(host)
    if dest.startswith("127."):
        return "127.0.0.1"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.connect((dest, port))
        return str(s.getsockname()[0])
