"""A pool's FCU links alone: its virtual FCU and its agents' FCU links over UDP or in-process.

Builds the virtual FCU a pool of ``--vehicles`` UAVs has (``uav_stack.runtime.make_virtual_fcu``:
the pool's stream rates, physics rate and boot) and one agent's ``FcuLink`` per vehicle, and ticks
them at 10 Hz as the pool's loop does (the FCU's datagrams and physics, every link's poll and
service, the FCU's datagrams; then a velocity setpoint from each link, and the FCU's datagrams),
without the rest of the agents (no control, no Zenoh). It measures the process's CPU time (user
and system: a UDP send's kernel work is the sender's) over ``--seconds`` after ``--warmup``, for
each transport of ``--transports``, alternated over ``--rounds`` rounds so that both share the
machine's load of the moment; reports the median per transport, in % of one core.

    python benchmarks/pool_fcu_link.py --vehicles 25 --rounds 2 --out benchmarks/results
    # -> benchmarks/results/pool_fcu_link.{json,csv}; about a minute
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from uav_stack.config import AgentConfig, VirtualUavConfig  # noqa: E402
from uav_stack.fcu_link import FcuLink  # noqa: E402
from uav_stack.geo import GeoPoint  # noqa: E402
from uav_stack.runtime import make_virtual_fcu  # noqa: E402

HOME = GeoPoint(47.397742, 8.545594, 488.0)
PERIOD = 0.1  # s: the pool's tick at the default 10 Hz


def measure(inproc: bool, vehicles: int, seconds: float, warmup: float) -> dict[str, float]:
    cfgs = [VirtualUavConfig(agent=AgentConfig(swarm="bench", uav=i + 1, origin=HOME, fcu=""), home=HOME)
            for i in range(vehicles)]
    fcu = make_virtual_fcu(cfgs, inproc=inproc)
    links = [FcuLink(v.link.url, source_system=v.sysid, target_system=v.sysid).open() for v in fcu.vehicles]
    try:
        for v, link in zip(fcu.vehicles, links, strict=True):
            assert link.local_address is not None
            v.link.set_owner(link.local_address, owner_only=True)  # as open_virtual_uav does
        start = time.monotonic()
        measure_from, end = start + warmup, start + warmup + seconds
        cpu0 = wall0 = rx0 = None
        next_tick = start
        while (now := time.monotonic()) < end:
            if cpu0 is None and now >= measure_from:
                cpu0, wall0, rx0 = time.process_time(), now, sum(lk.counts["rx"] for lk in links)
            if now < next_tick:
                time.sleep(next_tick - now)
                continue
            next_tick += PERIOD
            fcu.poll_io()
            fcu.service()
            for link in links:
                link.poll()
                link.service()
            fcu.poll_io()
            for link in links:
                if link.fcu_ids is not None:
                    link.send_velocity_ned(1.0, 0.0, 0.0)
            fcu.poll_io()
        assert cpu0 is not None and wall0 is not None and rx0 is not None
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        rx = sum(lk.counts["rx"] for lk in links) - rx0
    finally:
        for link in links:
            link.close()
        fcu.close()
    return {"cpu_pct": round(100 * cpu / wall, 3), "cpu_pct_per_vehicle": round(100 * cpu / wall / vehicles, 4),
            "messages_per_vehicle_s": round(rx / wall / vehicles, 1)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=25)
    ap.add_argument("--transports", nargs="+", choices=["udp", "inproc"], default=["udp", "inproc"])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=10.0, help="measured, s")
    ap.add_argument("--warmup", type=float, default=3.0, help="s before measuring (boot, pinning, the contract)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    rows: list[dict[str, object]] = []
    for r in range(args.rounds):
        for t in args.transports:
            row = {"round": r + 1, "transport": t, "vehicles": args.vehicles,
                   **measure(t == "inproc", args.vehicles, args.seconds, args.warmup)}
            print(row, flush=True)
            rows.append(row)
    medians = {t: statistics.median(float(str(row["cpu_pct"])) for row in rows if row["transport"] == t)
               for t in args.transports}
    for t, m in medians.items():
        print(f"{t:>6}: {m:.2f} % of a core for {args.vehicles} vehicles (median of {args.rounds})")
    write_results(Path(args.out), "pool_fcu_link", {"args": vars(args), "rows": rows, "median_cpu_pct": medians}, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
