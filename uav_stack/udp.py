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
