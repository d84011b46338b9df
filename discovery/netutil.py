"""Two local socket helpers every layer above needs: a free port, and a bounded wait for a TCP listener.

They live here, in the lowest layer that uses one of them (the discovery proxy's scout port), so
the runtimes, the tests and the benchmarks share one copy.
"""

from __future__ import annotations

import random
import socket
import time
from collections.abc import Callable
from pathlib import Path

# Ports below this are often services' well-known ports; free_port never hands them out.
_LOWEST_PORT = 10000
_handed_out: set[int] = set()  # ports this process has handed out: never twice
_random = random.SystemRandom()  # not the random module's state, which forked processes share


def ephemeral_range() -> tuple[int, int]:
    """The kernel's range for automatic binds (``net.ipv4.ip_local_port_range``; 32768–60999 on Linux)."""
    try:
        lo, hi = (int(v) for v in Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
        return lo, hi
    except (OSError, ValueError):
        return 32768, 60999


def free_port(kind: int = socket.SOCK_STREAM, host: str = "127.0.0.1") -> int:
    """A port that is free on ``host`` now (``SOCK_STREAM`` for TCP, ``SOCK_DGRAM`` for UDP), taken
    from outside the kernel's ephemeral range.

    Why outside: the port is released before it is returned, and the caller binds it a moment
    (up to seconds, for a process that starts) later. A port of the ephemeral range can be
    taken in between by any socket that binds automatically: an outgoing TCP connection, a UDP
    socket's first send. That happened to a virtual UAV's ground-station port in a test run
    ("Address already in use"). Ports outside that range are taken only by a process that asks
    for one by number, as this function's other callers do: each picks at random among ~27,000
    and never hands one out twice.
    """
    lo, hi = ephemeral_range()
    candidates = [(_LOWEST_PORT, lo - 1), (hi + 1, 65535)]
    spans = [(a, b) for a, b in candidates if b >= a]
    total = sum(b - a + 1 for a, b in spans)
    for _ in range(200 if total else 0):
        k = _random.randrange(total)
        for a, b in spans:
            if k <= b - a:
                port = a + k
                break
            k -= b - a + 1
        if port in _handed_out:
            continue
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind((host, port))
            except OSError:
                continue
        _handed_out.add(port)
        return port
    with socket.socket(socket.AF_INET, kind) as s:  # no free port outside the range: any the kernel has
        s.bind((host, 0))
        port = int(s.getsockname()[1])
        _handed_out.add(port)
        return port


def wait_tcp(host: str, port: int, timeout: float, alive: Callable[[], bool] | None = None,
             what: str = "the service", period: float = 0.1) -> None:
    """Wait until something accepts TCP connections on host:port, at most ``timeout`` s.

    ``alive``, if given, says whether the process that should listen still runs: once it says no,
    waiting longer is pointless and the error says so. ``period`` (s) is the pause between attempts.
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if alive is not None and not alive():
            raise RuntimeError(f"{what} on {host}:{port} exited before listening")
        try:
            with socket.create_connection((host, port), timeout=0.5):
                return
        except OSError:
            time.sleep(period)
    raise RuntimeError(f"nothing listens on {host}:{port} after {timeout:.0f} s")
