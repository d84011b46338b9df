"""Per-container against per-process cost: CPU and memory of a virtual UAV in each runtime.

For each swarm size N it flies the scaling benchmark's random-coverage mission (every UAV
moving and sharing poses at 10 Hz; ``benchmarks/scale.py``) once with the process runtime
and once with the docker runtime, waits ``--warmup`` s after the mission starts, then measures
over ``--window`` s:

* the UAV's own Python process (in a container: its main process, seen from the host):
  CPU in % of one core, RSS, PSS and USS, exactly as ``scale.py`` does;
* per container only: the ``containerd-shim`` that babysits it (CPU, RSS), and the
  container's memory cgroup (``usage``, which includes page cache, and the working set
  ``usage - inactive_file`` that ``docker stats`` shows);
* the docker daemon and containerd (CPU, RSS), which a container runtime adds once per host;
* RTF and pose age from the run summary.

    python benchmarks/containers.py --sizes 5 10 20 --out benchmarks/results

writes ``containers.json``, ``containers.csv`` and ``containers.png``. Medians over the UAVs
of one run per (N, runtime); needs the stack image (``mrswarm deploy build``).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import psutil
from msgspec.structs import replace
from rich.console import Console

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from benchmarks.scale import Sampler, scenario_for  # noqa: E402
from mrswarm.run.experiment import Experiment  # noqa: E402


def cgroup_memory(pid: int) -> tuple[float, float]:
    """(usage MB, working set MB) of the memory cgroup that holds ``pid`` (cgroup v1 or v2)."""
    try:
        lines = Path(f"/proc/{pid}/cgroup").read_text().splitlines()
    except OSError:
        return math.nan, math.nan
    for line in lines:
        _, ctrl, path = line.split(":", 2)
        if "memory" in ctrl.split(","):  # v1
            base = Path("/sys/fs/cgroup/memory") / path.lstrip("/")
            usage, stat, inactive = base / "memory.usage_in_bytes", base / "memory.stat", "total_inactive_file"
            break
    else:
        path = next((ln.split(":", 2)[2] for ln in lines if ln.startswith("0::")), "")
        root = Path("/sys/fs/cgroup/unified") if Path("/sys/fs/cgroup/unified").is_dir() else Path("/sys/fs/cgroup")
        base = root / path.lstrip("/")
        usage, stat, inactive = base / "memory.current", base / "memory.stat", "inactive_file"
    try:
        u = int(usage.read_text())
        st = dict(ln.split() for ln in stat.read_text().splitlines())
        return u / 2**20, (u - int(st.get(inactive, 0))) / 2**20
    except (OSError, ValueError):
        return math.nan, math.nan


def daemons() -> dict[str, psutil.Process]:
    out = {}
    for p in psutil.process_iter(["name"]):
        if p.info["name"] in ("dockerd", "containerd"):
            out[p.info["name"]] = p
    return out


class ContainerSampler(Sampler):
    """scale.py's sampler, plus each UAV container's shim and cgroup, and the docker daemons."""

    def __init__(self, warmup: float, window: float):
        super().__init__(warmup, window)
        self.extra_start: dict[str, tuple[float, psutil.Process]] = {}
        self.extra: dict[str, dict[str, float]] = {}

    def __call__(self, exp: Experiment, elapsed: float) -> None:
        starting = self.t_start is None and elapsed >= self.warmup
        ending = self.t_start is not None and self.t_end is None and time.time() - self.t_start >= self.window
        if starting and exp.runtime.name == "docker":
            for name, pid in exp.runtime.pids().items():
                if name.startswith("uav"):
                    shim = psutil.Process(pid).parent()
                    if shim is None:  # the container's process already gone: no shim to measure
                        continue
                    self.extra_start[f"shim:{name}"] = (sum(shim.cpu_times()[:2]), shim)
            for name, p in daemons().items():
                self.extra_start[name] = (sum(p.cpu_times()[:2]), p)
        super().__call__(exp, elapsed)
        if ending and self.t_end is not None and exp.runtime.name == "docker":
            dt = self.t_end - self.t_start  # type: ignore[operator]
            for name, (cpu0, p) in self.extra_start.items():
                try:
                    self.extra[name] = {"cpu_pct": 100.0 * (sum(p.cpu_times()[:2]) - cpu0) / dt,
                                        "rss_mb": p.memory_info().rss / 2**20}
                except psutil.NoSuchProcess:
                    self.extra[name] = {"cpu_pct": math.nan, "rss_mb": math.nan}
            for name, pid in exp.runtime.pids().items():
                if name.startswith("uav"):
                    usage, ws = cgroup_memory(pid)
                    self.extra[f"cgroup:{name}"] = {"usage_mb": usage, "working_set_mb": ws}


def _med(values: list[float]) -> float:
    vals = [v for v in values if not math.isnan(v)]
    return round(statistics.median(vals), 2) if vals else math.nan


def run_one(n: int, runtime: str, args: argparse.Namespace, console: Console) -> dict[str, Any]:
    sampler = ContainerSampler(args.warmup, args.window)
    scn = scenario_for(n, args.warmup + args.window + 2.0, "discovery-direct")
    scn = replace(scn, runtime=runtime, name=f"{scn.name}-{runtime}")
    if args.image:
        scn = replace(scn, docker=replace(scn.docker, image=args.image))
    exp = Experiment(scn, Path(args.out) / "runs", console=console, live=False, log_level="WARNING", probe=sampler)
    t0 = time.time()
    summary = exp.run().to_dict()
    uavs = {k: v for k, v in sampler.result.items() if k.startswith("uav")}
    if not uavs:
        raise SystemExit(f"N={n} {runtime}: no measurement (run aborted? {summary.get('aborted')})")
    col = lambda key: [v[key] for v in uavs.values()]  # noqa: E731
    ex = sampler.extra
    shims = [v for k, v in ex.items() if k.startswith("shim:")]
    cgs = [v for k, v in ex.items() if k.startswith("cgroup:")]
    age = summary.get("network", {}).get("transport_age_ms", {})
    row = {
        "n": n,
        "runtime": runtime,
        "uav_cpu_pct": _med(col("cpu_pct")),
        "uav_rss_mb": _med(col("rss_mb")),
        "uav_pss_mb": _med(col("pss_mb")),
        "uav_uss_mb": _med(col("uss_mb")),
        "shim_cpu_pct": _med([s["cpu_pct"] for s in shims]),
        "shim_rss_mb": _med([s["rss_mb"] for s in shims]),
        "cgroup_usage_mb": _med([c["usage_mb"] for c in cgs]),
        "cgroup_working_set_mb": _med([c["working_set_mb"] for c in cgs]),
        "dockerd_cpu_pct": round(ex.get("dockerd", {}).get("cpu_pct", math.nan), 2),
        "dockerd_rss_mb": round(ex.get("dockerd", {}).get("rss_mb", math.nan), 1),
        "containerd_cpu_pct": round(ex.get("containerd", {}).get("cpu_pct", math.nan), 2),
        "router_cpu_pct": round(sampler.result.get("router", {}).get("cpu_pct", math.nan), 2),
        "rtf_mean": summary.get("rtf", {}).get("mean"),
        "rtf_min": summary.get("rtf", {}).get("min"),
        "transport_age_p50_ms": age.get("p50"),
        "transport_age_p99_ms": age.get("p99"),
        "collisions": summary.get("separation", {}).get("collisions"),
        "wall_s": round(time.time() - t0, 1),
    }
    console.print(row)
    return row


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(15, 4))
    for rt, style in (("process", "o-"), ("docker", "s-")):
        rs = [r for r in rows if r["runtime"] == rt]
        ns = [r["n"] for r in rs]
        ax[0].plot(ns, [r["uav_cpu_pct"] for r in rs], style, label=f"{rt}: UAV process")
        ax[1].plot(ns, [r["uav_rss_mb"] for r in rs], style, label=f"{rt}: UAV RSS")
        ax[1].plot(ns, [r["uav_pss_mb"] for r in rs], style.replace("-", ":"), label=f"{rt}: UAV PSS")
        ax[2].plot(ns, [r["rtf_mean"] for r in rs], style, label=rt)
        if rt == "docker":
            ax[0].plot(ns, [r["uav_cpu_pct"] + r["shim_cpu_pct"] for r in rs], "s--", label="docker: + shim")
            ax[1].plot(ns, [r["uav_rss_mb"] + r["shim_rss_mb"] for r in rs], "s--", label="docker: RSS + shim")
            ax[1].plot(ns, [r["cgroup_working_set_mb"] for r in rs], "^-", label="docker: cgroup working set")
    ax[0].set_title("CPU per virtual UAV (% of one core)")
    ax[1].set_title("memory per virtual UAV (MB)")
    ax[2].set_title("real-time factor (mean)")
    ax[2].set_ylim(0, 1.05)
    for a in ax:
        a.set_xlabel("virtual UAVs (N)")
        a.legend(fontsize=7)
        a.grid(alpha=0.3)
    fig.suptitle(f"per-container vs per-process, {psutil.cpu_count()} cores (medians over the UAVs of one run)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[5, 10, 20])
    ap.add_argument("--runtimes", nargs="+", default=["process", "docker"], choices=["process", "docker"])
    ap.add_argument("--warmup", type=float, default=10.0, help="seconds after the mission starts before measuring")
    ap.add_argument("--window", type=float, default=20.0, help="measurement window, s")
    ap.add_argument("--image", default=None, help="stack image (default mrswarm:<version>)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    console = Console()
    rows = [run_one(n, rt, args, console) for n in args.sizes for rt in args.runtimes]
    write_results(out, "containers", {"args": vars(args), "cores": psutil.cpu_count(), "rows": rows}, rows)
    plot(rows, out / "containers.png")
    console.print(f"wrote {out}/containers.json/.csv/.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
