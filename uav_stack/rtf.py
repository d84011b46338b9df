"""Real-time factor (RTF): simulated seconds per wall-clock second, from (wall, sim) samples.

Both ends of a MAVLink link measure it with :class:`RtfMeter`: the virtual FCU its own sim
clock against the wall (published as NAMED_VALUE_FLOAT ``RTF``), and the agent any FCU's
``time_boot_ms`` against its own wall clock (a real flight controller gives 1.0).

Not measured yet is NaN, never 0.0: 0.0 is a real measurement (a paused simulator), and NaN
stays NaN through arithmetic, so an unknown RTF cannot pass for "stopped". Where a wire or
file format needs a number, the writer converts: the agent's ``Telemetry.rtf`` and the
FCU's NAMED_VALUE_FLOAT send 0.0 ("unknown" on the wire), the trajectory CSV writes -1.
"""

from __future__ import annotations

import math
from collections import deque

REBOOT_BACKSTEP_S = 1.0  # sim time going back by more than this means the FCU restarted


class RtfMeter:
    """Sliding-window and whole-run RTF from ``add(wall, sim)`` calls (both in seconds).

    ``value`` is the RTF over about the last ``window_s`` of wall time, ``total()`` since the
    first sample; both are NaN until the samples span at least ``min_span_s`` of wall time. At
    most one sample per ``sample_every_s`` is kept (the newest one always counts as the end
    point), so the cost does not depend on how often ``add`` is called. If the sim time goes
    back by more than a second (the FCU rebooted), the meter starts over.
    """

    def __init__(self, window_s: float = 5.0, sample_every_s: float = 0.2, min_span_s: float = 0.5):
        self.window_s = window_s
        self.sample_every_s = sample_every_s
        self.min_span_s = min_span_s
        self._samples: deque[tuple[float, float]] = deque()
        self._first: tuple[float, float] | None = None
        self._last: tuple[float, float] | None = None
        self._value: float | None = None  # :attr:`value` until the next sample (read several times a tick)

    def restart(self) -> None:
        """Forget every sample (a new run of the sim clock begins)."""
        self._samples.clear()
        self._first = self._last = None
        self._value = None

    def add(self, wall: float, sim: float) -> None:
        s = self._samples
        if s and sim < s[-1][1] - REBOOT_BACKSTEP_S:
            self.restart()
        self._value = None
        self._last = (wall, sim)
        if self._first is None:
            self._first = self._last
        if not s or wall - s[-1][0] >= self.sample_every_s:
            s.append(self._last)
        # keep exactly one sample at or beyond the window's far edge
        while len(s) > 2 and wall - s[1][0] >= self.window_s:
            s.popleft()

    def _rate(self, since: tuple[float, float] | None) -> float:
        last = self._last
        if since is None or last is None or last[0] - since[0] < self.min_span_s:
            return math.nan
        return (last[1] - since[1]) / (last[0] - since[0])

    @property
    def value(self) -> float:
        """RTF over the last ``window_s`` of wall time; NaN until measured."""
        v = self._value
        if v is None:
            v = self._value = self._rate(self._samples[0] if self._samples else None)
        return v

    def total(self) -> float:
        """RTF since the first sample (or the last restart); NaN until measured."""
        return self._rate(self._first)
