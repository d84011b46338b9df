"""The figures of a run folder, drawn from what mrswarm/analysis.py computed (matplotlib, Agg backend).

- ``<scenario>.png``: trajectories over the covered cells (coverage missions) or the goals
  (goto), and the minimum separation (plus coverage) over mission time;
- ``pose_age.png``: transport age, age at use and age of information per second, per UAV and their
  median, with the mission start and each netem change marked.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mrswarm.analysis import RunData
from mrswarm.netem_report import PoseAgeSeries
from mrswarm.scenario import Scenario
from mrswarm.summary import NetemChange


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_run(path: Path, scenario: Scenario, data: RunData) -> None:
    """Trajectories (left) and separation/coverage over time (right) -> ``path`` (PNG)."""
    plt = _pyplot()
    grid, pos, ids, min_sep, t0 = data.grid, data.pos, data.ids, data.min_separation, data.t0
    cov = data.coverage
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(14, 6), gridspec_kw={"width_ratios": [1.3, 1]})
    if cov is not None:
        xs, ys = cov.xs, cov.ys
        covered = np.where(np.isnan(cov.first_visit), np.nan, cov.first_visit - t0)
        step = xs[1] - xs[0] if len(xs) > 1 else 1.0
        extent = (xs[0] - step / 2, xs[-1] + step / 2, ys[0] - step / 2, ys[-1] + step / 2)
        # uncovered cells grey, covered ones coloured by the time of their first visit
        ax.imshow(np.ones_like(covered), origin="lower", extent=extent, cmap="Greys", vmin=0, vmax=6, aspect="equal")
        im = ax.imshow(covered, origin="lower", extent=extent, cmap="viridis", alpha=0.55, aspect="equal")
        fig.colorbar(im, ax=ax, fraction=0.035, label="first covered at (s)")
    m = scenario.mission
    if m.area is not None:
        x0, x1, y0, y1 = m.area.as_tuple()
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], "k--", lw=1)
    cmap = plt.get_cmap("tab20")
    rtf_of = {u.id: u.rtf for u in scenario.uav_list()}
    external = {u.id: u.realm_name for u in scenario.external_uavs()}
    for k, u in enumerate(ids):
        p = pos[k]
        label = f"UAV {u}" + (f" ({external[u]}, external FCU)" if u in external else
                              f" (RTF {rtf_of[u]:g})" if rtf_of.get(u, 1.0) != 1.0 else "")
        ax.plot(p[:, 0], p[:, 1], "-", lw=1.1, color=cmap(k % 20), label=label if len(ids) <= 12 else None)
        tr = data.tracks[u]
        ax.plot(tr.xyz[0, 0], tr.xyz[0, 1], "o", color=cmap(k % 20), ms=4)
    for uav in scenario.all_uavs():
        if uav.goal is not None:
            ax.plot(*uav.goal, "x", color="k", ms=8)
    if len(ids) == 2 and np.isfinite(min_sep).any():  # closest approach of a head-on encounter
        k = int(np.nanargmin(np.where(np.isfinite(min_sep), min_sep, np.nan)))
        ax.plot(pos[:, k, 0], pos[:, k, 1], "k:", lw=1)
        ax.plot(pos[:, k, 0].mean(), pos[:, k, 1].mean(), "*", color="tab:red", ms=12, label=f"closest {min_sep[k]:.1f} m")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"{scenario.name}: trajectories" + (" and covered cells" if cov is not None else ""))
    if len(ids) <= 12:
        ax.legend(fontsize=7, loc="upper right")
    sel = (grid >= t0) & (grid <= data.t_end)
    t_rel = grid[sel] - t0
    ms = np.where(np.isfinite(min_sep[sel]), min_sep[sel], np.nan)
    ax2.plot(t_rel, ms, color="tab:red", lw=1, label="min pairwise separation")
    ax2.axhline(scenario.flight.safety_distance, color="tab:red", ls=":", lw=1, label="safety distance")
    ax2.set_xlabel("time since mission start (s)")
    ax2.set_ylabel("separation (m)", color="tab:red")
    top = np.nanmax(ms) if np.isfinite(ms).any() else 10.0
    ax2.set_ylim(0, min(top * 1.1, 100.0))
    if cov is not None:
        ax3 = ax2.twinx()
        ax3.plot(cov.t, cov.fraction * 100, color="tab:green", lw=2, label="coverage")
        ax3.set_ylabel("coverage (%)", color="tab:green")
        ax3.set_ylim(0, 100)
    ax2.legend(loc="lower right", fontsize=8)
    ax2.set_title("coverage and separation over time" if cov is not None else "separation over time")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_pose_age(path: Path, age: PoseAgeSeries, changes: list[NetemChange]) -> None:
    """Transport age and age at use (top) and age of information (bottom) per second -> ``path`` (PNG)."""
    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    for s in age.series.values():
        t = s["t_wall"] - age.t0
        if "transport_p50_ms" in s:
            ax1.plot(t, s["transport_p50_ms"], lw=0.6, alpha=0.45)
        ax2.plot(t, s["aoi_mean_ms"], lw=0.6, alpha=0.45)
    ax1.plot(age.grid, age.transport_med, color="k", lw=2, label="transport age, median over UAVs")
    if not np.all(np.isnan(age.use_med)):
        ax1.plot(age.grid, age.use_med, color="tab:blue", lw=2, ls="--", label="age at use, median over UAVs")
    ax2.plot(age.grid, age.aoi_med, color="k", lw=2, label="median over UAVs")
    ax1.set_ylabel("pose age, p50 per second (ms)")
    ax2.set_ylabel("age of information, mean over\nneighbours (ms)")
    ax2.set_xlabel("time since mission start (s)")
    for ax in (ax1, ax2):
        ax.axvline(0.0, color="tab:green", lw=1, ls=":")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    for ch in changes:
        x = ch.applied_first - age.t0
        for ax in (ax1, ax2):
            ax.axvline(x, color="tab:red", lw=1, ls="--")
        label = f"netem ({ch.source}): {ch.preset or 'custom'}"
        ax1.annotate(label, (x, 0.04), xycoords=("data", "axes fraction"), xytext=(3, 0), textcoords="offset points",
                     rotation=90, va="bottom", ha="left", fontsize=8, color="tab:red")
    ax1.legend(loc="upper left", fontsize=8)
    ax1.set_title(f"pose age over time ({len(age.series)} UAVs; thin lines: each UAV's transport age, per second)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
