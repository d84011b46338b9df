"""Two (or more) commits side by side: the scale benchmark at one N, alternating between the commits.

Why: "behaviour unchanged, no regression beyond noise" is a claim about two versions of the code,
and on a noisy 2-core machine only an interleaved comparison in one run says anything: each round
flies every commit once, in turn, so a load spike hits both sides alike, and in the reverse
order in every other round (the side flown second measured about 4 % more, :func:`flying_order`). Each commit is checked out
into a throw-away git worktree and its own ``benchmarks/scale.py`` runs there (with ``PYTHONPATH``
pointing at that tree, also for the UAV processes it spawns), so an old commit is measured exactly
as it was; a commit with a ``setup.py`` gets its C extensions built in its tree first.

Writes ``<tag>.json`` (every run's row as that commit's scale.py reported it), ``<tag>.csv`` and
``<tag>.png`` (CPU per UAV, RTF and pose age per commit and round) into ``--out``.

    python benchmarks/commits.py 51f2dd7 03c8027 --n 25 --rounds 2 --tag house_n25

With ``--python`` given more than once, every commit is flown under each interpreter in turn
(the benchmark, the UAV processes and the C extensions all that interpreter's), labelled
``<commit>@<python>``: the same code on two builds of CPython, side by side.

    python benchmarks/commits.py HEAD --python /usr/bin/python3.11 --python python3 --n 1 --rounds 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, TypeVar

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
T = TypeVar("T")
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402

RUN_TIMEOUT_S = 900.0  # one scale.py run at one N and one configuration (N = 50: about 3 minutes)
FIELDS = ("cpu_pct_median", "cpu_pct_max", "rss_mb_median", "rtf_mean", "rtf_min", "pose_age_p50_ms", "transport_age_p50_ms",
          "transport_age_p99_ms", "use_age_p50_ms", "use_age_p99_ms", "all_airborne_s",
          "pose_age_p99_ms", "pose_loss", "collisions", "pose_sent_after_instant_p50_ms", "pose_sent_after_instant_p90_ms",
          "instant_spread_p50_ms", "feed_batches_per_instant")


def checkout(commit: str, where: Path, pythons: list[str]) -> Path:
    """A detached worktree of ``commit`` under ``where`` (removed by :func:`remove`), its C
    extensions built by each of ``pythons`` (one file per interpreter's ABI tag)."""
    tree = where / commit
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), commit], check=True,
                   capture_output=True)
    if (tree / "setup.py").exists():  # its compiled pieces, built in place as `pip install -e .` builds them
        for python in pythons:
            res = subprocess.run([python, "setup.py", "-q", "build_ext", "--inplace"], cwd=tree,
                                 capture_output=True, text=True)
            if res.returncode != 0:
                print(f"{commit}: build_ext by {python} failed, its pure-Python fallbacks run:\n{res.stderr[-2000:]}",
                      file=sys.stderr)
    return tree


def remove(tree: Path) -> None:
    subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], capture_output=True)


def run_scale(tree: Path, n: int, config: str, out: Path, extra: list[str], python: str = sys.executable
              ) -> dict[str, Any]:
    """One run of ``tree``'s own scale.py under ``python``; its one row."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    cmd = [python, str(tree / "benchmarks" / "scale.py"), "--sizes", str(n), "--configs", config,
           "--out", str(out), *extra]
    subprocess.run(cmd, cwd=tree, env=env, check=True, timeout=RUN_TIMEOUT_S)
    rows: list[dict[str, Any]] = json.loads((out / "scale.json").read_text())["rows"]
    return rows[0]


def summarise(rows: list[dict[str, Any]], commits: list[str]) -> dict[str, dict[str, float | None]]:
    """Per commit, the median over its rounds of each field (None when a commit did not report it)."""
    out: dict[str, dict[str, float | None]] = {}
    for c in commits:
        mine = [r for r in rows if r["commit"] == c]
        out[c] = {}
        for f in FIELDS:
            vals = [r[f] for r in mine if r.get(f) is not None]
            out[c][f] = round(statistics.median(vals), 4) if vals else None
    return out


def plot(rows: list[dict[str, Any]], commits: list[str], path: Path, title: str) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    for ax, (field, label) in zip(axes, (("cpu_pct_median", "CPU per UAV, % of a core (median)"),
                                         ("rtf_min", "RTF (slowest UAV)"),
                                         ("pose_age_p50_ms", "pose age p50, ms")), strict=True):
        for i, c in enumerate(commits):
            ys = [r.get(field) for r in rows if r["commit"] == c]
            xs = [i + 0.08 * k for k in range(len(ys))]
            ax.scatter(xs, [y if y is not None else float("nan") for y in ys], label=c)
        ax.set_xticks(range(len(commits)), commits)
        ax.set_title(label, fontsize=9)
        ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def flying_order(sides: list[T], rnd: int) -> list[tuple[int, T]]:
    """The sides of round ``rnd`` with their indices, in the order they fly: as given in even
    rounds, reversed in odd ones. Why: at N = 50 the side flown second in a round measured about
    4 % more CPU per UAV than the first, whichever commit it was (three rounds each way);
    alternating the order puts that on every side alike."""
    order = list(enumerate(sides))
    return order if rnd % 2 == 0 else order[::-1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("commits", nargs="+", help="commits (or branches) to compare, in this order")
    ap.add_argument("--n", type=int, default=25, help="virtual UAVs")
    ap.add_argument("--config", default="discovery-direct", help="scale.py network configuration")
    ap.add_argument("--rounds", type=int, default=2, help="each round flies every commit once, in turn")
    ap.add_argument("--scale-args", default="", help="more arguments for every scale.py run (one string)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--tag", default="commits")
    ap.add_argument("--python", action="append", default=None,
                    help="interpreter to fly with (default: this one); more than once: each commit under each")
    args = ap.parse_args(argv)
    pythons: list[str] = args.python or [sys.executable]
    sides = [(c, py) for c in args.commits for py in pythons]  # each round flies every side once, in turn (flying_order)

    def label(c: str, py: str) -> str:
        return c if len(pythons) == 1 else f"{c}@{py}"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="mrswarm-commits-") as tmp:
        where = Path(tmp)
        trees = {c: checkout(c, where, pythons) for c in args.commits}
        try:
            for rnd in range(args.rounds):
                for k, (c, py) in flying_order(sides, rnd):
                    res = where / f"res-{k}-{rnd}"
                    row = run_scale(trees[c], args.n, args.config, res, args.scale_args.split(), py)
                    rows.append({"commit": label(c, py), "round": rnd, **{f: row.get(f) for f in FIELDS}})
                    print(f"round {rnd} {label(c, py)}: " + ", ".join(f"{f}={row.get(f)}" for f in FIELDS), flush=True)
        finally:
            for tree in trees.values():
                remove(tree)
    labels = [label(c, py) for c, py in sides]
    summary = summarise(rows, labels)
    record = {"args": vars(args), "cores": os.cpu_count(), "rows": rows, "median": summary, "loadavg_end": os.getloadavg()}
    write_results(out, args.tag, record, rows)
    plot(rows, labels, out / f"{args.tag}.png", f"N = {args.n}, {args.config}, {args.rounds} rounds, interleaved")
    for c, s in summary.items():
        print(c, s)
    return 0


if __name__ == "__main__":
    sys.exit(main())
