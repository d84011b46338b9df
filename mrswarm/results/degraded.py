"""Why a run's records are incomplete: the ``degraded`` list of summary.json, and what makes ``mrswarm run`` exit 1.

A full or failing disk stops no process of a run (docs/reliability.md): each writer counts what it
could not write and goes on. The summary then has to say what is missing, from what the run folder
and the runner know:

* rows given up by a UAV (beyond its in-memory backlog), and runner files not written;
* a UAV whose records end well before its process stopped (what it still held in memory when it
  stopped, with the disk still full), or whose counters file is older than its end;
* the edge router's counters not written since well before the end;
* the flight recorder's gaps (it died and was restarted) and the records a full disk took none of;
* figures, ``transport_links.csv`` or ``summary.json`` not written (added by mrswarm/results/summarise.py).

A disk that was full for a while and took everything back (nothing lost within the backlogs) is not
degraded: its errors are in ``records``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mrswarm.records.summary import RECORDER, Recording, RecordingGap, RunInfo, RunSummary, uav_of

LATE_S = 3.0  # records or counters older than this before a process stopped are missing their end


def recording_report(info: RunInfo, t0: float) -> Recording | None:
    """The flight recording's files and the recorder's gaps (exited -> resumed), from run.json."""
    if not info.recording_files and not any(e.name == RECORDER for e in info.events):
        return None
    gaps = []
    for i, ev in enumerate(info.events):
        if ev.name != RECORDER or ev.event != "exited":
            continue
        nxt = next((e for e in info.events[i + 1:] if e.name == RECORDER and e.event in ("resumed", "exited")), None)
        to = nxt.t if nxt is not None and nxt.event == "resumed" else None
        # from where its file ends (its last flush: up to a second before it died), else from when it was seen down
        since = nxt.recorded_until if nxt is not None and nxt.recorded_until is not None else ev.t
        gaps.append(RecordingGap(from_s=round(since - t0, 2), to_s=round(to - t0, 2) if to is not None else None,
                                 gap_s=round(to - since, 2) if to is not None else None,
                                 cause=ev.signal or f"exit code {ev.exit_code}"))
    return Recording(files=list(info.recording_files), gaps=gaps, unwritten=info.recording_unwritten)


def _ended(info: RunInfo, name: str) -> float | None:
    """When the runner last saw ``name`` stop: its last exit (if it did not come back), else the runner's stop."""
    last = None
    for ev in info.events:
        if ev.name == name:
            last = ev.t if ev.event == "exited" else None
    return last if last is not None else info.stopping


def degraded_reasons(summary: RunSummary, info: RunInfo, run_dir: Path, last_record: dict[int, float],
                     stats: dict[int, dict[str, Any]]) -> list[str]:
    """What the run folder misses; ``last_record``: each UAV's newest trajectory row (wall time)."""
    out: list[str] = []
    rec = summary.records
    if rec and rec.rows_dropped:
        out.append(f"{rec.rows_dropped} trajectory or pose-age rows of UAVs {rec.uavs} lost (the disk refused them "
                   "beyond the in-memory backlog)")
    if info.write_errors:
        out.append(f"runner files not written: {', '.join(info.write_errors)}")
    if info.stopped is not None:  # what each process should have written by the time it stopped
        # each UAV by its own name, a pooled one too (a pool's events are its UAVs', mrswarm/run/supervisor.py)
        names = [n for n in info.pids if n not in info.pools] + [f"uav{u}" for us in info.pools.values() for u in us]
        for name in sorted(names):
            uav = uav_of(name)
            end = _ended(info, name)
            if uav is None or end is None:
                continue
            t = last_record.get(uav)  # (none at all: a UAV that never had a position, no disk's doing)
            stalled_to_end = any(e.name == name and e.event == "stalled" and e.t + (e.duration_s or 0.0) >= end - LATE_S
                                 for e in info.events)  # stopped (SIGSTOP) to the end: it wrote nothing, lost nothing
            if t is not None and end - t > LATE_S and not stalled_to_end:
                out.append(f"{name}: its trajectory ends {end - t:.0f} s before its process stopped (rows it held when "
                           "the disk was full)")
            counters = run_dir / f"{name}.json"
            try:
                age = end - counters.stat().st_mtime
            except OSError:
                age = None
            if uav in stats and age is not None and age > LATE_S:
                out.append(f"{name}: its counters ({counters.name}) are from {age:.0f} s before its end")
        stats_file = run_dir / "logs" / "router.stats.json"
        end = _ended(info, "router")
        try:
            age = (end - stats_file.stat().st_mtime) if end is not None else None
        except OSError:
            age = None
        if age is not None and age > LATE_S:
            out.append(f"the edge router's counters ({stats_file.name}) are from {age:.0f} s before its end")
    if r := summary.recording:
        for g in r.gaps:
            out.append(f"flight recording: the recorder was down from {g.from_s:.1f} s "
                       + (f"for {g.gap_s:.1f} s ({g.cause})" if g.gap_s is not None else f"to the end ({g.cause})"))
        if r.unwritten:
            out.append(f"flight recording: {r.unwritten} records not written (the disk refused them)")
    return out
