"""Cost of the agent's MAVLink router: the same swarm with and without ground-station routing.

Flies the scaling benchmark's random-coverage mission (``benchmarks/scale.py``) with N virtual
UAVs twice: once without routers, once with every agent's router sending its FCU's stream to
a ground-station port (``gcs.mavlink``), where this script drains and counts it like a ground
station would. It reports, per UAV process, the median CPU (% of one core) and RSS, the RTF,
and the traffic the ground station received.

    python benchmarks/gcs_router.py --n 10 --out benchmarks/results

writes ``gcs_router.json``, ``gcs_router.csv`` and ``gcs_router.png``.
"""

from __future__ import annotations

import argparse
import socket
import statistics
import sys
import threading
import time
from pathlib import Path
from typing import Any

import psutil
from msgspec.structs import replace
from rich.console import Console

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from benchmarks.scale import Sampler, scenario_for  # noqa: E402
from mrswarm.run.experiment import Experiment  # noqa: E402
from mrswarm.scenario import Gcs  # noqa: E402


class Sink:
    """A ground station that only counts: datagrams, bytes and MAVLink 2 frames per source sysid."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.datagrams = self.bytes = 0
        self.sysids: set[int] = set()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                data = self.sock.recv(65535)
            except TimeoutError:
                continue
            self.datagrams += 1
            self.bytes += len(data)
            if len(data) > 5 and data[0] == 0xFD:
                self.sysids.add(data[5])

    def __enter__(self) -> Sink:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(2)
        self.sock.close()


def run_once(n: int, routed: bool, args: argparse.Namespace, console: Console) -> dict[str, Any]:
    sampler = Sampler(args.warmup, args.window)
    scn = scenario_for(n, args.warmup + args.window + 2.0, "discovery-direct")
    with Sink() as sink:
        # the router is on by default (to UDP 14550): the baseline turns it off
        scn = replace(scn, gcs=Gcs(mavlink=True, port=sink.port) if routed else Gcs(mavlink=False))
        exp = Experiment(scn, Path(args.out) / "runs", console=console, live=False, log_level="WARNING", probe=sampler)
        t0 = time.time()
        d0 = b0 = 0
        summary = exp.run().to_dict()
        wall = time.time() - t0
        d0, b0 = sink.datagrams, sink.bytes
    uavs = {k: v for k, v in sampler.result.items() if k.startswith("uav")}
    if not uavs:
        raise SystemExit(f"no measurement (run aborted? {summary.get('aborted')})")
    rtf = summary.get("rtf", {})
    row = {
        "n": n,
        "router": routed,
        "cpu_pct_median": round(statistics.median(v["cpu_pct"] for v in uavs.values()), 3),
        "cpu_pct_max": round(max(v["cpu_pct"] for v in uavs.values()), 3),
        "rss_mb_median": round(statistics.median(v["rss_mb"] for v in uavs.values()), 1),
        "rtf_mean": rtf.get("mean"),
        "rtf_min": rtf.get("min"),
        "gcs_datagrams_per_s": round(d0 / wall, 1),
        "gcs_kbytes_per_s": round(b0 / wall / 1000, 2),
        "gcs_vehicles_seen": len(sink.sysids),
        "run_dir": summary.get("run_dir"),
    }
    console.print(row)
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--warmup", type=float, default=8.0)
    ap.add_argument("--window", type=float, default=30.0)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    console = Console()
    rows = [run_once(args.n, False, args, console), run_once(args.n, True, args, console)]
    write_results(out, "gcs_router", {"args": vars(args), "cores": psutil.cpu_count(), "rows": rows}, rows)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(12, 3.6))
    labels = ["no router", "router -> GCS"]
    ax[0].bar(labels, [r["cpu_pct_median"] for r in rows])
    ax[0].axhline(2.0, color="r", ls=":", label="budget 2 %")
    ax[0].set_title("CPU per UAV process (median, % of a core)")
    ax[1].bar(labels, [r["rss_mb_median"] for r in rows])
    ax[1].axhline(60.0, color="r", ls=":", label="budget 60 MB")
    ax[1].set_title("RSS per UAV process (median, MB)")
    ax[2].bar(labels, [r["rtf_min"] or 0 for r in rows])
    ax[2].axhline(0.98, color="r", ls=":", label="0.98")
    ax[2].set_ylim(0, 1.05)
    ax[2].set_title("RTF (min)")
    for a in ax:
        a.legend(fontsize=8)
    fig.suptitle(f"MAVLink router cost, N = {args.n} virtual UAVs, {psutil.cpu_count()} cores; "
                 f"GCS received {rows[1]['gcs_kbytes_per_s']} kB/s from {rows[1]['gcs_vehicles_seen']} vehicles")
    fig.tight_layout()
    fig.savefig(out / "gcs_router.png", dpi=110)
    console.print(f"wrote {out}/gcs_router.json/.csv/.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
