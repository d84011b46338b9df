"""A run folder's results: the numbers (mrswarm/results/analysis.py), the figures (mrswarm/results/plots.py), one summary.json.

Used by the runner when a run stops, and by ``mrswarm results <run dir>``, which rebuilds the
same files later from what the run folder holds (the scenario the run flew is saved in it as
``scenario.yaml``).
"""

from __future__ import annotations

import csv
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from groundfloor.errors import MrswarmError
from mrswarm.records.summary import LinkAge, RunInfo, RunSummary
from mrswarm.results.analysis import analyse_run
from mrswarm.results.plots import plot_pose_age, plot_run
from mrswarm.results.wording import metres, plural
from mrswarm.scenario import Scenario, ScenarioError, load_scenario


class ResultsError(MrswarmError):
    """A folder that cannot be analysed (not a run folder, or its records are unreadable)."""


def summarise_run(run_dir: Path, scenario: Scenario, stop: Callable[[], bool] = lambda: False,
                  info: RunInfo | None = None) -> RunSummary:
    """Analyse ``run_dir``, draw its figures and write its ``summary.json`` (once, atomically).

    ``info``: the runner's own record of the run (what run.json holds, or would, had the disk taken
    it); default: run.json. A figure that fails to draw is reported in the summary (``plot_error``)
    rather than losing the numbers; once ``stop()`` says so (a second Ctrl-C), the figures not drawn
    yet are skipped. A file the disk refuses (a figure, ``transport_links.csv``, summary.json) never
    ends the analysis: it is listed in ``degraded``, and a summary.json that cannot be written into
    the run folder is written to the temporary folder instead (``write_error`` says where), or
    nowhere (``write_error`` says so); the caller prints the summary in any case.
    """
    if info is None:
        try:
            info = RunInfo.load(run_dir / "run.json", scenario.name)
        except ValueError as exc:
            raise ResultsError(str(exc)) from None
    summary, data = analyse_run(run_dir, scenario, info)
    if data is not None and data.links and summary.network and summary.network.transport_age_links:
        path = run_dir / "transport_links.csv"
        try:
            write_link_ages(path, data.links)
            summary.network.transport_age_links.csv = str(path)
        except OSError as exc:
            summary.degraded.append(f"{path.name} not written: {exc.strerror or exc}")
            discard(path)
    if data is not None and stop():
        summary.plot_error = "skipped: the run was asked to stop fast (mrswarm results draws it later)"
    elif data is not None:
        path = run_dir / f"{scenario.name}.png"
        try:
            if scenario.world is not None:  # the world and the trajectories (docs/world.md)
                from mrswarm.results.world_plots import plot_world

                plot_world(path, scenario, data)
            else:
                plot_run(path, scenario, data)
            summary.plot = str(path)
        except Exception as exc:  # a plotting failure must not lose the numbers
            summary.plot_error = repr(exc)
            if isinstance(exc, OSError):
                summary.degraded.append(f"{path.name} not written: {exc.strerror or exc}")
                discard(path)  # what the disk took of it is no figure
        net = summary.network
        if data.pose_age is not None and net and net.pose_age_over_time:
            path = run_dir / "pose_age.png"
            if stop():
                net.pose_age_over_time.plot_error = "skipped: the run was asked to stop fast"
            else:
                try:
                    plot_pose_age(path, data.pose_age, net.netem.changes if net.netem else [], data.t_end - data.t0)
                    net.pose_age_over_time.plot = str(path)
                except Exception as exc:  # a plotting failure must not lose the numbers
                    net.pose_age_over_time.plot_error = repr(exc)
                    if isinstance(exc, OSError):
                        summary.degraded.append(f"{path.name} not written: {exc.strerror or exc}")
                        discard(path)
    write_summary(summary, run_dir)
    return summary


def discard(path: Path) -> None:
    """Remove what a refused write left of a file (a read-only disk refuses that too: then it stays)."""
    try:
        path.unlink(missing_ok=True)
    except OSError:
        pass


def write_summary(summary: RunSummary, run_dir: Path) -> None:
    """summary.json into the run folder; if the disk refuses it, into the temporary folder (``write_error`` says
    where, or that it is nowhere). Never raises."""
    target = run_dir / "summary.json"
    try:
        summary.write(target)
        return
    except OSError as exc:
        why = f"{target}: {exc.strerror or exc}"
    summary.degraded.append(f"summary.json not written into the run folder ({why})")
    fallback = Path(tempfile.gettempdir()) / f"mrswarm-{run_dir.name}-summary.json"
    summary.write_error = f"{why}; written to {fallback} instead"
    try:
        summary.write(fallback)
    except OSError as exc:
        summary.write_error = f"{why}; nor to {fallback} ({exc.strerror or exc}): only printed here"


def write_link_ages(path: Path, links: list[LinkAge]) -> None:
    """``transport_links.csv``: the transport age of every link, one row per ``sender->receiver``."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(("link", "n", "p50_ms", "p99_ms", "max_ms"))
        for lk in links:
            w.writerow((lk.link, lk.n, "" if lk.p50 is None else lk.p50, "" if lk.p99 is None else lk.p99,
                        "" if lk.max is None else lk.max))


def rebuild_results(run_dir: Path) -> RunSummary:
    """``mrswarm results``: summary.json and the figures again, from the files of a run folder."""
    if not run_dir.is_dir():
        raise ResultsError(f"{run_dir}: not a folder")
    scenario_file = run_dir / "scenario.yaml"
    if not scenario_file.exists():
        raise ResultsError(f"{run_dir}: no scenario.yaml (is it a folder written by `mrswarm run`?)")
    try:
        scenario = load_scenario(scenario_file)
    except ScenarioError as exc:
        raise ResultsError(str(exc)) from None
    return summarise_run(run_dir, scenario)


RECENT = 15  # runs listed by `mrswarm results` without a folder


def results_from_recording(path: Path, out: Path | None) -> Path:
    """``mrswarm results run.mcap``: export the run folder, which the caller then summarises."""
    from mrswarm.recorder.export import ExportError, default_out, export_csv

    try:
        info = export_csv(path, out or default_out(path))
    except ExportError as exc:
        raise ResultsError(str(exc)) from None
    if info["uavs"] == 0:
        raise ResultsError(f"{path}: no pose was recorded")
    return Path(info["out"])


def run_outcome(run_dir: Path) -> str:
    """One line of what a run folder's summary.json says: its outcome in words."""
    try:
        s = RunSummary.load(run_dir / "summary.json")
    except FileNotFoundError:
        return "no summary yet (flying, or stopped hard: mrswarm results DIR writes it)"
    except (OSError, ValueError) as exc:
        return f"summary.json unreadable ({exc.__class__.__name__})"
    if s.aborted:
        return f"aborted: {s.aborted}"
    if s.error:
        return s.error
    parts = [f"{s.uavs_recorded} UAVs"]
    if s.duration_s:
        parts.append(f"{s.duration_s:.0f} s")
    if s.coverage:
        parts.append(f"coverage {100 * s.coverage.final:.1f} %")
    sep = s.separation
    if sep and sep.min_m is not None:
        parts.append(f"closest {metres(sep.min_m)}")
    if s.safety_events:
        parts.append(f"{plural(sep.collisions if sep else 0, 'collision')}, {plural(len(s.incidents), 'incident')}")
    else:
        parts.append("no collision or incident")
    if s.interrupted:
        parts.append("interrupted")
    return ", ".join(parts)


def list_runs(console: Any, root: Path, limit: int = RECENT) -> int:
    """``mrswarm results`` alone: the newest run folders under ``root``, each with its outcome; exit code 0."""
    runs = sorted((d for d in root.glob("*") if (d / "run.json").exists() or (d / "scenario.yaml").exists()),
                  key=lambda d: d.stat().st_mtime, reverse=True) if root.is_dir() else []
    if not runs:
        console.print(f"no run folders in {root}/ (`mrswarm run` writes them there; with --out, elsewhere). "
                      "`mrswarm results DIR` rebuilds one's summary and figures.", highlight=False, soft_wrap=True)
        return 0
    from rich.table import Table

    t = Table(title=f"recent runs in {root}/ (newest first; `mrswarm results DIR` rebuilds one)", show_edge=False,
              title_justify="left")
    for col in ("run folder", "outcome"):
        t.add_column(col, overflow="fold")
    for d in runs[:limit]:
        t.add_row(str(d), run_outcome(d))
    console.print(t)
    if len(runs) > limit:
        console.print(f"and {len(runs) - limit} older", highlight=False)
    return 0
