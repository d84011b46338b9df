"""The figure of a world scenario (``<scenario>.png``): the world and the trajectories, and how it went over time.

The map: the fire grid at the end (unburnt fuel green, burnt out dark, extinguished blue,
still burning red, no fuel grey) or the plume (the cone before and, if the wind turned during the
mission, after the turn; or the Gaussian plume's concentration at flight altitude), the mission
or search area, the no-fly zones, the hub, each UAV's trajectory (a colour family per swarm when
several share the airspace), the goals, where the UAVs sprayed, and their last source estimates.
Beside it (below it, for a map much wider than tall): the localisation error over time (plume),
the burnt area and burning cells (fire), the separation between swarms (shared airspace), up to
the end of the mission.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from mrswarm.results.plots import (
    MAX_LEGEND,
    _pyplot,
    draw_area,
    draw_tracks,
    legend_below,
    map_and_time,
    map_extent,
    save_figure,
    separation_over_time,
    uav_colors,
)
from mrswarm.results.run_data import RunData
from mrswarm.scenario import Scenario
from world.config import ConePlume, GaussianPlume
from world.fire import BURNING, BURNT, EXTINGUISHED


def _fire_layer(ax: Any, grid: dict[str, np.ndarray]) -> list[Any]:
    """The fire grid at the end; returns the legend's keys to its colours."""
    from matplotlib.patches import Patch

    xs, ys, fuel, state = grid["xs"], grid["ys"], grid["fuel"], grid["state"]
    rgba = np.ones(state.shape + (4,))
    green = np.array([0.55, 0.78, 0.45])
    rgba[..., :3] = 1.0 - (1.0 - green) * fuel[..., None]  # paler where there is less fuel
    rgba[fuel <= 0.0] = (0.82, 0.82, 0.82, 1.0)
    rgba[state == BURNT] = (0.25, 0.18, 0.15, 1.0)
    rgba[state == EXTINGUISHED] = (0.35, 0.55, 0.95, 1.0)
    rgba[state == BURNING] = (0.95, 0.3, 0.1, 1.0)
    c = float(grid["cell_m"])
    ax.imshow(rgba, origin="lower", extent=(xs[0] - c / 2, xs[-1] + c / 2, ys[0] - c / 2, ys[-1] + c / 2), aspect="equal",
              interpolation="nearest", zorder=0)
    keys: list[tuple[tuple[float, float, float], str]] = [
        ((float(green[0]), float(green[1]), float(green[2])), "forest (paler: less fuel)"), ((0.25, 0.18, 0.15), "burnt out"),
        ((0.35, 0.55, 0.95), "put out"), ((0.95, 0.3, 0.1), "still burning"), ((0.82, 0.82, 0.82), "nothing to burn")]
    return [Patch(facecolor=col, edgecolor="none", label=label) for col, label in keys]


def _plume_layer(ax: Any, scn: Scenario, extent: tuple[float, float, float, float], t_end: float) -> None:
    w = scn.world
    assert w is not None and w.plume is not None
    p = w.plume
    sx, sy = p.source
    if isinstance(p, ConePlume):
        reach = p.range_m or 2.0 * max(abs(extent[1] - extent[0]), abs(extent[3] - extent[2]))
        times = [0.0] + ([w.wind.turn_after_s] if w.wind.turn_after_s is not None and w.wind.turn_after_s <= t_end else [])
        for k, t in enumerate(times):
            th = math.radians(w.wind.direction_at(t))
            half = math.radians(p.width_deg) / 2
            pts = [(sx, sy)] + [(sx + reach * math.cos(th + a), sy + reach * math.sin(th + a))
                                for a in np.linspace(-half, half, 24)]
            color = ("tab:purple", "tab:orange")[k % 2]
            ax.fill(*zip(*pts, strict=True), facecolor=color, alpha=0.15, edgecolor=color, lw=1, zorder=1,
                    label=f"plume from {t:g} s")
    elif isinstance(p, GaussianPlume):
        from world.plume import gaussian_reading

        gx, gy = np.meshgrid(np.linspace(extent[0], extent[1], 160), np.linspace(extent[2], extent[3], 160))
        grid = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, scn.flight.altitude)], axis=1)
        c = gaussian_reading(grid, p, w.wind.speed, w.wind.direction_at(t_end)).reshape(gx.shape)
        if (c > 0).any():
            lvl = np.log10(np.where(c > 0, c, np.nan))
            im = ax.imshow(lvl, origin="lower", extent=extent, cmap="Purples", alpha=0.6, aspect="equal", zorder=1)
            ax.figure.colorbar(im, ax=ax, fraction=0.035, label="log10 concentration at flight altitude (mg/m^3)")
    ax.plot(sx, sy, "*", color="k", ms=16, zorder=6, label="source")


def plot_world(path: Path, scn: Scenario, data: RunData) -> None:
    """The world map with the trajectories and the world's outcome over time -> ``path`` (PNG)."""
    save_figure(world_figure(scn, data), path)


def world_figure(scn: Scenario, data: RunData) -> Any:
    """The figure of :func:`plot_world` (a matplotlib Figure; the caller closes it)."""
    plt = _pyplot()
    wd = data.world
    w = scn.world
    assert w is not None
    ext = map_extent(data, scn)
    fig, ax, ax2 = map_and_time(plt, ext)
    ids = data.ids
    m = scn.mission
    t_end = data.t_end - data.t0
    fire_keys: list[Any] = []
    if wd is not None and wd.fire_grid is not None:
        fire_keys = _fire_layer(ax, wd.fire_grid)
    if w.plume is not None:
        _plume_layer(ax, scn, ext, t_end)
    for z in w.zones:
        poly = list(z.polygon) + [z.polygon[0]]
        ax.fill(*zip(*poly, strict=True), facecolor="none", edgecolor="k", hatch="///", lw=1.2, zorder=3,
                label="no-fly zone" if z is w.zones[0] else None)
        cx, cy = np.mean([p[0] for p in z.polygon]), np.mean([p[1] for p in z.polygon])
        ax.text(cx, cy, z.name or z.kind.replace("_", "-"), ha="center", va="center", fontsize=8, zorder=7,
                bbox={"fc": "white", "alpha": 0.8, "lw": 0})
    draw_area(ax, scn, "search area" if m.type == "plume" else "mission area")
    if m.wildfire is not None:
        hub = plt.Circle(m.wildfire.hub, m.wildfire.hub_radius, color="tab:blue", fill=False, lw=1.5, zorder=4, label="hub")
        ax.add_patch(hub)
        ax.text(*m.wildfire.hub, "hub", ha="center", va="center", fontsize=8, color="tab:blue", zorder=7)
    swarm_of = scn.swarm_of()
    swarms = list(dict.fromkeys(swarm_of[u] for u in ids if u in swarm_of))
    if len(swarms) > 1:  # one family of colours per swarm, a shade per UAV
        families = ("Blues", "Oranges", "Greens", "Purples", "Reds")
        colors: list[Any] = []
        labels: list[str | None] = []
        for u in ids:
            sw = swarm_of.get(u, scn.swarm)
            mates = [v for v in ids if swarm_of.get(v, scn.swarm) == sw]
            shade = 0.55 + 0.4 * (mates.index(u) / max(len(mates) - 1, 1))
            colors.append(plt.get_cmap(families[swarms.index(sw) % len(families)])(shade))
            labels.append(f"{sw} UAV {u}")
    else:
        colors, labels = uav_colors(len(ids)), [f"UAV {u}" for u in ids]
    lines = draw_tracks(ax, data, scn, colors, labels)
    goals = [g.goal for g in scn.all_uavs() if g.goal is not None]
    for k, goal in enumerate(goals):
        ax.plot(*goal, "x", color="k", ms=8, mew=2, zorder=7, label="goal" if k == 0 else None)
    if wd is not None and wd.sprays is not None:
        ax.plot(wd.sprays[:, 0], wd.sprays[:, 1], ".", color="navy", ms=2.5, alpha=0.6, zorder=6, label="sprays")
    if wd is not None and wd.estimates:
        last = np.array([e[-1, 1:] for e in wd.estimates.values() if len(e)])
        ax.plot(last[:, 0], last[:, 1], "x", color="tab:red", ms=8, mew=2, zorder=6, label="last source estimates")
    ax.set_xlim(ext[0], ext[1])
    ax.set_ylim(ext[2], ext[3])
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_title(f"{scn.name}: world and trajectories (dot: start, triangle: end)", fontsize=10)
    others = [h for h in ax.get_legend_handles_labels()[0] if h not in lines]
    legend_below(ax, (lines if len(ids) <= MAX_LEGEND else []) + others + fire_keys,
                 ncol=min(len(lines) + len(others) + len(fire_keys), 6))
    _over_time(ax2, scn, data)
    return fig


def _over_time(ax: Any, scn: Scenario, data: RunData) -> None:
    """The world's outcome over the mission; the time axis ends where the analysed mission did."""
    wd = data.world
    w = scn.world
    assert w is not None
    t_end = max(data.t_end - data.t0, 1.0)
    if wd is not None and wd.error_curve is not None and len(wd.error_curve):
        c = wd.error_curve
        ax.plot(c[:, 0], c[:, 1], color="tab:red", lw=2, label="median over UAVs")
        ax.plot(c[:, 0], c[:, 2], color="tab:red", lw=1, ls=":", label="best UAV")
        if w.wind.turn_after_s is not None and w.wind.turn_after_s <= t_end:  # only a turn that happened
            ax.axvline(w.wind.turn_after_s, color="tab:purple", ls="--", lw=1, label=f"wind turns {w.wind.turn_deg:g} deg")
        ax.set_ylabel("source localisation error (m)")
        ax.set_ylim(bottom=0)
        ax.set_title("plume source localisation error over the mission", fontsize=10)
        legend_below(ax)
    elif wd is not None and wd.fire_curve is not None and len(wd.fire_curve):
        c = wd.fire_curve
        ax.plot(c[:, 0], c[:, 1], color="tab:brown", lw=2, label="burnt area (m²)")
        ax.set_ylabel("burnt area (m²)", color="tab:brown")
        ax.set_ylim(bottom=0)
        ax3 = ax.twinx()
        ax3.plot(c[:, 0], c[:, 2], color="tab:red", lw=1, label="cells burning")
        ax3.set_ylabel("cells burning", color="tab:red")
        ax3.set_ylim(bottom=0)
        ax.set_title("fire over the mission", fontsize=10)
        legend_below(ax, ax.get_legend_handles_labels()[0] + ax3.get_legend_handles_labels()[0])
    elif wd is not None and wd.cross_separation is not None:
        separation_over_time(ax, scn, data, wd.cross_separation, label="closest UAVs of different swarms")
        ax.set_title("separation between swarms" + ("" if w.airspace.feed else " (airspace feed off)"), fontsize=10)
        legend_below(ax, ncol=2)
    else:
        separation_over_time(ax, scn, data)
        ax.set_title("separation over the mission", fontsize=10)
        legend_below(ax, ncol=2)
    ax.set_xlim(0, t_end)
    ax.set_xlabel("time since mission start (s)")
    ax.grid(alpha=0.3)
