"""The runner's stop signals: SIGINT (Ctrl-C), SIGTERM and SIGHUP become a stop request, never a traceback.

A handler only counts the signal; the runner's loops look at :attr:`StopSignals.requested`
between two ticks (0.1 s) and stop the run from there, so no exception ever lands inside a
file write, a Zenoh call or a figure. What follows is the same for every signal: every child
process is stopped and the summary is written from what is on disk.

* The first signal: stop the UAVs gracefully (SIGTERM, 5 s to flush their records), analyse,
  draw the figures.
* A second signal (any of the three): stop faster, SIGKILL after 1 s, and skip the figures
  that have not been drawn yet; summary.json is still written.
* SIGHUP (the terminal went away): the console is silenced, since writing to a closed
  terminal fails, and the run stops as for SIGTERM.

The exit code of an interrupted run is 128 + the first signal's number (130 for Ctrl-C).
"""

from __future__ import annotations

import signal
from types import FrameType
from typing import Any

from groundfloor.process import on_stop_signals

HANDLED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
GRACE_S = 5.0  # SIGTERM -> SIGKILL for the children on a normal stop, plus GRACE_S_PER_PROCESS each
# 100 UAV processes stopping at once on 2 cores (closing sessions, final records) did not all exit
# within 5 s; the ones still writing lost their last second
GRACE_S_PER_PROCESS = 0.05
FAST_GRACE_S = 1.0  # ... after a second signal


class Interrupted(Exception):
    """Raised by the runner's own loop (never by the handler) when a stop was requested."""


class StopSignals:
    """Counts stop signals; install in the main thread, restore when done."""

    def __init__(self) -> None:
        self.received: list[int] = []
        self._old: dict[int, Any] = {}

    def install(self) -> StopSignals:
        self._old.update(on_stop_signals(self._on_signal, HANDLED))
        return self

    def restore(self) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.received.append(signum)

    @property
    def installed(self) -> bool:
        return bool(self._old)

    @property
    def requested(self) -> bool:
        return bool(self.received)

    @property
    def fast(self) -> bool:
        """A second signal came: stop without waiting, skip what can be skipped."""
        return len(self.received) >= 2

    @property
    def hangup(self) -> bool:
        return signal.SIGHUP in self.received

    @property
    def names(self) -> list[str]:
        return [signal.Signals(s).name for s in self.received]

    @property
    def exit_code(self) -> int:
        """128 + the first signal's number (the shell's convention), 0 if none."""
        return 128 + self.received[0] if self.received else 0

    def check(self) -> None:
        """Raise :class:`Interrupted` if a stop was requested (call between two steps of work)."""
        if self.received:
            raise Interrupted(self.names[0])
