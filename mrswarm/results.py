"""Turn a run folder into a summary (JSON) and a picture (PNG).

Inputs, written by the UAVs while flying (see uav_stack/recorder.py): ``uav<N>.csv``
trajectories and ``uav<N>.json`` counters; and by the runner: ``run.json``. Separation
and coverage are computed from the UAVs' own flight-controller positions, not from the
poses they exchanged, so network impairments cannot hide a collision.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from swarmnet.stats import LogHistogram

GRID_HZ = 10.0
AIRBORNE_Z = 1.0  # m above the origin: below this a UAV is on the ground (not a collision candidate)


@dataclass
class Track:
    uav: int
    t: np.ndarray  # wall time
    t_sim: np.ndarray
    xyz: np.ndarray  # (n, 3)
    phase: list[str]
    rtf: np.ndarray


def load_tracks(run_dir: Path) -> dict[int, Track]:
    tracks: dict[int, Track] = {}
    for path in sorted(run_dir.glob("uav*.csv")):
        uav = int(path.stem[3:])
        rows = []
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                try:
                    rows.append((float(r["t_wall"]), float(r["t_sim"]), float(r["x"]), float(r["y"]), float(r["z"]), r["phase"], float(r["rtf"])))
                except (KeyError, ValueError, TypeError):
                    continue  # a line cut by a crash
        if not rows:
            continue
        rows.sort(key=lambda r: r[0])
        a = np.array([r[:5] for r in rows], dtype=float)
        tracks[uav] = Track(uav, a[:, 0], a[:, 1], a[:, 2:5], [r[5] for r in rows], np.array([r[6] for r in rows]))
    return tracks


def load_stats(run_dir: Path) -> dict[int, dict[str, Any]]:
    out = {}
    for path in sorted(run_dir.glob("uav*.json")):
        try:
            out[int(path.stem[3:])] = json.loads(path.read_text())
        except (ValueError, OSError):
            continue
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


def separation(grid: np.ndarray, pos: np.ndarray, ids: list[int], collision_distance: float) -> dict[str, Any]:
    """Minimum pairwise 3-D distance between airborne UAVs, per time step and overall."""
    n = len(ids)
    min_t = np.full(len(grid), np.inf)
    best = (math.inf, None, None, None)
    collisions = 0
    pairs_below: list[dict[str, Any]] = []
    for i in range(n):
        for j in range(i + 1, n):
            d = np.linalg.norm(pos[i] - pos[j], axis=1)
            airborne = (pos[i, :, 2] > AIRBORNE_Z) & (pos[j, :, 2] > AIRBORNE_Z)
            d = np.where(airborne & ~np.isnan(d), d, np.inf)
            min_t = np.minimum(min_t, d)
            k = int(np.argmin(d))
            if d[k] < best[0]:
                best = (float(d[k]), ids[i], ids[j], float(grid[k]))
            below = d < collision_distance
            onsets = int(np.count_nonzero(below[1:] & ~below[:-1]) + (1 if below.size and below[0] else 0))
            if onsets:
                collisions += onsets
                pairs_below.append({"pair": [ids[i], ids[j]], "onsets": onsets, "min": float(d[k])})
    return {
        "min": best[0] if best[0] != math.inf else None,
        "min_pair": [best[1], best[2]] if best[1] is not None else None,
        "min_at": best[3],
        "collisions": collisions,
        "collision_pairs": pairs_below,
        "per_step": min_t,
    }


def coverage(grid: np.ndarray, pos: np.ndarray, active: np.ndarray, area: tuple[float, float, float, float],
             radius: float) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Fraction of the area's cells seen (within ``radius`` of an active UAV) by each grid time.

    Returns (coverage per grid step, first-visit time per cell or NaN, (cell x centres, cell y centres)).
    """
    x0, x1, y0, y1 = area
    cell = max(radius / 2.0, 0.5)
    xs = np.arange(x0 + cell / 2, x1, cell)
    ys = np.arange(y0 + cell / 2, y1, cell)
    cx, cy = np.meshgrid(xs, ys)
    cells = np.stack([cx.ravel(), cy.ravel()], axis=1)
    first = np.full(len(cells), np.inf)
    r2 = radius * radius
    n_uav, n_t, _ = pos.shape
    for k in range(n_t):
        pts = pos[:, k, :2][active[:, k]]
        if len(pts) == 0:
            continue
        d2 = ((cells[:, None, :] - pts[None, :, :]) ** 2).sum(axis=2).min(axis=1)
        hit = (d2 <= r2) & (first == np.inf)
        first[hit] = grid[k]
    frac = np.searchsorted(np.sort(first), grid, side="right") / len(cells)
    first_visit = np.where(np.isinf(first), np.nan, first).reshape(cy.shape)
    return frac, first_visit, (xs, ys)


def time_to(frac: np.ndarray, grid: np.ndarray, t0: float, level: float) -> float | None:
    idx = np.nonzero(frac >= level)[0]
    return float(grid[idx[0]] - t0) if len(idx) else None


def analyze(run_dir: Path, scenario: Any, write: bool = True) -> dict[str, Any]:
    """Compute the summary of a finished (or interrupted) run and write summary.json + PNG."""
    run = json.loads((run_dir / "run.json").read_text()) if (run_dir / "run.json").exists() else {}
    tracks = load_tracks(run_dir)
    stats = load_stats(run_dir)
    fl = scenario.flight
    summary: dict[str, Any] = {
        "scenario": scenario.name,
        "run_dir": str(run_dir),
        "uavs_planned": len(scenario.uav_list()),
        "uavs_recorded": len(tracks),
        "interrupted": bool(run.get("interrupted")),
    }
    if not tracks:
        summary["error"] = "no trajectory was recorded"
        if write:
            (run_dir / "summary.json").write_text(json.dumps(summary, indent=2))
        return summary
    t_first = min(tr.t[0] for tr in tracks.values())
    t_last = max(tr.t[-1] for tr in tracks.values())
    t0 = run.get("mission_start") or t_first
    t_end = min(t_last, t0 + scenario.duration) if run.get("mission_start") else t_last
    grid, pos, ids = resample(tracks, t_first, t_last)
    sep = separation(grid, pos, ids, fl.collision_distance)
    in_mission = grid >= t0
    sep_mission = sep["per_step"][in_mission & (grid <= t_end)]
    finite = sep_mission[np.isfinite(sep_mission)]
    summary["separation"] = {
        "min_m": sep["min"],
        "min_pair": sep["min_pair"],
        "min_at_s": (sep["min_at"] - t0) if sep["min_at"] is not None else None,
        "min_during_mission_m": float(finite.min()) if finite.size else None,
        "safety_distance_m": fl.safety_distance,
        "time_below_safety_s": float(np.count_nonzero(finite < fl.safety_distance) / GRID_HZ),
        "collision_distance_m": fl.collision_distance,
        "collisions": sep["collisions"],
        "collision_pairs": sep["collision_pairs"],
    }
    # phases per grid step (mission-active mask for coverage)
    active = np.zeros(pos.shape[:2], dtype=bool)
    for k, u in enumerate(ids):
        tr = tracks[u]
        flying = np.array([p in ("mission", "done") for p in tr.phase])
        idx = np.clip(np.searchsorted(tr.t, grid, side="right") - 1, 0, len(tr.t) - 1)
        active[k] = flying[idx] & (grid >= tr.t[0]) & (grid <= tr.t[-1]) & ~np.isnan(pos[k, :, 0])
    m = scenario.mission
    cov_curve = None
    if m.type == "coverage" and m.area is not None:
        frac, first_visit, axes = coverage(grid, pos, active, m.area.as_tuple(), m.sensor_radius)
        sel = (grid >= t0) & (grid <= t_end)
        cov_curve = (grid[sel] - t0, frac[sel])
        summary["coverage"] = {
            "final": float(frac[sel][-1]) if sel.any() else 0.0,
            "time_to_50_s": time_to(frac, grid, t0, 0.5),
            "time_to_90_s": time_to(frac, grid, t0, 0.9),
            "curve": [[round(float(t), 1), round(float(c), 4)] for t, c in zip(*cov_curve)][:: int(GRID_HZ)],
            "sensor_radius_m": m.sensor_radius,
            "strategy": m.strategy,
        }
    else:
        first_visit, axes = None, None
    if m.type == "goto":
        summary["goals"] = goals_report(scenario, tracks, fl)
        if len(ids) == 2:
            summary["encounter"] = encounter_report(scenario, grid, pos, ids, sep["per_step"])
    summary["rtf"] = rtf_report(tracks, stats, t0, t_end)
    summary["network"] = network_report(stats)
    _netem_sections(summary["network"], run_dir, stats, t0, t_end, write)
    summary["processes"] = run.get("exit_codes", {})
    summary["duration_s"] = float(t_end - t0)
    if write:
        (run_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=_json_default))
        try:
            plot_run(run_dir / f"{scenario.name}.png", scenario, tracks, grid, pos, ids, sep["per_step"], t0, t_end, cov_curve,
                     first_visit, axes)
            summary["plot"] = str(run_dir / f"{scenario.name}.png")
            (run_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=_json_default))
        except Exception as exc:  # a plotting failure must not lose the numbers
            summary["plot_error"] = repr(exc)
    return summary


def _netem_sections(network: dict[str, Any], run_dir: Path, stats: dict[int, dict[str, Any]], t0: float, t_end: float,
                    write: bool) -> None:
    """Per-link netem statistics and pose age over time (with its plot): mrswarm/netem_report.py."""
    from mrswarm.netem_report import netem_report, pose_age_report

    ne = netem_report(stats)
    if ne is not None:
        network["netem"] = ne
    try:
        age = pose_age_report(run_dir, t0, t_end, ne["changes"] if ne else None, run_dir / "pose_age.png" if write else None)
    except Exception as exc:  # a plotting failure must not lose the numbers
        network["pose_age_over_time_error"] = repr(exc)
        return
    if age is not None:
        network["pose_age_over_time"] = age


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)


def goals_report(scenario: Any, tracks: dict[int, Track], fl: Any) -> dict[str, Any]:
    out = {}
    for u in scenario.uav_list():
        tr = tracks.get(u.id)
        if tr is None or u.goal is None:
            out[str(u.id)] = {"reached": False, "final_distance_m": None}
            continue
        d = np.hypot(tr.xyz[:, 0] - u.goal[0], tr.xyz[:, 1] - u.goal[1])
        reached = np.nonzero(d <= 2.0)[0]
        out[str(u.id)] = {
            "reached": bool(len(reached)),
            "final_distance_m": float(d[-1]),
            "reached_at_wall": float(tr.t[reached[0]]) if len(reached) else None,
        }
    return out


def encounter_report(scenario: Any, grid: np.ndarray, pos: np.ndarray, ids: list[int], per_step: np.ndarray) -> dict[str, Any]:
    """Where two UAVs flying at each other met: the midpoint at their closest approach."""
    k = int(np.argmin(per_step))
    if not np.isfinite(per_step[k]):
        return {}
    a, b = pos[0, k, :2], pos[1, k, :2]
    mid = (a + b) / 2
    starts = {u.id: np.array(u.start) for u in scenario.uav_list()}
    return {
        "time_wall": float(grid[k]),
        "separation_m": float(per_step[k]),
        "meeting_point": [round(float(mid[0]), 2), round(float(mid[1]), 2)],
        "distance_from_start_m": {str(u): round(float(np.linalg.norm(mid - starts[u])), 2) for u in ids},
    }


def rtf_report(tracks: dict[int, Track], stats: dict[int, dict[str, Any]], t0: float, t1: float) -> dict[str, Any]:
    per = {}
    for u, tr in tracks.items():
        sel = (tr.t >= t0) & (tr.t <= t1)
        if np.count_nonzero(sel) >= 2:
            tw, ts = tr.t[sel], tr.t_sim[sel]
            per[str(u)] = round(float((ts[-1] - ts[0]) / (tw[-1] - tw[0])), 4) if tw[-1] > tw[0] else None
        else:
            per[str(u)] = None
    vals = [v for v in per.values() if v is not None]
    return {"per_uav": per, "mean": float(np.mean(vals)) if vals else None, "min": float(np.min(vals)) if vals else None}


def network_report(stats: dict[int, dict[str, Any]]) -> dict[str, Any]:
    h = LogHistogram()
    sent: dict[str, int] = {}
    recv: dict[str, int] = {}
    rej: dict[str, int] = {}
    lost = received = 0
    for s in stats.values():
        net = s.get("net", {})
        try:
            h.merge(LogHistogram.from_dict(net["pose_age"]))
        except (KeyError, ValueError):
            pass
        for src, dst in ((net.get("sent", {}), sent), (net.get("received", {}), recv), (net.get("rejected", {}), rej)):
            for k, v in src.items():
                dst[k] = dst.get(k, 0) + int(v)
        for nb in s.get("neighbours", {}).values():
            lost += int(nb.get("lost", 0))
            received += int(nb.get("received", 0))
    ms = lambda v: round(v * 1000.0, 2) if v == v else None  # noqa: E731
    return {
        "pose_age_ms": {"p50": ms(h.percentile(50)), "p99": ms(h.percentile(99)), "mean": ms(h.mean), "max": ms(h.max), "n": h.n},
        "messages_sent": sent,
        "messages_received": recv,
        "messages_rejected": rej,
        "pose_loss": round(lost / (lost + received), 5) if lost + received else 0.0,
    }


def plot_run(path: Path, scenario: Any, tracks: dict[int, Track], grid: np.ndarray, pos: np.ndarray, ids: list[int],
             min_sep: np.ndarray, t0: float, t_end: float, cov_curve: tuple[np.ndarray, np.ndarray] | None,
             first_visit: np.ndarray | None, axes: tuple[np.ndarray, np.ndarray] | None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(14, 6), gridspec_kw={"width_ratios": [1.3, 1]})
    if first_visit is not None and axes is not None:
        xs, ys = axes
        covered = np.where(np.isnan(first_visit), np.nan, first_visit - t0)
        step = xs[1] - xs[0] if len(xs) > 1 else 1.0
        extent = (xs[0] - step / 2, xs[-1] + step / 2, ys[0] - step / 2, ys[-1] + step / 2)
        ax.imshow(np.ones_like(covered), origin="lower", extent=extent, cmap="Greys", vmin=0, vmax=6, aspect="equal")  # uncovered: grey
        im = ax.imshow(covered, origin="lower", extent=extent, cmap="viridis", alpha=0.55, aspect="equal")
        fig.colorbar(im, ax=ax, fraction=0.035, label="first covered at (s)")
    m = scenario.mission
    if m.area is not None:
        x0, x1, y0, y1 = m.area.as_tuple()
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], "k--", lw=1)
    cmap = plt.get_cmap("tab20")
    rtf_of = {u.id: u.rtf for u in scenario.uav_list()}
    for k, u in enumerate(ids):
        p = pos[k]
        label = f"UAV {u}" + (f" (RTF {rtf_of[u]:g})" if rtf_of.get(u, 1.0) != 1.0 else "")
        ax.plot(p[:, 0], p[:, 1], "-", lw=1.1, color=cmap(k % 20), label=label if len(ids) <= 12 else None)
        tr = tracks[u]
        ax.plot(tr.xyz[0, 0], tr.xyz[0, 1], "o", color=cmap(k % 20), ms=4)
    for u in scenario.uav_list():
        if u.goal is not None:
            ax.plot(*u.goal, "x", color="k", ms=8)
    if len(ids) == 2 and np.isfinite(min_sep).any():  # closest approach of a head-on encounter
        k = int(np.nanargmin(np.where(np.isfinite(min_sep), min_sep, np.nan)))
        ax.plot(pos[:, k, 0], pos[:, k, 1], "k:", lw=1)
        ax.plot(pos[:, k, 0].mean(), pos[:, k, 1].mean(), "*", color="tab:red", ms=12, label=f"closest {min_sep[k]:.1f} m")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"{scenario.name}: trajectories" + (" and covered cells" if first_visit is not None else ""))
    if len(ids) <= 12:
        ax.legend(fontsize=7, loc="upper right")
    sel = (grid >= t0) & (grid <= t_end)
    t_rel = grid[sel] - t0
    ms = np.where(np.isfinite(min_sep[sel]), min_sep[sel], np.nan)
    ax2.plot(t_rel, ms, color="tab:red", lw=1, label="min pairwise separation")
    ax2.axhline(scenario.flight.safety_distance, color="tab:red", ls=":", lw=1, label="safety distance")
    ax2.set_xlabel("time since mission start (s)")
    ax2.set_ylabel("separation (m)", color="tab:red")
    top = np.nanmax(ms) if np.isfinite(ms).any() else 10.0
    ax2.set_ylim(0, min(top * 1.1, 100.0))
    if cov_curve is not None:
        ax3 = ax2.twinx()
        ax3.plot(cov_curve[0], cov_curve[1] * 100, color="tab:green", lw=2, label="coverage")
        ax3.set_ylabel("coverage (%)", color="tab:green")
        ax3.set_ylim(0, 100)
    ax2.legend(loc="lower right", fontsize=8)
    ax2.set_title("coverage and separation over time" if cov_curve is not None else "separation over time")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
