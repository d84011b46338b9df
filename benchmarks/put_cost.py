"""What one Zenoh ``put`` costs the publishing thread, back to back and after a pause.

A UAV publishes a 48-byte pose ten times a second, then sleeps until its next tick, while other
processes run and evict its CPU caches. This measures the CPU time of the publishing thread per
``put`` (``time.thread_time``) on a declared publisher with the pose's options, with a
subscriber in another process and a Zenoh router on 127.0.0.1 (plain TCP), for several pauses
between puts: back to back (warm), 1 ms and 100 ms (a UAV's tick). The ratio is the price of
running cold, which every step of a UAV's loop pays.

    python benchmarks/put_cost.py --out benchmarks/results
    # -> benchmarks/results/put_cost.{json,csv,png}; about 1 minute
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from discovery.netutil import free_port  # noqa: E402
from swarmnet.connectivity import TransportTuning, base_config, to_zenoh  # noqa: E402

PAYLOAD = bytes(48)

_ROUTER = """
import sys, threading
from discovery.rendezvous import serve
serve([sys.argv[1]], threading.Event())
"""

_SUBSCRIBER = """
import sys, time, zenoh
from swarmnet.connectivity import TransportTuning, base_config, to_zenoh
s = zenoh.open(to_zenoh(base_config("peer", (sys.argv[1],), ("tcp/127.0.0.1:0",), TransportTuning())))
sub = s.declare_subscriber("bench/**", lambda sample: None)
time.sleep(float(sys.argv[2]))
"""


def measure(pauses: list[float], puts: int, endpoint: str) -> dict[float, list[float]]:
    """CPU µs of each ``put`` after each pause (s), pauses alternated put by put."""
    import zenoh

    s = zenoh.open(to_zenoh(base_config("peer", (endpoint,), ("tcp/127.0.0.1:0",), TransportTuning())))
    try:
        pub = s.declare_publisher("bench/1/pose", congestion_control=zenoh.CongestionControl.DROP,
                                  priority=zenoh.Priority.DATA_HIGH, express=True)
        time.sleep(2.0)  # the subscriber's declaration reaches us
        out: dict[float, list[float]] = {p: [] for p in pauses}
        for i in range(puts):
            for pause in pauses if i % 2 == 0 else pauses[::-1]:
                time.sleep(pause)
                t0 = time.thread_time_ns()
                pub.put(PAYLOAD)
                out[pause].append((time.thread_time_ns() - t0) / 1000.0)
        return out
    finally:
        s.close()


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    labels = [f"{r['pause_ms']:g} ms" for r in rows]
    ax.bar(labels, [r["p50_us"] for r in rows], color="tab:blue", alpha=0.7, label="p50")
    ax.plot(labels, [r["p90_us"] for r in rows], "k_", ms=25, label="p90")
    ax.set_xlabel("pause before each put")
    ax.set_ylabel("CPU µs per put (publishing thread)")
    ax.set_title("Zenoh put of a 48-byte pose: warm and cold")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pauses-ms", type=float, nargs="+", default=[0.0, 1.0, 100.0])
    ap.add_argument("--puts", type=int, default=200, help="puts per pause")
    ap.add_argument("--out", type=Path, default=None, help="folder for put_cost.{json,csv,png} (default: print only)")
    args = ap.parse_args(argv)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    pauses = [p / 1000.0 for p in args.pauses_ms]
    budget = 10.0 + args.puts * sum(pauses) * 1.5
    # ``-c`` in the checkout: its packages import from the working directory
    router = subprocess.Popen([sys.executable, "-c", _ROUTER, endpoint], stdout=subprocess.DEVNULL, cwd=ROOT)
    sub = None
    try:
        time.sleep(1.5)
        sub = subprocess.Popen([sys.executable, "-c", _SUBSCRIBER, endpoint, str(budget)], cwd=ROOT)
        time.sleep(1.5)
        per = measure(pauses, args.puts, endpoint)
    finally:
        for p in (sub, router):
            if p is not None:
                p.kill()
                p.wait(10)
    rows = []
    for pause, vals in per.items():
        vals.sort()
        row = {"pause_ms": pause * 1000.0, "puts": len(vals), "p50_us": round(statistics.median(vals), 1),
               "p90_us": round(vals[int(0.9 * (len(vals) - 1))], 1)}
        rows.append(row)
        print(f"pause {row['pause_ms']:6.1f} ms: put p50 {row['p50_us']:6.1f} us, p90 {row['p90_us']:6.1f} us")
    if args.out is not None:
        write_results(args.out, "put_cost", rows, rows)
        plot(rows, args.out / "put_cost.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
