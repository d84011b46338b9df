"""Two variants of the virtual UAV in one run: half the fleet flies A, half B, CPU compared UAV by UAV.

Why: flown one after the other (benchmarks/commits.py), a lone UAV's CPU moves by about 5 % from
one run to the next on this machine, so a change worth 2 % needs many rounds to show. In one run
both halves share every load spike, the same swarm and the same network: the ratio of their
medians moves by about 1.5 % (its A/A rounds, docs/performance.md). The price: a mixed fleet,
so the two variants must speak the same wire format, and what the change does to the others (the
poses it sends them) shows on both halves.

A variant is code, environment or both:

* ``--b-commit REV``: B's UAV processes import the code of ``REV`` (a throw-away git worktree, its C
  extensions built there, first on their ``PYTHONPATH``); the runner, the edge router and A's UAVs
  run this tree;
* ``--b-env NAME=VALUE`` (repeatable): B's UAV processes get it in their environment
  (``PYTHONMALLOC=malloc``, ``GLIBC_TUNABLES=glibc.malloc.hugetlb=1``, ...);
* neither: an A/A run, which measures the method's own spread.

B flies the odd UAVs in even rounds and the even UAVs in odd rounds, so that a UAV's place in the
swarm does not count as B's. Per round: the median CPU of each half (% of one core, over
``--window`` s, from the scheduler's nanosecond account of each process's threads; the ratio of
benchmarks/scale.py's clock-tick figures beside it), their ratio B/A, each half's RSS and slowest
RTF. Writes ``<tag>.json``, ``<tag>.csv`` and ``<tag>.png`` into ``--out``.

    python benchmarks/paired.py --n 10 --rounds 4 --b-env PYTHONMALLOC=malloc --tag paired_malloc
    python benchmarks/paired.py --n 10 --rounds 4 --b-commit HEAD~1 --tag paired_last
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rich.console import Console

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.commits import checkout, remove  # noqa: E402
from benchmarks.output import write_results  # noqa: E402
from benchmarks.scale import CONFIGS, Sampler, scenario_for  # noqa: E402
from mrswarm.run.experiment import Experiment  # noqa: E402
from uav_stack.tick_meter import threads_cpu_ns  # noqa: E402


def thread_ns(pid: int) -> dict[int, int] | None:
    """CPU time (ns) each thread of process ``pid`` has run so far, by thread id, from the
    scheduler's own account (``/proc/<pid>/task/*/schedstat``); None if the process is gone.
    Nanoseconds rather than the 10 ms clock ticks of ``cpu_times()``: 40 s of a UAV at 2 % are 80
    ticks, so one tick is more than 1 % of the reading."""
    return {tid: ns for tid, (_comm, ns) in threads_cpu_ns(pid).items()} or None


def window_ns(before: dict[int, int], after: dict[int, int]) -> int:
    """CPU time (ns) a process's threads ran between two :func:`thread_ns` readings. A thread
    started in between counts from its start; one that ended in between is missed (a UAV's
    threads live as long as it does)."""
    return sum(ns - before.get(tid, 0) for tid, ns in after.items())


class PairedSampler(Sampler):
    """:class:`~benchmarks.scale.Sampler`, also keeping each UAV process's environment as the window
    opens (the proof that each half flew what it was meant to) and its CPU in nanoseconds
    (:func:`thread_ns`) over the same window, in ``result[name]["cpu_pct_ns"]``."""

    def __init__(self, warmup: float, window: float):
        super().__init__(warmup, window)
        self.environ: dict[str, dict[str, str]] = {}
        self._ns0: dict[str, tuple[float, dict[int, int]]] = {}

    def __call__(self, exp: Experiment, elapsed: float) -> None:
        opened, closed = self.t_start is not None, self.t_end is not None
        super().__call__(exp, elapsed)
        if not opened and self.t_start is not None:  # the window has just opened
            for name, (_cpu, proc) in self.start.items():
                if not name.startswith("uav"):
                    continue
                ns = thread_ns(proc.pid)
                if ns is not None:
                    self._ns0[name] = (time.monotonic(), ns)
                try:
                    self.environ[name] = proc.environ()
                except Exception:  # noqa: BLE001 - gone, or not ours to read: left unchecked
                    pass
        if not closed and self.t_end is not None:  # the window has just closed
            for name, (t0, ns0) in self._ns0.items():
                ns = thread_ns(self.start[name][1].pid)
                if ns is not None and name in self.result:
                    self.result[name]["cpu_pct_ns"] = 100.0 * window_ns(ns0, ns) / 1e9 / (time.monotonic() - t0)


def check_halves(environ: dict[str, dict[str, str]], rnd: int, b_env: dict[str, str], b_tree: Path | None) -> None:
    """Every UAV process flew its half's variant: B's with ``b_env`` and B's tree first on its path,
    A's without them."""
    for name, env in environ.items():
        b = b_flies(name, rnd)
        has_env = all(env.get(k) == v for k, v in b_env.items())
        on_b_tree = b_tree is not None and env.get("PYTHONPATH", "").split(os.pathsep)[0] == str(b_tree)
        if b_env and has_env != b:
            raise SystemExit(f"round {rnd}: {name} {'lacks' if b else 'has'} B's environment")
        if b_tree is not None and on_b_tree != b:
            raise SystemExit(f"round {rnd}: {name} {'does not run' if b else 'runs'} B's code")


def b_flies(name: str, rnd: int) -> bool:
    """Whether the UAV process ``name`` (``uav<id>``) flies variant B in round ``rnd``."""
    return int(name[3:]) % 2 == (1 if rnd % 2 == 0 else 0)


def fly_round(rnd: int, args: argparse.Namespace, b_env: dict[str, str], b_tree: Path | None,
              console: Console) -> dict[str, Any]:
    """One run of ``--n`` UAVs, half of them B; the round's row."""
    sampler = PairedSampler(args.warmup, args.window)
    scn = scenario_for(args.n, args.warmup + args.window + 2.0, args.config)
    exp = Experiment(scn, Path(args.out) / "runs", console=console, live=False, log_level="WARNING", probe=sampler)
    rt: Any = exp.runtime  # the process runtime: every child is spawned with its environment (rt._env)
    env_a = rt._env
    env_b = dict(env_a, **b_env)
    if b_tree is not None:  # B's code first on the path: its packages shadow this tree's
        env_b["PYTHONPATH"] = os.pathsep.join([str(b_tree), env_a.get("PYTHONPATH", "")])
    spawn = rt._spawn

    def spawn_paired(name: str, argv: list[str]) -> None:
        rt._env = env_b if name.startswith("uav") and b_flies(name, rnd) else env_a
        try:
            spawn(name, argv)
        finally:
            rt._env = env_a

    rt._spawn = spawn_paired
    summary = exp.run().to_dict()
    check_halves(sampler.environ, rnd, b_env, b_tree)
    rtf = summary.get("rtf", {}).get("per_uav", {})
    halves: dict[str, dict[str, list[float]]] = {k: {"cpu": [], "ticks": [], "rss": [], "rtf": []} for k in ("a", "b")}
    for name, r in sampler.result.items():
        if not name.startswith("uav"):
            continue
        h = halves["b" if b_flies(name, rnd) else "a"]
        h["cpu"].append(r.get("cpu_pct_ns", r["cpu_pct"]))
        h["ticks"].append(r["cpu_pct"])
        h["rss"].append(r["rss_mb"])
        if name[3:] in rtf:
            h["rtf"].append(rtf[name[3:]])
    if not halves["a"]["cpu"] or not halves["b"]["cpu"]:
        raise SystemExit(f"round {rnd}: no measurement ({summary.get('aborted')}); see {summary.get('run_dir')}")
    a, b = (statistics.median(halves[k]["cpu"]) for k in ("a", "b"))
    row = {
        "round": rnd, "b_uavs": "odd" if b_flies("uav1", rnd) else "even",
        "n_a": len(halves["a"]["cpu"]), "n_b": len(halves["b"]["cpu"]),
        "cpu_pct_a": round(a, 4), "cpu_pct_b": round(b, 4), "ratio_b_a": round(b / a, 4),
        "ratio_b_a_ticks": round(statistics.median(halves["b"]["ticks"]) / statistics.median(halves["a"]["ticks"]), 4),
        "rss_mb_a": round(statistics.median(halves["a"]["rss"]), 1), "rss_mb_b": round(statistics.median(halves["b"]["rss"]), 1),
        "rtf_min_a": min(halves["a"]["rtf"], default=None), "rtf_min_b": min(halves["b"]["rtf"], default=None),
        "checked_uavs": len(sampler.environ),
        "collisions": summary.get("separation", {}).get("collisions"), "run_dir": summary.get("run_dir"),
    }
    console.print(row)
    return row


def plot(rows: list[dict[str, Any]], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    rounds = [r["round"] for r in rows]
    ax[0].plot(rounds, [r["cpu_pct_a"] for r in rows], "o-", label="A")
    ax[0].plot(rounds, [r["cpu_pct_b"] for r in rows], "s-", label="B")
    ax[0].set_title("CPU per UAV process, median of each half (% of one core)")
    ax[0].set_xlabel("round")
    ax[0].legend()
    ax[1].plot(rounds, [r["ratio_b_a"] for r in rows], "o", color="C2")
    ax[1].axhline(1.0, color="k", lw=0.8)
    ax[1].axhline(statistics.median(r["ratio_b_a"] for r in rows), color="C2", ls="--", label="median")
    ax[1].set_title("B / A, same run")
    ax[1].set_xlabel("round")
    ax[1].legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10, help="virtual UAVs, half of them B (at least 2)")
    ap.add_argument("--config", default="default", choices=sorted(CONFIGS), help="scale.py network configuration")
    ap.add_argument("--rounds", type=int, default=4, help="runs; B's half alternates between odd and even UAV ids")
    ap.add_argument("--b-commit", default=None, help="B's UAVs run this commit's code")
    ap.add_argument("--b-env", action="append", default=[], metavar="NAME=VALUE", help="B's UAVs get it in their environment")
    ap.add_argument("--warmup", type=float, default=8.0, help="seconds after the mission starts before measuring")
    ap.add_argument("--window", type=float, default=40.0, help="measurement window, s")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--tag", default="paired")
    args = ap.parse_args(argv)
    if args.n < 2:
        ap.error("--n: at least 2, one UAV per variant")
    b_env: dict[str, str] = {}
    for kv in args.b_env:
        name, sep, value = kv.partition("=")
        if not sep or not name:
            ap.error(f"--b-env: expected NAME=VALUE, got {kv!r}")
        b_env[name] = value
    console = Console()
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="mrswarm-paired-") as tmp:
        b_tree = checkout(args.b_commit, Path(tmp), [sys.executable]) if args.b_commit else None
        try:
            for rnd in range(args.rounds):
                rows.append(fly_round(rnd, args, b_env, b_tree, console))
        finally:
            if b_tree is not None:
                remove(b_tree)
    ratios = [r["ratio_b_a"] for r in rows]
    what = " ".join([f"commit {args.b_commit}"] * bool(args.b_commit) + [f"{k}={v}" for k, v in b_env.items()]) or "A/A"
    summary = {"b": what, "ratio_median": round(statistics.median(ratios), 4), "ratio_min": min(ratios), "ratio_max": max(ratios),
               "b_lower_rounds": sum(r < 1.0 for r in ratios), "rounds": len(ratios)}
    out = Path(args.out)
    write_results(out, args.tag, {"args": vars(args), "cores": os.cpu_count(), "rows": rows, "summary": summary,
                                  "loadavg_end": os.getloadavg()}, rows)
    plot(rows, out / f"{args.tag}.png", f"B = {what}; N = {args.n}, {args.config}, {args.rounds} runs")
    console.print(summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
