"""Time to a full peer-to-peer mesh, N = 10, 25, 50 hosts, beacon relay vs router rendezvous.

Each run builds a routed namespace lab (``discovery/netlab.py``: every host on its own
subnet behind a core router, no multicast), starts the discovery server (or a Zenoh
rendezvous router) on the edge host and one probe node per host
(``mrswarm discovery probe``, no pose traffic), all at once, and waits until every node has
a direct Zenoh link to every other. Link times come from each session's transport events.

Reported per run:

* ``pair_ms`` p50/p95/max: for every ordered pair (a, b), when a saw its link to b, after
  both sessions were open (the discovery latency a pair experiences);
* ``mesh_after_last_open_ms``: from the moment the last session opened until the mesh was
  complete (the processes start one after another on a small machine; this removes that);
* ``launch_to_mesh_s``: from launching the first process to the full mesh (includes
  Python/Zenoh start-up of N processes, so it mostly measures the machine);
* links per node (one TCP link per pair is expected) and the server's datagram counters.

    sudo python benchmarks/discovery_mesh.py --sizes 10 25 50 --out benchmarks/results

writes ``discovery_mesh.json``, ``discovery_mesh.csv`` and ``discovery_mesh.png``. Needs root.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.discovery_lab import SwarmLab  # noqa: E402

KEY = "benchmark-key-0123456789abcdef01"


def pct(values: list[float], q: float) -> float:
    v = sorted(values)
    if not v:
        return float("nan")
    k = min(len(v) - 1, max(0, round(q / 100 * (len(v) - 1))))
    return v[k]


def run_one(n: int, mode: str, workdir: Path, timeout: float) -> dict[str, Any]:
    hosts = [f"h{i}" for i in range(1, n + 1)]
    names = [f"n{i}" for i in range(1, n + 1)]
    with SwarmLab(workdir / f"{mode}-{n}", hosts, {"bench": KEY}, second_octet=70) as lab:
        router = None
        if mode == "discovery":
            lab.start_server()
        else:
            edge = lab.addr("edge")
            router = f"tcp/{edge}:7447"
            p = lab._spawn("router", "edge", [sys.executable, "-m", "discovery.rendezvous", "--listen", router])
            deadline = time.monotonic() + 30
            while "rendezvous router" not in p.log.read_text():
                if time.monotonic() > deadline or p.proc.poll() is not None:
                    raise RuntimeError(f"router did not start: {p.log.read_text()[-2000:]}")
                time.sleep(0.05)
        t_launch = time.time()
        for i, (name, host) in enumerate(zip(names, hosts, strict=True), 1):
            lab.start_probe(name, host, "bench", i, publish=0, connectivity=mode, connect=router,
                            extra_args=("--status-period", "0.5", "--poll", "0.1"))

        def meshed(st: dict[str, dict[str, Any]]) -> bool:
            z = {k: s["zid"] for k, s in st.items()}
            return all(set(st[a]["peers"]) >= {z[b] for b in names if b != a} for a in names)

        st = lab.wait_status(names, meshed, timeout, period=0.5)
        ok = len(st) == n and meshed(st)
        server_stats: dict[str, Any] = {}
        if mode == "discovery":
            try:
                _, server_stats = lab.query("bench")
            except Exception as exc:  # noqa: BLE001 - report, do not fail the benchmark
                server_stats = {"error": str(exc)}
    if not ok:
        return {"n": n, "mode": mode, "ok": False, "nodes_reporting": len(st)}
    z = {k: s["zid"] for k, s in st.items()}
    opened = {k: s["opened_at"] for k, s in st.items()}
    pairs = [st[a]["peers"][z[b]] - max(opened[a], opened[b]) for a in names for b in names if a != b]
    t_full = max(st[a]["peers"][z[b]] for a in names for b in names if a != b)
    return {
        "n": n, "mode": mode, "ok": True,
        "pair_ms": {"p50": 1000 * pct(pairs, 50), "p95": 1000 * pct(pairs, 95), "max": 1000 * max(pairs)},
        "mesh_after_last_open_ms": 1000 * (t_full - max(opened.values())),
        "launch_to_mesh_s": t_full - t_launch,
        "open_span_s": max(opened.values()) - min(opened.values()),
        "links_per_node": statistics.mean(s["links"] for s in st.values()) - (1 if mode == "rendezvous" else 0),
        "server": {k: server_stats.get(k) for k in ("rx", "tx", "beacons", "pushes", "snapshots", "acks", "uptime")}
        if server_stats else {},
    }


def plot(results: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for mode, colour in (("discovery", "tab:blue"), ("rendezvous", "tab:orange")):
        rs = [r for r in results if r["mode"] == mode and r["ok"]]
        if not rs:
            continue
        ns = [r["n"] for r in rs]
        axes[0].plot(ns, [r["pair_ms"]["p50"] for r in rs], "o-", color=colour, label=f"{mode} p50")
        axes[0].plot(ns, [r["pair_ms"]["p95"] for r in rs], "s--", color=colour, label=f"{mode} p95")
        axes[1].plot(ns, [r["mesh_after_last_open_ms"] for r in rs], "o-", color=colour, label=mode)
    axes[0].set(title="pair linked after both sessions opened", xlabel="hosts N", ylabel="ms")
    axes[1].set(title="full mesh after the last session opened", xlabel="hosts N", ylabel="ms")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle("Discovery on a routed namespace topology (no multicast): beacon relay vs router rendezvous")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 25, 50])
    ap.add_argument("--modes", nargs="+", default=["discovery", "rendezvous"], choices=["discovery", "rendezvous"])
    ap.add_argument("--out", default="benchmarks/results")
    ap.add_argument("--timeout", type=float, default=180.0)
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    work = out / "discovery_mesh_runs"
    results = []
    for n in args.sizes:
        for mode in args.modes:
            r = run_one(n, mode, work, args.timeout)
            results.append(r)
            if r["ok"]:
                print(f"N={n:3d} {mode:10s} pair p50 {r['pair_ms']['p50']:6.0f} ms  p95 {r['pair_ms']['p95']:6.0f} ms  "
                      f"max {r['pair_ms']['max']:6.0f} ms  mesh after last open {r['mesh_after_last_open_ms']:6.0f} ms  "
                      f"launch->mesh {r['launch_to_mesh_s']:5.1f} s  links/node {r['links_per_node']:.1f}", flush=True)
            else:
                print(f"N={n:3d} {mode:10s} NO FULL MESH within {args.timeout:.0f} s", flush=True)
    meta = {"command": " ".join(sys.argv), "time": time.strftime("%Y-%m-%d %H:%M:%S"), "results": results}
    (out / "discovery_mesh.json").write_text(json.dumps(meta, indent=2))
    with open(out / "discovery_mesh.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["n", "mode", "ok", "pair_p50_ms", "pair_p95_ms", "pair_max_ms", "mesh_after_last_open_ms",
                    "launch_to_mesh_s", "links_per_node"])
        for r in results:
            if r["ok"]:
                w.writerow([r["n"], r["mode"], True, f"{r['pair_ms']['p50']:.1f}", f"{r['pair_ms']['p95']:.1f}",
                            f"{r['pair_ms']['max']:.1f}", f"{r['mesh_after_last_open_ms']:.1f}",
                            f"{r['launch_to_mesh_s']:.2f}", f"{r['links_per_node']:.2f}"])
            else:
                w.writerow([r["n"], r["mode"], False] + [""] * 6)
    plot(results, out / "discovery_mesh.png")
    print(f"wrote {out / 'discovery_mesh.json'}, .csv, .png")
    return 0 if all(r["ok"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
