"""Counting the links of certificates the roster does not list (revoked, or never issued), and the
connections a flood left no room for.

Zenoh 1.10 cannot check a revocation list when a TLS link opens, so a revoked certificate of
the swarm's CA still completes its handshake. Access control then grants it nothing (the roster
lists no subject for it, and the default is deny), but Zenoh drops its messages silently. This
watch makes the link visible: it reads the node's link events, and every link whose
certificate names an identity outside the roster is counted (``NodeStats.refused``) and
logged once. It cannot close the link: zenoh-python has no call for that.

It also reads, once a second, how many connection attempts the kernel turned away at the node's
TLS listener because its accept queue was full (``refused.accept_queue_full``, SYNs dropped; a
client tries again). Zenoh 1.10's TLS listener takes a pause of 100 ms after each handshake it
refuses (``TLS_ACCEPT_THROTTLE_TIME``, fixed), so it refuses at most 10 connections a second: under
a flood of junk connections ``refused.tls_handshake`` (swarmnet/security/zenoh_log.py) grows by 10
a second while the rest wait in that queue, and what does not fit in it is counted here.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING, Any

import zenoh

from swarmnet.own_sockets import kernel_drops, tcp_listeners

if TYPE_CHECKING:
    from swarmnet.stats import NodeStats

log = logging.getLogger(__name__)


class LinkWatch:
    """Reads ``session``'s link events from the owner's loop (a bounded ring, no callback)."""

    def __init__(self, session: zenoh.Session, members: frozenset[str], stats: NodeStats):
        self.members = members
        self.stats = stats
        self.seen: set[tuple[str, str]] = set()  # (identity, remote locator) of links already counted
        self._events: Any = session.info.declare_link_events_listener(zenoh.handlers.RingChannel(256), history=True)
        stats.refused["accept_queue_full"] += 0  # the key exists before it is counted (no resize while read)
        self._listeners: list[Any] = []
        self._drops_base: list[int] = []
        self._next_look = 0.0
        self._next_find = 0.0

    def _count_queue_drops(self) -> None:
        now = time.monotonic()
        if now < self._next_look:
            return
        self._next_look = now + 1.0
        if not self._listeners and now >= self._next_find:  # Zenoh's listeners: found once they exist
            self._next_find = now + 10.0
            try:
                self._listeners = tcp_listeners()
                self._drops_base = [kernel_drops(s) for s in self._listeners]
            except OSError:
                self._listeners = []
        total = 0
        for s, base in zip(self._listeners, self._drops_base, strict=True):
            try:
                total += kernel_drops(s) - base
            except OSError:
                pass
        self.stats.refused["accept_queue_full"] = max(self.stats.refused["accept_queue_full"], total)

    def poll(self, budget: int = 256) -> None:
        """Count the non-member links that opened since the last poll (and, once a second, the accept-queue drops)."""
        self._count_queue_drops()
        for _ in range(budget):
            ev = self._events.try_recv()
            if ev is None:
                return
            link = ev.link
            ident = link.auth_identifier
            if ev.kind != zenoh.SampleKind.PUT or ident is None or ident in self.members:
                continue
            key = (ident, str(link.dst))
            if key in self.seen:
                continue
            self.seen.add(key)
            self.stats.refused["non_member_link"] += 1
            log.warning("link from %s (%s): not a member of the swarm's roster (revoked or unknown); "
                        "access control denies it everything", ident, link.dst)

    def close(self) -> None:
        try:
            self._events.undeclare()
        except zenoh.ZError:
            pass
        for s in self._listeners:
            s.close()
        self._listeners = []
        self._drops_base = []
