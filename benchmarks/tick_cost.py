"""What each part of a lone virtual UAV's tick costs, and why it costs more in a UAV than alone.

Two measurements, one after the other on the same machine:

* **the tick, part by part**: a lone virtual UAV (or ``--n`` of them, medians over the UAVs)
  in the default configuration (``scale.py --sizes N --configs default``) flies with its tick meter on
  (``MRSWARM_TICK_METER``, uav_stack/tick_meter.py): the thread CPU (µs) per tick of each part
  of its loop, nested parts included in their callers, and of the whole loop thread; and the
  CPU per tick of the process's other threads (Zenoh's runtime, the pose inlet's);
* **warm against paused**: a few of those parts' own work, run in this process back to back
  (warm caches, the cost a micro-benchmark shows) and 100 ms apart (as a UAV's tick runs them,
  after other processes have run): the FCU's GLOBAL_POSITION_INT and ATTITUDE encoders, the
  pose's encoding and the counters file's atomic replace. The ratio is what running once per
  tick costs over running in a loop.

    python benchmarks/tick_cost.py --out benchmarks/results   # about 2 minutes
    # -> benchmarks/results/tick_cost.{json,csv,png}
    python benchmarks/tick_cost.py --n 30 --out benchmarks/results   # a UAV of 30: tick_cost_n30.*
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402

PAUSE_S = 0.1  # a UAV's tick period


def fly_metered(n: int, window: float, work: Path) -> dict[str, Any]:
    """N UAVs' tick meter reports (uav_stack/tick_meter.py), as one report of their medians per
    part, and the scale benchmark's row."""
    meter_dir = work / "meter"
    meter_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, MRSWARM_TICK_METER=str(meter_dir))
    out = work / "scale"
    res = subprocess.run([sys.executable, "benchmarks/scale.py", "--sizes", str(n), "--configs", "default",
                          "--window", str(window), "--out", str(out)], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=600 + window)
    reports = [json.loads(p.read_text()) for p in sorted(meter_dir.glob("tick_uav*.json"))]
    if res.returncode != 0 or len(reports) != n:
        raise SystemExit(f"the metered UAVs did not fly ({len(reports)} of {n} reports):\n{res.stdout[-2000:]}\n"
                         f"{res.stderr[-2000:]}")
    row = json.loads((out / "scale.json").read_text())["rows"][0]
    return {"n": n, "meter": median_report(reports), "cpu_pct": row["cpu_pct_median"], "rtf_min": row["rtf_min"]}


def median_report(reports: list[dict[str, Any]]) -> dict[str, Any]:
    """Per part, the median over the UAVs of each figure (one UAV: its own report)."""
    med = statistics.median
    parts = []
    for i, part in enumerate(reports[0]["parts"]):
        each = [r["parts"][i] for r in reports]
        parts.append({"part": part["part"], "calls_per_tick": round(med(p["calls_per_tick"] for p in each), 3),
                      "cpu_us_per_tick": round(med(p["cpu_us_per_tick"] for p in each), 1)})
    threads = {k: round(med(r["threads_us_per_tick"][k] for r in reports), 1) for k in reports[0].get("threads_us_per_tick", {})}
    return {"uavs": len(reports), "ticks": med(r["ticks"] for r in reports), "parts": parts,
            "thread_cpu_us_per_tick": round(med(r["thread_cpu_us_per_tick"] for r in reports), 1),
            "threads_us_per_tick": threads}


def parts_under_test(work: Path) -> tuple[dict[str, Callable[[], object]], Callable[[], None]]:
    """The callables measured warm and paused, and what closes what they opened."""
    from swarmnet.messages import Pose, Realm, encode_pose
    from uav_stack.fcu import FcuConfig, VehicleConfig, VirtualFcu
    from uav_stack.fcu.streams import ENCODERS
    from uav_stack.recorder import write_json_atomic

    fcu = VirtualFcu(FcuConfig(vehicles=[VehicleConfig(sysid=1, listen=("127.0.0.1", 0))]))
    fcu.open()
    v = fcu.vehicles[0]
    v.finish_boot()  # booted: the position messages are sent
    clock = fcu.clock
    gpi, att = ENCODERS["GLOBAL_POSITION_INT"], ENCODERS["ATTITUDE"]
    pose = Pose(uav=1, realm=Realm.VIRTUAL, seq=1, t_sim=1.0, t_wall=time.time(), x=1.0, y=2.0, z=3.0,
                vx=0.1, vy=0.2, vz=0.3, yaw=0.4)
    counters = {"uav": 1, "agent": {f"counter_{k}": k for k in range(40)}, "net": {"sent": {"pose": 1200}},
                "written_at": time.time()}
    path = work / "uav1.json"

    def position() -> object:
        clock.steps += 1  # a new step: the geodetic position is computed anew, as in flight
        return gpi(v)

    parts: dict[str, Callable[[], object]] = {"GLOBAL_POSITION_INT encoded": position}
    parts.update({"ATTITUDE encoded": lambda: att(v), "pose encoded": lambda: encode_pose(pose),
                  "counters file replaced": lambda: write_json_atomic(path, counters)})
    return parts, fcu.close


def thread_us(fn: Callable[[], object], n: int, pause: float) -> float:
    """Median thread CPU (µs) of ``fn()`` over ``n`` calls, ``pause`` s apart."""
    samples = []
    for _ in range(n):
        t0 = time.thread_time_ns()
        fn()
        samples.append(time.thread_time_ns() - t0)
        if pause:
            time.sleep(pause)
    return statistics.median(samples) / 1e3


def plot(meter: dict[str, Any], micro: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    parts = meter["parts"]
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [3, 2]})
    a.barh([p["part"] for p in parts], [p["cpu_us_per_tick"] for p in parts], color="tab:blue")
    a.invert_yaxis()
    a.set_xlabel("thread CPU per tick, µs (nested parts included in their callers)")
    who = "A lone UAV's tick" if meter["uavs"] == 1 else f"A UAV of {meter['uavs']}: its tick (medians)"
    a.set_title(f"{who}: {meter['thread_cpu_us_per_tick']:.0f} µs of its loop thread")
    a.tick_params(axis="y", labelsize=7)
    x = range(len(micro))
    b.bar([i - 0.2 for i in x], [m["warm_us"] for m in micro], 0.4, label="back to back")
    b.bar([i + 0.2 for i in x], [m["paused_us"] for m in micro], 0.4, label=f"{PAUSE_S * 1000:.0f} ms apart")
    b.set_xticks(list(x), [m["part"] for m in micro], rotation=20, ha="right", fontsize=8)
    b.set_ylabel("thread CPU per call, µs (median)")
    b.set_yscale("log")
    b.legend()
    b.set_title("The same work warm and once per tick")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1, help="UAVs flown (the figures are their medians)")
    ap.add_argument("--window", type=float, default=40.0, help="s of the scale benchmark's measurement window")
    ap.add_argument("--paused-calls", type=int, default=60, help="calls per part 100 ms apart")
    ap.add_argument("--out", type=Path, default=None, help="folder for tick_cost.{json,csv,png} (default: print only)")
    ap.add_argument("--tag", default=None, help="output file names: <tag>.json/.csv/.png (default: tick_cost, tick_cost_n<N>)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="mrswarm-tick-") as tmp:
        work = Path(tmp)
        flight = fly_metered(args.n, args.window, work)
        meter = flight["meter"]
        print(f"N = {args.n}: {meter['ticks']} ticks, the loop thread {meter['thread_cpu_us_per_tick']:.0f} µs per tick "
              f"(process {flight['cpu_pct']:.2f} % of a core, RTF min {flight['rtf_min']:.3f})")
        print("  threads, µs of CPU per tick: " + ", ".join(f"{k} {v:.0f}" for k, v in meter["threads_us_per_tick"].items())
              + " (the loop's; Zenoh's runtime; the interpreter's other threads: the pose inlet's)")
        for p in meter["parts"]:
            print(f"  {p['part']:50s} {p['calls_per_tick']:5.2f} calls  {p['cpu_us_per_tick']:7.1f} µs")
        fns, close = parts_under_test(work)
        micro = []
        try:
            for name, fn in fns.items():
                thread_us(fn, 200, 0.0)  # warm-up
                warm = thread_us(fn, 2000, 0.0)
                paused = thread_us(fn, args.paused_calls, PAUSE_S)
                micro.append({"part": name, "warm_us": round(warm, 2), "paused_us": round(paused, 2),
                              "ratio": round(paused / warm, 1)})
                print(f"  {name:30s} back to back {warm:7.2f} µs, {PAUSE_S * 1000:.0f} ms apart {paused:7.2f} µs "
                      f"({paused / warm:.1f} x)")
        finally:
            close()
    if args.out is not None:
        rows = [{"kind": "tick", **p} for p in meter["parts"]] + [{"kind": "warm_vs_paused", **m} for m in micro]
        record = {"args": {k: str(v) for k, v in vars(args).items()}, "flight": flight, "warm_vs_paused": micro}
        name = args.tag or ("tick_cost" if args.n == 1 else f"tick_cost_n{args.n}")
        write_results(args.out, name, record, rows)
        plot(meter, micro, args.out / f"{name}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
