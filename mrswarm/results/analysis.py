"""The numbers of a run: from the files in a run folder to a :class:`~mrswarm.records.summary.RunSummary`.

Inputs, written by the UAVs while flying (uav_stack/recorder.py): ``uav<N>.csv`` trajectories
(wall and simulated time, FCU position in the swarm frame, agent phase, RTF) and ``uav<N>.json``
counters; by the runner: ``run.json``. A UAV whose flight controller is external and whose agent
recorded elsewhere (on its companion computer) gets the poses it shared, from the flight recording.
Every UAV recorded counts, whether the scenario lists it or not. Separation and coverage come from the UAVs' own
flight-controller positions, not from the poses they exchanged, so network impairments cannot
hide a collision. Positions are resampled on a common 10 Hz grid of wall time.

No plotting here (mrswarm/results/plots.py draws the figures from :class:`RunData`), so the numbers can
be computed where matplotlib is not installed or fails.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from groundfloor.histogram import LogHistogram
from mrswarm.records.summary import (
    CollisionPair,
    Coverage,
    Encounter,
    ExternalUav,
    Goal,
    LinkAge,
    LinkAges,
    Mavlink,
    Network,
    PoseAge,
    Rtf,
    RunInfo,
    RunSummary,
    Security,
    Separation,
    Takeoff,
)
from mrswarm.results.behaviour_report import behaviour_incidents, behaviour_summary, pool_agent_incidents
from mrswarm.results.coverage import coverage, time_to
from mrswarm.results.degraded import degraded_reasons, recording_report
from mrswarm.results.fault_report import failsafe_events, fault_table, lost_uavs, record_errors, service_outages, stalls
from mrswarm.results.incidents import find_incidents, safety_incident
from mrswarm.results.netem_report import netem_report, pose_age_report
from mrswarm.results.run_data import AIRBORNE_Z, GRID_HZ, CoverageMap, RunData, Track
from mrswarm.results.saturation import saturation_reasons
from mrswarm.results.world_report import world_report
from mrswarm.scenario import Scenario
from uav_stack.phases import WORKING
from uav_stack.recorder import links_file_name

GOAL_RADIUS = 2.0  # m (horizontal): a goto UAV this close to its goal has reached it
BREACH_GAP_S = 1.0  # s: a pair back above the safety distance for less than this is one incident, not two


@dataclass
class SeparationSteps:
    """Minimum pairwise distance per grid step and overall (see :func:`separation`)."""

    per_step: np.ndarray  # m per grid step, inf where fewer than two UAVs are airborne
    min: float | None  # m
    min_pair: list[int] | None
    min_at: float | None  # wall
    closest: int | None  # grid step of min_at
    collisions: int
    collision_pairs: list[CollisionPair]
    onsets: list[tuple[float, int, int]]  # (wall time, uav, uav) of every collision onset
    breaches: list[Breach] = field(default_factory=list)  # stretches of a pair below the safety distance (in the window)


@dataclass
class Breach:
    """Two UAVs closer than the safety distance: from ``start`` to ``end`` (grid indices, ``end`` included),
    ``steps`` grid steps below it (shorter gaps than :data:`BREACH_GAP_S` joined), at least ``min`` m apart."""

    pair: tuple[int, int]
    start: int
    end: int
    steps: int
    min: float
    min_at: int


def load_tracks(run_dir: Path) -> dict[int, Track]:
    tracks: dict[int, Track] = {}
    for path in sorted(run_dir.glob("uav*.csv")):
        try:
            uav = int(path.stem[3:])
        except ValueError:
            continue
        rows = []
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                try:
                    row = (float(r["t_wall"]), float(r["t_sim"]), float(r["x"]), float(r["y"]), float(r["z"]), r["phase"],
                           float(r["rtf"]), float(r.get("vz") or 0.0), int(r.get("armed") or 1))
                except (KeyError, ValueError, TypeError):
                    continue  # a line cut by a crash or a full disk
                if all(math.isfinite(v) for v in row[:5]):
                    rows.append(row)
        if not rows:
            continue
        rows.sort(key=lambda r: r[0])
        a = np.array([r[:5] for r in rows], dtype=float)
        tracks[uav] = Track(uav, a[:, 0], a[:, 1], a[:, 2:5], [r[5] for r in rows], np.array([r[6] for r in rows]),
                            vz=np.array([r[7] for r in rows]), armed=np.array([r[8] for r in rows]))
    return tracks


def load_stats(run_dir: Path) -> dict[int, dict[str, Any]]:
    """The last counters JSON of every UAV (``uav<N>.json``), with its per-link pose ages
    (``age_links_uav<N>.json``) as ``net.transport_age_links`` and, for a pool's UAV, the per-neighbour
    counters of its pool's file (``neighbours_in``) as ``neighbours``; unreadable files are skipped."""
    out = {}
    for path in sorted(run_dir.glob("uav*.json")):
        try:
            d = json.loads(path.read_text())
            uav = int(path.stem[3:])
        except (ValueError, OSError):
            continue
        if isinstance(d, dict):
            out[uav] = d
    shared: dict[str, dict[str, Any]] = {}  # a pool's file of the per-neighbour counters its UAVs share
    for uav, d in out.items():
        name = d.get("neighbours_in")
        if isinstance(name, str) and "neighbours" not in d:
            if name not in shared:
                try:
                    nb = json.loads((run_dir / Path(name).name).read_text()).get("neighbours")
                except (ValueError, OSError, AttributeError):
                    nb = None
                shared[name] = nb if isinstance(nb, dict) else {}
            d["neighbours"] = {k: v for k, v in shared[name].items() if k != str(uav)}  # every UAV but itself
    for uav, d in out.items():
        try:
            links = json.loads((run_dir / links_file_name(uav)).read_text())
        except (ValueError, OSError):
            continue  # none yet, or a run from before the file existed (its counters file carries them)
        net = d.get("net")
        if isinstance(links, dict) and isinstance(net, dict) and isinstance(links.get("transport_age_links"), dict):
            net["transport_age_links"] = links["transport_age_links"]
    return out


def load_ages(run_dir: Path) -> dict[int, dict[str, np.ndarray]]:
    """Every UAV's ``age_uav<N>.csv`` (uav_stack/pose_age.py), a column a key (``t_wall``, ``aoi_max_ms``, ...): read
    once, for the pose age over time (netem_report.py) and the detection of network faults (fault_report.py).
    A row without its wall time, a line cut by a crash and an unreadable file are skipped."""
    out: dict[int, dict[str, np.ndarray]] = {}
    for path in sorted(run_dir.glob("age_uav*.csv")):
        try:
            uav = int(path.stem[len("age_uav"):])
        except ValueError:
            continue
        cols: dict[str, list[float]] = {}
        try:
            with open(path, newline="") as f:
                for r in csv.DictReader(f):
                    try:
                        vals = {k: float(v) if v not in ("", None) else math.nan for k, v in r.items()}
                    except (TypeError, ValueError):
                        continue  # a line cut by a crash
                    if math.isfinite(vals.get("t_wall", math.nan)):
                        for k, v in vals.items():
                            cols.setdefault(k, []).append(v)
        except OSError:
            continue
        if cols.get("t_wall"):
            series = {k: np.array(v) for k, v in cols.items()}
            if "transport_p50_ms" not in series and "age_p50_ms" in series:  # a run folder of an earlier version
                series["transport_p50_ms"] = series["age_p50_ms"]
            out[uav] = series
    return out


def resample(tracks: dict[int, Track], t0: float, t1: float) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Positions of every UAV on a common 10 Hz grid; NaN where a UAV has no data."""
    grid = np.arange(t0, t1 + 1e-9, 1.0 / GRID_HZ)
    ids = sorted(tracks)
    pos = np.full((len(ids), len(grid), 3), np.nan)
    for k, u in enumerate(ids):
        tr = tracks[u]
        if len(tr.t) < 2:
            continue
        inside = (grid >= tr.t[0]) & (grid <= tr.t[-1])
        for d in range(3):
            pos[k, inside, d] = np.interp(grid[inside], tr.t, tr.xyz[:, d])
        # a gap in the log (process stalled or died) is not a straight line: blank it out
        gaps = np.where(np.diff(tr.t) > 1.0)[0]
        for g in gaps:
            pos[k, (grid > tr.t[g]) & (grid < tr.t[g + 1]), :] = np.nan
    return grid, pos, ids


def breaches_of(pair: tuple[int, int], d: np.ndarray, below: np.ndarray) -> list[Breach]:
    """The stretches where ``below`` holds for one pair (``d``: its distance per grid step), gaps shorter than
    :data:`BREACH_GAP_S` joined."""
    idx = np.nonzero(below)[0]
    if not len(idx):
        return []
    cuts = np.nonzero(np.diff(idx) > BREACH_GAP_S * GRID_HZ)[0]
    out = []
    for run in np.split(idx, cuts + 1):
        k = int(run[np.argmin(d[run])])
        out.append(Breach(pair=pair, start=int(run[0]), end=int(run[-1]), steps=len(run), min=float(d[k]), min_at=k))
    return out


def separation(grid: np.ndarray, pos: np.ndarray, ids: list[int], collision_distance: float,
               safety_distance: float | None = None, window: np.ndarray | None = None) -> SeparationSteps:
    """Minimum pairwise 3-D distance between airborne UAVs, per time step and overall; with ``safety_distance``,
    every stretch of a pair below it within ``window`` (a mask of the grid; default: all of it)."""
    n = len(ids)
    min_t = np.full(len(grid), np.inf)
    best: tuple[float, int | None, int | None, int | None] = (math.inf, None, None, None)
    collisions = 0
    pairs_below: list[CollisionPair] = []
    onset_times: list[tuple[float, int, int]] = []
    breaches: list[Breach] = []
    for i in range(n):
        for j in range(i + 1, n):
            d = np.linalg.norm(pos[i] - pos[j], axis=1)
            airborne = (pos[i, :, 2] > AIRBORNE_Z) & (pos[j, :, 2] > AIRBORNE_Z)
            d = np.where(airborne & ~np.isnan(d), d, np.inf)
            min_t = np.minimum(min_t, d)
            k = int(np.argmin(d))
            if d[k] < best[0]:
                best = (float(d[k]), ids[i], ids[j], k)
            below = d < collision_distance
            starts = np.nonzero(below & ~np.concatenate(([False], below[:-1])))[0]
            onsets = len(starts)
            onset_times += [(float(grid[k]), ids[i], ids[j]) for k in starts]
            if onsets:
                collisions += onsets
                pairs_below.append(CollisionPair(pair=[ids[i], ids[j]], onsets=onsets, min=float(d[k])))
            if safety_distance is not None:
                near = d < safety_distance
                breaches += breaches_of((ids[i], ids[j]), d, near if window is None else near & window)
    return SeparationSteps(
        per_step=min_t,
        min=best[0] if best[0] != math.inf else None,
        min_pair=[best[1], best[2]] if best[1] is not None and best[2] is not None else None,
        min_at=float(grid[best[3]]) if best[3] is not None else None,
        closest=best[3],
        collisions=collisions,
        collision_pairs=pairs_below,
        onsets=sorted(onset_times),
        breaches=sorted(breaches, key=lambda b: (b.start, b.pair)),
    )


def working_mask(tracks: dict[int, Track], grid: np.ndarray, pos: np.ndarray, ids: list[int]) -> np.ndarray:
    """(n_uav, n_grid): the UAV is recorded there and works on its mission (phase in ``AgentPhase`` WORKING)."""
    active = np.zeros(pos.shape[:2], dtype=bool)
    for k, u in enumerate(ids):
        tr = tracks[u]
        working = np.array([p in WORKING for p in tr.phase])
        idx = np.clip(np.searchsorted(tr.t, grid, side="right") - 1, 0, len(tr.t) - 1)
        active[k] = working[idx] & (grid >= tr.t[0]) & (grid <= tr.t[-1]) & ~np.isnan(pos[k, :, 0])
    return active


def goals_report(scenario: Scenario, tracks: dict[int, Track]) -> dict[str, Goal]:
    out = {}
    for u in scenario.all_uavs():
        tr = tracks.get(u.id)
        if tr is None or u.goal is None:
            out[str(u.id)] = Goal(reached=False, final_distance_m=None)
            continue
        d = np.hypot(tr.xyz[:, 0] - u.goal[0], tr.xyz[:, 1] - u.goal[1])
        reached = np.nonzero(d <= GOAL_RADIUS)[0]
        out[str(u.id)] = Goal(reached=bool(len(reached)), final_distance_m=float(d[-1]),
                              reached_at_wall=float(tr.t[reached[0]]) if len(reached) else None)
    return out


def encounter_report(scenario: Scenario, grid: np.ndarray, pos: np.ndarray, ids: list[int],
                     tracks: dict[int, Track]) -> Encounter | None:
    """Where two UAVs flying at each other met: the midpoint at their closest approach (None: never both
    airborne, or not two UAVs to pair).

    The pair: the scenario's two UAVs if both were recorded, else the two UAVs of the run folder (a
    scenario of one virtual UAV, with a real UAV's records beside it). Each UAV's start is where the
    scenario spawned it if this run simulated its flight controller, else its first recorded position
    (an external UAV stands where its autopilot is, a UAV the scenario does not list where it was)."""
    planned = [u.id for u in scenario.all_uavs()]
    pair = [u for u in planned if u in ids] if len(planned) == 2 else []
    if len(pair) != 2:
        pair = list(ids) if len(ids) == 2 else []
    if len(pair) != 2:
        return None
    i, j = ids.index(pair[0]), ids.index(pair[1])
    d = np.linalg.norm(pos[i] - pos[j], axis=1)
    airborne = (pos[i, :, 2] > AIRBORNE_Z) & (pos[j, :, 2] > AIRBORNE_Z)
    d = np.where(airborne & ~np.isnan(d), d, np.inf)
    k = int(np.argmin(d))
    if not np.isfinite(d[k]):
        return None
    mid = (pos[i, k, :2] + pos[j, k, :2]) / 2
    spawned = {u.id: np.array(u.start) for u in scenario.all_uavs() if not u.external}

    def start(u: int) -> np.ndarray:
        return spawned[u] if u in spawned else tracks[u].xyz[0, :2]

    return Encounter(
        time_wall=float(grid[k]),
        separation_m=float(d[k]),
        meeting_point=[round(float(mid[0]), 2), round(float(mid[1]), 2)],
        distance_from_start_m={str(u): round(float(np.linalg.norm(mid - start(u))), 2) for u in pair},
    )


def tracks_from_recording(run_dir: Path, uavs: list[int]) -> dict[int, Track]:
    """The trajectories of ``uavs`` from the run's flight recording (``run.mcap``): the poses each UAV
    shared with the swarm (the FCU's position as its agent published it, at its pose rate). For an
    external UAV whose agent recorded elsewhere (on its companion computer). Empty without a recording."""
    path = run_dir / "run.mcap"
    if not uavs or not path.is_file():
        return {}
    import tempfile

    from mrswarm.recorder.export import export_csv

    with tempfile.TemporaryDirectory(prefix="mrswarm-tracks-") as tmp:
        export_csv(path, Path(tmp))
        tracks = load_tracks(Path(tmp))
    return {u: tr for u, tr in tracks.items() if u in uavs}


def external_report(scenario: Scenario, run_dir: Path, tracks: dict[int, Track]) -> list[ExternalUav]:
    """Every UAV whose flight controller is external, and where its trajectory comes from; the ones without
    their own ``uav<N>.csv`` get the poses they shared, from the recording, into ``tracks``."""
    external = scenario.external_uavs()
    missing = [u.id for u in external if u.id not in tracks]
    error = ""
    try:
        from_recording = tracks_from_recording(run_dir, missing)
    except Exception as exc:  # noqa: BLE001 - a bad recording must not lose the other numbers
        from_recording, error = {}, f"the recording could not be read: {exc}"
    tracks.update(from_recording)
    out = []
    for u in external:
        if u.id in from_recording:
            source, detail = "recording", "the poses it shared, from run.mcap (its agent recorded elsewhere)"
        elif u.id in tracks:
            source, detail = "agent", f"uav{u.id}.csv, written by its agent"
        else:
            source = "none"
            detail = error or (f"no uav{u.id}.csv and no poses in a recording: copy uav{u.id}.csv from its companion "
                               "into the run folder, then `mrswarm results`")
        out.append(ExternalUav(uav=u.id, realm=u.realm_name, fcu=u.fcu or "", agent=u.agent, trajectory=source, detail=detail))
    return out


def rtf_report(tracks: dict[int, Track], t0: float, t1: float) -> Rtf:
    """Simulated over wall time between the first and last record of each UAV within [t0, t1]."""
    per: dict[str, float | None] = {}
    for u, tr in tracks.items():
        sel = (tr.t >= t0) & (tr.t <= t1)
        if np.count_nonzero(sel) >= 2:
            tw, ts = tr.t[sel], tr.t_sim[sel]
            per[str(u)] = round(float((ts[-1] - ts[0]) / (tw[-1] - tw[0])), 4) if tw[-1] > tw[0] else None
        else:
            per[str(u)] = None
    vals = [v for v in per.values() if v is not None]
    return Rtf(per_uav=per, mean=float(np.mean(vals)) if vals else None, min=float(np.min(vals)) if vals else None)


def _age(h: LogHistogram) -> PoseAge:
    return PoseAge(p50=_ms(h.percentile(50)), p99=_ms(h.percentile(99)), mean=_ms(h.mean), max=_ms(h.max), n=h.n)


def _ms(v: float) -> float | None:
    return round(v * 1000.0, 2) if v == v else None


def _hist(d: Any) -> LogHistogram | None:
    try:
        return LogHistogram.from_dict(d)
    except (KeyError, ValueError, TypeError, AttributeError):
        return None


def link_ages(stats: dict[int, dict[str, Any]]) -> list[LinkAge]:
    """The transport age of every link ``sender -> receiver`` the UAVs recorded, by link."""
    out = []
    for uav, s in sorted(stats.items()):
        for src, d in sorted((s.get("net", {}).get("transport_age_links") or {}).items(), key=lambda kv: str(kv[0])):
            h = _hist(d)
            if h is not None and h.n:
                out.append(LinkAge(link=f"{src}->{uav}", p50=_ms(h.percentile(50)), p99=_ms(h.percentile(99)), max=_ms(h.max),
                                   n=h.n))
    return out


def link_summary(links: list[LinkAge], worst: int = 5) -> LinkAges:
    def med(vals: list[float | None]) -> float | None:
        v = [x for x in vals if x is not None]
        return round(float(np.median(v)), 2) if v else None

    ranked = sorted((lk for lk in links if lk.p99 is not None), key=lambda lk: lk.p99 or 0.0, reverse=True)
    return LinkAges(links=len(links), p50_median_ms=med([lk.p50 for lk in links]), p99_median_ms=med([lk.p99 for lk in links]),
                    p99_max_ms=ranked[0].p99 if ranked else None, worst=ranked[:worst])


def network_report(stats: dict[int, dict[str, Any]]) -> Network:
    """Both pose ages (merged histograms), message counters summed over UAVs, and pose loss from sequence gaps."""
    transport, use = LogHistogram(), LogHistogram()
    sent: dict[str, int] = {}
    recv: dict[str, int] = {}
    rej: dict[str, int] = {}
    negative: dict[str, int] = {}
    lost = received = 0
    for s in stats.values():
        net = s.get("net", {})
        # "pose_age": the name of the transport age in run folders of earlier versions
        for h, key in ((transport, "transport_age" if "transport_age" in net else "pose_age"), (use, "use_age")):
            part = _hist(net.get(key))
            if part is not None:
                h.merge(part)
        for src, dst in ((net.get("sent", {}), sent), (net.get("received", {}), recv), (net.get("rejected", {}), rej),
                         (net.get("negative_ages", {}), negative)):
            for k, v in src.items():
                dst[k] = dst.get(k, 0) + int(v)
        for nb in s.get("neighbours", {}).values():
            lost += int(nb.get("lost", 0))
            received += int(nb.get("received", 0))
    return Network(
        transport_age_ms=_age(transport),
        use_age_ms=_age(use),
        messages_sent=sent,
        messages_received=recv,
        messages_rejected=rej,
        pose_loss=round(lost / (lost + received), 5) if lost + received else 0.0,
        negative_ages=negative,
    )


def security_report(run_dir: Path, mode: str, stats: dict[int, dict[str, Any]]) -> Security:
    """The run's security mode and the refusals its UAVs and its edge router counted."""
    uavs: dict[str, int] = {}
    for s in stats.values():
        for k, v in s.get("net", {}).get("refused", {}).items():
            uavs[k] = uavs.get(k, 0) + int(v)
    try:
        router = {str(k): int(v) for k, v in json.loads((run_dir / "logs" / "router.stats.json").read_text())["refused"].items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        router = {}  # insecure, or a runtime whose router writes no counters (docker)
    return Security(mode=mode, refused_by_uavs=uavs, refused_by_router=router)


MAVLINK_REFUSED = ("unsigned_refused", "unsigned_commands_refused", "bad_signature", "replayed", "unknown_id_refused",
                   "setup_signing_dropped", "foreign_source", "spoofed_own_id")
MAVLINK_ACCEPTED = ("signed", "unsigned_accepted", "to_fcu")


def mavlink_report(mode: str, stats: dict[int, dict[str, Any]]) -> Mavlink:
    """What the UAVs' MAVLink routers accepted and refused, summed over the UAVs."""
    refused = dict.fromkeys(MAVLINK_REFUSED, 0)
    accepted = dict.fromkeys(MAVLINK_ACCEPTED, 0)
    for s in stats.values():
        rt = s.get("mavlink_router") or {}
        for out in (refused, accepted):
            for k in out:
                v = rt.get(k, 0)
                out[k] += int(v) if isinstance(v, int) else 0
    return Mavlink(mode=mode, refused=refused, accepted=accepted)
def _interrupted_at(summary: RunSummary, info: RunInfo, t_last: float | None) -> None:
    """An interrupted run's last known time: when the runner stopped it, else (the runner died) the newest
    thing on disk: a UAV's last record, or run.json's last event."""
    if not summary.interrupted:
        return
    known = [t for t in (t_last, *(e.t for e in info.events), info.mission_start, info.started or None) if t]
    at = info.stopped if info.stopped is not None else max(known, default=None)
    if at is None:
        return
    summary.interrupted_at_wall = round(at, 3)
    if info.mission_start is not None:
        summary.interrupted_at_s = round(at - info.mission_start, 3)


def analyse_run(run_dir: Path, scenario: Scenario, info: RunInfo) -> tuple[RunSummary, RunData | None]:
    """The summary of a finished (or interrupted, or aborted) run, and the series its figures need.

    The mission window is [``info.mission_start``, + ``scenario.duration``]; a run that never
    started its mission is analysed from its first record to its last. RunData is None when no
    UAV recorded a trajectory (the summary then carries ``error``).
    """
    tracks = load_tracks(run_dir)
    external = external_report(scenario, run_dir, tracks) if scenario.external_uavs() else None
    stats = load_stats(run_dir)
    fl = scenario.flight
    summary = RunSummary(
        scenario=scenario.name,
        run_dir=str(run_dir),
        uavs_planned=len(scenario.all_uavs()),
        uavs_recorded=len(tracks),
        interrupted=info.interrupted,
        processes=dict(info.exit_codes),
        aborted=info.aborted,
        stop_signals=list(info.stop_signals),
    )
    if external is not None:
        summary.external_uavs = external
    t_ref = info.mission_start or info.started
    if info.stopped is None:  # run.json has no end: the runner died (SIGKILL, power) before writing it
        summary.interrupted = summary.runner_lost = True
    summary.lost_uavs = lost_uavs(info, t_ref)
    summary.stalls = stalls(info, t_ref)
    summary.services = service_outages(info, t_ref)
    summary.failsafes = failsafe_events(stats, t_ref)
    behaviour = behaviour_summary(stats)  # SDK behaviours (docs/sdk.md)
    if behaviour is not None:
        summary.behaviour = behaviour
    errors = record_errors(stats, info)
    if errors is not None:
        summary.records = errors
    if info.security is not None:
        summary.security = security_report(run_dir, info.security, stats)
    if info.mavlink is not None:
        summary.mavlink = mavlink_report(info.mavlink, stats)
    recording = recording_report(info, t_ref)
    if recording is not None:
        summary.recording = recording
    summary.degraded = degraded_reasons(summary, info, run_dir, {u: float(tr.t[-1]) for u, tr in tracks.items()}, stats)
    if not tracks:
        summary.error = "no trajectory was recorded"
        _interrupted_at(summary, info, None)
        return summary, None
    t_first = float(min(tr.t[0] for tr in tracks.values()))
    t_last = float(max(tr.t[-1] for tr in tracks.values()))
    _interrupted_at(summary, info, t_last)
    t0 = info.mission_start or t_first
    t_end = min(t_last, t0 + scenario.duration) if info.mission_start else t_last
    if info.mission_start and info.all_done_at is not None:  # the mission ended early: its end, not the shutdown after it
        t_end = min(t_end, t0 + info.all_done_at)
    grid, pos, ids = resample(tracks, t_first, t_last)
    in_mission = (grid >= t0) & (grid <= t_end)
    sep = separation(grid, pos, ids, fl.collision_distance, fl.safety_distance, in_mission)
    sep_mission = sep.per_step[in_mission]
    finite = sep_mission[np.isfinite(sep_mission)]
    summary.separation = Separation(
        min_m=sep.min,
        min_pair=sep.min_pair,
        min_at_s=(sep.min_at - t0) if sep.min_at is not None else None,
        min_during_mission_m=float(finite.min()) if finite.size else None,
        safety_distance_m=fl.safety_distance,
        time_below_safety_s=float(np.count_nonzero(finite < fl.safety_distance) / GRID_HZ),
        collision_distance_m=fl.collision_distance,
        collisions=sep.collisions,
        collision_pairs=sep.collision_pairs,
    )
    m = scenario.mission
    working = working_mask(tracks, grid, pos, ids)
    cov_map = None
    if m.type == "coverage" and m.area is not None:
        frac, first_visit, (xs, ys) = coverage(grid, pos, working, m.area.as_tuple(), m.sensor_radius,
                                               m.coverage_cell_m)
        cov_map = CoverageMap(first_visit=first_visit, xs=xs, ys=ys, t=grid[in_mission] - t0, fraction=frac[in_mission])
        summary.coverage = Coverage(
            final=float(cov_map.fraction[-1]) if in_mission.any() else 0.0,
            time_to_50_s=time_to(frac, grid, t0, 0.5),
            time_to_90_s=time_to(frac, grid, t0, 0.9),
            curve=[(round(float(t), 1), round(float(c), 4))
                   for t, c in zip(cov_map.t, cov_map.fraction, strict=True)][:: int(GRID_HZ)],
            sensor_radius_m=m.sensor_radius,
            strategy=m.strategy,
        )
    if m.type == "goto":
        summary.goals = goals_report(scenario, tracks)
        if len(ids) == 2 or len(scenario.all_uavs()) == 2:
            summary.encounter = encounter_report(scenario, grid, pos, ids, tracks)
    for u, tr in sorted(tracks.items()):
        if tr.vz is not None and tr.armed is not None:
            summary.incidents += find_incidents(u, tr.t, tr.xyz[:, 2], tr.vz, tr.armed, t0)
    summary.incidents += [safety_incident(b.pair, float(grid[b.start] - t0), b.steps / GRID_HZ, b.min,
                                          float(grid[b.min_at] - t0), fl.safety_distance) for b in sep.breaches]
    summary.incidents += behaviour_incidents(stats, t0) + pool_agent_incidents(stats, t0)
    summary.incidents.sort(key=lambda i: i.t_s)
    ages: dict[int, dict[str, np.ndarray]] = {}
    age_error = None
    try:
        ages = load_ages(run_dir)
    except Exception as exc:  # a bug here must not lose the other numbers
        age_error = repr(exc)
    if info.faults:
        area = m.area.as_tuple() if m.area is not None else None
        summary.faults = fault_table(
            info, t0, t_end, ages, sep.onsets, {u: (grid, working[k]) for k, u in enumerate(ids)},
            [u.id for u in scenario.uav_list()], fl.speed * 2.0 * m.sensor_radius,
            (area[1] - area[0]) * (area[3] - area[2]) if area is not None and m.type == "coverage" else None)
    summary.rtf = rtf_report(tracks, t0, t_end)
    network = network_report(stats)
    links = link_ages(stats)
    if links:
        network.transport_age_links = link_summary(links)
    if info.takeoff_sent is not None:
        summary.takeoff = Takeoff(acked_s=info.takeoff_acked_s, all_airborne_s=info.all_airborne_s, sends=info.takeoff_sends,
                                  late={str(lt.uav): lt.stage for lt in info.late},
                                  by_state=info.takeoff_by_state)
    ne = netem_report(stats)
    if ne is not None:
        network.netem = ne
    age_series = None
    try:
        age = pose_age_report(ages, t0, t_end)
    except Exception as exc:  # a bug here must not lose the other numbers
        age_error = repr(exc)
    else:
        if age is not None:
            network.pose_age_over_time, age_series = age
    if age_error is not None:
        network.pose_age_over_time_error = age_error
    summary.network = network
    summary.saturated = saturation_reasons(network.pose_loss, stats, interest=scenario.network.interest is not None)
    summary.duration_s = float(t_end - t0)
    world_data = None
    if scenario.world is not None:
        summary.world, world_data = world_report(run_dir, scenario, pos, ids, t0, t_end, stats)
    data = RunData(tracks=tracks, grid=grid, pos=pos, ids=ids, min_separation=sep.per_step, t0=t0, t_end=t_end,
                   coverage=cov_map, pose_age=age_series, links=links, world=world_data, closest=sep.closest)
    return summary, data
