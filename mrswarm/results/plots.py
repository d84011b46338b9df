"""The figures of a run folder, drawn from what mrswarm/results/analysis.py computed (matplotlib, Agg backend).

- ``<scenario>.png``: the map (the mission area, the covered cells by the time of their first
  visit, every UAV's trajectory from its start, the goals) and, beside or below it, the minimum
  separation (plus coverage) over mission time, with the safety and collision distances and the
  time below the safety distance shaded;
- ``pose_age.png``: transport age, age at use and age of information per second of the mission,
  per UAV and their median, with each netem change marked.

Shared by both, and by mrswarm/results/world_plots.py: a palette that keeps 20 UAVs apart
(:func:`uav_colors`), legends outside the data (:func:`legend_below`), a layout fitted to the
map's shape (:func:`map_and_time`), axes that end where the mission did.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mrswarm.records.summary import NetemChange
from mrswarm.results.run_data import PoseAgeSeries, RunData
from mrswarm.scenario import Scenario

DPI = 100  # a 13 x 6.5 in figure is 1300 x 650 px: sharp on a page, small on disk
# Twenty colours that stay apart on white and on the light grey of the covered cells: matplotlib's tab10,
# then ten darker or more saturated hues of other names (not tab20, whose neighbours are one hue, light and dark)
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
           "#000080", "#b8860b", "#006400", "#ff00ff", "#000000", "#8b0000", "#556b2f", "#ff1493", "#4b0082", "#008080")
MAX_LEGEND = 20  # UAVs named in a legend; more are one colour cycle, said in the title


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: Path) -> None:
    """Write a figure (PNG) and free it, also when the disk refuses it."""
    try:
        fig.savefig(path, dpi=DPI)
    finally:
        _pyplot().close(fig)


def uav_colors(n: int) -> list[str]:
    """One colour per UAV: 20 distinct ones, then the same again."""
    return [PALETTE[k % len(PALETTE)] for k in range(n)]


def legend_below(ax: Any, handles: list[Any] | None = None, ncol: int | None = None, **kw: Any) -> None:
    """The axes' legend under them, outside the data (nothing when there is nothing to name)."""
    if handles is None:
        handles, labels = ax.get_legend_handles_labels()
    else:
        labels = [h.get_label() for h in handles]
    if not handles:
        return
    n = len(handles)
    ax.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, -0.12), frameon=False, fontsize=8,
              ncol=ncol or min(n, 5), handlelength=1.6, columnspacing=1.2, **kw)


def map_and_time(plt: Any, extent: tuple[float, float, float, float]) -> tuple[Any, Any, Any]:
    """A figure with the map and the plot over time: side by side, or for a map much wider than tall (two swarms
    on a line, a long corridor) the plot below it, so that neither is squashed."""
    w, h = extent[1] - extent[0], extent[3] - extent[2]
    aspect = w / h if h > 0 else 1.0
    if aspect >= 1.8:
        map_h = min(8.0, 12.0 / aspect) + 0.8
        fig = plt.figure(figsize=(12, map_h + 4.6), layout="constrained")
        ax, ax2 = fig.subplots(2, 1, gridspec_kw={"height_ratios": [map_h, 4.6]})
    else:
        fig = plt.figure(figsize=(14, 6.8), layout="constrained")
        ax, ax2 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.25, 1]})
    return fig, ax, ax2


def map_extent(data: RunData, scenario: Scenario, pad: float = 5.0) -> tuple[float, float, float, float]:
    """What the map shows: every recorded position, the mission area and the goals, with a margin."""
    pos = data.pos
    finite = pos[~np.isnan(pos[..., 0])][:, :2]
    pts = [finite] if len(finite) else []
    m = scenario.mission
    if m.area is not None:
        x0, x1, y0, y1 = m.area.as_tuple()
        pts.append(np.array([[x0, y0], [x1, y1]]))
    goals = [u.goal for u in scenario.all_uavs() if u.goal is not None]
    if goals:
        pts.append(np.array(goals, dtype=float))
    w = scenario.world
    if w is not None:
        if w.fire is not None:
            a = w.fire.area
            pts.append(np.array([[a.x_min, a.y_min], [a.x_max, a.y_max]]))
        for z in w.zones:
            pts.append(np.array(z.polygon, dtype=float))
    if m.wildfire is not None:
        (hx, hy), r = m.wildfire.hub, m.wildfire.hub_radius
        pts.append(np.array([[hx - r, hy - r], [hx + r, hy + r]]))
    allp = np.concatenate(pts) if pts else np.zeros((1, 2))
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    return (float(lo[0] - pad), float(hi[0] + pad), float(lo[1] - pad), float(hi[1] + pad))


def draw_tracks(ax: Any, data: RunData, scenario: Scenario, colors: Sequence[Any] | None = None,
                labels: Sequence[str | None] | None = None) -> list[Any]:
    """Every UAV's trajectory (a white edge keeps it readable over any background), a dot at its start and a
    triangle at its end; returns the lines, for a legend."""
    import matplotlib.patheffects as pe

    ids = data.ids
    colors = colors or uav_colors(len(ids))
    rtf_of = {u.id: u.rtf for u in scenario.all_uavs()}
    external = {u.id: u.realm_name for u in scenario.external_uavs()}
    halo = [pe.Stroke(linewidth=2.6, foreground="white", alpha=0.8), pe.Normal()]
    lines = []
    for k, u in enumerate(ids):
        p = data.pos[k]
        label = labels[k] if labels is not None else f"UAV {u}" + (
            f" ({external[u]}, external FCU)" if u in external else f" (RTF {rtf_of[u]:g})" if rtf_of.get(u, 1.0) != 1.0 else "")
        (line,) = ax.plot(p[:, 0], p[:, 1], "-", lw=1.3, color=colors[k], label=label, path_effects=halo, zorder=5)
        lines.append(line)
        tr = data.tracks[u]
        ax.plot(tr.xyz[0, 0], tr.xyz[0, 1], "o", color=colors[k], ms=4.5, mec="white", mew=0.6, zorder=6)
        ok = np.nonzero(~np.isnan(p[:, 0]))[0]
        if len(ok):
            ax.plot(p[ok[-1], 0], p[ok[-1], 1], "^", color=colors[k], ms=5, mec="white", mew=0.6, zorder=6)
    return lines


def draw_area(ax: Any, scenario: Scenario, label: str = "mission area") -> None:
    m = scenario.mission
    if m.area is not None:
        x0, x1, y0, y1 = m.area.as_tuple()
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], "--", color="0.25", lw=1.1, label=label, zorder=4)


def separation_over_time(ax: Any, scenario: Scenario, data: RunData, series: np.ndarray | None = None,
                         label: str = "closest pair of UAVs") -> None:
    """The minimum separation over mission time, the safety and collision distances, the time below the safety
    distance shaded; the axes end where the analysed mission did."""
    grid, t0 = data.grid, data.t0
    sel = (grid >= t0) & (grid <= data.t_end)
    t_rel = grid[sel] - t0
    vals = (data.min_separation if series is None else series)[sel]
    ms = np.where(np.isfinite(vals), vals, np.nan)
    fl = scenario.flight
    ax.plot(t_rel, ms, color="tab:red", lw=1.4, label=label)
    ax.axhline(fl.safety_distance, color="tab:red", ls=":", lw=1.2, label=f"safety distance ({fl.safety_distance:g} m)")
    ax.axhline(fl.collision_distance, color="k", ls="--", lw=1, label=f"collision distance ({fl.collision_distance:g} m)")
    below = np.nan_to_num(ms, nan=np.inf) < fl.safety_distance
    if below.any():
        ax.fill_between(t_rel, 0, 1, where=below, transform=ax.get_xaxis_transform(), color="tab:red", alpha=0.15, lw=0,
                        label="below the safety distance")
    top = float(np.nanmax(ms)) if np.isfinite(ms).any() else 2 * fl.safety_distance
    ax.set_ylim(0, min(max(top * 1.08, 2 * fl.safety_distance), 100.0))
    ax.set_xlim(0, max(float(t_rel[-1]) if len(t_rel) else 1.0, 1.0))
    ax.set_xlabel("time since mission start (s)")
    ax.set_ylabel("separation (m)")
    ax.grid(alpha=0.3)


def plot_run(path: Path, scenario: Scenario, data: RunData) -> None:
    """The map and the separation/coverage over time -> ``path`` (PNG)."""
    save_figure(run_figure(scenario, data), path)


def run_figure(scenario: Scenario, data: RunData) -> Any:
    """The figure of :func:`plot_run` (a matplotlib Figure; the caller closes it)."""
    plt = _pyplot()
    extent = map_extent(data, scenario)
    fig, ax, ax2 = map_and_time(plt, extent)
    cov, t0 = data.coverage, data.t0
    if cov is not None:
        xs, ys = cov.xs, cov.ys
        covered = np.where(np.isnan(cov.first_visit), np.nan, cov.first_visit - t0)
        step = xs[1] - xs[0] if len(xs) > 1 else 1.0
        cells = (xs[0] - step / 2, xs[-1] + step / 2, ys[0] - step / 2, ys[-1] + step / 2)
        never = np.where(np.isnan(covered), 1.0, np.nan)  # never covered: pale red
        ax.imshow(never, origin="lower", extent=cells, cmap="Reds", vmin=0, vmax=4, aspect="equal", interpolation="nearest",
                  zorder=1)
        from matplotlib.colors import ListedColormap

        # greys from mid (covered at the start) to nearly white (covered last): the trajectories' colours stay apart
        greys = ListedColormap(plt.get_cmap("Greys")(np.linspace(0.55, 0.08, 256)))
        im = ax.imshow(covered, origin="lower", extent=cells, cmap=greys, vmin=0.0, aspect="equal", interpolation="nearest",
                       zorder=1)
        fig.colorbar(im, ax=ax, fraction=0.04, pad=0.01, label="cell first covered at (s since the mission start; "
                                                               "pale red: never)")
    draw_area(ax, scenario)
    ids = data.ids
    lines = draw_tracks(ax, data, scenario)
    goals = [(u.id, u.goal) for u in scenario.all_uavs() if u.goal is not None]
    for k, (_, g) in enumerate(goals):
        ax.plot(*g, "x", color="k", ms=9, mew=2, zorder=7, label="goal" if k == 0 else None)
    c = data.closest
    if len(ids) == 2 and c is not None:  # closest approach of a head-on encounter
        ax.plot(data.pos[:, c, 0], data.pos[:, c, 1], "k:", lw=1, zorder=7)
        ax.plot(data.pos[:, c, 0].mean(), data.pos[:, c, 1].mean(), "*", color="tab:red", ms=13, zorder=8,
                label=f"closest, {data.min_separation[c]:.1f} m")
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    many = f"; {len(ids)} UAVs, colours repeat after {MAX_LEGEND}" if len(ids) > MAX_LEGEND else ""
    ax.set_title(f"{scenario.name}: trajectories (dot: start, triangle: end)"
                 + (" over the covered cells" if cov is not None else "") + many, fontsize=10)
    others = [h for h in ax.get_legend_handles_labels()[0] if h not in lines]
    legend_below(ax, (lines[:MAX_LEGEND] if len(ids) <= MAX_LEGEND else []) + others, ncol=min(len(lines) + len(others), 7))
    separation_over_time(ax2, scenario, data)
    handles = ax2.get_legend_handles_labels()[0]
    if cov is not None:
        ax3 = ax2.twinx()
        ax3.plot(cov.t, cov.fraction * 100, color="tab:green", lw=2, label="area covered")
        ax3.set_ylabel("area covered (%)", color="tab:green")
        ax3.set_ylim(0, 102)
        handles += ax3.get_legend_handles_labels()[0]
    legend_below(ax2, handles, ncol=3)
    ax2.set_title("separation" + (" and coverage" if cov is not None else "") + " over the mission", fontsize=10)
    return fig


def plot_pose_age(path: Path, age: PoseAgeSeries, changes: list[NetemChange], t_end: float | None = None) -> None:
    """Transport age and age at use (top) and age of information (bottom) per second of the mission -> ``path`` (PNG)."""
    save_figure(pose_age_figure(age, changes, t_end), path)


def pose_age_figure(age: PoseAgeSeries, changes: list[NetemChange], t_end: float | None = None) -> Any:
    """The figure of :func:`plot_pose_age`: only the mission (0 to ``t_end`` s, the analysed end), since before it
    the UAVs are starting and the last second of a run holds its shutdown, whose ages say nothing of the swarm."""
    plt = _pyplot()
    fig = plt.figure(figsize=(11, 7.2), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    end = float(t_end) if t_end is not None else float(age.grid[-1])
    colors = uav_colors(len(age.series))
    for k, s in enumerate(age.series.values()):
        t = s["t_wall"] - age.t0
        inside = (t >= 0.0) & (t <= end)
        if "transport_p50_ms" in s:
            ax1.plot(t[inside], s["transport_p50_ms"][inside], lw=0.6, alpha=0.5, color=colors[k])
        ax2.plot(t[inside], s["aoi_mean_ms"][inside], lw=0.6, alpha=0.5, color=colors[k])
    g = (age.grid >= 0.0) & (age.grid <= end)
    ax1.plot(age.grid[g], age.transport_med[g], color="k", lw=2,
             label="transport age (sender's stamp to arrival), median over UAVs")
    if not np.all(np.isnan(age.use_med[g])):
        ax1.plot(age.grid[g], age.use_med[g], color="tab:blue", lw=2, ls="--",
                 label="age at use (arrival to the controller), median over UAVs")
    ax2.plot(age.grid[g], age.aoi_med[g], color="k", lw=2, label="age of information, median over UAVs")
    ax1.set_ylabel("pose age, p50 of each second (ms)")
    ax2.set_ylabel("age of information, mean over\nneighbours (ms)")
    ax2.set_xlabel("time since mission start (s)")
    for ax in (ax1, ax2):
        ax.set_ylim(bottom=0)
        ax.set_xlim(0, max(end, 1.0))
        ax.grid(alpha=0.3)
    for ch in changes:
        x = ch.applied_first - age.t0
        if not 0.0 <= x <= end:
            continue
        for ax in (ax1, ax2):
            ax.axvline(x, color="tab:red", lw=1, ls="--")
        ax1.annotate(f"netem ({ch.source}): {ch.preset or 'custom'}", (x, 0.04), xycoords=("data", "axes fraction"),
                     xytext=(3, 0), textcoords="offset points", rotation=90, va="bottom", ha="left", fontsize=8,
                     color="tab:red")
    handles = ax1.get_legend_handles_labels()[0] + ax2.get_legend_handles_labels()[0]
    fig.legend(handles, [h.get_label() for h in handles], loc="outside lower center", ncol=2, frameon=False, fontsize=8)
    ax1.set_title(f"pose age over the mission ({len(age.series)} UAVs; thin lines: each UAV, per second)", fontsize=10)
    return fig
