"""Reading the discovery server's registry (for ``mrswarm discovery nodes`` and ground stations).

    nodes, stats = query_registry("10.0.0.2:7450", "alpha", key)

A query is authenticated with the swarm's key like a beacon, and answers only for that
swarm. The answer may span several datagrams; a lost one makes the query time out, and
the caller simply asks again.
"""

from __future__ import annotations

import os
import socket
import time
from typing import Any

from discovery.protocol import (
    MAX_DATAGRAM,
    MsgType,
    PartAssembler,
    ProtocolError,
    RegisteredNode,
    ReplayGuard,
    check_key,
    parse_registry,
    seal,
    unseal,
)
from discovery.proxy import parse_server, resolve
from groundfloor.errors import MrswarmError

RECV_BUFFER = 4 << 20  # bytes


class QueryTimeout(TimeoutError, MrswarmError):
    pass


def query_registry(server: str, swarm: str, key: str | bytes, timeout: float = 1.0,
                   attempts: int = 3) -> tuple[list[RegisteredNode], dict[str, Any]]:
    """The swarm's current members and the server's counters; raises :class:`QueryTimeout`."""
    addr = resolve(parse_server(server))
    k = check_key(key)
    fam = socket.AF_INET6 if ":" in addr[0] else socket.AF_INET
    guard = ReplayGuard()
    with socket.socket(fam, socket.SOCK_DGRAM) as s:
        # a large swarm's answer is hundreds of datagrams sent back to back: room for all of
        # them (the kernel caps this at net.core.rmem_max)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECV_BUFFER)
        for _ in range(max(1, attempts)):
            qid = int.from_bytes(os.urandom(4), "big")
            s.sendto(seal(MsgType.QUERY, swarm, k, [qid]), addr)
            parts = PartAssembler()
            stats: dict[str, Any] = {}
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                # a socket timeout, not select(): select() fails on descriptors above 1023 (a busy process)
                s.settimeout(max(1e-3, deadline - time.monotonic()))
                try:
                    data, src = s.recvfrom(MAX_DATAGRAM + 1)
                except TimeoutError:
                    break
                if src[:2] != addr:
                    continue
                try:
                    env = unseal(data, lambda sw: k if sw == swarm else None)
                    guard.check(env)
                    if env.type != MsgType.REGISTRY:
                        continue
                    rqid, part, n, rows, st = parse_registry(env.body, swarm)
                except ProtocolError:
                    continue
                if rqid != qid:
                    continue
                if st is not None:
                    stats = st
                whole = parts.add(rqid, part, n, rows)
                if whole is not None:
                    return whole, stats
    raise QueryTimeout(f"no answer from the discovery server at {server} for swarm {swarm!r} "
                       f"(down, unreachable, or a different key)")
