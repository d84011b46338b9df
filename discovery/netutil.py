"""Two local socket helpers every layer above needs: a free port, and a bounded wait for a TCP listener.

They live here, in the lowest layer that uses one of them (the discovery proxy's scout port), so
the runtimes, the tests and the benchmarks share one copy.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable


def free_port(kind: int = socket.SOCK_STREAM, host: str = "127.0.0.1") -> int:
    """A port the kernel has just found free on ``host`` (``SOCK_STREAM`` for TCP, ``SOCK_DGRAM`` for UDP).

    The port is released before it is returned: another process could take it in between, which
    on a loopback test machine is rare enough.
    """
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind((host, 0))
        port: int = s.getsockname()[1]
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
