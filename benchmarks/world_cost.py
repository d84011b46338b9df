"""Cost of the world service: CPU of the ``python -m world`` process serving N UAVs, one sensor each.

A real edge router (``python -m discovery.rendezvous``) and a real world service process (the
one ``mrswarm run`` starts) on 127.0.0.1, secured as in a run (a throw-away CA, mutual TLS,
access control; ``--insecure``: plain TCP); this script stands in for N UAVs: one Zenoh client
session (as the swarm's edge, the one identity that may put every UAV's pose) publishes N poses
at 10 Hz on the UAVs' pose keys (moving in circles through the pollutant cone) and subscribes to
every UAV's readings, counting them and their delay. After a warm-up it takes the world
process's user + system CPU time over a window, and its RSS.

    python benchmarks/world_cost.py --sizes 1 10 25 50 --rate 10 --out benchmarks/results

writes ``world_cost.json`` and ``world_cost.png``. ``--sensor fire`` serves a downward camera
over a burning grid instead of the binary pollutant sensor (a heavier reading).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import psutil
import zenoh

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from deploy.process_runtime import wait_file  # noqa: E402
from discovery.netutil import free_port, wait_tcp  # noqa: E402
from mrswarm.run.keys import throwaway_keys  # noqa: E402
from swarmnet.connectivity import Rendezvous, to_zenoh  # noqa: E402
from swarmnet.keyspace import SwarmKeys  # noqa: E402
from swarmnet.messages import Pose, Realm, decode_reading, encode_pose  # noqa: E402
from swarmnet.security.credentials import Credentials  # noqa: E402
from swarmnet.security.identity import NodeName  # noqa: E402
from uav_stack.config import NetworkConfig, SensorSpec  # noqa: E402
from uav_stack.geo import GeoPoint  # noqa: E402
from world.config import ConePlume, Fire, Rect, ServedSwarm, Wind, WorldConfig, WorldServiceConfig  # noqa: E402

SWARM = "bench"


def world_config(sensor: str, rate: float, endpoint: str, record: str, keys: Path | None) -> WorldServiceConfig:
    if sensor == "fire":
        world = WorldConfig(fire=Fire(area=Rect(-100, 100, -100, 100), ignite=((0.0, 0.0),), cell_m=5.0),
                            sensors=(SensorSpec(name="fire", type="fire", rate_hz=rate, range_m=20.0),))
    else:
        world = WorldConfig(wind=Wind(direction_deg=10.0), plume=ConePlume(source=(-50.0, 0.0)),
                            sensors=(SensorSpec(name="pollutant", type="pollutant", rate_hz=rate, latency_s=0.05),))
    net = NetworkConfig(connectivity="rendezvous", endpoints=(endpoint,), mode="client",
                        security=Credentials(keys=str(keys)) if keys is not None else None)
    return WorldServiceConfig(world=world, swarms=(ServedSwarm(name=SWARM, origin=GeoPoint(46.6167, 14.265, 446.0),
                                                               network=net),), record_dir=record, start="now")


def measure(n: int, sensor: str, rate: float, warmup: float, window: float, secure: bool) -> dict[str, Any]:
    port = free_port()
    procs: list[subprocess.Popen[bytes]] = []
    with tempfile.TemporaryDirectory(prefix="world-cost-") as tmp:
        keys = throwaway_keys(Path(tmp) / "keys", SWARM, [NodeName("edge", 0, SWARM)]) if secure else None
        endpoint = f"{'tls' if secure else 'tcp'}/127.0.0.1:{port}"
        try:
            stats = Path(tmp) / "router.stats.json"
            security = ["--keys", str(keys), "--stats", str(stats)] if keys is not None else ["--insecure"]
            router = subprocess.Popen([sys.executable, "-m", "discovery.rendezvous", "--listen", endpoint, *security],
                                      cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            procs.append(router)
            if keys is not None:  # a bare TCP probe would count as a refused handshake
                wait_file(stats, timeout=20.0, proc=router)
            else:
                wait_tcp("127.0.0.1", port, timeout=20.0)
            cfg_path = Path(tmp) / "world.json"
            cfg_path.write_text(world_config(sensor, rate, endpoint, tmp, keys).to_json())
            world = subprocess.Popen([sys.executable, "-m", "world", "--config", str(cfg_path), "--log-level", "WARNING"],
                                     cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            procs.append(world)
            creds = Credentials(keys=str(keys), identity=f"edge.{SWARM}") if keys is not None else None
            return _drive(n, endpoint, creds, world.pid, rate, warmup, window)
        finally:
            for p in reversed(procs):
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()


def _drive(n: int, endpoint: str, creds: Credentials | None, world_pid: int, rate: float, warmup: float,
           window: float) -> dict[str, Any]:
    conf = to_zenoh(Rendezvous((endpoint,), mode="client", credentials=creds).zenoh_config())
    keys = SwarmKeys(SWARM)
    with zenoh.open(conf) as s:
        sub = s.declare_subscriber(f"{keys.prefix}/*/sense/*", zenoh.handlers.RingChannel(100_000))
        pubs = [s.declare_publisher(keys.pose(u)) for u in range(1, n + 1)]
        proc = psutil.Process(world_pid)
        t_start = time.time()
        t_window = t_start + warmup
        t_end = t_window + window
        cpu0 = None
        delays: list[float] = []
        readings = 0
        seq = 0
        nxt = time.time()
        while time.time() < t_end:
            now = time.time()
            if now >= nxt:
                nxt += 0.1  # poses at 10 Hz
                for u, pub in enumerate(pubs, 1):
                    a = 0.2 * (now - t_start) + u
                    x, y = 40.0 * math.cos(a), 40.0 * math.sin(a)
                    pub.put(encode_pose(Pose(u, Realm.VIRTUAL, seq & 0xFFFF, now - t_start, now, x, y, 15.0,
                                             -8.0 * math.sin(a), 8.0 * math.cos(a), 0.0, 0.0)))
                seq += 1
            if cpu0 is None and now >= t_window:
                cpu0 = proc.cpu_times()
            while (sample := sub.try_recv()) is not None:
                if cpu0 is not None:
                    r = decode_reading(sample.payload.to_bytes())
                    readings += 1
                    delays.append(time.time() - r.t_meas)
            time.sleep(0.002)
        cpu1 = proc.cpu_times()
        rss = proc.memory_info().rss
    assert cpu0 is not None
    cpu = (cpu1.user - cpu0.user) + (cpu1.system - cpu0.system)
    delays.sort()
    return {"n": n, "rate_hz": rate, "cpu_percent": round(100.0 * cpu / window, 2), "rss_mb": round(rss / 2**20, 1),
            "readings_per_s": round(readings / window, 1), "expected_per_s": n * rate,
            "delay_ms_p50": round(1000 * statistics.median(delays), 1) if delays else None,
            "delay_ms_p99": round(1000 * delays[int(0.99 * (len(delays) - 1))], 1) if delays else None}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 10, 25, 50])
    ap.add_argument("--rate", type=float, default=10.0, help="readings per second per UAV")
    ap.add_argument("--sensor", choices=["pollutant", "fire"], default="pollutant")
    ap.add_argument("--insecure", action="store_true", help="plain TCP without access control (default: as a run, secured)")
    ap.add_argument("--warmup", type=float, default=5.0)
    ap.add_argument("--window", type=float, default=20.0, help="seconds of CPU measured")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in args.sizes:
        r = measure(n, args.sensor, args.rate, args.warmup, args.window, secure=not args.insecure)
        print(json.dumps(r), flush=True)
        rows.append(r)
    meta = {"sensor": args.sensor, "secured": not args.insecure, "window_s": args.window, "cpus": os.cpu_count(),
            "load_before": os.getloadavg(),
            "measured": time.strftime("%Y-%m-%d %H:%M"), "rows": rows}
    (out / f"world_cost{'' if args.sensor == 'pollutant' else '_' + args.sensor}.json").write_text(json.dumps(meta, indent=1))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.plot([r["n"] for r in rows], [r["cpu_percent"] for r in rows], "o-", label="world service CPU")
    ax.set_xlabel("UAVs served (one sensor each)")
    ax.set_ylabel(f"CPU (% of one core), {args.rate:g} readings/s per UAV")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.set_title(f"world service cost ({args.sensor} sensor)")
    fig.tight_layout()
    fig.savefig(out / f"world_cost{'' if args.sensor == 'pollutant' else '_' + args.sensor}.png", dpi=110)
    return 0


if __name__ == "__main__":
    sys.exit(main())
