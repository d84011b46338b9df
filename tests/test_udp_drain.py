"""Reading every pending datagram of a UDP socket, on real sockets."""

from __future__ import annotations

import os
import socket
import time

from uav_stack import udp


def _sock() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.setblocking(False)
    return s


def _closed_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = int(s.getsockname()[1])
    s.close()
    return port


def test_every_datagram_with_its_sender_in_order_and_bounded() -> None:
    rx, a, b = _sock(), _sock(), _sock()
    try:
        sent = []
        for k in range(10):
            src = a if k % 2 == 0 else b
            payload = bytes([k]) * (k * 150)  # an empty datagram first, then up to 1350 bytes
            src.sendto(payload, rx.getsockname())
            sent.append((payload, src.getsockname()))
        big = os.urandom(60_000)
        a.sendto(big, rx.getsockname())
        sent.append((big, a.getsockname()))
        time.sleep(0.05)  # loopback: queued at once, almost
        first = udp.drain(rx, 4)  # at most 4 per call: the rest wait
        rest = udp.drain(rx, 64)
        assert [(d, (h, p)) for d, (h, p) in first + rest] == sent
        assert all(type(h) is str and type(p) is int for _, (h, p) in first + rest)
        assert udp.drain(rx, 64) == []  # nothing left: no exception, an empty list
        assert udp.drain(None, 64) == []
    finally:
        for s in (rx, a, b):
            s.close()


def test_a_refused_send_is_counted_for_the_caller_never_data() -> None:
    """With refusals reported (IP_RECVERR), a datagram to a port nobody listens on comes back as
    ECONNREFUSED at the next read: the reader says so and returns no data for it."""
    s = _sock()
    try:
        assert udp.report_refusals(s)
        s.sendto(b"x", ("127.0.0.1", _closed_port()))
        time.sleep(0.05)
        refusals = []
        assert udp.drain(s, 64, lambda: refusals.append(1)) == []
        assert refusals == [1]
        assert udp.clear_errors(s) >= 1
        assert udp.drain(s, 64, lambda: refusals.append(1)) == [] and refusals == [1]
    finally:
        s.close()
