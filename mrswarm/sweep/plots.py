"""Each metric against the swept parameter: the mean of every cell with its confidence interval, every run a dot.

As the paper's figures: the parameter on the horizontal axis (the number of UAVs, a netem
preset), the mean over seeds as a marker joined by a line, its 95 % interval as an error bar,
one line per combination of the other grid keys. A cell where some runs have no value (a
coverage time never reached) says how many have one (``2/3``). Written per metric
(``plots/<metric>.png``) and as one figure of every plotted metric (``overview.png``).
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

from mrswarm.results.plots import PALETTE, _pyplot, legend_below
from mrswarm.sweep.campaign import value_label
from mrswarm.sweep.slots import SlotState
from mrswarm.sweep.table import CellStats, Table, metric

DPI = 100
PLOTS = "plots"
OVERVIEW = "overview.png"
AXIS_NAMES = {"fleet.count": "number of UAVs", "network.netem.preset": "link (netem preset)", "duration": "mission duration (s)",
              "flight.speed": "cruise speed (m/s)", "flight.safety_distance": "safety distance (m)"}


def _numeric(values: list[Any]) -> bool:
    return bool(values) and all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)


def _series(t: Table) -> list[tuple[str, list[CellStats]]]:
    """The cells grouped by the values of the grid keys other than x, each group in x order."""
    x = t.x
    groups: dict[str, list[CellStats]] = {}
    for c in t.cells:
        others = [(k, v) for k, v in c.values.items() if k != x and len(t.grid.get(k, [])) > 1]
        label = ", ".join(f"{_short(k)} {value_label(v)}" for k, v in others)
        groups.setdefault(label, []).append(c)
    return list(groups.items())


def _short(key: str) -> str:
    return {"fleet.count": "N", "network.netem.preset": "netem"}.get(key, key.rsplit(".", 1)[-1])


def draw_metric(ax: Any, t: Table, path: str, ylabel: bool = True) -> None:
    """One metric's panel (``ylabel``: the metric's name on the axis, else only its unit, under a title that names it)."""
    m = metric(path)
    x = t.x
    xs_all = t.grid.get(x, []) if x is not None else []
    numeric = _numeric(xs_all)
    labels = [value_label(v) for v in xs_all]
    series = _series(t)
    span = (max(xs_all) - min(xs_all)) if numeric and len(xs_all) > 1 else 1.0
    step = 0.03 * span if numeric else 0.08
    for i, (label, cells) in enumerate(series):
        color = PALETTE[i % len(PALETTE)]
        dodge = (i - (len(series) - 1) / 2) * step
        px, py, lo, hi = [], [], [], []
        for c in cells:
            s = c.stats.get(path)
            xv: Any = c.values.get(x) if x is not None else None
            pos = (float(xv) if numeric else float(labels.index(value_label(xv)))) if x is not None else 0.0
            pos += dodge
            runs = [r.values.get(path) for r in t.rows if r.state == SlotState.OK and r.cell == c.values]
            dots = [v * m.scale for v in runs if v is not None and math.isfinite(v)]
            ax.plot([pos] * len(dots), dots, "o", ms=3.2, color=color, alpha=0.35, mew=0, zorder=3)
            if s is None or s.mean is None:
                continue
            px.append(pos)
            py.append(s.mean * m.scale)
            lo.append((s.mean - s.ci_low) * m.scale if s.ci_low is not None else 0.0)
            hi.append((s.ci_high - s.mean) * m.scale if s.ci_high is not None else 0.0)
            if s.n < s.runs:
                ax.annotate(f"{s.n}/{s.runs}", (pos, s.mean * m.scale), xytext=(5, 4), textcoords="offset points",
                            fontsize=7, color=color)
        if px:
            ax.errorbar(px, py, yerr=[lo, hi], fmt="-o", color=color, ms=5, lw=1.4, capsize=4, elinewidth=1.2,
                        label=label or None, zorder=4)
    if x is not None and not numeric:
        ax.set_xticks(range(len(labels)), labels)
        ax.set_xlim(-0.5, len(labels) - 0.5)
    elif numeric:
        ax.set_xticks(sorted(float(v) for v in xs_all))
        pad = 0.08 * span
        ax.set_xlim(min(xs_all) - pad, max(xs_all) + pad)
    else:
        ax.set_xticks([0.0], ["all runs"])
    ax.set_xlabel(AXIS_NAMES.get(x or "", x or ""))
    if ylabel:
        ax.set_ylabel(f"{m.label}" + (f" ({m.unit})" if m.unit and m.unit != "cores" else ""))
    else:
        ax.set_ylabel(m.unit)
    ax.grid(alpha=0.3)
    lo_lim, hi_lim = ax.get_ylim()
    bottom = 0.0 if lo_lim >= 0 or lo_lim > -0.05 * (hi_lim - lo_lim) else lo_lim
    ax.set_ylim(bottom, hi_lim + 0.06 * (hi_lim - bottom))  # room above the highest interval


def _caption(t: Table) -> str:
    pct = f"{100 * t.level:g} %"
    seeds = f"{t.seeds} seed{'s' if t.seeds != 1 else ''}"
    return f"{t.name}: mean and {pct} confidence interval (t) over {seeds} per cell; dots: single runs"


def plot_metric(path: Path, t: Table, name: str) -> None:
    plt = _pyplot()
    fig = plt.figure(figsize=(6.4, 4.6), layout="constrained")
    ax = fig.subplots()
    draw_metric(ax, t, name)
    ax.set_title(metric(name).label, fontsize=10)
    legend_below(ax, ncol=3)
    fig.suptitle(_caption(t), fontsize=8)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def plot_overview(path: Path, t: Table, names: list[str]) -> None:
    plt = _pyplot()
    n = len(names)
    cols = 1 if n == 1 else 2 if n <= 4 else 3
    rows = math.ceil(n / cols)
    fig = plt.figure(figsize=(4.4 * cols + 0.6, 3.3 * rows + 0.9), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False)
    for k, name in enumerate(names):
        ax = axes[k // cols][k % cols]
        draw_metric(ax, t, name, ylabel=False)
        ax.set_title(metric(name).label, fontsize=9)
    for k in range(n, rows * cols):
        axes[k // cols][k % cols].set_visible(False)
    handles, labels = axes[0][0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="outside lower center", ncol=min(len(handles), 5), frameon=False, fontsize=8)
    fig.suptitle(_caption(t), fontsize=10)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def file_name(metric_path: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.\-]+", "_", metric_path) + ".png"


def write_plots(campaign_dir: Path, t: Table) -> list[Path]:
    """``plots/<metric>.png`` for every plotted metric and ``overview.png``; nothing without a complete run."""
    if not t.plots or not any(r.state == SlotState.OK for r in t.rows):
        return []
    folder = campaign_dir / PLOTS
    folder.mkdir(exist_ok=True)
    out = []
    for name in t.plots:
        p = folder / file_name(name)
        plot_metric(p, t, name)
        out.append(p)
    p = campaign_dir / OVERVIEW
    plot_overview(p, t, t.plots)
    return [p, *out]
