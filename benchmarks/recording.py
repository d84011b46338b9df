"""Cost of the flight recorder: CPU and memory of its process, and MB of MCAP per minute of flight.

Flies the scaling benchmark's random-coverage mission (``benchmarks/scale.py``) with N virtual
UAVs and the runner's recorder on (as ``mrswarm run`` does by default). Over a measurement window
in the mission it samples the recorder process (``mrswarm gcs record --mcap``, beside the runner):
CPU (% of one core), RSS, and how fast ``run.mcap`` grows; after the run, the file's messages and
its size. The recorder's messages per second tell what it carried: every pose (10 Hz per UAV),
telemetry (2 Hz), states (1 Hz), the 5 Hz 3-D scene, logs and counters.

    python benchmarks/recording.py --n 50 --out benchmarks/results

writes ``recording.json`` and ``recording.csv``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import psutil
from rich.console import Console

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from benchmarks.scale import scenario_for  # noqa: E402
from mrswarm.recorder.reader import Recording, read_recording  # noqa: E402
from mrswarm.run.experiment import Experiment  # noqa: E402


class RecorderProbe:
    """Samples the recorder process and its file at the start and the end of the window."""

    def __init__(self, warmup: float, window: float):
        self.warmup, self.window = warmup, window
        self.t0: float | None = None
        self.start: tuple[float, int] | None = None  # cpu s, file bytes
        self.proc: psutil.Process | None = None
        self.result: dict[str, float] = {}
        self.rss: list[float] = []
        self.window_wall = (0.0, 0.0)

    def __call__(self, exp: Experiment, elapsed: float) -> None:
        rec = exp.recorder
        if rec is None or elapsed < self.warmup or self.result:
            return
        if self.proc is None:
            self.proc = psutil.Process(rec.pid)
        c = self.proc.cpu_times()
        cpu = c.user + c.system
        size = rec.path.stat().st_size
        self.rss.append(self.proc.memory_info().rss / 1e6)
        now = time.time()
        if self.t0 is None:
            self.t0, self.start = now, (cpu, size)
        elif now - self.t0 >= self.window:
            assert self.start is not None
            dt = now - self.t0
            self.window_wall = (self.t0, now)
            self.result = {"window_s": round(dt, 1), "recorder_cpu_pct": round(100.0 * (cpu - self.start[0]) / dt, 2),
                           "recorder_rss_mb_max": round(max(self.rss), 1),
                           "mb_per_min": round((size - self.start[1]) / dt * 60 / 1e6, 3)}


def run_once(n: int, args: argparse.Namespace, console: Console) -> dict[str, Any]:
    probe = RecorderProbe(args.warmup, args.window)
    scn = scenario_for(n, args.warmup + args.window + 3.0, "discovery-direct")
    exp = Experiment(scn, Path(args.runs), console=console, live=False, probe=probe)
    exp.run()
    if exp.recorder is None or not probe.result:
        raise RuntimeError(f"N={n}: no measurement (recorder {'off' if exp.recorder is None else 'on'}; run too short?)")
    rec = Recording(exp.recorder.path)
    t0, t1 = (int(t * 1e9) for t in probe.window_wall)
    n_msgs = in_window = 0
    for m in read_recording(exp.recorder.path, rec):
        n_msgs += 1
        in_window += t0 <= m.log_time <= t1
    return {"n": n, **probe.result, "messages_per_s": round(in_window / probe.result["window_s"], 1),
            "file_mb": round(exp.recorder.path.stat().st_size / 1e6, 2), "messages": n_msgs, "complete": rec.complete,
            "run_dir": str(exp.run_dir)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[50], help="swarm sizes (default 50)")
    ap.add_argument("--warmup", type=float, default=15.0, help="s of mission before the window (default 15)")
    ap.add_argument("--window", type=float, default=60.0, help="s of measurement (default 60)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"), help="where recording.json/.csv go")
    ap.add_argument("--runs", default="/tmp/mrswarm-bench-recording", help="run folders")
    args = ap.parse_args(argv)
    console = Console()
    rows = []
    for n in args.n:
        r = run_once(n, args, console)
        rows.append(r)
        console.print(f"N={n}: recorder {r['recorder_cpu_pct']} % of a core, {r['recorder_rss_mb_max']} MB RSS, "
                      f"{r['mb_per_min']} MB/min of flight, {r['messages_per_s']} messages/s; file {r['file_mb']} MB")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"date": time.strftime("%Y-%m-%d"), "cpus": psutil.cpu_count(), "warmup_s": args.warmup, "window_s": args.window}
    write_results(out, "recording", {"meta": meta, "rows": rows}, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
