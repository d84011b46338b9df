"""Scaling benchmark: RTF, CPU and memory per virtual UAV, pose age, as the swarm grows.

For each swarm size N it flies a random-coverage mission (every UAV keeps moving and
exchanging poses at 10 Hz) with the process runtime, waits ``--warmup`` seconds after the
mission starts, then measures every process over ``--window`` seconds:

* CPU: user+system time of each UAV process over the window, in % of one core;
* memory at the end of the window: RSS (the budget), plus USS and PSS (shared pages split);
* RTF of every virtual FCU (sim time / wall time over the mission, from its own log);
* both pose ages, from every agent's histograms (p50/p99): the transport age (the sender's
  stamp to the arrival in the receiving process) and the age at use (arrival to the
  controller's first use);
* the takeoff: every UAV's acknowledgement and every UAV airborne, s after the command;
* the edge router's, the discovery server's and the runner's own CPU, reported separately.

    python benchmarks/scale.py --sizes 1 10 25 50 100 --configs discovery-direct client-edge --out benchmarks/results

flies every network configuration of ``--configs`` at every N (interleaved, so that all
configurations share the machine's load of the moment) and writes ``scale.json``,
``scale.csv`` and ``scale.png`` (medians per N and configuration, side by side).

Spatial interest (docs/scale.md) on against off: the ``*-interest`` configurations are the edge
feed with ``network.interest`` (``--interest-radius-m``, ``--interest-far-hz``); each row also
gives the poses each UAV received a second and the mean number of others within the radius::

    python benchmarks/scale.py --sizes 10 25 50 100 --configs client-edge client-edge-interest --tag scale_interest

Ticks on the wall clock's grid (``network.align_ticks``, the default) against each UAV's own:
``client-edge-aligned`` against ``client-edge``, ``discovery-direct-aligned`` against
``discovery-direct``; every named configuration but ``*-aligned`` has each UAV tick on its own
grid, as before the option existed.
The machine is noisy: numbers are medians over the UAV processes of one run per cell.
"""

from __future__ import annotations

import argparse
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

from benchmarks.output import write_results  # noqa: E402
from mrswarm.run.experiment import Experiment  # noqa: E402
from mrswarm.scenario import Scenario, parse_scenario  # noqa: E402

# name -> (network.connectivity, network.mode, network.pose_feed); None: the scenario leaves it unset
CONFIGS: dict[str, tuple[str | None, str | None, str | None]] = {
    "default": (None, None, None),  # chosen for N: discovery-direct-aligned up to 25 UAVs, client-edge-aligned above
    "discovery-direct": ("discovery", "peer", "direct"),  # beacon relay, peer mesh, every pose direct
    "discovery-edge": ("discovery", "peer", "edge"),      # beacon relay, poses batched by the edge router
    "client-edge": ("rendezvous", "client", "edge"),      # every UAV a client of the edge router, batched poses
    "rendezvous-direct": ("rendezvous", "peer", "direct"),
    "discovery-edge-interest": ("discovery", "peer", "edge"),  # as discovery-edge, with spatial interest
    "client-edge-interest": ("rendezvous", "client", "edge"),  # as client-edge, with spatial interest
    "client-edge-aligned": ("rendezvous", "client", "edge"),  # as client-edge, every UAV's ticks on the wall clock's grid
    "discovery-direct-aligned": ("discovery", "peer", "direct"),  # as discovery-direct, ticks on the wall clock's grid
}
INTEREST = {"radius_m": 60.0, "margin_m": 5.0, "far_rate_hz": 0.5}  # 60 m: ~4.5 others within it at 2500 m^2 per UAV


def scenario_for(n: int, duration: float, config: str, interest: dict[str, float] | None = None,
                 lease_s: float | None = None, pool: int = 1) -> Scenario:
    connectivity, mode, feed = CONFIGS[config]
    side = max(120.0, 50.0 * math.sqrt(n))  # constant density: ~2500 m^2 per UAV
    network: dict[str, Any] = {k: v for k, v in (("connectivity", connectivity), ("mode", mode), ("pose_feed", feed))
                               if v is not None}
    if lease_s is not None:
        network["lease_s"] = lease_s
    spacing = 8.0  # a packed start, spreading over the field during the mission
    if config.endswith("-interest"):
        network["interest"] = interest or INTEREST
        spacing = side / math.ceil(math.sqrt(n))  # at the field's density from the start: interest filters from the first tick
    if config != "default":  # each named configuration says it; the default's choice is the scenario's
        network["align_ticks"] = config.endswith("-aligned")
    return parse_scenario({
        "name": f"scale{n}",
        "swarm": f"bench{n}",
        "seed": 1,
        "duration": duration,
        "origin": {"lat": 46.6167, "lon": 14.2650, "alt": 446.0},
        "network": network,
        "flight": {"altitude": 6, "speed": 5.0, "safety_distance": 5.0, "collision_distance": 1.0},
        "mission": {"type": "coverage", "strategy": "random",
                    "area": {"x_min": -side / 2, "x_max": side / 2, "y_min": -side / 2, "y_max": side / 2}, "sensor_radius": 10},
        "fleet": {"count": n, "spawn": {"pattern": "grid", "spacing": spacing, "center": [0, 0]}, "pool": pool},
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
        """The run's processes still alive (a UAV that has exited is left out: the run flies on without it)."""
        procs: dict[str, psutil.Process] = {}
        for n, pid in exp.runtime.pids().items():
            try:
                procs[n] = psutil.Process(pid)
            except psutil.NoSuchProcess:
                pass
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


def per_uav(result: dict[str, dict[str, float]], pools: dict[str, list[int]]) -> dict[str, dict[str, float]]:
    """Each UAV's share of its process: a UAV process's own figures, a pool's divided among its UAVs."""
    out = {k: v for k, v in result.items() if k.startswith("uav")}
    for name, uavs in pools.items():
        v = result.get(name)
        if v is not None:
            share = {k: x / len(uavs) if k != "threads" else x for k, x in v.items()}
            out.update({f"uav{u}": share for u in uavs})
    return out


def run_size(n: int, config: str, args: argparse.Namespace, console: Console,
             adapt: Callable[[Scenario], Scenario] | None = None, pool: int = 1) -> dict[str, Any]:
    """One run of N UAVs in ``config`` (``pool`` UAVs to a process); ``adapt`` changes the scenario first
    (benchmarks/security.py)."""
    sampler = Sampler(args.warmup, args.window)
    interest = {**INTEREST, "radius_m": getattr(args, "interest_radius_m", INTEREST["radius_m"]),
                "far_rate_hz": getattr(args, "interest_far_hz", INTEREST["far_rate_hz"])}
    scn = scenario_for(n, args.warmup + args.window + 2.0, config, interest, getattr(args, "lease_s", None), pool)
    if adapt is not None:
        scn = adapt(scn)
    exp = Experiment(scn, Path(args.out) / "runs", console=console, live=False, log_level="WARNING", probe=sampler)
    t0 = time.time()
    summary = exp.run().to_dict()
    uavs = per_uav(sampler.result, exp.run_info.pools)
    if not uavs:  # the run aborted before the window: a row that says why, and the other cells still count
        row = {"n": n, "config": config, "aborted": str(summary.get("aborted")), "takeoff": summary.get("takeoff"),
               "wall_s": round(time.time() - t0, 1), "run_dir": summary.get("run_dir")}
        console.print(f"[red]N={n} {config}: no measurement:[/] {row['aborted']}")
        return row
    med = lambda key: statistics.median(v[key] for v in uavs.values())  # noqa: E731
    mx = lambda key: max(v[key] for v in uavs.values())  # noqa: E731
    rtf = summary.get("rtf", {})
    net = summary.get("network", {})
    age, use = net.get("transport_age_ms", {}), net.get("use_age_ms", {})
    takeoff = summary.get("takeoff", {})
    row = {
        "n": n,
        "config": config,
        "pool": pool,  # UAVs per process (fleet.pool); CPU and memory below are per UAV either way
        "connectivity": scn.network.connectivity,  # as resolved: the "default" config's choice for this N
        "mode": scn.network.mode,
        "feed": scn.network.pose_feed,
        "cpu_pct_median": round(med("cpu_pct"), 3),
        "cpu_pct_max": round(mx("cpu_pct"), 3),
        "rss_mb_median": round(med("rss_mb"), 1),
        "rss_mb_max": round(mx("rss_mb"), 1),
        "uss_mb_median": round(med("uss_mb"), 1),
        "pss_mb_median": round(med("pss_mb"), 1),
        "threads_median": med("threads"),
        "rtf_mean": rtf.get("mean"),
        "rtf_min": rtf.get("min"),
        "transport_age_p50_ms": age.get("p50"),
        "transport_age_p99_ms": age.get("p99"),
        "transport_age_max_ms": age.get("max"),
        "use_age_p50_ms": use.get("p50"),
        "use_age_p99_ms": use.get("p99"),
        "pose_loss": net.get("pose_loss"),
        "takeoff_acked_s": takeoff.get("acked_s"),
        "all_airborne_s": takeoff.get("all_airborne_s"),
        "takeoff_sends": takeoff.get("sends"),
        "router_cpu_pct": round(sampler.result.get("router", {}).get("cpu_pct", math.nan), 2),
        "discovery_cpu_pct": round(sampler.result.get("discovery", {}).get("cpu_pct", math.nan), 2),
        "runner_cpu_pct": round(sampler.result.get("runner", {}).get("cpu_pct", math.nan), 2),
        "collisions": summary.get("separation", {}).get("collisions"),
        **pose_traffic(Path(summary["run_dir"]), n, interest["radius_m"]),
        **pose_instants(Path(summary["run_dir"]), n),
        "wall_s": round(time.time() - t0, 1),
        "run_dir": summary.get("run_dir"),
    }
    console.print(row)
    return row


def pose_traffic(run: Path, n: int, radius: float) -> dict[str, Any]:
    """Poses each UAV received a second (median over UAVs: all it received, over the seconds since
    its takeoff command, so slightly high), the ratio of the full feed ((N - 1) times every pose
    sent) to what arrived, and the mean number of others within ``radius`` (sampled once a second)."""
    import numpy as np

    from mrswarm.results.analysis import load_stats, load_tracks, resample

    stats = load_stats(run)
    rates = [s["net"]["received"].get("pose", 0) / max(1e-3, s["written_at"] - s["started_at"])
             for s in stats.values() if s.get("started_at") and s.get("written_at")]
    sent = sum(s["net"]["sent"].get("pose", 0) for s in stats.values())
    got = sum(s["net"]["received"].get("pose", 0) for s in stats.values())
    within = math.nan
    tracks = load_tracks(run)
    if len(tracks) > 1:
        _g, pos, _ids = resample(tracks, max(t.t[0] for t in tracks.values()), min(t.t[-1] for t in tracks.values()))
        xy = pos[:, ::10, :2]
        if xy.shape[1]:
            d = np.linalg.norm(xy[:, None] - xy[None, :], axis=-1)
            within = float(np.nanmean((d <= radius).sum(axis=1) - 1))
    return {"poses_rx_per_uav_s": round(statistics.median(rates), 1) if rates else None,
            "full_feed_ratio": round((n - 1) * sent / got, 2) if got else None,
            "within_radius_mean": round(within, 2)}


def pose_instants(run: Path, n: int) -> dict[str, Any]:
    """When the poses of an instant leave, and in how many edge-feed batches they arrive.

    With aligned ticks every UAV publishes at the same instants (whole multiples of the pose
    period since the Unix epoch); on a loaded machine they queue for the cores, so their poses
    leave spread after it, and the edge feed carries the spread in more batches (each a wake-up
    of every UAV). From the flight record (every pose's sender stamp, ``t_wall``): how long after
    its instant a pose left (p50 / p90 over all poses, ms) and how far apart an instant's first
    and last pose left (p50 over instants heard from at least 80 % of the UAVs, ms); from the
    UAVs' status files: edge-feed batches per instant (median over UAVs: batches received over
    instants' worth of poses, ``(N - 1)`` poses an instant; None without the edge feed)."""
    import json

    import msgspec
    import numpy as np
    from mcap.reader import make_reader

    from mrswarm.results.analysis import load_stats
    from uav_stack.config import AgentConfig

    period = 1.0 / next(f.default for f in msgspec.structs.fields(AgentConfig) if f.name == "pose_rate_hz")
    offsets: list[float] = []
    instants: dict[int, list[float]] = {}
    record = run / "run.mcap"
    if record.exists():
        with open(record, "rb") as f:
            for _schema, channel, message in make_reader(f).iter_messages():
                if not channel.topic.endswith("/pose"):
                    continue
                t = float(json.loads(message.data)["t_wall"])
                k = math.floor(t / period + 1e-9)
                offset = t - k * period
                offsets.append(offset)
                instants.setdefault(k, []).append(offset)
    spreads = [max(v) - min(v) for v in instants.values() if len(v) >= 0.8 * n and n > 1]
    per_instant = []
    for s in load_stats(run).values():
        rx = s.get("net", {}).get("received", {})
        if rx.get("pose_batch") and rx.get("pose") and n > 1:
            per_instant.append(rx["pose_batch"] / (rx["pose"] / (n - 1)))
    ms = lambda q, v: round(1000.0 * float(np.percentile(v, q)), 2) if v else None  # noqa: E731
    return {"pose_sent_after_instant_p50_ms": ms(50, offsets), "pose_sent_after_instant_p90_ms": ms(90, offsets),
            "instant_spread_p50_ms": ms(50, spreads),
            "feed_batches_per_instant": round(statistics.median(per_instant), 2) if per_instant else None}


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 6, figsize=(26, 4.2))
    configs = list(dict.fromkeys(r["config"] for r in rows))
    for i, cfg in enumerate(configs):
        rs = sorted((r for r in rows if r["config"] == cfg), key=lambda r: r["n"])
        ns = [r["n"] for r in rs]
        c = f"C{i}"
        ax[0].plot(ns, [r["cpu_pct_median"] for r in rs], "o-", color=c, label=cfg)
        ax[1].plot(ns, [r["rss_mb_median"] for r in rs], "o-", color=c, label=f"{cfg} RSS")
        ax[1].plot(ns, [r["pss_mb_median"] for r in rs], "s:", color=c, alpha=0.6, label=f"{cfg} PSS")
        ax[2].plot(ns, [r["rtf_min"] for r in rs], "o-", color=c, label=f"{cfg} (min)")
        ax[3].plot(ns, [r.get("transport_age_p50_ms") for r in rs], "o-", color=c, label=f"{cfg} transport p50")
        ax[3].plot(ns, [r.get("transport_age_p99_ms") for r in rs], "x--", color=c, alpha=0.6, label=f"{cfg} transport p99")
        ax[3].plot(ns, [r.get("use_age_p50_ms") for r in rs], "s:", color=c, alpha=0.8, label=f"{cfg} at use p50")
        ax[4].plot(ns, [r.get("all_airborne_s") for r in rs], "o-", color=c, label=f"{cfg} all airborne")
        ax[4].plot(ns, [r.get("takeoff_acked_s") for r in rs], "x--", color=c, alpha=0.6, label=f"{cfg} all acknowledged")
        ax[5].plot(ns, [r.get("poses_rx_per_uav_s") for r in rs], "o-", color=c, label=cfg)
    ax[0].axhline(1.5, color="r", ls=":", label="budget 1.5 %")
    ax[0].set_title("CPU per UAV process, median (% of one core)")
    ax[1].axhline(60.0, color="r", ls=":", label="budget 60 MB RSS")
    ax[1].set_title("memory per UAV process, median (MB)")
    ax[2].axhline(0.98, color="r", ls=":", label="0.98")
    ax[2].set_ylim(min([0.95] + [r["rtf_min"] - 0.02 for r in rows if r["rtf_min"] is not None]), 1.02)
    ax[2].set_title("real-time factor, slowest UAV")
    ax[3].set_yscale("log")
    ax[3].set_title("pose ages at the receivers (ms)")
    ax[4].set_title("takeoff: s after the command")
    ax[5].set_yscale("log")
    ax[5].set_title("poses received per UAV a second (median)")
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
    ap.add_argument("--pools", type=int, nargs="+", default=[1],
                    help="UAVs per process (fleet.pool), each measured in turn: 1 = a process per UAV")
    ap.add_argument("--warmup", type=float, default=8.0, help="seconds after the mission starts before measuring")
    ap.add_argument("--window", type=float, default=30.0, help="measurement window, s")
    ap.add_argument("--configs", nargs="+", choices=list(CONFIGS), default=["discovery-direct", "discovery-edge", "client-edge"],
                    help="network configurations (connectivity-feed), all flown at every N")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--tag", default="scale", help="output file names: <tag>.json/.csv/.png")
    ap.add_argument("--interest-radius-m", type=float, default=INTEREST["radius_m"],
                    help="spatial interest radius of the *-interest configurations, m")
    ap.add_argument("--interest-far-hz", type=float, default=INTEREST["far_rate_hz"],
                    help="far rate of the *-interest configurations, Hz")
    ap.add_argument("--lease-s", type=float, default=None,
                    help="network.lease_s of every run (default: the scenario's 3 s; N = 100 on 2 cores needs 10)")
    ap.add_argument("--replot", action="store_true", help="only redraw scale.png from the scale.json in --out")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.replot:
        plot(json.loads((out / f"{args.tag}.json").read_text())["rows"], out / f"{args.tag}.png")
        return 0
    out.mkdir(parents=True, exist_ok=True)
    console = Console()
    # side by side: for each size, each configuration with each pool size (1: a process per UAV)
    rows = [run_size(n, cfg, args, console, pool=k) for n in args.sizes for cfg in args.configs for k in args.pools]
    tag = args.tag
    write_results(out, tag, {"args": vars(args), "cores": psutil.cpu_count(), "rows": rows}, rows)
    measured = [r for r in rows if "aborted" not in r]
    if measured:
        plot(measured, out / f"{tag}.png")
    console.print(f"wrote {out / tag}.json/.csv/.png")
    return 1 if len(measured) < len(rows) else 0  # 1: a cell aborted (its row says why)


if __name__ == "__main__":
    sys.exit(main())
