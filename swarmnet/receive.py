"""The one receive path: drain a ring channel from the owner's loop, accept or reject each sample.

Every subscription of :class:`~swarmnet.node.SwarmNode`, :class:`~swarmnet.observer.SwarmObserver`
and :class:`~swarmnet.feed.PoseFeed` delivers into a bounded Zenoh ``RingChannel`` (the
oldest sample is dropped when it is full), and the owner drains it with :func:`receive` from
its own loop. No Python runs on Zenoh's threads: a slow zenoh-python callback stalls the whole
session (measured: one slow callback delayed an unrelated 10 Hz topic from the same peer by up
to 11 s), whereas a ring nobody drains only loses its oldest samples. Draining in batches is
also much cheaper than waking a Python thread per message.

The path, top to bottom::

    drain(ring, budget)            at most `budget` samples per call, oldest first
      -> accept(key, payload)      decode + the stream's rules (swarmnet.messages.accept_*)
      -> Accepted(key, item, payload), or Rejected: counted in NodeStats.rejected[reason]

What happens to an accepted item (the netem shim, the neighbour table, the inbox) is the
owner's business; counting it as received is too, because the owner knows when it is
delivered.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING, Generic, NamedTuple, TypeVar

from swarmnet.messages import Rejected
from swarmnet.stats import NodeStats

if TYPE_CHECKING:
    from typing import TypeAlias

    import zenoh

    Ring: TypeAlias = zenoh.Subscriber[zenoh.handlers.Handler[zenoh.Sample]]

T = TypeVar("T")
Accept = Callable[[str, bytes], T]  # (key, payload) -> message, or raises Rejected

DRAIN_BUDGET = 10_000  # samples per subscription per call: a flood cannot hold the owner's loop in one drain


class Accepted(NamedTuple, Generic[T]):
    """A sample that passed its stream's rules."""

    key: str  # the Zenoh key it arrived on
    item: T  # the decoded message
    payload: bytes  # as received (the edge feed forwards it; the netem shim's rate limit counts its length)


def drain(ring: Ring, budget: int = DRAIN_BUDGET) -> Iterator[zenoh.Sample]:
    """The samples waiting in ``ring``, oldest first, at most ``budget`` of them; the rest stay
    for the next call. Never blocks."""
    for _ in range(budget):
        sample = ring.try_recv()
        if sample is None:
            return
        yield sample


def accept_each(arrivals: Iterable[tuple[str, bytes]], accept: Accept[T], stats: NodeStats) -> Iterator[Accepted[T]]:
    """Run ``accept`` on every ``(key, payload)``; count each rejection in ``stats`` and skip it."""
    for key, payload in arrivals:
        try:
            item = accept(key, payload)
        except Rejected as exc:
            stats.reject(exc.reason, key, exc.detail)
            continue
        yield Accepted(key, item, payload)


def receive(ring: Ring, accept: Accept[T], stats: NodeStats, budget: int = DRAIN_BUDGET) -> Iterator[Accepted[T]]:
    """The accepted samples waiting in ``ring`` (at most ``budget`` drained per call)."""
    return accept_each(((str(s.key_expr), s.payload.to_bytes()) for s in drain(ring, budget)), accept, stats)
