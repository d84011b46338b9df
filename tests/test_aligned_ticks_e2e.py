"""``network.align_ticks``: every UAV ticks on the wall clock's grid, so the edge feed carries a
round of poses in one batch rather than one batch per pose, and with direct poses the control
runs as soon as the instant's poses are in (docs/scale.md).

Real UAV processes through a real edge router: four UAVs fly a short coverage in client mode
with the edge feed. Each tick's poses leave at the grid's instants and its control runs as
soon as the others' poses of the instant are in, so the trajectory rows (one per control,
stamped with the wall time) of every UAV must fall a few ms after the 100 ms grid, the poses
must be used a few ms after they arrived, and the batches the UAVs received must each carry
the poses of several others.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from mrswarm.results.analysis import load_stats, load_tracks
from mrswarm.run.experiment import Experiment
from mrswarm.scenario import parse_scenario

N = 4
PERIOD = 0.1  # s: the agent's 10 Hz tick


EDGE = {"connectivity": "rendezvous", "mode": "client", "pose_feed": "edge"}
DIRECT = {"connectivity": "discovery", "mode": "peer", "pose_feed": "direct"}


def scenario(align: bool, network: dict[str, str] = EDGE) -> object:
    return parse_scenario({
        "name": "aligned",
        "swarm": "aligned",
        "seed": 3,
        "duration": 12,
        "origin": {"lat": 46.6167, "lon": 14.2650, "alt": 446.0},
        "network": {**network, "align_ticks": align},
        "flight": {"altitude": 6, "speed": 5.0, "safety_distance": 5.0, "collision_distance": 1.0},
        "mission": {"type": "coverage", "strategy": "lawnmower", "area": {"x_min": -30, "x_max": 30, "y_min": -20, "y_max": 20},
                    "sensor_radius": 6},
        "fleet": {"count": N, "spawn": {"pattern": "line", "spacing": 8, "center": [0, -25]}},
    })


def fly(tmp_path: Path, align: bool) -> tuple[dict[int, float], float, dict[str, float]]:
    """Each UAV's median time of its controls after the 100 ms grid's instants (s), the
    neighbours' poses per edge-feed batch received, over the swarm, and the summary's age at
    use (ms: p50, p99...)."""
    exp = Experiment(scenario(align), tmp_path / str(align), console=Console(quiet=True), live=False,  # type: ignore[arg-type]
                     log_level="WARNING")
    summary = exp.run().to_dict()
    run = Path(summary["run_dir"])
    assert summary["uavs_recorded"] == N, summary.get("aborted")
    assert summary["separation"]["collisions"] == 0
    off_grid = {}
    for uav, track in load_tracks(run).items():
        off_grid[uav] = float(np.median(np.mod(track.t, PERIOD)))
    stats = load_stats(run)
    poses = sum(s["net"]["received"].get("pose", 0) for s in stats.values())
    batches = sum(s["net"]["received"].get("pose_batch", 0) for s in stats.values())
    assert batches > 0, "no edge-feed batch received"
    return off_grid, poses / batches, summary["network"]["use_age_ms"]


@pytest.mark.e2e
def test_aligned_ticks_fall_on_the_grid_and_share_batches(tmp_path: Path) -> None:
    off_grid, per_batch, use = fly(tmp_path, align=True)
    # every UAV's controls a few ms after the same wall-clock instants, once the batches of the
    # instant are in: not half a period later (a loaded machine runs them later)
    assert max(off_grid.values()) < 0.025, off_grid
    assert use["n"] > 100 and use["p50"] < 20.0, use
    # a round's poses reach each UAV together: the 3 others in one batch, not one batch each
    assert per_batch >= 2.0, per_batch

    # each UAV's own grid: ticks anywhere in the period, a batch per pose or so, poses used later
    _own, own_per_batch, own_use = fly(tmp_path, align=False)
    assert own_per_batch < per_batch, (own_per_batch, per_batch)
    assert own_use["p50"] > 30.0 and use["p50"] < own_use["p50"] / 2, (use, own_use)


def fly_direct(tmp_path: Path, align: bool) -> dict[str, float]:
    """The summary's age at use (ms: p50, p99...) of a flight with direct poses."""
    exp = Experiment(scenario(align, DIRECT), tmp_path / f"direct-{align}", console=Console(quiet=True),  # type: ignore[arg-type]
                     live=False, log_level="WARNING")
    summary = exp.run().to_dict()
    assert summary["uavs_recorded"] == N, summary.get("aborted")
    assert summary["separation"]["collisions"] == 0
    use: dict[str, float] = summary["network"]["use_age_ms"]
    assert use["n"] > 100, use
    return use


@pytest.mark.e2e
def test_aligned_ticks_with_direct_poses_control_on_the_poses_of_the_instant(tmp_path: Path) -> None:
    """With direct poses the control runs as soon as the instant's poses are in: they are used
    within a few ms of their arrival, where a UAV on its own grid uses them half a period later
    on average (they arrive anywhere in its 100 ms)."""
    aligned = fly_direct(tmp_path, align=True)
    own = fly_direct(tmp_path, align=False)
    assert aligned["p50"] < 20.0, aligned
    assert own["p50"] > 30.0, own
    assert aligned["p50"] < own["p50"] / 2, (aligned, own)
