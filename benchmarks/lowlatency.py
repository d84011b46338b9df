"""Zenoh's ``lowlatency`` unicast transport against its default one, for a UAV's pose stream.

Zenoh can skip its transmission pipeline (``transport.unicast.lowlatency: true``, which needs
``qos.enabled: false`` on both ends): each ``put`` then writes to the socket on the publishing
thread instead of handing the message to Zenoh's TX thread. That saves a thread wake-up per
put, so it might have made a UAV cheaper. This measures it as a UAV sends: one 48-byte pose
every 100 ms over a direct TCP link on 127.0.0.1 to a subscriber in another process, both
sessions with the UAV's lean runtime and the same transport mode; per round and mode, the CPU
of the publishing thread per ``put``, the CPU of each whole process, and the pose's transport
age at the subscriber (p50 / p99). The modes alternate within each round.

The figures favour lowlatency on loopback, and mrswarm still does not use it: a ``put`` then
waits until the socket takes the bytes, with no queue to drop from, so a stalled uplink would
stall the UAV's loop (docs/performance.md, "Measured and not adopted").

    python benchmarks/lowlatency.py --rounds 3 --out benchmarks/results
    # -> benchmarks/results/lowlatency.{json,csv,png}; about 2 minutes
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from discovery.netutil import free_port  # noqa: E402
from swarmnet.connectivity import TransportTuning, base_config, lean_zenoh_runtime  # noqa: E402

MODES = ("default", "lowlatency")
PAYLOAD_PAD = bytes(40)  # 8 bytes of send time + 40: a 48-byte pose


def session_config(connect: tuple[str, ...], listen: tuple[str, ...], mode: str) -> dict[str, Any]:
    """A UAV's peer configuration (plain TCP), with the lowlatency transport if ``mode`` says so."""
    cfg = base_config("peer", connect, listen, TransportTuning())
    if mode == "lowlatency":
        cfg["transport"]["unicast"].update(lowlatency=True, qos={"enabled": False})
    return cfg


_SUBSCRIBER = r"""
import json, os, struct, sys, time
sys.path.insert(0, os.getcwd())
from swarmnet.connectivity import lean_zenoh_runtime
lean_zenoh_runtime()
import zenoh
from benchmarks.lowlatency import session_config
s = zenoh.open(zenoh.Config.from_json5(json.dumps(session_config((), (sys.argv[1],), sys.argv[2]))))
ages = []
def on_pose(sample):
    ages.append(time.time() - struct.unpack_from("d", sample.payload.to_bytes())[0])
sub = s.declare_subscriber("bench/*/pose", on_pose)
print("ready", flush=True)
c0 = time.process_time()
time.sleep(float(sys.argv[3]))
print(json.dumps({"ages": ages, "cpu_s": time.process_time() - c0}), flush=True)
os._exit(0)  # no session teardown to wait for
"""


def one_run(mode: str, seconds: float, period: float) -> dict[str, Any]:
    """One publisher (this process) and one subscriber process in ``mode``; the figures of the run."""
    import zenoh

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    span = seconds + 3.0  # the subscriber's window: the publisher's, plus its connect and settle
    sub = subprocess.Popen([sys.executable, "-c", _SUBSCRIBER, endpoint, mode, str(span)], cwd=ROOT,
                           stdout=subprocess.PIPE, text=True)
    try:
        assert sub.stdout is not None
        if sub.stdout.readline().strip() != "ready":
            raise RuntimeError("the subscriber did not start")
        s = zenoh.open(zenoh.Config.from_json5(json.dumps(session_config((endpoint,), (), mode))))
        pub = s.declare_publisher("bench/1/pose", congestion_control=zenoh.CongestionControl.DROP,
                                  priority=zenoh.Priority.DATA_HIGH, express=True)
        time.sleep(1.0)  # the subscriber's declaration reaches us
        put_us: list[float] = []
        c0 = time.process_time()
        t_end = time.monotonic() + seconds
        nxt = time.monotonic()
        while time.monotonic() < t_end:
            nxt += period
            time.sleep(max(0.0, nxt - time.monotonic()))
            t0 = time.thread_time_ns()
            pub.put(struct.pack("d", time.time()) + PAYLOAD_PAD)
            put_us.append((time.thread_time_ns() - t0) / 1000.0)
        pub_cpu = time.process_time() - c0
        out, _ = sub.communicate(timeout=span + 30.0)
        got = json.loads(out.strip().splitlines()[-1])
        s.close()
    finally:
        if sub.poll() is None:
            sub.kill()
            sub.wait(10)
    ages = sorted(a * 1000.0 for a in got["ages"])
    return {"mode": mode, "puts": len(put_us), "received": len(ages),
            "put_cpu_us_p50": round(statistics.median(put_us), 1),
            "publisher_cpu_pct": round(100.0 * pub_cpu / seconds, 3),
            "subscriber_cpu_pct": round(100.0 * got["cpu_s"] / span, 3),
            "age_p50_ms": round(ages[len(ages) // 2], 3) if ages else None,
            "age_p99_ms": round(ages[int(0.99 * (len(ages) - 1))], 3) if ages else None}


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fields = (("put_cpu_us_p50", "CPU per put (publishing thread), µs"), ("publisher_cpu_pct", "publisher, % of a core"),
              ("subscriber_cpu_pct", "subscriber, % of a core"), ("age_p50_ms", "transport age p50, ms"))
    fig, axes = plt.subplots(1, len(fields), figsize=(13, 3.4))
    for ax, (field, label) in zip(axes, fields, strict=True):
        for j, mode in enumerate(MODES):
            ys = [r[field] for r in rows if r["mode"] == mode and r[field] is not None]
            ax.scatter([j] * len(ys), ys, color=f"C{j}")
        ax.set_xticks(range(len(MODES)), MODES)
        ax.set_title(label, fontsize=9)
        ax.set_xlim(-0.6, len(MODES) - 0.4)
        ax.grid(alpha=0.3)
    fig.suptitle("a 48-byte pose every 100 ms over one TCP link: Zenoh's default transport against lowlatency", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3, help="each round runs both modes, alternated")
    ap.add_argument("--seconds", type=float, default=20.0, help="publishing window per run, s")
    ap.add_argument("--period-ms", type=float, default=100.0, help="between two puts (a UAV's pose period), ms")
    ap.add_argument("--out", type=Path, default=None, help="folder for lowlatency.{json,csv,png} (default: print only)")
    args = ap.parse_args(argv)
    lean_zenoh_runtime()  # as a UAV process has it (before this process's first session)
    rows: list[dict[str, Any]] = []
    for rnd in range(args.rounds):
        for mode in MODES if rnd % 2 == 0 else MODES[::-1]:
            row = {"round": rnd, **one_run(mode, args.seconds, args.period_ms / 1000.0)}
            rows.append(row)
            print(row, flush=True)
    if args.out is not None:
        write_results(args.out, "lowlatency", {"args": {k: str(v) for k, v in vars(args).items()},
                                               "zenoh_runtime": os.environ.get("ZENOH_RUNTIME"), "rows": rows}, rows)
        plot(rows, args.out / "lowlatency.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
