"""The sweep's progress: a rich progress bar with the time left and a line per running run (in a terminal),
otherwise a line per run started and ended and a progress line every :data:`PLAIN_EVERY_S` seconds.

The time left is the wall time the remaining runs should take, divided by the runs flying at
once. A run's wall time is predicted from the runs of the campaign that have flown (this
sweep's and, after a resume, the earlier ones' from their ``slot.json``): the mean of its own
cell's, else its mission duration plus the mean time the runs took beyond their mission
(start-up, takeoff, analysis), else a first guess from the scenario (:func:`prior_wall_s`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from rich.console import Console, Group
from rich.live import Live
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from mrswarm.scenario import Scenario
from mrswarm.sweep.campaign import Slot
from mrswarm.sweep.launch import Flight

PLAIN_EVERY_S = 30.0
PRIOR_BASE_S = 12.0  # s a run takes besides its mission and climb: processes, ready, the summary and its figures
PRIOR_PER_UAV_S = 0.5
CLIMB_RATE = 1.5  # m/s, as the runner plans its takeoff (mrswarm/run/experiment.py)


def prior_wall_s(scn: Scenario) -> float:
    """A first guess of a run's wall time before any has flown."""
    return scn.duration + PRIOR_BASE_S + scn.flight.altitude / CLIMB_RATE + PRIOR_PER_UAV_S * len(scn.all_uavs())


def duration(seconds: float) -> str:
    """``45 s``, ``12 min``, ``1 h 05 min``."""
    s = max(0.0, seconds)
    if s < 90:
        return f"{s:.0f} s"
    if s < 3600:
        return f"{s / 60:.0f} min"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


@dataclass
class Estimator:
    """Predicts the wall time of a run from the runs flown so far."""

    by_cell: dict[int, list[float]] = field(default_factory=dict)
    overhead: list[float] = field(default_factory=list)  # wall time beyond the mission's duration

    def flown(self, slot: Slot, wall_s: float) -> None:
        self.by_cell.setdefault(slot.cell.index, []).append(wall_s)
        self.overhead.append(max(0.0, wall_s - slot.scenario.duration))

    def predict(self, slot: Slot) -> float:
        seen = self.by_cell.get(slot.cell.index)
        if seen:
            return sum(seen) / len(seen)
        if self.overhead:
            return slot.scenario.duration + sum(self.overhead) / len(self.overhead)
        return prior_wall_s(slot.scenario)

    def time_left(self, pending: list[Slot], running: list[Flight], parallel: int) -> float:
        work = sum(self.predict(s) for s in pending) + sum(max(self.predict(r.slot) - r.elapsed, 0.0) for r in running)
        return work / max(1, parallel)


class SweepProgress:
    """What the sweep shows while it flies."""

    def __init__(self, console: Console, total: int, done: int, live: bool) -> None:
        self.console = console
        self.total = total
        self.live = live and console.is_terminal
        self.done = done
        self.failed = 0
        self.waiting = ""  # why no further run starts now (parallel runs)
        self._last_plain = time.monotonic()
        self._progress = Progress(TextColumn("[bold]sweep[/]"), BarColumn(), MofNCompleteColumn(), TextColumn("runs"),
                                  TimeElapsedColumn(), TextColumn("{task.fields[left]}"), console=console)
        self._task = self._progress.add_task("sweep", total=total, completed=done, left="")
        self._live: Live | None = None
        self._running: list[Flight] = []

    def __enter__(self) -> SweepProgress:
        if self.live:
            self._live = Live(self._render(), console=self.console, refresh_per_second=2, transient=False)
            self._live.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._live is not None:
            self._live.update(self._render())
            self._live.__exit__(*exc)
            self._live = None

    def say(self, text: str) -> None:
        """A line above the bar (or a plain line)."""
        self.console.print(text, highlight=False, soft_wrap=not self.console.is_terminal)

    def update(self, done: int, failed: int, running: list[Flight], left_s: float | None) -> None:
        self.done, self.failed, self._running = done, failed, running
        left = f"about {duration(left_s)} left" if left_s is not None and done < self.total else ""
        self._progress.update(self._task, completed=done, left=left + (f", {failed} failed" if failed else ""))
        if self._live is not None:
            self._live.update(self._render())
            return
        now = time.monotonic()
        if running and now - self._last_plain >= PLAIN_EVERY_S:
            self._last_plain = now
            flying = "; ".join(f"{r.slot.label} for {duration(r.elapsed)}" for r in running)
            self.say(f"sweep: {done}/{self.total} runs done{f', {failed} failed' if failed else ''}; flying: {flying}"
                     + (f"; {left}" if left else ""))

    def _render(self) -> Group:
        rows = Table.grid(padding=(0, 1))
        rows.add_column(style="cyan", no_wrap=True)
        rows.add_column(no_wrap=True)
        rows.add_column(overflow="ellipsis", no_wrap=True)
        for r in self._running:
            rows.add_row(escape(r.slot.label), duration(r.elapsed), escape(r.last_line()))
        parts: list[Any] = [self._progress]
        if self._running:
            parts.append(rows)
        if self.waiting:
            parts.append(f"[dim]next run waits: {escape(self.waiting)}[/]")
        return Group(*parts)
