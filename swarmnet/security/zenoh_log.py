"""Counting the TLS handshakes a node's listener refused, from Zenoh's own log.

A connection without a certificate, with a certificate of another CA, or in plain TCP is
refused by Zenoh's TLS listener during the handshake, before any session exists: Python never
sees it. Zenoh logs one warning per refused handshake (target ``zenoh_link_tls::unicast``), to
the process's standard output. :class:`ZenohLogTap` puts a pipe in front of that output: every
line still reaches where it went before (the process's log), and each refused handshake is
counted in ``NodeStats.refused["tls_handshake"]``.

Zenoh 1.10's listener pauses 100 ms after each handshake it refuses (a fixed throttle), so it
refuses at most 10 a second: under a flood the count grows at that pace while the other connections
wait in the kernel's accept queue, each counted when Zenoh reaches it; what the full queue turns
away is counted apart (``refused.accept_queue_full``, swarmnet/security/links.py).

Zenoh's access-control denials are not counted here: Zenoh logs them only at trace level (one
line per key expression, as it caches decisions), and zenoh-python is built without Zenoh's
drop statistics. docs/security.md says what is counted where.
"""

from __future__ import annotations

import os
import re
import sys
import threading
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from swarmnet.stats import NodeStats

# Zenoh's log filter for the processes that tap it: errors, and the TLS listener's warnings (one
# per refused handshake). Zenoh's other warnings stay off, as in a process that does not tap it.
ZENOH_LOG_LEVEL = "error,zenoh_link_tls::unicast=warn"
_ANSI = re.compile(rb"\x1b\[[0-9;]*m")
_REFUSED = re.compile(rb"WARN.*zenoh_link_tls::unicast")


def is_refused_handshake(line: bytes) -> bool:
    """A line of Zenoh's log saying its TLS listener refused a handshake."""
    return _REFUSED.search(_ANSI.sub(b"", line)) is not None


class ZenohLogTap:
    """Reads the process's standard output through a pipe (a daemon thread), forwards every byte,
    counts refused handshakes. Install once per process, before the session opens."""

    def __init__(self, stats: NodeStats, level: str = ZENOH_LOG_LEVEL):
        import zenoh

        self.stats = stats
        stats.refused["tls_handshake"] += 0  # the key exists before the thread counts (no resize while read)
        sys.stdout.flush()
        self._out = os.dup(1)  # where standard output went: the log file or terminal
        r, w = os.pipe()
        os.dup2(w, 1)
        os.close(w)
        self._thread = threading.Thread(target=self._pump, args=(r,), name="zenoh-log-tap", daemon=True)
        self._thread.start()
        zenoh.init_log_from_env_or(level)

    def _pump(self, fd: int) -> None:
        buf = b""
        while True:
            try:
                chunk = os.read(fd, 65536)
            except OSError:
                return
            if not chunk:
                return
            try:
                os.write(self._out, chunk)
            except OSError:
                pass
            buf += chunk
            *lines, buf = buf.split(b"\n")
            for line in lines:
                if is_refused_handshake(line):
                    self.stats.refused["tls_handshake"] += 1
            buf = buf[-65536:]
