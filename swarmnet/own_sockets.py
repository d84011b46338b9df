"""This process's own sockets, found by what they are bound to, and the kernel's drop counter of each.

Zenoh opens sockets the Python side has no handle on (its scouting sockets, its TLS listener).
They are still this process's descriptors: :func:`find_sockets` looks them up in ``/proc/self/fd``
and returns socket objects on descriptors of their own (duplicates: closing one leaves Zenoh's
open). :func:`kernel_drops` reads the count of what the kernel dropped at a socket (``SO_MEMINFO``:
datagrams a socket filter refused, a full receive queue, SYNs a full accept queue turned away).
Linux only.
"""

from __future__ import annotations

import os
import socket
import stat
import struct
from collections.abc import Callable

from groundfloor.net import Addr

SO_MEMINFO = getattr(socket, "SO_MEMINFO", 55)
SK_MEMINFO_DROPS = 8  # index of the drop counter in SO_MEMINFO's array of u32 (Linux >= 4.6)


def kernel_drops(sock: socket.socket) -> int:
    """What the kernel dropped at ``sock`` since it was made (its filter, a full queue)."""
    info = sock.getsockopt(socket.SOL_SOCKET, SO_MEMINFO, 4 * (SK_MEMINFO_DROPS + 1))
    return int(struct.unpack_from("I", info, 4 * SK_MEMINFO_DROPS)[0])


def find_sockets(match: Callable[[socket.socket], bool]) -> list[socket.socket]:
    """This process's sockets for which ``match`` is true, each on a descriptor of its own (close them)."""
    found = []
    for name in os.listdir("/proc/self/fd"):
        try:
            fd = int(name)
            if not stat.S_ISSOCK(os.stat(fd).st_mode):
                continue
            dup = os.dup(fd)
        except (ValueError, OSError):  # closed meanwhile
            continue
        try:
            s = socket.socket(fileno=dup)
        except OSError:
            os.close(dup)
            continue
        try:
            keep = match(s)
        except OSError:
            keep = False
        if keep:
            found.append(s)
        else:
            s.close()
    return found


def udp_sockets(addresses: set[Addr]) -> dict[Addr, socket.socket]:
    """This process's IPv4 UDP sockets bound to ``addresses``, by address."""
    def bound(s: socket.socket) -> bool:
        return s.family == socket.AF_INET and s.type == socket.SOCK_DGRAM and s.getsockname()[:2] in addresses

    out: dict[Addr, socket.socket] = {}
    for s in find_sockets(bound):
        addr = s.getsockname()[:2]
        if addr in out:
            s.close()
        else:
            out[addr] = s
    return out


def tcp_listeners() -> list[socket.socket]:
    """This process's listening TCP sockets (IPv4 and IPv6)."""
    def listening(s: socket.socket) -> bool:
        return (s.family in (socket.AF_INET, socket.AF_INET6) and s.type == socket.SOCK_STREAM
                and bool(s.getsockopt(socket.SOL_SOCKET, socket.SO_ACCEPTCONN)))

    return find_sockets(listening)
