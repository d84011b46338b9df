"""Run analysis of the netem shim: per-link statistics and pose age over time (summary.json + PNG).

Inputs are what every UAV writes while flying: the ``netem`` section of ``uav<N>.json``
(per-link counters and delay histograms, the history of configuration changes) and
``age_uav<N>.csv`` (per-second pose age and age of information, uav_stack/pose_age.py).
"""

from __future__ import annotations

import csv
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from swarmnet.stats import LogHistogram

_COUNTERS = ("sent", "delivered", "duplicated", "reordered", "jumps")


def _ms(v: float) -> float | None:
    return round(v * 1000.0, 2) if v == v and v != math.inf else None


def _hist(d: dict[str, Any] | None) -> LogHistogram:
    try:
        return LogHistogram.from_dict(d or {})
    except (KeyError, ValueError, TypeError):
        return LogHistogram()


def _delay(h: LogHistogram) -> dict[str, Any]:
    return {"mean": _ms(h.mean), "p50": _ms(h.percentile(50)), "p99": _ms(h.percentile(99)), "max": _ms(h.max) if h.n else None}


def netem_report(stats: dict[int, dict[str, Any]]) -> dict[str, Any] | None:
    """Per-link rows, totals per link class and overall, and the configuration changes."""
    links: list[dict[str, Any]] = []
    classes: dict[str, dict[str, Any]] = {}
    class_hist: dict[str, LogHistogram] = {}
    changes: dict[tuple[Any, str, str], dict[str, Any]] = {}
    configs: dict[str, list[int]] = {}
    for uav, s in sorted(stats.items()):
        ne = s.get("netem")
        if not isinstance(ne, dict):
            continue
        configs.setdefault(str(ne.get("config")), []).append(uav)
        for c in ne.get("changes", []):
            key = (c.get("id"), str(c.get("source")), str(c.get("config")))
            ch = changes.setdefault(key, {"id": c.get("id"), "source": c.get("source"), "preset": c.get("preset"),
                                          "config": c.get("config"), "t_sent": c.get("t_sent"), "applied": []})
            ch["applied"].append(float(c.get("t", 0.0)))
        for src, lk in (ne.get("links") or {}).items():
            cls = lk.get("class") or "unimpaired"
            h = _hist(lk.get("delay"))
            dropped = {k: int(v) for k, v in (lk.get("dropped") or {}).items() if v}
            row = {"link": f"{src}->{uav}", "class": cls, **{k: int(lk.get(k, 0)) for k in _COUNTERS},
                   "dropped": sum(dropped.values()), "dropped_by": dropped, "delay_ms": _delay(h)}
            links.append(row)
            tot = classes.setdefault(cls, {"links": 0, **{k: 0 for k in _COUNTERS}, "dropped": 0, "dropped_by": {}})
            tot["links"] += 1
            for k in (*_COUNTERS, "dropped"):
                tot[k] += row[k]
            for k, v in dropped.items():
                tot["dropped_by"][k] = tot["dropped_by"].get(k, 0) + v
            class_hist.setdefault(cls, LogHistogram()).merge(h)
    if not configs:
        return None
    all_h = LogHistogram()
    for cls, tot in classes.items():
        tot["loss"] = round(tot["dropped"] / (tot["sent"] + tot["duplicated"]), 5) if tot["sent"] else 0.0
        tot["delay_ms"] = _delay(class_hist[cls])
        all_h.merge(class_hist[cls])
    total = {k: sum(t[k] for t in classes.values()) for k in (*_COUNTERS, "dropped")}
    total["loss"] = round(total["dropped"] / (total["sent"] + total["duplicated"]), 5) if total["sent"] else 0.0
    total["delay_ms"] = _delay(all_h)
    change_list = []
    for ch in sorted(changes.values(), key=lambda c: min(c["applied"])):
        ap = ch.pop("applied")
        ch.update(uavs=len(ap), applied_first=min(ap), applied_last=max(ap))
        if ch.get("t_sent"):
            ch["latency_max_s"] = round(max(ap) - ch["t_sent"], 4)
        change_list.append(ch)
    return {
        "configs": [{"config": c, "uavs": u} for c, u in configs.items()],
        "changes": change_list,
        "total": total,
        "classes": classes,
        "links": sorted(links, key=lambda r: (r["class"], r["link"])),
    }


def load_age_series(run_dir: Path) -> dict[int, dict[str, np.ndarray]]:
    out: dict[int, dict[str, np.ndarray]] = {}
    for path in sorted(run_dir.glob("age_uav*.csv")):
        try:
            uav = int(path.stem[len("age_uav"):])
        except ValueError:
            continue
        cols: dict[str, list[float]] = {}
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                try:
                    vals = {k: float(v) if v not in ("", None) else math.nan for k, v in r.items()}
                except (TypeError, ValueError):
                    continue  # a line cut by a crash
                for k, v in vals.items():
                    cols.setdefault(k, []).append(v)
        if cols.get("t_wall"):
            out[uav] = {k: np.array(v) for k, v in cols.items()}
    return out


def pose_age_report(run_dir: Path, t0: float, t_end: float, changes: list[dict[str, Any]] | None,
                    plot_path: Path | None) -> dict[str, Any] | None:
    """Swarm-wide pose age per second (medians over UAVs) and, if ``plot_path``, the plot."""
    series = load_age_series(run_dir)
    if not series:
        return None
    t_first = min(float(s["t_wall"][0]) for s in series.values())
    grid = np.arange(math.floor(t_first - t0), math.ceil(t_end - t0) + 1.0)

    def on_grid(key: str) -> np.ndarray:
        m = np.full((len(series), len(grid)), np.nan)
        for k, s in enumerate(series.values()):
            idx = np.round(s["t_wall"] - t0).astype(int) - int(grid[0])
            ok = (idx >= 0) & (idx < len(grid))
            m[k, idx[ok]] = s[key][ok]
        return m

    age = on_grid("age_mean_ms")
    aoi = on_grid("aoi_mean_ms")
    with warnings.catch_warnings():  # seconds where no UAV has a value are NaN, which is what we want
        warnings.simplefilter("ignore", RuntimeWarning)
        age_med = np.nanmedian(age, axis=0)
        aoi_med = np.nanmedian(aoi, axis=0)
        aoi_max = np.nanmax(on_grid("aoi_max_ms"), axis=0)
    keep = ~np.isnan(age_med) | ~np.isnan(aoi_med)
    r = lambda a: [None if v != v else round(float(v), 1) for v in a[keep]]  # noqa: E731
    out: dict[str, Any] = {"t_s": [float(t) for t in grid[keep]], "age_mean_ms": r(age_med), "aoi_mean_ms": r(aoi_med),
                           "aoi_max_ms": r(aoi_max)}
    if plot_path is not None:
        try:
            plot_pose_age(plot_path, grid, series, t0, age_med, aoi_med, changes or [])
            out["plot"] = str(plot_path)
        except Exception as exc:  # a plotting failure must not lose the numbers
            out["plot_error"] = repr(exc)
    return out


def plot_pose_age(path: Path, grid: np.ndarray, series: dict[int, dict[str, np.ndarray]], t0: float,
                  age_med: np.ndarray, aoi_med: np.ndarray, changes: list[dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    for uav, s in series.items():
        t = s["t_wall"] - t0
        ax1.plot(t, s["age_mean_ms"], lw=0.6, alpha=0.45)
        ax2.plot(t, s["aoi_mean_ms"], lw=0.6, alpha=0.45)
    ax1.plot(grid, age_med, color="k", lw=2, label="median over UAVs")
    ax2.plot(grid, aoi_med, color="k", lw=2, label="median over UAVs")
    ax1.set_ylabel("pose age on arrival,\nmean per second (ms)")
    ax2.set_ylabel("age of information, mean over\nneighbours (ms)")
    ax2.set_xlabel("time since mission start (s)")
    for ax in (ax1, ax2):
        ax.axvline(0.0, color="tab:green", lw=1, ls=":")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    for ch in changes:
        x = float(ch["applied_first"]) - t0
        for ax in (ax1, ax2):
            ax.axvline(x, color="tab:red", lw=1, ls="--")
        label = f"netem ({ch.get('source')}): {ch.get('preset') or 'custom'}"
        ax1.annotate(label, (x, 0.04), xycoords=("data", "axes fraction"), xytext=(3, 0), textcoords="offset points",
                     rotation=90, va="bottom", ha="left", fontsize=8, color="tab:red")
    ax1.legend(loc="upper left", fontsize=8)
    ax1.set_title(f"pose age over time ({len(series)} UAVs; thin lines: each UAV, per second)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
