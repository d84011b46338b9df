"""Non-blocking UDP helpers shared by the virtual FCU's links and the agent's MAVLink router."""

from __future__ import annotations

import socket

Addr = tuple[str, int]


def drain(sock: socket.socket | None, max_datagrams: int) -> list[tuple[bytes, Addr]]:
    """Every datagram pending on a non-blocking socket (at most ``max_datagrams``), with its sender.

    Errors the kernel reports for an earlier send (ECONNREFUSED from a peer that is not
    listening) are skipped, not raised.
    """
    out: list[tuple[bytes, Addr]] = []
    if sock is None:
        return out
    for _ in range(max_datagrams):
        try:
            data, addr = sock.recvfrom(65535)
        except (BlockingIOError, InterruptedError):
            break
        except OSError:
            continue
        out.append((data, (addr[0], addr[1])))
    return out


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
