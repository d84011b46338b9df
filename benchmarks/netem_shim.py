"""Cost of the netem shim per received message: the shim alone, and inside SwarmNode.poll.

Two measurements:

1. **shim**: ``NetemShim.offer`` (+ ``release``) per message on one link, pure Python, no
   network, for the presets ``none`` (the no-impairment path), ``lan``, ``5g-campus``,
   ``degraded`` and ``wifi-mesh`` (distance model on).
2. **poll**: the receive path of a real :class:`SwarmNode` (real Zenoh sessions on
   127.0.0.1): publishers send ``--batch`` poses from several UAV ids, the receiver drains
   them in one ``poll()`` and a second poll (5 s later on its clock) releases what the shim
   held; cost per pose of both polls (decode + checks + shim + neighbour table), without a
   shim (``netem: null``) and with each preset. The no-impairment path's *added* cost is
   ``poll[none] - poll[off]``.

    python benchmarks/netem_shim.py --out benchmarks/results

writes ``netem_shim.json``, ``netem_shim.csv`` and ``netem_shim.png``. Medians over
``--repeats`` rounds; the machine is noisy, so compare medians, not single rounds.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from discovery.netutil import free_port  # noqa: E402
from discovery.rendezvous import serve  # noqa: E402
from swarmnet.connectivity import Rendezvous  # noqa: E402
from swarmnet.messages import Realm  # noqa: E402
from swarmnet.netem import NetemShim, parse_netem  # noqa: E402
from swarmnet.node import NodeIdentity, SwarmNode  # noqa: E402

PRESETS = ["none", "lan", "5g-campus", "degraded", "wifi-mesh"]


def bench_shim(preset: str, n: int, repeats: int) -> float:
    """Median seconds per message of offer() + release() on one link (10 Hz traffic on a fake clock)."""
    times = []
    for r in range(repeats):
        shim = NetemShim(parse_netem({"preset": preset}, default_seed=r), 2)
        shim.own_pos = (0.0, 0.0, 20.0)
        link = shim.link(1, Realm.VIRTUAL)
        link.pos = (120.0, 0.0, 20.0)
        offer, release = shim.offer, shim.release
        t = 1000.0
        t0 = time.perf_counter()
        for i in range(n):
            t += 0.1
            offer(link, t, 0, i, "", 40)
            release(t)
        times.append((time.perf_counter() - t0) / n)
    return statistics.median(times)


def bench_poll(presets: list[str | None], batch: int, senders: int, repeats: int,
               rdv: Rendezvous) -> dict[str | None, dict[str, float]]:
    """Median seconds per pose of SwarmNode.poll for one receiver per preset, all fed the same poses.

    All receivers subscribe to the same publishers and are polled one after the other in each
    round (in a rotating order), so they see the same load; the added cost of a preset is the
    median of its per-round difference to the receiver without a shim.
    """
    pubs = [SwarmNode(NodeIdentity("bench", i), rdv).open() for i in range(1, senders + 1)]
    rxs = {p: SwarmNode(NodeIdentity("bench", 1000 + k), rdv, netem=None if p is None else {"preset": p, "seed": 1},
                        ring_size=max(1024, 2 * batch)).open() for k, p in enumerate(presets)}
    try:
        want = senders + len(presets)
        deadline = time.time() + 20
        while time.time() < deadline and not all((r.poll(), len(r.alive_uavs()) == want)[1] for r in rxs.values()):
            time.sleep(0.05)
        time.sleep(0.3)
        per: dict[str | None, list[float]] = {p: [] for p in presets}
        k = 0
        order = list(presets)
        for _ in range(repeats):
            for j in range(batch):
                p = pubs[j % senders]
                p._next_pose = 0.0
                p.publish_pose(t_sim=k * 0.1, x=float(j % 50), y=float(k % 50), z=10.0, vx=1.0, vy=0.0, vz=0.0, yaw=0.0)
                k += 1
            time.sleep(0.5)  # everything is in the ring channels
            order = order[1:] + order[:1]
            for name in order:
                rx = rxs[name]
                now = time.time()
                t0 = time.perf_counter()
                rx.poll(now)
                rx.poll(now + 5.0)  # what the shim held is released (and applied) by a later poll
                per[name].append((time.perf_counter() - t0) / batch)
        out: dict[str | None, dict[str, float]] = {}
        for name in presets:
            diffs = [a - b for a, b in zip(per[name], per[presets[0]], strict=True)]
            rx = rxs[name]
            out[name] = {"per_msg": statistics.median(per[name]), "added": statistics.median(diffs),
                         "received": rx.stats.received["pose"], "rejected": sum(rx.stats.rejected.values())}
        return out
    finally:
        for r in rxs.values():
            r.close()
        for p in pubs:
            p.close()


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    shim = [r for r in rows if r["what"] == "shim"]
    poll = [r for r in rows if r["what"] == "poll"]
    a1.bar([r["preset"] for r in shim], [r["us_per_msg"] for r in shim], color="tab:blue")
    a1.set_title("NetemShim.offer + release, per message")
    a2.bar([r["preset"] for r in poll], [r["us_per_msg"] for r in poll], color="tab:orange")
    a2.set_title("SwarmNode.poll per received pose (real Zenoh)")
    off = next((r["us_per_msg"] for r in poll if r["preset"] == "off"), 0.0)
    a1.axhline(10.0, color="tab:red", ls=":", lw=1, label="10 us")
    a2.axhline(off + 10.0, color="tab:red", ls=":", lw=1, label="no shim + 10 us")
    for ax in (a1, a2):
        ax.set_ylabel("us per message")
        ax.tick_params(axis="x", rotation=20)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200_000, help="messages per shim round")
    ap.add_argument("--batch", type=int, default=1000, help="poses per poll round")
    ap.add_argument("--senders", type=int, default=9, help="UAVs publishing (links at the receiver)")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    for preset in PRESETS:
        us = bench_shim(preset, args.n, max(3, args.repeats // 3)) * 1e6
        rows.append({"what": "shim", "preset": preset, "us_per_msg": round(us, 3)})
        print(f"shim  {preset:10s} {us:6.2f} us/msg", flush=True)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    stop = threading.Event()
    th = threading.Thread(target=serve, args=([endpoint], stop), daemon=True)
    th.start()
    time.sleep(0.8)
    try:
        rdv = Rendezvous((endpoint,))
        res = bench_poll([None, *PRESETS], args.batch, args.senders, args.repeats, rdv)
        for poll_preset, r in res.items():
            label = "off" if poll_preset is None else poll_preset
            rows.append({"what": "poll", "preset": label, "us_per_msg": round(r["per_msg"] * 1e6, 3),
                         "added_us_per_msg": round(r["added"] * 1e6, 3), "received": r["received"], "rejected": r["rejected"]})
            print(f"poll  {label:10s} {r['per_msg'] * 1e6:6.2f} us/pose (+{r['added'] * 1e6:5.2f} us vs no shim)", flush=True)
    finally:
        stop.set()
        th.join(5)
    added = next(r["added_us_per_msg"] for r in rows if r["what"] == "poll" and r["preset"] == "none")
    result = {"rows": rows, "no_impairment_added_us_per_msg": added,
              "args": vars(args), "python": sys.version.split()[0], "time": time.strftime("%Y-%m-%d %H:%M:%S")}
    write_results(out, "netem_shim", result, rows,
                  fieldnames=["what", "preset", "us_per_msg", "added_us_per_msg", "received", "rejected"])
    plot(rows, out / "netem_shim.png")
    print(f"no-impairment path adds {added:.2f} us per received pose; wrote {out}/netem_shim.{{json,csv,png}}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
