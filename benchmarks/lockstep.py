"""Lock-step time against real time: how much faster, and the same outcome.

Speed: for each swarm size of ``--sizes`` it flies the coverage scenario (``scenarios/coverage.yaml``,
``fleet.count = N``) in lock-step time and reports how fast the simulated clock ran (simulated s per
wall s over the clock's whole run, takeoff included: ``run.json``'s ``lockstep.speedup``), the wall
time of the run from start to summary, the share of the clock's time spent waiting for the pools, and
where a tick goes: each pool's work, its loop's CPU and its wait per step (ms), and the CPU per UAV and
tick (us).

Outcome: for ``--seeds`` seeds it flies the same scenario at ``--fidelity-n`` UAVs in real time and in
lock-step time, alternating (so that both share the machine's load of the moment), and compares
coverage T90 and the minimum separation: the lock-step runs' values against the real-time runs'
mean and 95 % confidence interval (Student's t), as ``mrswarm sweep`` computes them. It also flies
one seed twice in lock-step and says whether every trajectory is the same, row for row.

    python benchmarks/lockstep.py --sizes 10 100 --seeds 5 --out benchmarks/results

writes ``lockstep.json`` and ``lockstep.csv`` (one row per run).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from mrswarm.sweep.stats import summarise  # noqa: E402
from mrswarm.testing import Flight, fly  # noqa: E402

SCENARIO = ROOT / "scenarios" / "coverage.yaml"


def flown(out: Path, n: int, seed: int, lockstep: bool, duration: float | None) -> tuple[Flight, float]:
    sets = [f"fleet.count={n}", f"seed={seed}"] + (["time=lockstep"] if lockstep else [])
    if duration is not None:
        sets.append(f"duration={duration:g}")
    t0 = time.monotonic()
    f = fly(scenario=SCENARIO, out=out, sets=sets, record=False)
    return f, time.monotonic() - t0


def row(kind: str, n: int, seed: int, f: Flight, wall: float) -> dict[str, Any]:
    import json

    info = json.loads((f.run_dir / "run.json").read_text())
    ls = info.get("lockstep") or {}
    cov = f.summary.get("coverage") or {}
    sep = f.summary.get("separation") or {}
    pools = info.get("pools") or {}
    return {"kind": kind, "n": n, "seed": seed, "aborted": f.summary.get("aborted"), "run_wall_s": round(wall, 1),
            "speedup": ls.get("speedup"), "clock_sim_s": ls.get("sim_s"), "clock_wall_s": ls.get("wall_s"),
            "clock_waiting_share": round(ls["waiting_s"] / ls["wall_s"], 3) if ls.get("wall_s") else None,
            **pool_steps(f, pools), "t90_s": cov.get("time_to_90_s"), "coverage": cov.get("final"),
            "min_separation_m": sep.get("min_m"), "collisions": sep.get("collisions"), "run_dir": str(f.run_dir)}


def pool_steps(f: Flight, pools: dict[str, list[int]]) -> dict[str, float | None]:
    """Where a lock-step tick goes, per step and pool (the mean over pools of their loops' ``loop.lockstep``, ms):
    its work (step in to answer out), the loop's CPU in it, the wait for the next step; and the CPU per UAV and
    tick (us): the figure the speed at large N depends on (docs/campaigns.md)."""
    seen = [(len(uavs), (f.stats.get(uavs[0], {}).get("loop") or {}).get("lockstep")) for uavs in pools.values() if uavs]
    steps = [(size, st) for size, st in seen if isinstance(st, dict)]
    if not steps:
        return {"pool_work_ms": None, "pool_cpu_ms": None, "pool_wait_ms": None, "cpu_us_per_uav_tick": None}
    mean = statistics.fmean
    return {"pool_work_ms": round(mean(st["work_ms"] for _, st in steps), 2),
            "pool_cpu_ms": round(mean(st["cpu_ms"] for _, st in steps), 2),
            "pool_wait_ms": round(mean(st["wait_ms"] for _, st in steps), 2),
            "cpu_us_per_uav_tick": round(1000.0 * sum(st["cpu_ms"] for _, st in steps) / sum(s for s, _ in steps), 1)}


def interval(values: list[float]) -> tuple[float, float, float]:
    """Mean and 95 % interval of the mean, as the sweep's table computes them."""
    s = summarise(values)
    assert s.mean is not None
    return s.mean, s.ci_low if s.ci_low is not None else s.mean, s.ci_high if s.ci_high is not None else s.mean


def same_flight(a: Flight, b: Flight) -> bool:
    if a.trajectories.keys() != b.trajectories.keys():
        return False
    for u, ta in a.trajectories.items():
        tb = b.trajectories[u]
        n = min(len(ta.t), len(tb.t))
        ra = np.column_stack([ta.t, ta.x, ta.y, ta.z, ta.vx, ta.vy])[:n]
        rb = np.column_stack([tb.t, tb.x, tb.y, tb.z, tb.vx, tb.vy])[:n]
        if n < 10 or not np.array_equal(ra, rb):
            return False
    return True


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 100], help="swarm sizes for the speed")
    ap.add_argument("--speed-duration", type=float, default=None, help="mission s of the speed runs (default: the scenario's)")
    ap.add_argument("--seeds", type=int, default=5, help="seeds of the outcome comparison (0: none)")
    ap.add_argument("--fidelity-n", type=int, default=10, help="UAVs of the outcome comparison")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    ap.add_argument("--runs", type=Path, default=Path("/tmp/mrswarm-lockstep-bench"), help="where the run folders go")
    ap.add_argument("--tag", default="lockstep")
    args = ap.parse_args(argv)
    console = Console()
    rows: list[dict[str, Any]] = []
    for n in args.sizes:
        f, wall = flown(args.runs / f"speed-{n}", n, 7, True, args.speed_duration)
        rows.append(row("lockstep-speed", n, 7, f, wall))
        console.print(rows[-1])
    real: list[dict[str, Any]] = []
    lock: list[dict[str, Any]] = []
    for seed in range(args.seeds):
        for lockstep in (False, True):
            f, wall = flown(args.runs / f"fidelity-{seed}-{'lockstep' if lockstep else 'real'}", args.fidelity_n, seed,
                            lockstep, None)
            r = row("lockstep" if lockstep else "real", args.fidelity_n, seed, f, wall)
            (lock if lockstep else real).append(r)
            rows.append(r)
            console.print(r)
    record: dict[str, Any] = {"args": {k: str(v) for k, v in vars(args).items()}, "rows": rows}
    if real and lock:
        cmp: dict[str, Any] = {}
        for metric in ("t90_s", "min_separation_m"):
            rv = [r[metric] for r in real if r[metric] is not None]
            lv = [r[metric] for r in lock if r[metric] is not None]
            m, lo, hi = interval(rv)
            lm = statistics.fmean(lv) if lv else None
            cmp[metric] = {"real_mean": round(m, 3), "real_ci95": [round(lo, 3), round(hi, 3)],
                           "lockstep_mean": round(lm, 3) if lm is not None else None,
                           "lockstep_values": lv, "real_values": rv,
                           "lockstep_mean_within": lm is not None and lo <= lm <= hi}
        record["outcome"] = cmp
        console.print(cmp)
    if args.seeds:
        a, _ = flown(args.runs / "same-a", args.fidelity_n, 0, True, None)
        b, _ = flown(args.runs / "same-b", args.fidelity_n, 0, True, None)
        record["one_seed_one_flight"] = same_flight(a, b)
        console.print(f"one seed, one flight: {record['one_seed_one_flight']}")
    write_results(args.out, args.tag, record, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
