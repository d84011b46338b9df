"""One command to many UAVs, until every one has acknowledged it: re-sent with backoff, bounded in time.

The runner sends ``takeoff`` and ``start`` to the whole fleet. On a loaded machine (100 UAV
processes on 2 cores) a command or its acknowledgement can be late or lost in a full queue, so
a fixed wait with one re-send is not enough. Here the command goes to every UAV, the runner
sleeps on its observer's waker (an acknowledgement wakes it at once), and the UAVs that have not
answered are sent it again after 0.5 s, then 1, 2, 4, 4 ... s, until all answered or the
deadline passed. Commands are idempotent in the agent (a second ``takeoff`` answers "already
taking off"), and an acknowledgement of any of the sends counts. So does, if the caller gives
``took_effect``, the UAV's own state showing the command took effect (a ``takeoff`` UAV that
reports ``arming``): an acknowledgement is one message, sent once and droppable in a full
queue, whereas the state is published every second.

The deadline grows with the fleet: :func:`command_deadline` gives 6 s plus 0.15 s per UAV
(21 s for 100 UAVs), because the UAVs answer one by one on a shared machine.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from swarmnet.messages import CommandAck
from swarmnet.observer import PendingCommand, SwarmObserver

DEADLINE_BASE_S = 6.0
DEADLINE_PER_UAV_S = 0.15
FIRST_RESEND_S = 0.5  # the silent UAVs get the command again after this, then twice as long each time ...
MAX_BACKOFF_S = 4.0  # ... up to this


def command_deadline(n: int) -> float:
    """Seconds a command round to ``n`` UAVs may take."""
    return DEADLINE_BASE_S + DEADLINE_PER_UAV_S * n


@dataclass
class CommandRound:
    """The outcome of :func:`command_round`."""

    verb: str
    targets: list[int]
    sent_at: float  # wall time of the first send
    sends: int = 0
    acks: dict[int, CommandAck] = field(default_factory=dict)
    acked_at: dict[int, float] = field(default_factory=dict)  # wall time each UAV's first ack arrived
    by_state: dict[int, float] = field(default_factory=dict)  # UAVs whose state showed it first, and when
    complete_at: float | None = None  # wall time the last ack (or state) arrived

    gone: set[int] = field(default_factory=set)  # targets that stopped being expected (their process was lost)

    @property
    def missing(self) -> list[int]:
        return sorted(set(self.targets) - set(self.acks) - set(self.by_state) - self.gone)

    @property
    def refused(self) -> dict[int, str]:
        return {u: a.message for u, a in self.acks.items() if not a.ok}

    @property
    def duration(self) -> float | None:
        """Seconds from the first send to the last acknowledgement (None: not all acknowledged)."""
        return None if self.complete_at is None else self.complete_at - self.sent_at


def command_round(observer: SwarmObserver, verb: str, targets: list[int], timeout: float,
                  progress: Callable[[CommandRound], None] | None = None, clock: Callable[[], float] = time.time,
                  took_effect: Callable[[int], bool] | None = None, tick: Callable[[], None] | None = None,
                  active: Callable[[], Iterable[int]] | None = None, tick_every: float = 0.1,
                  tick_advances: bool = False) -> CommandRound:
    """Send ``verb`` to ``targets`` until each acknowledged or ``timeout`` s passed (see the module's docstring).

    ``progress`` is called after every wake-up (for a display); ``took_effect(uav)`` tells from
    the UAV's last reported state that it got the command; ``tick`` runs at least every
    ``tick_every`` s (the runner's supervision; it may raise to abort); ``active()`` names the
    targets still expected (a UAV whose process was lost is not waited for); ``tick_advances``: each
    ``tick`` moves ``clock`` on by itself (lock-step time), nothing is waited for. Never raises for
    missing or refused acknowledgements: the caller reads :attr:`CommandRound.missing` and ``refused``.
    """
    r = CommandRound(verb, sorted(targets), sent_at=clock())
    deadline = r.sent_at + timeout
    sent: list[PendingCommand] = [observer.command(verb, r.targets)]
    r.sends = 1
    backoff = FIRST_RESEND_S
    next_send = r.sent_at + backoff
    while True:
        if tick is not None:
            tick()
        if active is not None:
            r.gone = set(r.targets) - set(active())
        observer.poll()
        for p in sent:
            for uav, ack in p.acks.items():
                if uav not in r.acks:
                    r.acks[uav] = ack
                    r.acked_at[uav] = p.acked_at.get(uav, clock())
        if took_effect is not None:
            for uav in r.missing:
                if took_effect(uav):
                    r.by_state[uav] = clock()
        if progress is not None:
            progress(r)
        now = clock()
        if not r.missing:
            r.complete_at = max([*r.acked_at.values(), *r.by_state.values()], default=now)
            break
        if now >= deadline:
            break
        if now >= next_send:
            sent.append(observer.command(verb, r.missing))
            r.sends += 1
            backoff = min(backoff * 2.0, MAX_BACKOFF_S)
            next_send = now + backoff
        if tick_advances:
            continue
        wake = min(next_send, deadline, clock() + tick_every if tick is not None else math.inf)
        observer.waker.wait(max(0.0, wake - clock()))
    for p in sent:
        observer.pending.pop(p.cmd.cmd_id, None)
    return r
