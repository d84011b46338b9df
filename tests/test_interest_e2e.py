"""Spatial interest end to end (docs/scale.md): 50 UAVs, about 5 within each one's radius, secured.

One run checks what a user cares about: no collision, every UAV heard from every other, and
each UAV received at least 5 times fewer poses than the full feed would have brought it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from mrswarm.results.analysis import load_stats, load_tracks, resample
from mrswarm.run.experiment import Experiment
from mrswarm.scenario import parse_scenario

N = 50
RADIUS = 50.0  # about the avoidance's reach: 5 m safety + 2 x 6 m/s over its 4 s horizon (docs/scale.md)
SIDE = 280.0  # m: 49 others on 280 x 280 m put ~4.9 within 50 m of a UAV (fewer at the field's edges)


def scenario() -> object:
    spacing = SIDE / math.ceil(math.sqrt(N))  # spread from the start: 35 m apart, at most 8 within the radius on the ground
    return parse_scenario({
        "name": "interest50",
        "swarm": "interest",
        "seed": 5,
        "duration": 25,
        "origin": {"lat": 46.6167, "lon": 14.2650, "alt": 446.0},
        "network": {"connectivity": "rendezvous", "mode": "client", "pose_feed": "edge",
                    "interest": {"radius_m": RADIUS, "margin_m": 5.0, "far_rate_hz": 0.5}},
        "flight": {"altitude": 6, "speed": 5.0, "safety_distance": 5.0, "collision_distance": 1.0},
        "mission": {"type": "coverage", "strategy": "random",
                    "area": {"x_min": -SIDE / 2, "x_max": SIDE / 2, "y_min": -SIDE / 2, "y_max": SIDE / 2},
                    "sensor_radius": 10},
        "fleet": {"count": N, "spawn": {"pattern": "grid", "spacing": spacing, "center": [0, 0]}},
    })


@pytest.mark.e2e
def test_fifty_uavs_receive_five_times_fewer_poses_without_collisions(tmp_path: Path) -> None:
    exp = Experiment(scenario(), tmp_path, console=Console(quiet=True), live=False, log_level="WARNING")  # type: ignore[arg-type]
    summary = exp.run().to_dict()
    run = Path(summary["run_dir"])
    assert summary["uavs_recorded"] == N, summary.get("aborted")
    assert summary["separation"]["collisions"] == 0
    assert summary["security"]["mode"] == "mtls"  # secured, as every run by default

    # about 5 neighbours within the radius, on average over the mission
    tracks = load_tracks(run)
    t0 = max(tr.t[0] for tr in tracks.values())
    t1 = min(tr.t[-1] for tr in tracks.values())
    _grid, pos, _ids = resample(tracks, t0, t1)
    xy = pos[:, ::10, :2]  # once a second
    d = np.linalg.norm(xy[:, None, :, :] - xy[None, :, :, :], axis=-1)  # (n, n, t)
    within = (d <= RADIUS).sum(axis=1) - 1  # others within the radius, per UAV and second
    mean_within = float(np.nanmean(within))
    assert 2.5 <= mean_within <= 8.0, mean_within

    stats = load_stats(run)
    sent = sum(s["net"]["sent"]["pose"] for s in stats.values())
    received = {u: s["net"]["received"].get("pose", 0) for u, s in stats.items()}
    full_feed = (N - 1) * sent  # every pose of every UAV to every other UAV
    reduction = full_feed / sum(received.values())
    assert reduction >= 5.0, (reduction, mean_within)
    # 50 UAVs are pooled by default (fleet.pool auto): each pool's one session downloads the near
    # feeds of its UAVs and the far feed once, so what reached the pools is as far below the full feed
    pools = {s["pool_session"]["name"]: s["pool_session"]["received"]["pose"] for s in stats.values() if "pool_session" in s}
    assert len(pools) == 2, pools
    assert full_feed / sum(pools.values()) >= 5.0, (full_feed, pools)
    # and everyone still hears from everyone (the far rate), so the map and the membership stay whole
    heard = [len(s.get("neighbours", {})) for s in stats.values()]
    assert min(heard) >= N - 1 - 2, heard
