"""The figure of a world scenario (``<scenario>.png``): the world and the trajectories, and how it went over time.

Left, the map: the fire grid at the end (unburnt fuel green, burnt out dark, extinguished blue,
still burning red, no fuel grey) or the plume (the cone before and after the wind turned, or
the Gaussian plume's concentration at flight altitude), the no-fly zones, the hub, each UAV's
trajectory (coloured by swarm when several share the airspace), where the UAVs sprayed, and
their last source estimates. Right: the localisation error over time (plume), the burnt area
and burning cells (fire), the separation between swarms (shared airspace).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from mrswarm.analysis import RunData
from mrswarm.plots import _pyplot
from mrswarm.scenario import Scenario
from world.config import ConePlume, GaussianPlume
from world.fire import BURNING, BURNT, EXTINGUISHED


def _fire_layer(ax: Any, grid: dict[str, np.ndarray]) -> None:
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
    """The world map with the trajectories (left) and the world's outcome over time (right) -> ``path`` (PNG)."""
    plt = _pyplot()
    wd = data.world
    w = scn.world
    assert w is not None
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(15, 6.5), gridspec_kw={"width_ratios": [1.3, 1]})
    pos, ids = data.pos, data.ids
    finite = pos[~np.isnan(pos[..., 0])]
    lo, hi = finite[:, :2].min(axis=0), finite[:, :2].max(axis=0)
    if w.fire is not None:
        a = w.fire.area
        lo, hi = np.minimum(lo, (a.x_min, a.y_min)), np.maximum(hi, (a.x_max, a.y_max))
    m = scn.mission
    if m.area is not None:
        lo, hi = np.minimum(lo, (m.area.x_min, m.area.y_min)), np.maximum(hi, (m.area.x_max, m.area.y_max))
    pad = 5.0
    extent = (float(lo[0] - pad), float(hi[0] + pad), float(lo[1] - pad), float(hi[1] + pad))
    if wd is not None and wd.fire_grid is not None:
        _fire_layer(ax, wd.fire_grid)
    if w.plume is not None:
        _plume_layer(ax, scn, extent, data.t_end - data.t0)
    for z in w.zones:
        poly = list(z.polygon) + [z.polygon[0]]
        ax.fill(*zip(*poly, strict=True), facecolor="none", edgecolor="k", hatch="///", lw=1.2, zorder=3)
        cx, cy = np.mean([p[0] for p in z.polygon]), np.mean([p[1] for p in z.polygon])
        ax.text(cx, cy, z.name or z.kind.replace("_", "-"), ha="center", va="center", fontsize=8, zorder=7,
                bbox={"fc": "white", "alpha": 0.7, "lw": 0})
    if m.area is not None and m.type == "plume":
        ar = m.area
        ax.plot([ar.x_min, ar.x_max, ar.x_max, ar.x_min, ar.x_min], [ar.y_min, ar.y_min, ar.y_max, ar.y_max, ar.y_min],
                "k--", lw=0.8)
    if m.wildfire is not None:
        hub = plt.Circle(m.wildfire.hub, m.wildfire.hub_radius, color="tab:blue", fill=False, lw=1.5, zorder=4)
        ax.add_patch(hub)
        ax.text(*m.wildfire.hub, "hub", ha="center", va="center", fontsize=8, color="tab:blue", zorder=7)
    swarm_of = scn.swarm_of()
    swarms = list(dict.fromkeys(swarm_of[u] for u in ids if u in swarm_of))
    cmap = plt.get_cmap("tab10" if len(swarms) > 1 else "tab20")
    labelled: set[str] = set()
    for k, u in enumerate(ids):
        p = pos[k]
        sw = swarm_of.get(u, scn.swarm)
        color = cmap(swarms.index(sw) % 10) if len(swarms) > 1 else cmap(k % 20)
        label = (f"swarm {sw}" if sw not in labelled else None) if len(swarms) > 1 else (f"UAV {u}" if len(ids) <= 12 else None)
        labelled.add(sw)
        ax.plot(p[:, 0], p[:, 1], "-", lw=1.0, color=color, label=label, zorder=5)
        tr = data.tracks[u]
        ax.plot(tr.xyz[0, 0], tr.xyz[0, 1], "o", color=color, ms=3.5, zorder=5)
    if wd is not None and wd.sprays is not None:
        ax.plot(wd.sprays[:, 0], wd.sprays[:, 1], ".", color="tab:blue", ms=2, alpha=0.5, zorder=5, label="sprays")
    if wd is not None and wd.estimates:
        last = np.array([e[-1, 1:] for e in wd.estimates.values() if len(e)])
        ax.plot(last[:, 0], last[:, 1], "x", color="tab:red", ms=8, mew=2, zorder=6, label="last source estimates")
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_title(f"{scn.name}: world and trajectories")
    ax.legend(fontsize=7, loc="upper right")
    _over_time(ax2, scn, data)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _over_time(ax: Any, scn: Scenario, data: RunData) -> None:
    wd = data.world
    w = scn.world
    assert w is not None
    if wd is not None and wd.error_curve is not None and len(wd.error_curve):
        c = wd.error_curve
        ax.plot(c[:, 0], c[:, 1], color="tab:red", lw=2, label="median over UAVs")
        ax.plot(c[:, 0], c[:, 2], color="tab:red", lw=1, ls=":", label="best UAV")
        if w.wind.turn_after_s is not None:
            ax.axvline(w.wind.turn_after_s, color="tab:purple", ls="--", lw=1, label=f"wind turns {w.wind.turn_deg:g} deg")
        ax.set_ylabel("source localisation error (m)")
        ax.set_ylim(bottom=0)
        ax.set_title("plume source localisation error over time")
    elif wd is not None and wd.fire_curve is not None and len(wd.fire_curve):
        c = wd.fire_curve
        ax.plot(c[:, 0], c[:, 1], color="tab:brown", lw=2, label="burnt area (m^2)")
        ax.set_ylabel("burnt area (m^2)", color="tab:brown")
        ax3 = ax.twinx()
        ax3.plot(c[:, 0], c[:, 2], color="tab:red", lw=1, label="cells burning")
        ax3.set_ylabel("cells burning", color="tab:red")
        ax3.set_ylim(bottom=0)
        ax.set_title("fire over time")
    elif wd is not None and wd.cross_separation is not None:
        sel = (data.grid >= data.t0) & (data.grid <= data.t_end)
        sep = np.where(np.isfinite(wd.cross_separation[sel]), wd.cross_separation[sel], np.nan)
        ax.plot(data.grid[sel] - data.t0, sep, color="tab:red", lw=1.5, label="closest UAVs of different swarms")
        ax.axhline(scn.flight.safety_distance, color="tab:red", ls=":", lw=1, label="safety distance")
        ax.axhline(scn.flight.collision_distance, color="k", ls="--", lw=1, label="collision distance")
        ax.set_ylabel("separation (m)")
        ax.set_ylim(bottom=0)
        ax.set_title("separation between swarms" + ("" if w.airspace.feed else " (airspace feed off)"))
    else:
        sel = (data.grid >= data.t0) & (data.grid <= data.t_end)
        ms = np.where(np.isfinite(data.min_separation[sel]), data.min_separation[sel], np.nan)
        ax.plot(data.grid[sel] - data.t0, ms, color="tab:red", lw=1, label="min pairwise separation")
        ax.set_ylabel("separation (m)")
        ax.set_title("separation over time")
    ax.set_xlabel("time since mission start (s)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
