"""The numbers of a world scenario (docs/world.md): from the run folder to :class:`~mrswarm.records.world_summary.WorldSummary`.

Inputs: what the world service recorded (world/record.py: ``world.json``, ``world_fire.csv``,
``world_fire.npz``, ``world_estimates.csv``, ``world_actuations.csv``), the UAVs' counters
(``uav<N>.json``: their sensors, their neighbours, the airspace feed) and their trajectories as
resampled by mrswarm/results/analysis.py. Zones and separation between swarms come from the UAVs' own
flight-controller positions, like every separation of the analysis.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from groundfloor.histogram import LogHistogram
from mrswarm.records.world_summary import (
    AirspaceReport,
    FireReport,
    PlumeReport,
    SensorDelivery,
    WorldService,
    WorldSummary,
    ZoneReport,
)
from mrswarm.results.run_data import AIRBORNE_Z, WorldData
from mrswarm.scenario import Scenario


def _read_csv(path: Path) -> list[dict[str, str]]:
    try:
        with open(path, newline="") as f:
            return list(csv.DictReader(f))
    except OSError:
        return []


def _floats(row: dict[str, str], *names: str) -> tuple[float, ...] | None:
    try:
        return tuple(float(row[n]) for n in names)
    except (KeyError, TypeError, ValueError):
        return None


# ---- geometry, vectorised over points -----------------------------------------------------------------
def inside(points: np.ndarray, polygon: tuple[tuple[float, float], ...]) -> np.ndarray:
    """Even-odd rule for every row of ``points`` (n, 2)."""
    x, y = points[:, 0], points[:, 1]
    out = np.zeros(len(points), dtype=bool)
    n = len(polygon)
    for i in range(n):
        (ax, ay), (bx, by) = polygon[i], polygon[(i + 1) % n]
        if ay == by:
            continue
        cross = ((ay > y) != (by > y)) & (x < ax + (y - ay) * (bx - ax) / (by - ay))
        out ^= cross
    return out


def edge_distance(points: np.ndarray, polygon: tuple[tuple[float, float], ...]) -> np.ndarray:
    """Distance of every row of ``points`` (n, 2) to the polygon's boundary."""
    best = np.full(len(points), np.inf)
    n = len(polygon)
    for i in range(n):
        a, b = np.array(polygon[i], dtype=float), np.array(polygon[(i + 1) % n], dtype=float)
        ab = b - a
        t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-18), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - (a + t[:, None] * ab), axis=1))
    return best


# ---- the parts --------------------------------------------------------------------------------------
def sensor_report(scn: Scenario, stats: dict[int, dict[str, Any]]) -> dict[str, SensorDelivery]:
    assert scn.world is not None
    out = {}
    for spec in scn.world.sensors:
        h, wait = LogHistogram(), LogHistogram()
        received = 0
        rates = []
        for s in stats.values():
            st = ((s.get("payload") or {}).get("sensors") or {}).get(spec.name)
            if not isinstance(st, dict):
                continue
            received += int(st.get("received", 0))
            if st.get("rate_hz"):
                rates.append(float(st["rate_hz"]))
            for into, key in ((h, "delay_hist"), (wait, "wait_hist")):
                try:
                    into.merge(LogHistogram.from_dict(st[key]))
                except (KeyError, ValueError, TypeError):
                    pass

        def ms(v: float) -> float | None:
            return round(v * 1000.0, 2) if v == v else None

        out[spec.name] = SensorDelivery(type=spec.type, received=received,
                                        rate_hz_median=float(np.median(rates)) if rates else None,
                                        delay_ms_p50=ms(h.percentile(50)), delay_ms_p99=ms(h.percentile(99)),
                                        latency_s=spec.latency_s, wait_ms_p50=ms(wait.percentile(50)) if wait.n else None,
                                        wait_ms_p99=ms(wait.percentile(99)) if wait.n else None,
                                        world_tick_ms=round(1000.0 / scn.world.tick_hz, 2))
    return out


def plume_report(scn: Scenario, run_dir: Path, t0: float, t_end: float, wd: WorldData) -> PlumeReport | None:
    w = scn.world
    if w is None or w.plume is None:
        return None
    sx, sy = w.plume.source
    per: dict[int, list[tuple[float, float, float]]] = {}
    for row in _read_csv(run_dir / "world_estimates.csv"):
        v = _floats(row, "t_wall", "uav", "x", "y")
        if v is not None:
            per.setdefault(int(v[1]), []).append((v[0] - t0, v[2], v[3]))
    wd.estimates = {u: np.array(sorted(e)) for u, e in per.items()}
    curve = []
    for s in np.arange(0.0, max(t_end - t0, 0.0) + 1e-9, 1.0):
        errs = []
        for e in wd.estimates.values():
            k = np.searchsorted(e[:, 0], s, side="right") - 1
            if k >= 0:
                errs.append(math.hypot(e[k, 1] - sx, e[k, 2] - sy))
        curve.append((float(s), float(np.median(errs)) if errs else None, float(min(errs)) if errs else None))
    wd.error_curve = np.array([(s, np.nan if m is None else m, np.nan if b is None else b) for s, m, b in curve])
    firsts = [float(e[0, 0]) for e in wd.estimates.values() if len(e)]
    below = [s for s, m, _ in curve if m is not None and m < 5.0]
    return PlumeReport(
        source=[sx, sy], estimates=sum(len(e) for e in wd.estimates.values()), uavs_estimating=len(wd.estimates),
        first_estimate_s=round(min(firsts), 2) if firsts else None,
        error_final_m=round(curve[-1][1], 2) if curve and curve[-1][1] is not None else None,
        error_best_final_m=round(curve[-1][2], 2) if curve and curve[-1][2] is not None else None,
        below_5m_at_s=below[0] if below else None,
        error_curve=[(s, None if m is None else round(m, 2), None if b is None else round(b, 2)) for s, m, b in curve],
    )


def fire_report(scn: Scenario, run_dir: Path, t0: float, service: dict[str, Any], wd: WorldData) -> FireReport | None:
    if scn.world is None or scn.world.fire is None:
        return None
    fire = service.get("fire") or {}
    world_t0 = service.get("t0")
    shift = (world_t0 - t0) if isinstance(world_t0, (int, float)) else 0.0  # world time -> mission time
    rows = [v for r in _read_csv(run_dir / "world_fire.csv") if (v := _floats(r, "t_s", "burnt_area_m2", "burning"))]
    wd.fire_curve = np.array([(t + shift, a, b) for t, a, b in rows]) if rows else None
    try:
        with np.load(run_dir / "world_fire.npz") as z:
            wd.fire_grid = {k: z[k] for k in z.files}
    except (OSError, ValueError):
        wd.fire_grid = None
    sprays = [v for r in _read_csv(run_dir / "world_actuations.csv") if (v := _floats(r, "x", "y", "released_l")) and v[2] > 0]
    wd.sprays = np.array([(x, y) for x, y, _ in sprays]) if sprays else None
    out_at = fire.get("out_at_s")
    return FireReport(
        burnt_area_m2=float(fire.get("burnt_area_m2", 0.0)), cells_ignited=int(fire.get("ignited", 0)),
        cells_extinguished=int(fire.get("extinguished", 0)), cells_burning_at_end=int(fire.get("burning", 0)),
        extinguished_at_s=round(out_at + shift, 2) if isinstance(out_at, (int, float)) else None,
        sprayed_l=float(fire.get("sprayed_l", 0.0)), actuations=int((service.get("counts") or {}).get("actuations", 0)),
        area_curve=[(round(t, 1), a, int(b)) for t, a, b in (wd.fire_curve.tolist() if wd.fire_curve is not None else [])],
    )


def zone_report(scn: Scenario, pos: np.ndarray, ids: list[int]) -> ZoneReport | None:
    if scn.world is None or not scn.world.zones:
        return None
    entries = 0
    entering: set[int] = set()
    clearance = math.inf
    for k, u in enumerate(ids):
        p = pos[k]
        ok = ~np.isnan(p[:, 0]) & (p[:, 2] > AIRBORNE_Z)
        pts, z = p[ok, :2], p[ok, 2]
        if not len(pts):
            continue
        for zone in scn.world.zones:
            at_height = (z >= zone.floor) & (z <= zone.ceiling)
            ins = inside(pts, zone.polygon) & at_height
            if ins.any():
                entries += int(ins.sum())
                entering.add(u)
            out = at_height & ~ins
            if out.any():
                clearance = min(clearance, float(edge_distance(pts[out], zone.polygon).min()))
    return ZoneReport(zones=len(scn.world.zones), entries=entries, uavs_entering=sorted(entering),
                      min_clearance_m=round(clearance, 3) if clearance != math.inf else None)


def airspace_report(scn: Scenario, pos: np.ndarray, ids: list[int], stats: dict[int, dict[str, Any]],
                    wd: WorldData) -> AirspaceReport | None:
    if not scn.other_swarms:
        return None
    swarm_of = scn.swarm_of()
    fl = scn.flight
    per_step = np.full(pos.shape[1], np.inf)
    conflicts = collisions = 0
    for i in range(len(ids)):
        for j in range(i + 1, len(ids)):
            if swarm_of.get(ids[i]) == swarm_of.get(ids[j]):
                continue
            d = np.linalg.norm(pos[i] - pos[j], axis=1)
            airborne = (pos[i, :, 2] > AIRBORNE_Z) & (pos[j, :, 2] > AIRBORNE_Z)
            d = np.where(airborne & ~np.isnan(d), d, np.inf)
            per_step = np.minimum(per_step, d)
            for limit, kind in ((fl.safety_distance, "conflict"), (fl.collision_distance, "collision")):
                below = d < limit
                onsets = int(np.count_nonzero(below[1:] & ~below[:-1]) + (1 if below.size and below[0] else 0))
                if kind == "conflict":
                    conflicts += onsets
                else:
                    collisions += onsets
    wd.cross_separation = per_step
    cross = traffic = 0
    for u, s in stats.items():
        mine = swarm_of.get(u)
        for nb, v in (s.get("neighbours") or {}).items():
            try:
                if swarm_of.get(int(nb)) != mine:
                    cross += int(v.get("received", 0))
            except (ValueError, TypeError, AttributeError):
                continue
        t = (s.get("payload") or {}).get("traffic") or {}
        traffic += int(t.get("messages", 0)) if isinstance(t, dict) else 0
    finite = per_step[np.isfinite(per_step)]
    swarms: dict[str, list[int]] = {}
    for u, sw in swarm_of.items():
        swarms.setdefault(sw, []).append(u)
    return AirspaceReport(
        swarms={k: sorted(v) for k, v in swarms.items()},
        feed=bool(scn.world is not None and scn.world.airspace.feed),
        min_separation_m=round(float(finite.min()), 3) if finite.size else None,
        conflicts=conflicts, collisions=collisions, cross_swarm_samples=cross, traffic_messages=traffic)


def world_report(run_dir: Path, scn: Scenario, pos: np.ndarray, ids: list[int], t0: float, t_end: float,
                 stats: dict[int, dict[str, Any]]) -> tuple[WorldSummary, WorldData]:
    """The world section of a run's summary, and the series its figure needs."""
    wd = WorldData()
    try:
        service = json.loads((run_dir / "world.json").read_text())
    except (OSError, ValueError):
        service = {}
    svc = None
    if service:
        rejected: dict[str, int] = {}
        for net in (service.get("net") or {}).values():
            for k, v in (net.get("rejected") or {}).items():
                rejected[k] = rejected.get(k, 0) + int(v)
        svc = WorldService(cpu_percent=service.get("cpu_percent"), uavs_tracked=int(service.get("uavs_tracked", 0)),
                           readings={k: int(v) for k, v in (service.get("readings") or {}).items()}, rejected=rejected)
    out = WorldSummary(service=svc, sensors=sensor_report(scn, stats))
    if (p := plume_report(scn, run_dir, t0, t_end, wd)) is not None:
        out.plume = p
    if (f := fire_report(scn, run_dir, t0, service, wd)) is not None:
        out.fire = f
    if (z := zone_report(scn, pos, ids)) is not None:
        out.zones = z
    if (a := airspace_report(scn, pos, ids, stats, wd)) is not None:
        out.airspace = a
    return out, wd
