"""Counting the links of certificates the roster does not list (revoked, or never issued).

Zenoh 1.10 cannot check a revocation list when a TLS link opens, so a revoked certificate of
the swarm's CA still completes its handshake. Access control then grants it nothing (the roster
lists no subject for it, and the default is deny), but Zenoh drops its messages silently. This
watch makes the link visible: it reads the node's link events, and every link whose
certificate names an identity outside the roster is counted (``NodeStats.refused``) and
logged once. It cannot close the link: zenoh-python has no call for that.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import zenoh

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

    def poll(self, budget: int = 256) -> None:
        """Count the non-member links that opened since the last poll."""
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
