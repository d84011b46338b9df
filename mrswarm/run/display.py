"""The runner's live status: a rich panel on a terminal; otherwise (a pipe, a log, CI) plain lines.

Without a terminal: a line when the stage changes, one per milestone (every UAV acknowledged
``takeoff``, all airborne), and a progress line every :data:`LINE_EVERY_S` (the mission clock,
coverage, separation, RTF), each printed once.

It only reads: the scenario, the runner's :class:`~mrswarm.run.live.RunProgress`, the
:class:`~mrswarm.run.live.LiveMetrics` and the observer's view of every UAV.
"""

from __future__ import annotations

import math
import time

import numpy as np
from rich.console import Console, Group
from rich.live import Live
from rich.panel import Panel
from rich.progress_bar import ProgressBar
from rich.table import Table

from mrswarm.run.live import LiveMetrics, RunProgress, RunStage
from mrswarm.scenario import Scenario
from swarmnet.observer import SwarmObserver

LINE_EVERY_S = 5.0  # without a terminal: one status line this often


def status_table(scenario: Scenario, progress: RunProgress, metrics: LiveMetrics, obs: SwarmObserver | None) -> Group:
    """The live panel: stage and mission clock, agents per phase, coverage, separation, RTF, pose ages."""
    phases: dict[str, int] = {}
    rtfs = []
    transport, use = [], []  # ms, each UAV's p50 over its last second (from its telemetry)
    if obs is not None:
        for v in obs.uavs.values():
            if v.state is not None:
                phases[v.state.phase] = phases.get(v.state.phase, 0) + 1
            tm = v.telemetry
            if tm is not None:
                if tm.rtf > 0:
                    rtfs.append(tm.rtf)
                if tm.transport_ms >= 0:
                    transport.append(tm.transport_ms)
                if tm.use_ms >= 0:
                    use.append(tm.use_ms)
    elapsed = progress.elapsed()
    m = metrics
    t = Table.grid(padding=(0, 2))
    t.add_row("scenario", f"[bold]{scenario.name}[/] ({len(scenario.uav_list())} UAVs, swarm '{scenario.swarm}')")
    t.add_row("stage", str(progress.stage) + (f"  {elapsed:5.1f} / {scenario.duration:.0f} s" if elapsed is not None else "")
              + (f"  ({progress.detail})" if progress.detail else ""))
    t.add_row("agents", ", ".join(f"{k} {v}" for k, v in sorted(phases.items())) or "none heard yet")
    if m.coverage is not None:
        t.add_row("coverage", f"{100 * m.coverage:5.1f} %")
    t.add_row("min separation", "fewer than two UAVs airborne" if m.min_sep == math.inf
              else f"{m.min_sep_now:5.1f} m now, {m.min_sep:5.1f} m lowest")
    t.add_row("RTF", f"mean {np.mean(rtfs):.3f}, min {min(rtfs):.3f}" if rtfs else "not reported yet")
    t.add_row("pose age", (f"transport {float(np.median(transport)):.1f} ms" if transport else "transport not measured yet")
              + (f", at use {float(np.median(use)):.1f} ms" if use else "") + " (p50, median over UAVs)")
    bar = ProgressBar(total=scenario.duration, completed=min(elapsed or 0.0, scenario.duration), width=60)
    return Group(Panel(t, title="mrswarm run", expand=False), bar)


def fleet_rtf(obs: SwarmObserver | None) -> list[float]:
    """Each UAV's real-time factor as its telemetry last reported it (only those measured)."""
    if obs is None:
        return []
    return [v.telemetry.rtf for v in obs.uavs.values() if v.telemetry is not None and v.telemetry.rtf > 0]


def status_line(progress: RunProgress, metrics: LiveMetrics, obs: SwarmObserver | None, since: float | None = None) -> str:
    """The progress line for logs and pipes: the mission clock, coverage, separation and RTF.

    ``[mission] 35 of 120 s, coverage 40.1 %, separation 6.0 m (lowest 5.2 m), RTF 1.00 (lowest 0.98)``; before
    the mission, the stage's own clock (``since``, wall time it began) and the agents per phase."""
    now = time.time()
    elapsed = progress.elapsed()
    parts: list[str] = []
    if elapsed is not None:
        parts.append(f"{min(elapsed, progress.duration):.0f} of {progress.duration:.0f} s")
    else:
        if since is not None:
            parts.append(f"{now - since:.0f} s")
        phases: dict[str, int] = {}
        for v in (obs.uavs.values() if obs is not None else ()):
            if v.state is not None:
                phases[v.state.phase] = phases.get(v.state.phase, 0) + 1
        parts.append(", ".join(f"{k} {n}" for k, n in sorted(phases.items())) or "no UAV heard yet")
    if metrics.coverage is not None:
        parts.append(f"coverage {100 * metrics.coverage:.1f} %")
    if metrics.min_sep != math.inf:
        parts.append(f"separation {metrics.min_sep_now:.1f} m (lowest {metrics.min_sep:.1f} m)")
    rtfs = fleet_rtf(obs)
    if rtfs:
        parts.append(f"RTF {float(np.mean(rtfs)):.2f} (lowest {min(rtfs):.2f})")
    elif elapsed is not None:
        parts.append("RTF not reported yet")
    return f"[{progress.stage}] " + ", ".join(parts)


class Display:
    """Live status while a run flies. ``with Display(...) as display: ... display.refresh(observer)``."""

    def __init__(self, console: Console, live: bool, scenario: Scenario, progress: RunProgress, metrics: LiveMetrics):
        self.console = console
        self.use_live = live and console.is_terminal
        self.scenario = scenario
        self.progress = progress
        self.metrics = metrics
        self._live: Live | None = None
        self._last_line = 0.0  # wall time of the last progress line (without a terminal)
        self._last_text = ""  # ... and what it said
        self._stage: RunStage | None = None  # the stage a line was printed for
        self._stage_since: float | None = None  # wall time it began
        self._milestones = 0  # of progress.milestones, printed

    def __enter__(self) -> Display:
        if self.use_live:
            self._live = Live(self._table(None), console=self.console, refresh_per_second=4, transient=False)
            self._live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._live is not None:
            self._live.__exit__(None, None, None)
            self._live = None

    def refresh(self, obs: SwarmObserver | None) -> None:
        if self._live is not None:
            self._live.update(self._table(obs))
            return
        # without a terminal: a line when the stage changes and for each milestone, once; a progress line every
        # LINE_EVERY_S, never the same twice
        now = time.time()
        p = self.progress
        for text in p.milestones[self._milestones:]:  # under the stage they were reached in (the last one shown)
            self._print(f"[{self._stage or p.stage}] {text}")
        self._milestones = len(p.milestones)
        if p.stage != self._stage:
            self._stage, self._stage_since = p.stage, now
            self._print(f"[{p.stage}]")
            # the first progress line of a stage LINE_EVERY_S into it; at the end, at once: where the mission ended
            self._last_line = -math.inf if p.stage == RunStage.STOPPING else now
        if now - self._last_line < LINE_EVERY_S:
            return
        self._last_line = now
        line = status_line(p, self.metrics, obs, self._stage_since)
        if line != self._last_text:
            self._last_text = line
            self._print(line)

    def _print(self, line: str) -> None:
        # one line each, never folded at a pipe's 80 columns: a log is read and grepped line by line
        self.console.print(line, markup=False, highlight=False, soft_wrap=True)

    def _table(self, obs: SwarmObserver | None) -> Group:
        return status_table(self.scenario, self.progress, self.metrics, obs)
