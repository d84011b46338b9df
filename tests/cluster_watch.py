"""A ground station's eyes for tests/test_cluster_swarm.py, run on the cluster's manager node.

    python3 -m tests.cluster_watch --connect tls/10.213.0.11:7447 --swarm s --keys DIR --uavs 9 --out watch.json

It joins the swarm through the edge router like ``mrswarm gcs`` does (as ``ctl``, so it does
not collide with the ``gcs-1`` the test's commands use), writes ``<out>.ready`` once every UAV
reports ``ready``, then follows the flight until every UAV reports ``done`` (or ``--seconds``
pass) and writes what it saw: each UAV's phase, start and last position, and the smallest
distance between two airborne UAVs (m) over the whole flight, sampled at 10 Hz.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

from swarmnet.observer import SwarmObserver
from swarmnet.security.credentials import Credentials
from swarmnet.security.identity import NodeName
from uav_stack.config import NetworkConfig
from uav_stack.runtime import make_connectivity


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--swarm", required=True)
    ap.add_argument("--keys", required=True)
    ap.add_argument("--uavs", type=int, required=True)
    ap.add_argument("--seconds", type=float, default=240.0)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    ids = list(range(1, args.uavs + 1))
    net = NetworkConfig(endpoints=(args.connect,), mode="client", security=Credentials(keys=args.keys))
    out: dict[str, object] = {"ready": False, "min_separation": math.inf}
    end = time.monotonic() + args.seconds
    with SwarmObserver(args.swarm, make_connectivity(net, NodeName("ctl", 0, args.swarm)), name="cluster-watch") as obs:
        starts: dict[int, tuple[float, float, float]] = {}
        min_sep = math.inf
        while time.monotonic() < end:
            obs.poll()
            phases = obs.phases()
            if not out["ready"] and all(phases.get(u) == "ready" for u in ids):
                out["ready"] = True
                starts = {u: (v.pose.x, v.pose.y, v.pose.z) for u, v in obs.uavs.items() if v.pose is not None}
                Path(f"{args.out}.ready").write_text("ready\n")
            pts = [(v.pose.x, v.pose.y, v.pose.z) for v in obs.uavs.values() if v.pose is not None and v.pose.z > 1.0]
            for i in range(len(pts)):
                for j in range(i + 1, len(pts)):
                    min_sep = min(min_sep, math.dist(pts[i], pts[j]))
            if out["ready"] and all(phases.get(u) == "done" for u in ids):
                break
            time.sleep(0.1)
        out.update(min_separation=min_sep if math.isfinite(min_sep) else None,
                   phases={str(u): p for u, p in obs.phases().items()},
                   start={str(u): p for u, p in starts.items()},
                   end={str(u): (v.pose.x, v.pose.y, v.pose.z) for u, v in obs.uavs.items() if v.pose is not None})
    Path(args.out).write_text(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
