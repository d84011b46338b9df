"""discovery.netutil.free_port hands out ports that automatic binds cannot take in the meantime."""

from __future__ import annotations

import socket
from pathlib import Path

from discovery.netutil import ephemeral_range, free_port


def test_free_ports_lie_outside_the_ephemeral_range_are_bindable_and_never_repeat() -> None:
    lo, hi = ephemeral_range()
    assert (lo, hi) == tuple(int(v) for v in Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
    ports = [free_port() for _ in range(100)] + [free_port(socket.SOCK_DGRAM) for _ in range(100)]
    assert len(set(ports)) == len(ports)
    assert all(not lo <= p <= hi and 10000 <= p <= 65535 for p in ports)
    for kind, port in ((socket.SOCK_STREAM, ports[0]), (socket.SOCK_DGRAM, ports[-1])):
        with socket.socket(socket.AF_INET, kind) as s:
            s.bind(("127.0.0.1", port))  # free when handed out: the caller can bind it

