"""The edge feed's receive path per pose, in-process: what a UAV's Python pays for each pose it takes in.

Feeds ``--batches`` edge-feed batches of ``--senders`` poses each through
:class:`~swarmnet.node.SwarmNode`'s receive stages after the drain (each batched pose accepted,
the netem filter without a shim, the neighbour table, both age histograms) with no network,
and reports the median CPU time per pose over ``--repeats`` rounds (µs). The network's share
(Zenoh, the receive thread) is measured by ``transport.py`` and ``scale.py``, and direct poses
through a real session by ``netem_shim.py``; this isolates the Python work that grows with the
number of neighbours when the default network batches poses (above 25 UAVs).

Before/after a change, side by side in one run: give each checkout with ``--repo`` (a git
worktree of the older commit, for example); the checkouts are measured in turn, each round in
a fresh interpreter, alternating, so that both see the machine's load of the moment::

    git worktree add /tmp/before HEAD~1
    python benchmarks/receive_path.py --repo /tmp/before --repo . --rounds 3

``--direct`` feeds direct poses instead (a message per neighbour pose, the default network up
to 25 UAVs), each accepted by its stream's rule as the drain does it, then taken in.

The numbers are warm (the same poses again and again, caches hot): a UAV that wakes ten times
a second pays a few times more per pose.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

# Runs inside a fresh interpreter whose sys.path starts at the checkout being measured.
_CHILD = r"""
import json, statistics, sys, time
from functools import partial
import swarmnet.node as node_module
from swarmnet.connectivity import Rendezvous
from swarmnet.messages import Pose, PoseBatch, Realm, accept_neighbour_pose, encode_pose, encode_pose_batch
from swarmnet.node import _BATCH, POSE, Inbox, NodeIdentity, SwarmNode
from swarmnet.receive import Accepted

senders, batches, repeats, direct = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4] == "direct"
node = SwarmNode(NodeIdentity("bench", 1), Rendezvous(endpoints=("tcp/127.0.0.1:9",)))  # never opened
ids = list(range(2, 2 + senders))
rule = partial(accept_neighbour_pose, me=1)
# a direct pose's stream: checkouts with the compiled intake keep the payload and decode it in _take_in
accept = getattr(node_module, "_as_received", rule) if hasattr(node, "_pose_rule") else rule
if hasattr(node, "_pose_rule"):
    node._pose_rule = rule

def arrivals(k, now):
    if direct:  # the poses of one tick, each accepted by its stream's rule as receive() does
        tick = [(f"mrs/bench/{u}/pose", encode_pose(Pose(u, Realm.VIRTUAL, k % 65536, 0.1 * k, now - 0.003, 1.0, 2.0, 3.0,
                                                          0.1, 0.2, 0.3, 0.5))) for u in ids]
        return ((POSE, Accepted(key, accept(key, p), p, now)) for key, p in tick)
    poses = [encode_pose(Pose(u, Realm.VIRTUAL, k % 65536, 0.1 * k, now - 0.003, 1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.5))
             for u in ids]
    batch = PoseBatch(k, now, ids, poses)  # checkouts before the compiled intake take the decoded batch, later ones the payload
    return [(_BATCH, Accepted("mrs/bench/feed/poses", batch, encode_pose_batch(batch), now))]

def chained(arrivals, now, inbox):  # checkouts before SwarmNode._take_in: the stages one after the other
    for kd, item, at in node._through_netem(node._unbatch(arrivals), now):
        node._deliver(kd, item, at, inbox)

take_in = getattr(node, "_take_in", chained)

def one_round(seq0):
    now = time.time()
    feed = [arrivals(seq0 + k, now) for k in range(batches)]
    inbox = Inbox()
    t0 = time.thread_time()
    for arr in feed:
        take_in(iter(arr), now, inbox)  # (a direct tick's generator accepts each pose as it is taken in)
    return (time.thread_time() - t0) / (batches * senders)

one_round(0)  # warm-up
per = [one_round((r + 1) * batches) for r in range(repeats)]
print(json.dumps({"us_per_pose": 1e6 * statistics.median(per)}))
"""


def measure(repo: Path, senders: int, batches: int, repeats: int, direct: bool = False) -> float:
    """Median µs per pose of one fresh interpreter importing swarmnet from ``repo``."""
    out = subprocess.run([sys.executable, "-c", f"import sys; sys.path.insert(0, {str(repo)!r})\n" + _CHILD,
                          str(senders), str(batches), str(repeats), "direct" if direct else "batch"],
                         capture_output=True, text=True, timeout=300, cwd=repo)
    if out.returncode != 0:
        raise SystemExit(f"{repo}: the measuring interpreter failed:\n{out.stderr}")
    return float(json.loads(out.stdout.strip().splitlines()[-1])["us_per_pose"])


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    """Each checkout's rounds (dots) and median (bar), µs per pose."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    names = [Path(r["repo"]).name or r["repo"] for r in rows]
    ax.bar(names, [r["us_per_pose_median"] for r in rows], color="tab:blue", alpha=0.6)
    for i, r in enumerate(rows):
        ax.plot([i] * len(r["us_per_pose_rounds"]), r["us_per_pose_rounds"], "k.", ms=5)
    ax.set_ylabel("CPU µs per batched pose")
    what = "direct poses" if rows[0].get("direct") else "edge-feed batches"
    ax.set_title(f"receive path, {what}, {rows[0]['senders']} poses per tick (warm)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repo", action="append", type=Path, help="checkout to measure (repeatable; default: this one)")
    ap.add_argument("--senders", type=int, default=49, help="poses per batch: the others of a 50-UAV swarm")
    ap.add_argument("--batches", type=int, default=200, help="batches per round")
    ap.add_argument("--repeats", type=int, default=7, help="rounds per interpreter (the median is kept)")
    ap.add_argument("--rounds", type=int, default=3, help="fresh interpreters per checkout, alternated")
    ap.add_argument("--direct", action="store_true",
                    help="direct poses (a message each, the default network up to 25 UAVs), each accepted by its "
                         "stream's rule, instead of edge-feed batches")
    ap.add_argument("--out", type=Path, default=None, help="folder for receive_path.{json,csv,png} (default: print only)")
    ap.add_argument("--tag", default="receive_path", help="file name stem in --out")
    args = ap.parse_args(argv)
    repos = [r.resolve() for r in (args.repo or [ROOT])]
    results: list[dict[str, Any]] = []
    per: dict[Path, list[float]] = {repo: [] for repo in repos}
    for i in range(args.rounds):
        for repo in repos if i % 2 == 0 else repos[::-1]:
            per[repo].append(measure(repo, args.senders, args.batches, args.repeats, args.direct))
    for repo, vals in per.items():
        row = {"repo": str(repo), "direct": args.direct, "senders": args.senders,
               "us_per_pose_median": round(statistics.median(vals), 2), "us_per_pose_rounds": [round(v, 2) for v in vals]}
        results.append(row)
        print(f"{repo}: {row['us_per_pose_median']:.2f} us/pose (rounds: {row['us_per_pose_rounds']})")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / f"{args.tag}.json").write_text(json.dumps(results, indent=2) + "\n")
        with open(args.out / f"{args.tag}.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["repo", "senders", "us_per_pose_median", "us_per_pose_rounds"])
            for r in results:
                w.writerow([r["repo"], r["senders"], r["us_per_pose_median"],
                            " ".join(map(str, r["us_per_pose_rounds"]))])
        plot(results, args.out / f"{args.tag}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
