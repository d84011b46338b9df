"""Spatial interest at larger N without flight dynamics: many pose publishers in one process.

Checks the traffic model of docs/scale.md where the full stack (a process per UAV) cannot go on
one machine. One process publishes the poses of N simulated UAVs at 10 Hz through one Zenoh
client session (positions moving at 5 m/s in straight lines, bouncing off the edges of a
square field of ``--area-per-uav`` m^2 per UAV, so the density stays constant as N grows); the
edge router runs the real pose feed as its own process, with or without spatial interest; a few
*probe* UAVs (real :class:`~swarmnet.node.SwarmNode` receive paths, in a second process) count
the poses they receive. Per N and setting it reports

* ``rx_per_uav_s``: poses a probe received a second (median of the probes), and what the model
  predicts: ``10 (N - 1)`` without interest, ``10 k + f (N - 1 - k)`` with it (``k``: the probe's
  mean number of others within the radius, measured from the simulated positions; ``f``: the far rate);
* ``router_cpu_pct``: the edge router's CPU over the window (% of one core), and per 1000 poses/s in;
* ``publisher_cpu_pct``: the simulator's own CPU (it is not a cost of the system).

    python benchmarks/interest_model.py --sizes 50 100 200 400 --out benchmarks/results

writes ``interest_model.json``, ``.csv`` and ``.png``. Plain TCP (a lab: no certificates for the
simulated UAVs), loopback only.
"""

from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from discovery.netutil import free_port, wait_tcp  # noqa: E402
from swarmnet.connectivity import Rendezvous, to_zenoh  # noqa: E402
from swarmnet.keyspace import SwarmKeys  # noqa: E402
from swarmnet.messages import Pose, Realm, encode_pose  # noqa: E402
from swarmnet.node import NodeIdentity, SwarmNode  # noqa: E402

SWARM = "sim"
RATE_HZ = 10.0
SPEED = 5.0  # m/s


def field_side(n: int, area_per_uav: float) -> float:
    return math.sqrt(n * area_per_uav)


def probes_run(endpoint: str, ids: list[int], near: bool, seconds: float, out: Any) -> None:
    """The probe UAVs: each a SwarmNode on the edge feed, polled at 50 Hz; sends its counts back."""
    conn = Rendezvous((endpoint,), mode="client")
    nodes = [SwarmNode(NodeIdentity(SWARM, i), conn, pose_feed="edge", near_feed=near).open() for i in ids]
    try:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for nd in nodes:
                nd.poll()
            time.sleep(0.02)
        out.send({nd.identity.uav: {"poses": nd.stats.received["pose"], "batches": nd.stats.received["pose_batch"]}
                  for nd in nodes})
    finally:
        for nd in nodes:
            nd.close()
    out.close()
    os._exit(0)  # no interpreter teardown under Zenoh's threads (it can abort with "exception not rethrown")


def run_cell(n: int, interest: bool, args: argparse.Namespace) -> dict[str, Any]:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    argv = [sys.executable, "-m", "discovery.rendezvous", "--listen", endpoint, "--insecure", "--feed", SWARM]
    if interest:
        argv += ["--interest-radius-m", f"{args.radius}", "--interest-margin-m", "0", "--interest-far-hz", f"{args.far_hz}"]
    router = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              env=dict(os.environ, PYTHONPATH=str(ROOT)))
    import zenoh

    try:
        wait_tcp("127.0.0.1", port, timeout=20.0, alive=lambda: router.poll() is None, what="the router")
        rng = np.random.default_rng(n)
        side = field_side(n, args.area_per_uav)
        xy = rng.uniform(0.0, side, (n, 2))
        ang = rng.uniform(0.0, 2 * math.pi, n)
        vel = SPEED * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        probe_ids = list(range(1, args.probes + 1))
        total = args.warmup + args.window
        recv, send = mp.Pipe(duplex=False)
        probe = mp.get_context("spawn").Process(target=probes_run, args=(endpoint, probe_ids, interest, total + 1.0, send))
        probe.start()
        keys = SwarmKeys(SWARM)
        session = zenoh.open(to_zenoh(Rendezvous((endpoint,), mode="client").zenoh_config()))
        pubs = [session.declare_publisher(keys.pose(i + 1), congestion_control=zenoh.CongestionControl.DROP) for i in range(n)]
        me, rp = psutil.Process(), psutil.Process(router.pid)
        seq, within = 0, []
        time.sleep(1.0)  # the probes subscribe
        t_start = time.monotonic()
        next_tick = t_start
        cpu0: tuple[float, float, float] | None = None
        while (now := time.monotonic()) < t_start + total:
            if cpu0 is None and now >= t_start + args.warmup:
                c, r = me.cpu_times(), rp.cpu_times()
                cpu0 = (now, c.user + c.system, r.user + r.system)
            xy += vel / RATE_HZ
            for d in (0, 1):  # bounce off the field's edges
                out = (xy[:, d] < 0) | (xy[:, d] > side)
                vel[out, d] *= -1
            xy = np.clip(xy, 0.0, side)
            for i in range(n):  # spread over the period, as UAVs with their own clocks are
                due = next_tick + i / (n * RATE_HZ)
                if (wait := due - time.monotonic()) > 0.0005:
                    time.sleep(wait)
                pose = Pose(i + 1, Realm.VIRTUAL, seq, seq / RATE_HZ, time.time(), float(xy[i, 0]), float(xy[i, 1]), 10.0,
                            float(vel[i, 0]), float(vel[i, 1]), 0.0, 0.0)
                pubs[i].put(encode_pose(pose))
            seq = (seq + 1) % 65536
            if cpu0 is not None and seq % int(RATE_HZ) == 0:
                d2 = ((xy[: len(probe_ids), None, :] - xy[None, :, :]) ** 2).sum(axis=-1)
                within.append(float(((d2 <= args.radius ** 2).sum(axis=1) - 1).mean()))
            next_tick += 1.0 / RATE_HZ
            time.sleep(max(0.0, next_tick - time.monotonic()))
        assert cpu0 is not None
        dt = time.monotonic() - cpu0[0]
        c, r = me.cpu_times(), rp.cpu_times()
        pub_cpu = 100.0 * (c.user + c.system - cpu0[1]) / dt
        router_cpu = 100.0 * (r.user + r.system - cpu0[2]) / dt
        counts = recv.recv() if recv.poll(total + 15.0) else {}
        probe.join(10)
        session.close()
    finally:
        router.terminate()
        router.wait(10)
    rx = statistics.median(v["poses"] / total for v in counts.values()) if counts else math.nan
    k = statistics.fmean(within) if within else math.nan
    model = RATE_HZ * k + args.far_hz * (n - 1 - k) if interest else RATE_HZ * (n - 1)
    row = {"n": n, "interest": interest, "radius_m": args.radius if interest else None,
           "far_hz": args.far_hz if interest else None,
           "within_mean": round(k, 2), "rx_per_uav_s": round(rx, 1), "model_rx_per_uav_s": round(model, 1),
           "batches_per_uav_s": round(statistics.median(v["batches"] / total for v in counts.values()), 1) if counts else None,
            "router_cpu_pct": round(router_cpu, 1), "router_cpu_pct_per_kpose_s": round(router_cpu / (n * RATE_HZ / 1000.0), 2),
           "publisher_cpu_pct": round(pub_cpu, 1)}
    print(row, flush=True)
    return row


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    for on, c in ((False, "C0"), (True, "C1")):
        rs = sorted((r for r in rows if r["interest"] is on), key=lambda r: r["n"])
        label = "interest" if on else "full feed"
        ax[0].plot([r["n"] for r in rs], [r["rx_per_uav_s"] for r in rs], "o-", color=c, label=f"{label}, measured")
        ax[0].plot([r["n"] for r in rs], [r["model_rx_per_uav_s"] for r in rs], "x--", color=c, label=f"{label}, model")
        ax[1].plot([r["n"] for r in rs], [r["router_cpu_pct"] for r in rs], "o-", color=c, label=label)
    ax[0].set_title("poses received per UAV a second")
    ax[0].set_yscale("log")
    ax[1].set_title("edge router CPU (% of one core)")
    for a in ax:
        a.set_xlabel("simulated UAVs (N)")
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle(f"spatial interest model check, {psutil.cpu_count()} cores")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[50, 100, 200, 400])
    ap.add_argument("--radius", type=float, default=60.0, help="interest radius, m")
    ap.add_argument("--far-hz", type=float, default=0.5, help="far rate, Hz")
    ap.add_argument("--area-per-uav", type=float, default=2500.0, help="m^2 of field per UAV (the density)")
    ap.add_argument("--probes", type=int, default=5, help="receiving UAVs measured")
    ap.add_argument("--warmup", type=float, default=3.0, help="s")
    ap.add_argument("--window", type=float, default=10.0, help="s")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--tag", default="interest_model")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = [run_cell(n, on, args) for n in args.sizes for on in (False, True)]
    write_results(out, args.tag, {"args": vars(args), "cores": psutil.cpu_count(), "rows": rows}, rows)
    plot(rows, out / f"{args.tag}.png")
    print(f"wrote {out / args.tag}.json/.csv/.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
