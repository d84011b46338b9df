"""The netem shim's statistics and the pose age over time, for summary.json (the plot: mrswarm/results/plots.py).

Inputs are what every UAV writes while flying: the ``netem`` section of ``uav<N>.json``
(per-link counters and delay histograms, the history of configuration changes) and
``age_uav<N>.csv`` (per-second pose ages and age of information, uav_stack/pose_age.py).
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from groundfloor.histogram import LogHistogram
from mrswarm.records.summary import Delay, Netem, NetemChange, NetemClass, NetemConfigUse, NetemLink, NetemTotals, PoseAgeOverTime
from mrswarm.results.run_data import PoseAgeSeries

_COUNTERS = ("sent", "delivered", "duplicated", "reordered", "jumps")


def _ms(v: float) -> float | None:
    return round(v * 1000.0, 2) if v == v and v != math.inf else None


def _hist(d: dict[str, Any] | None) -> LogHistogram:
    try:
        return LogHistogram.from_dict(d or {})
    except (KeyError, ValueError, TypeError):
        return LogHistogram()


def _delay(h: LogHistogram) -> Delay:
    return Delay(mean=_ms(h.mean), p50=_ms(h.percentile(50)), p99=_ms(h.percentile(99)), max=_ms(h.max) if h.n else None)


def netem_report(stats: dict[int, dict[str, Any]]) -> Netem | None:
    """Per-link rows, totals per link class and overall, and the configuration changes (None: netem never configured)."""
    links: list[NetemLink] = []
    counts: dict[str, dict[str, int]] = {}  # per class: links, the counters, dropped
    dropped_by: dict[str, dict[str, int]] = {}
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
                                          "config": str(c.get("config")), "t_sent": c.get("t_sent"), "applied": []})
            ch["applied"].append(float(c.get("t", 0.0)))
        for src, lk in (ne.get("links") or {}).items():
            cls = lk.get("class") or "unimpaired"
            h = _hist(lk.get("delay"))
            dropped = {k: int(v) for k, v in (lk.get("dropped") or {}).items() if v}
            n = {k: int(lk.get(k, 0)) for k in _COUNTERS}
            n["dropped"] = sum(dropped.values())
            links.append(NetemLink(link=f"{src}->{uav}", cls=cls, **n, dropped_by=dropped, delay_ms=_delay(h)))
            tot = counts.setdefault(cls, dict.fromkeys(("links", *_COUNTERS, "dropped"), 0))
            tot["links"] += 1
            for k, v in n.items():
                tot[k] += v
            by = dropped_by.setdefault(cls, {})
            for k, v in dropped.items():
                by[k] = by.get(k, 0) + v
            class_hist.setdefault(cls, LogHistogram()).merge(h)
    if not configs:
        return None
    all_h = LogHistogram()
    classes: dict[str, NetemClass] = {}
    for cls, tot in counts.items():
        classes[cls] = NetemClass(**tot, dropped_by=dropped_by[cls], loss=_loss(tot), delay_ms=_delay(class_hist[cls]))
        all_h.merge(class_hist[cls])
    total = {k: sum(t[k] for t in counts.values()) for k in (*_COUNTERS, "dropped")}
    change_list = []
    for ch in sorted(changes.values(), key=lambda c: min(c["applied"])):
        ap = ch.pop("applied")
        change = NetemChange(**ch, uavs=len(ap), applied_first=min(ap), applied_last=max(ap))
        if ch.get("t_sent"):
            change.latency_max_s = round(max(ap) - ch["t_sent"], 4)
        change_list.append(change)
    return Netem(
        configs=[NetemConfigUse(config=c, uavs=u) for c, u in configs.items()],
        changes=change_list,
        total=NetemTotals(**total, loss=_loss(total), delay_ms=_delay(all_h)),
        classes=classes,
        links=sorted(links, key=lambda r: (r.cls, r.link)),
    )


def _loss(n: dict[str, int]) -> float:
    """Dropped share of what the shim was offered (a duplicate is offered too)."""
    return round(n["dropped"] / (n["sent"] + n["duplicated"]), 5) if n["sent"] else 0.0


def pose_age_report(series: dict[int, dict[str, np.ndarray]], t0: float,
                    t_end: float) -> tuple[PoseAgeOverTime, PoseAgeSeries] | None:
    """Swarm-wide pose age per second (medians over UAVs) from every UAV's ``age_uav<N>.csv`` columns
    (:func:`~mrswarm.results.analysis.load_ages`); None if no UAV wrote one."""
    if not series:
        return None
    t_first = min(float(s["t_wall"][0]) for s in series.values())
    grid = np.arange(math.floor(t_first - t0), math.ceil(t_end - t0) + 1.0)

    def on_grid(key: str) -> np.ndarray:
        m = np.full((len(series), len(grid)), np.nan)
        for k, s in enumerate(series.values()):
            if key not in s:
                continue
            idx = np.round(s["t_wall"] - t0).astype(int) - int(grid[0])
            ok = (idx >= 0) & (idx < len(grid))
            m[k, idx[ok]] = s[key][ok]
        return m

    with warnings.catch_warnings():  # seconds where no UAV has a value are NaN, which is what we want
        warnings.simplefilter("ignore", RuntimeWarning)
        transport_med = np.nanmedian(on_grid("transport_p50_ms"), axis=0)
        use_med = np.nanmedian(on_grid("use_p50_ms"), axis=0)
        aoi_med = np.nanmedian(on_grid("aoi_mean_ms"), axis=0)
        aoi_max = np.nanmax(on_grid("aoi_max_ms"), axis=0)
    keep = ~np.isnan(transport_med) | ~np.isnan(aoi_med)

    def r(a: np.ndarray) -> list[float | None]:
        return [None if v != v else round(float(v), 2) for v in a[keep]]

    report = PoseAgeOverTime(t_s=[float(t) for t in grid[keep]], transport_p50_ms=r(transport_med), use_p50_ms=r(use_med),
                             aoi_mean_ms=r(aoi_med), aoi_max_ms=r(aoi_max))
    return report, PoseAgeSeries(grid=grid, series=series, t0=t0, transport_med=transport_med, use_med=use_med,
                                 aoi_med=aoi_med)
