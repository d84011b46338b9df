"""The runner's live status: a rich panel on a terminal, a plain line every 5 s otherwise.

It only reads: the scenario, the runner's :class:`~mrswarm.live.RunProgress`, the
:class:`~mrswarm.live.LiveMetrics` and the observer's view of every UAV.
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

from mrswarm.live import LiveMetrics, RunProgress
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
    t.add_row("agents", ", ".join(f"{k} {v}" for k, v in sorted(phases.items())) or "-")
    if m.coverage is not None:
        t.add_row("coverage", f"{100 * m.coverage:5.1f} %")
    t.add_row("min separation", "-" if m.min_sep == math.inf else f"{m.min_sep_now:5.1f} m now, {m.min_sep:5.1f} m lowest")
    t.add_row("RTF", f"mean {np.mean(rtfs):.3f}, min {min(rtfs):.3f}" if rtfs else "-")
    t.add_row("pose age", (f"transport {float(np.median(transport)):.1f} ms" if transport else "transport -")
              + (f", at use {float(np.median(use)):.1f} ms" if use else "") + " (p50, median over UAVs)")
    bar = ProgressBar(total=scenario.duration, completed=min(elapsed or 0.0, scenario.duration), width=60)
    return Group(Panel(t, title="mrswarm run", expand=False), bar)


def status_line(progress: RunProgress, metrics: LiveMetrics) -> str:
    """One line for logs and pipes: ``[stage] t=12s coverage=40.1% min_sep=6.0m``."""
    elapsed = progress.elapsed()
    cov = metrics.coverage
    return (f"[{progress.stage}]"
            + (f" {progress.detail}" if progress.detail else "")
            + (f" t={elapsed:.0f}s" if elapsed is not None else "")
            + (f" coverage={100 * cov:.1f}%" if cov is not None else "")
            + ("" if metrics.min_sep == math.inf else f" min_sep={metrics.min_sep:.1f}m"))


class Display:
    """Live status while a run flies. ``with Display(...) as display: ... display.refresh(observer)``."""

    def __init__(self, console: Console, live: bool, scenario: Scenario, progress: RunProgress, metrics: LiveMetrics):
        self.console = console
        self.use_live = live and console.is_terminal
        self.scenario = scenario
        self.progress = progress
        self.metrics = metrics
        self._live: Live | None = None
        self._last_line = 0.0  # wall time of the last plain line

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
        if time.time() - self._last_line < LINE_EVERY_S:
            return
        self._last_line = time.time()
        # one line each, never folded at a pipe's 80 columns: a log is read and grepped line by line
        self.console.print(status_line(self.progress, self.metrics), markup=False, highlight=False, soft_wrap=True)

    def _table(self, obs: SwarmObserver | None) -> Group:
        return status_table(self.scenario, self.progress, self.metrics, obs)
