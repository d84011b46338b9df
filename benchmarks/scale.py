"""Scaling benchmark: RTF, CPU and memory per virtual UAV, pose age, as the swarm grows.

For each swarm size N it flies a random-coverage mission (every UAV keeps moving and
exchanging poses at 10 Hz) with the process runtime, waits ``--warmup`` seconds after the
mission starts, then measures every process over ``--window`` seconds:

* CPU: user+system time of each UAV process over the window, in % of one core;
* memory at the end of the window: RSS (the budget), plus USS and PSS (shared pages split);
* RTF of every virtual FCU (sim time / wall time over the mission, from its own log);
* pose age at the receivers (p50/p99, from every agent's histogram);
* the rendezvous router's and the runner's own CPU, reported separately.

    python benchmarks/scale.py --sizes 1 10 25 50 --out benchmarks/results

flies every network configuration of ``--configs`` at every N (interleaved, so that all
configurations share the machine's load of the moment) and writes ``scale.json``,
``scale.csv`` and ``scale.png`` (medians per N and configuration, side by side).
The machine is noisy: numbers are medians over the UAV processes of one run per cell.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import psutil
from rich.console import Console

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mrswarm.experiment import Experiment  # noqa: E402
from mrswarm.scenario import Scenario, parse_scenario  # noqa: E402

# name -> (network.connectivity, network.mode, network.pose_feed)
CONFIGS: dict[str, tuple[str, str, str]] = {
    "discovery-direct": ("discovery", "peer", "direct"),  # the default: beacon relay, peer mesh, every pose direct
    "discovery-edge": ("discovery", "peer", "edge"),      # beacon relay, poses batched by the edge router
    "client-edge": ("rendezvous", "client", "edge"),      # every UAV a client of the edge router, batched poses
    "rendezvous-direct": ("rendezvous", "peer", "direct"),
}


def scenario_for(n: int, duration: float, config: str) -> Scenario:
    connectivity, mode, feed = CONFIGS[config]
    side = max(120.0, 50.0 * math.sqrt(n))  # constant density: ~2500 m^2 per UAV
    return parse_scenario({
        "name": f"scale{n}",
        "swarm": f"bench{n}",
        "seed": 1,
        "duration": duration,
        "origin": {"lat": 46.6167, "lon": 14.2650, "alt": 446.0},
        "network": {"connectivity": connectivity, "mode": mode, "pose_feed": feed},
        "flight": {"altitude": 6, "speed": 5.0, "safety_distance": 5.0, "collision_distance": 1.0},
        "mission": {"type": "coverage", "strategy": "random",
                    "area": {"x_min": -side / 2, "x_max": side / 2, "y_min": -side / 2, "y_max": side / 2}, "sensor_radius": 10},
        "fleet": {"count": n, "spawn": {"pattern": "grid", "spacing": 8, "center": [0, 0]}},
    })


class Sampler:
    """Snapshots of every process of the run at the start and the end of the window."""

    def __init__(self, warmup: float, window: float):
        self.warmup, self.window = warmup, window
        self.t_start: float | None = None
        self.t_end: float | None = None
        self.start: dict[str, tuple[float, psutil.Process]] = {}
        self.result: dict[str, dict[str, float]] = {}

    def _procs(self, exp: Experiment) -> dict[str, psutil.Process]:
        procs = {n: psutil.Process(pid) for n, pid in exp.runtime.pids().items()}
        procs["runner"] = psutil.Process()
        return procs

    def __call__(self, exp: Experiment, elapsed: float) -> None:
        if self.t_start is None and elapsed >= self.warmup:
            self.t_start = time.time()
            for name, p in self._procs(exp).items():
                c = p.cpu_times()
                self.start[name] = (c.user + c.system, p)
        elif self.t_start is not None and self.t_end is None and time.time() - self.t_start >= self.window:
            self.t_end = time.time()
            dt = self.t_end - self.t_start
            for name, (cpu0, p) in self.start.items():
                try:
                    c = p.cpu_times()
                    mem = p.memory_full_info()
                    self.result[name] = {
                        "cpu_pct": 100.0 * (c.user + c.system - cpu0) / dt,
                        "rss_mb": mem.rss / 2**20, "uss_mb": mem.uss / 2**20, "pss_mb": mem.pss / 2**20,
                        "threads": p.num_threads(),
                    }
                except psutil.NoSuchProcess:
                    self.result[name] = {"cpu_pct": math.nan, "rss_mb": math.nan, "uss_mb": math.nan, "pss_mb": math.nan,
                                         "threads": 0}


def run_size(n: int, config: str, args: argparse.Namespace, console: Console,
             adapt: Callable[[Scenario], Scenario] | None = None) -> dict[str, Any]:
    """One run of N UAVs in ``config``; ``adapt`` changes the scenario first (benchmarks/security.py)."""
    sampler = Sampler(args.warmup, args.window)
    scn = scenario_for(n, args.warmup + args.window + 2.0, config)
    if adapt is not None:
        scn = adapt(scn)
    exp = Experiment(scn, Path(args.out) / "runs", console=console, live=False, log_level="WARNING", probe=sampler)
    t0 = time.time()
    summary = exp.run().to_dict()
    uavs = {k: v for k, v in sampler.result.items() if k.startswith("uav")}
    if not uavs:
        raise SystemExit(f"N={n}: no measurement (run aborted? {summary.get('aborted')})")
    med = lambda key: statistics.median(v[key] for v in uavs.values())  # noqa: E731
    mx = lambda key: max(v[key] for v in uavs.values())  # noqa: E731
    rtf = summary.get("rtf", {})
    age = summary.get("network", {}).get("pose_age_ms", {})
    row = {
        "n": n,
        "config": config,
        "connectivity": CONFIGS[config][0],
        "mode": CONFIGS[config][1],
        "feed": CONFIGS[config][2],
        "cpu_pct_median": round(med("cpu_pct"), 3),
        "cpu_pct_max": round(mx("cpu_pct"), 3),
        "rss_mb_median": round(med("rss_mb"), 1),
        "rss_mb_max": round(mx("rss_mb"), 1),
        "uss_mb_median": round(med("uss_mb"), 1),
        "pss_mb_median": round(med("pss_mb"), 1),
        "threads_median": med("threads"),
        "rtf_mean": rtf.get("mean"),
        "rtf_min": rtf.get("min"),
        "pose_age_p50_ms": age.get("p50"),
        "pose_age_p99_ms": age.get("p99"),
        "pose_loss": summary.get("network", {}).get("pose_loss"),
        "router_cpu_pct": round(sampler.result.get("router", {}).get("cpu_pct", math.nan), 2),
        "discovery_cpu_pct": round(sampler.result.get("discovery", {}).get("cpu_pct", math.nan), 2),
        "runner_cpu_pct": round(sampler.result.get("runner", {}).get("cpu_pct", math.nan), 2),
        "collisions": summary.get("separation", {}).get("collisions"),
        "wall_s": round(time.time() - t0, 1),
        "run_dir": summary.get("run_dir"),
    }
    console.print(row)
    return row


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 4, figsize=(18, 4.2))
    configs = list(dict.fromkeys(r["config"] for r in rows))
    for i, cfg in enumerate(configs):
        rs = sorted((r for r in rows if r["config"] == cfg), key=lambda r: r["n"])
        ns = [r["n"] for r in rs]
        c = f"C{i}"
        ax[0].plot(ns, [r["cpu_pct_median"] for r in rs], "o-", color=c, label=cfg)
        ax[1].plot(ns, [r["rss_mb_median"] for r in rs], "o-", color=c, label=f"{cfg} RSS")
        ax[1].plot(ns, [r["pss_mb_median"] for r in rs], "s:", color=c, alpha=0.6, label=f"{cfg} PSS")
        ax[2].plot(ns, [r["rtf_min"] for r in rs], "o-", color=c, label=f"{cfg} (min)")
        ax[3].plot(ns, [r["pose_age_p50_ms"] for r in rs], "o-", color=c, label=f"{cfg} p50")
        ax[3].plot(ns, [r["pose_age_p99_ms"] for r in rs], "x--", color=c, alpha=0.6, label=f"{cfg} p99")
    ax[0].axhline(2.0, color="r", ls=":", label="budget 2 %")
    ax[0].set_title("CPU per UAV process, median (% of one core)")
    ax[1].axhline(60.0, color="r", ls=":", label="budget 60 MB RSS")
    ax[1].set_title("memory per UAV process, median (MB)")
    ax[2].axhline(0.98, color="r", ls=":", label="0.98")
    ax[2].set_ylim(min([0.95] + [r["rtf_min"] - 0.02 for r in rows if r["rtf_min"] is not None]), 1.02)
    ax[2].set_title("real-time factor, slowest UAV")
    ax[3].set_yscale("log")
    ax[3].set_title("pose age at the receivers (ms)")
    for a in ax:
        a.set_xlabel("virtual UAVs (N)")
        a.legend(fontsize=7)
        a.grid(alpha=0.3)
    fig.suptitle(f"mrswarm scaling, process runtime, one run per cell, {psutil.cpu_count()} cores")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 10, 25, 50])
    ap.add_argument("--warmup", type=float, default=8.0, help="seconds after the mission starts before measuring")
    ap.add_argument("--window", type=float, default=30.0, help="measurement window, s")
    ap.add_argument("--configs", nargs="+", choices=list(CONFIGS), default=["discovery-direct", "discovery-edge", "client-edge"],
                    help="network configurations (connectivity-feed), all flown at every N")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--replot", action="store_true", help="only redraw scale.png from the scale.json in --out")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.replot:
        plot(json.loads((out / "scale.json").read_text())["rows"], out / "scale.png")
        return 0
    out.mkdir(parents=True, exist_ok=True)
    console = Console()
    rows = [run_size(n, cfg, args, console) for n in args.sizes for cfg in args.configs]
    tag = "scale"
    (out / f"{tag}.json").write_text(json.dumps({"args": vars(args), "cores": psutil.cpu_count(), "rows": rows}, indent=2))
    with open(out / f"{tag}.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    plot(rows, out / f"{tag}.png")
    console.print(f"wrote {out / tag}.json/.csv/.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
