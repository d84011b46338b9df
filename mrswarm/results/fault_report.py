"""The resilience part of summary.json: lost UAVs, service outages, the per-fault table, failsafes, recording errors, stalls.

Inputs are the run folder's records only (so ``mrswarm results`` rebuilds them, even for a run
whose runner was killed): ``run.json`` (process events and the fault schedule with the times
the runner saw each symptom and recovery, mrswarm/run/chaos.py), the UAVs' ``uav<N>.json``
(failsafe events, recording errors), ``age_uav<N>.csv`` (age of information, for network
faults) and the trajectories. How each column is measured is in docs/reliability.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from mrswarm.records.summary import (
    SERVICES,
    FailsafeEvent,
    FaultRecord,
    FaultReport,
    LostUav,
    RecordErrors,
    RunInfo,
    ServiceOutage,
    Stall,
    uav_of,
)
from mrswarm.scenario.faults import NETWORK, STALE_S

AFTER_FAULT_S = 30.0  # collisions are attributed to a fault until it recovered, or this long after it ended


def lost_uavs(info: RunInfo, t0: float) -> list[LostUav]:
    out: list[LostUav] = []
    for i, ev in enumerate(info.events):
        uav = uav_of(ev.name)
        if uav is None or ev.event != "exited":
            continue
        back = next((e.t for e in info.events[i + 1:] if e.name == ev.name and e.event == "restarted"), None)
        injected = any(f.kind == "kill_uav" and uav in f.targets and f.injected is not None and 0 <= ev.t - f.injected < 5.0
                       for f in info.faults)
        out.append(LostUav(uav=uav, t_s=round(ev.t - t0, 2), exit_code=ev.exit_code, signal=ev.signal, last_pose=ev.last_pose,
                           restarted_s=round(back - t0, 2) if back is not None else None, injected=injected,
                           error=ev.error))
    return out


def service_outages(info: RunInfo, t0: float) -> list[ServiceOutage]:
    out: list[ServiceOutage] = []
    for i, ev in enumerate(info.events):
        if ev.name not in SERVICES or ev.event != "exited":
            continue
        back = next((e.t for e in info.events[i + 1:] if e.name == ev.name and e.event == "restarted"), None)
        out.append(ServiceOutage(name=ev.name, down_s=round(ev.t - t0, 2), exit_code=ev.exit_code,
                                 restarted_s=round(back - t0, 2) if back is not None else None))
    return out


def failsafe_events(stats: dict[int, dict[str, Any]], t0: float) -> list[FailsafeEvent]:
    out: list[FailsafeEvent] = []
    for uav, s in sorted(stats.items()):
        fs = s.get("failsafes")
        if not isinstance(fs, dict):
            continue
        for e in fs.get("events", []):
            try:
                out.append(FailsafeEvent(uav=uav, t_s=round(float(e["t"]) - t0, 2), failsafe=str(e["failsafe"]),
                                         event=str(e["event"]), detail=str(e.get("detail", ""))[:200]))
            except (KeyError, TypeError, ValueError):
                continue
    return sorted(out, key=lambda e: (e.t_s, e.uav))


def record_errors(stats: dict[int, dict[str, Any]], info: RunInfo) -> RecordErrors | None:
    uavs: list[int] = []
    errors: dict[str, int] = {}
    rows = files = 0
    for uav, s in sorted(stats.items()):
        r = s.get("records")
        if not isinstance(r, dict) or not r.get("errors"):
            continue
        uavs.append(uav)
        for k, v in r["errors"].items():
            errors[str(k)] = errors.get(str(k), 0) + int(v)
        rows += int(r.get("rows_dropped", 0))
        files += int(r.get("files_not_written", 0))
    if not uavs and not info.write_errors:
        return None
    return RecordErrors(uavs=uavs, errors=errors, rows_dropped=rows, files_not_written=files, runner=list(info.write_errors))


def aoi_of(ages: dict[int, dict[str, np.ndarray]]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per UAV: (wall times, max age of information over its neighbours, s), from its ``age_uav<N>.csv`` columns."""
    return {u: (s["t_wall"], s["aoi_max_ms"] / 1000.0) for u, s in ages.items() if "aoi_max_ms" in s}


def _network_times(rec: FaultRecord, aoi: dict[int, tuple[np.ndarray, np.ndarray]],
                   ids: Sequence[int]) -> tuple[float | None, float | None]:
    """Detection and recovery of a partition or outage: some affected UAV's knowledge of a neighbour older than
    STALE_S, then every affected UAV's fresh again after the fault ended (1 s resolution: one record a second)."""
    if rec.injected is None:
        return None, None
    end = rec.ends or rec.injected
    affected = [u for u in (rec.targets or ids) if u in aoi]
    detected = recovered = None
    for u in affected:
        t, a = aoi[u]
        hit = np.nonzero((t >= rec.injected) & (t <= end + 1.0) & (a > STALE_S))[0]
        if len(hit):
            detected = float(t[hit[0]]) if detected is None else min(detected, float(t[hit[0]]))
    if detected is None:
        return None, None
    for u in affected:
        t, a = aoi[u]
        ok = np.nonzero((t > end) & ~(a > STALE_S))[0]
        if not len(ok):
            return detected, None
        recovered = float(t[ok[0]]) if recovered is None else max(recovered, float(t[ok[0]]))
    return detected, recovered


def fault_table(info: RunInfo, t0: float, t_end: float, ages: dict[int, dict[str, np.ndarray]],
                onsets: list[tuple[float, int, int]],
                working: dict[int, tuple[np.ndarray, np.ndarray]], ids: Sequence[int], sweep_m2_per_s: float,
                area_m2: float | None) -> list[FaultReport]:
    """One row per fault of the schedule.

    ``ages``: every UAV's ``age_uav<N>.csv`` columns (the age of information tells a network fault's detection and
    recovery); ``working`` holds per UAV (grid wall times, working flag) from the trajectories;
    ``sweep_m2_per_s`` is the area one working UAV sweeps per second (cruise speed x sensor diameter).
    """
    aoi = aoi_of(ages)
    rows: list[FaultReport] = []
    for rec in sorted(info.faults, key=lambda r: (r.injected or math.inf, r.index)):
        if rec.injected is None:
            rows.append(FaultReport(kind=rec.kind, at_s=rec.at_s, targets=rec.targets, ok=False, detection_s=None,
                                    recovery_s=None, collisions=0, coverage_lost=None,
                                    detail="not injected (the run ended first)"))
            continue
        detected, recovered = rec.detected, rec.recovered
        if rec.kind in NETWORK:
            detected, recovered = _network_times(rec, aoi, ids)
        until = recovered if recovered is not None else min(t_end, (rec.ends or rec.injected) + AFTER_FAULT_S)
        collisions = sum(1 for t, _, _ in onsets if rec.injected <= t <= until)
        lost = None
        if area_m2:
            out_s = 0.0
            for u in rec.targets or ids:
                g, w = working.get(u, (np.array([]), np.array([], dtype=bool)))
                if not len(g):
                    continue
                before = w[(g < rec.injected) & (g >= rec.injected - 2.0)]
                if not before.any():
                    continue  # it was not working when the fault came: nothing lost
                sel = (g >= rec.injected) & (g <= (recovered if recovered is not None else t_end))
                out_s += float(np.count_nonzero(sel & ~w)) * (float(g[1] - g[0]) if len(g) > 1 else 0.0)
            lost = round(min(1.0, out_s * sweep_m2_per_s / area_m2), 4)
        rows.append(FaultReport(
            kind=rec.kind, at_s=round(rec.injected - t0, 2), targets=rec.targets, ok=rec.ok,
            detection_s=round(detected - rec.injected, 2) if detected is not None else None,
            recovery_s=round(recovered - rec.injected, 2) if recovered is not None else None,
            collisions=collisions, coverage_lost=lost, detail=rec.detail[:200]))
    return rows


def stalls(info: RunInfo, t0: float) -> list[Stall]:
    """The run's stalls, from run.json's events."""
    out = []
    for ev in info.events:
        uav = uav_of(ev.name)
        if ev.event == "stalled" and uav is not None and ev.duration_s is not None:
            out.append(Stall(uav=uav, from_s=round(ev.t - t0, 2), duration_s=ev.duration_s))
    return sorted(out, key=lambda s: (s.from_s, s.uav))
