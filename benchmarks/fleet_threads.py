"""Where a fleet of virtual UAVs spends its CPU: by thread, by library, by symbol (Linux ``perf``).

The tick meter (``tick_cost.py``) times parts of a UAV's loop from inside; ``uav_profile.py``
charges one UAV's loop thread to Python functions (3.12 and newer). This one looks at every
UAV of a fleet from outside, with any interpreter: ``perf record -e cpu-clock -a`` samples the
whole machine for ``--seconds`` while ``scale.py`` flies ``--n`` UAVs, and each sample of a UAV
process is charged to its thread and to the library its instruction was in (the interpreter,
Zenoh, the kernel, numpy...).

A UAV process's threads, by role: ``loop`` (the UAV's main thread: virtual FCU, agent, records;
the Python thread with the most samples), ``inlet`` (its other Python threads: the pose
inlet's), ``zenoh`` (Zenoh's runtime, ``app-0``; a UAV runs all of Zenoh on it). The UAV
processes are those with that one Zenoh thread (a router's Zenoh has ``rx-``, ``tx-`` and ``acc-``
threads too) and a share of samples within ten times the others'.

    apt-get install linux-perf                  # Debian; perf must run as root
    python benchmarks/fleet_threads.py --n 50 --out benchmarks/results
    # -> benchmarks/results/fleet_threads_n50.{json,csv,png}; about 3 minutes
"""

from __future__ import annotations

import argparse
import collections
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import plot_shares, write_results  # noqa: E402

ZENOH_THREAD = "app-0"
ROUTER_THREADS = ("rx-", "tx-", "acc-", "net-")
HEADER = re.compile(r"^\s*(?P<comm>.+?)\s+(?P<pid>\d+)/(?P<tid>\d+)\s+(?P<ip>[0-9a-f]+)\s+(?P<sym>.*?)\s+\((?P<dso>.*)\)\s*$")


def samples(perf_data: Path) -> list[tuple[str, int, int, str, str]]:
    """(comm, pid, tid, library, symbol) of every sample."""
    out = subprocess.run(["perf", "script", "-i", str(perf_data), "-F", "comm,pid,tid,ip,sym,dso"], capture_output=True,
                         text=True, timeout=600, check=True).stdout
    rows = []
    for line in out.splitlines():
        m = HEADER.match(line)
        if m:
            rows.append((m["comm"], int(m["pid"]), int(m["tid"]), m["dso"].rsplit("/", 1)[-1], m["sym"]))
    return rows


def roles(rows: list[tuple[str, int, int, str, str]]) -> tuple[dict[int, str], list[int]]:
    """Each UAV thread's role, and the UAV processes (see the module's docstring)."""
    per_pid = collections.Counter(r[1] for r in rows)
    # a router (the edge router, the runner's) runs Zenoh's default runtime: rx-, tx-, acc- threads
    routers = {r[1] for r in rows if r[0].startswith(ROUTER_THREADS)}
    with_zenoh = {r[1] for r in rows if r[0] == ZENOH_THREAD} - routers
    if not with_zenoh:
        return {}, []
    typical = sorted(per_pid[p] for p in with_zenoh)[len(with_zenoh) // 2]
    uavs = [p for p in with_zenoh if typical / 10 <= per_pid[p] <= typical * 10]
    by_thread: dict[int, collections.Counter[tuple[int, str]]] = collections.defaultdict(collections.Counter)
    for comm, pid, tid, _, _ in rows:
        if pid in uavs:
            by_thread[pid][(tid, comm)] += 1
    role: dict[int, str] = {}
    for threads in by_thread.values():
        python = sorted(((n, tid) for (tid, comm), n in threads.items() if comm.startswith("python")), reverse=True)
        for k, (_, tid) in enumerate(python):
            role[tid] = "loop" if k == 0 else "inlet"
        for (tid, comm), _ in threads.items():
            if not comm.startswith("python"):
                role[tid] = "zenoh" if comm == ZENOH_THREAD else comm
    return role, uavs


def analyse(rows: list[tuple[str, int, int, str, str]], seconds: float, freq: int) -> dict[str, Any]:
    role, uavs = roles(rows)
    mine = [r for r in rows if r[1] in set(uavs)]
    if not mine:
        raise SystemExit("no UAV process was sampled")
    n = len(mine)
    by_role = collections.Counter(role.get(r[2], "?") for r in mine)
    by_lib = collections.Counter((role.get(r[2], "?"), r[3]) for r in mine)
    by_sym: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    for r in mine:
        by_sym[role.get(r[2], "?")][f"{r[4]} ({r[3]})"] += 1
    return {
        "uavs": len(uavs),
        "samples": n,
        "cpu_pct_per_uav": round(100.0 * n / len(uavs) / seconds / freq, 3),
        "roles_pct": {k: round(100.0 * v / n, 2) for k, v in by_role.most_common()},
        "libraries_pct": [{"role": k[0], "library": k[1], "pct": round(100.0 * v / n, 2)} for k, v in by_lib.most_common(40)],
        "symbols_pct": {k: [{"symbol": s, "pct": round(100.0 * v / n, 2)} for s, v in c.most_common(25)]
                        for k, c in by_sym.items()},
    }


def plot(result: dict[str, Any], path: Path, title: str) -> None:
    libs = result["libraries_pct"][:16]
    plot_shares(path, [f"{r['role']}: {r['library'][:40]}" for r in libs], [r["pct"] for r in libs],
                "% of the UAVs' CPU samples", title)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=50, help="virtual UAVs")
    ap.add_argument("--config", default="default", help="scale.py network configuration")
    ap.add_argument("--seconds", type=float, default=30.0, help="s of sampling, once the mission runs")
    ap.add_argument("--freq", type=int, default=997, help="samples a second per CPU")
    ap.add_argument("--out", type=Path, default=None, help="folder for fleet_threads_n<N>.{json,csv,png} (default: print only)")
    ap.add_argument("--tag", default=None, help="file names (default fleet_threads_n<N>)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="mrswarm-fleet-threads-") as tmp:
        work = Path(tmp)
        fleet = subprocess.Popen([sys.executable, "benchmarks/scale.py", "--sizes", str(args.n), "--configs", args.config,
                                  "--warmup", "15", "--window", str(args.seconds + 40.0), "--out", str(work / "scale")],
                                 cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            run_dir = None
            deadline = time.monotonic() + 300.0
            while run_dir is None and time.monotonic() < deadline and fleet.poll() is None:  # bounded: 5 min
                found = sorted((work / "scale" / "runs").glob("*/uav*.json")) if (work / "scale" / "runs").exists() else []
                if len(found) >= args.n:
                    run_dir = found[0].parent
                time.sleep(1.0)
            if run_dir is None:
                raise SystemExit("the fleet did not come up within 5 minutes")
            time.sleep(30.0)  # take-off and the mission's start
            data = work / "perf.data"
            subprocess.run(["perf", "record", "-q", "-e", "cpu-clock", "-F", str(args.freq), "-a", "-o", str(data), "--",
                            "sleep", str(args.seconds)], check=True, timeout=args.seconds + 60.0,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            result = analyse(samples(data), args.seconds, args.freq)
            fleet.wait(240.0)  # its window ends soon after: the runner lands and stops every UAV
        finally:
            if fleet.poll() is None:
                fleet.terminate()  # (its UAVs leave when their launcher is gone)
                try:
                    fleet.wait(60.0)
                except subprocess.TimeoutExpired:
                    fleet.kill()
    result.update({"n": args.n, "config": args.config, "seconds": args.seconds, "freq": args.freq})
    print(f"N = {args.n}: {result['uavs']} UAV processes, {result['cpu_pct_per_uav']} % of a core each (perf's count)")
    print("  by thread: " + ", ".join(f"{k} {v} %" for k, v in result["roles_pct"].items()))
    for r in result["libraries_pct"][:14]:
        print(f"  {r['pct']:5.1f} %  {r['role']:6s} {r['library']}")
    if args.out is not None:
        tag = args.tag or f"fleet_threads_n{args.n}"
        write_results(args.out, tag, result, result["libraries_pct"])
        plot(result, args.out / f"{tag}.png", f"{args.n} virtual UAVs ({args.config}): their CPU by thread and library")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
