"""End to end with the world service: `mrswarm run` of the world scenarios, real processes throughout.

- wildfire, the scenario as shipped (8 UAVs, 120 s): virtual cameras, tanks and sprayers in a run
  put cells out, the fire burns less than it would have alone by the same time, no UAV enters the
  no-fly zone on its way from the hub to the fire, and no two UAVs come closer than the safety
  distance (the swarm once squeezed two to 3.3 m of each other against the village, at 5 m);
- two swarms with their own keys meet head-on: with the edge's airspace feed, no conflict and no
  collision between them, and no UAV receives a single pose of the other swarm; without the
  feed, every head-on pair loses separation.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from mrswarm.scenario import load_scenario
from tests.test_run_e2e import alive, only_run_dir, run_cli
from world.fire import FireGrid

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.e2e


def run(scenario: str, out: Path, *sets: str, timeout: float = 300, exit_code: int = 0) -> tuple[Path, dict[str, Any]]:
    """Run ``scenario``; ``exit_code`` is the one the run must end with (3: it completed with collisions)."""
    args = [str(ROOT / "scenarios" / scenario)] + [a for s in sets for a in ("--set", s)]
    res = run_cli(args, out, timeout=timeout)
    assert res.returncode == exit_code, res.stdout[-3000:] + res.stderr[-3000:]
    run_dir = only_run_dir(out)
    run_info = json.loads((run_dir / "run.json").read_text())
    assert run_info["exit_codes"]["world"] == 0  # the world service stopped cleanly (and wrote its records)
    assert not [n for n, pid in run_info["pids"].items() if alive(pid)], "processes left behind"
    return run_dir, json.loads((run_dir / "summary.json").read_text())


def test_wildfire_uavs_put_cells_out_and_stay_out_of_the_no_fly_zone(tmp_path: Path) -> None:
    run_dir, s = run("wildfire.yaml", tmp_path, timeout=420)
    w = s["world"]
    fire = w["fire"]
    assert fire["actuations"] > 0 and fire["sprayed_l"] > 0
    assert fire["cells_extinguished"] >= 1
    # the same fire left alone, to the same experiment time, burns more
    scn = load_scenario(run_dir / "scenario.yaml")
    assert scn.world is not None and scn.world.fire is not None
    alone = FireGrid(scn.world.fire, scn.world.wind)
    alone.ignite()
    alone.advance(json.loads((run_dir / "world.json").read_text())["t_s"])
    assert fire["burnt_area_m2"] < alone.burnt_area_m2
    # the village lies on the straight line from the hub to the fire: every UAV flew round it
    assert w["zones"] == {"zones": 1, "entries": 0, "uavs_entering": [], "min_clearance_m": w["zones"]["min_clearance_m"]}
    assert w["zones"]["min_clearance_m"] > 0.0
    # each virtual sensor delivered at its rate, no earlier than its latency
    for name, rate in (("fire", 5.0), ("tank", 2.0), ("alarm", 1.0)):
        d = w["sensors"][name]
        assert d["rate_hz_median"] == pytest.approx(rate, rel=0.1), (name, d)
        assert d["delay_ms_p50"] >= 1000 * d["latency_s"], (name, d)
        # ... and within a world tick, the transport and the p50's bin (5 %) of it: stamped as it arrived
        assert d["delay_ms_p50"] <= (1000 * d["latency_s"] + d["world_tick_ms"] + 10.0) * 1.05, (name, d)
        assert 0.0 <= d["wait_ms_p50"] <= 105.0, (name, d)  # then up to a control tick (10 Hz) to its use
    sep = s["separation"]
    assert sep["collisions"] == 0 and sep["time_below_safety_s"] == 0.0 and sep["min_during_mission_m"] >= 5.0, sep
    assert not s["incidents"], s["incidents"]
    assert (run_dir / "wildfire.png").stat().st_size > 20_000


def test_two_swarms_share_the_airspace_apart_and_the_feed_prevents_conflicts(tmp_path: Path) -> None:
    run_dir, s = run("two_swarms.yaml", tmp_path / "feed")
    a = s["world"]["airspace"]
    assert a["swarms"] == {"alpha": [1, 2, 3], "bravo": [11, 12, 13]}
    assert a["feed"] is True and a["traffic_messages"] > 0
    assert a["conflicts"] == 0 and a["collisions"] == 0
    assert a["min_separation_m"] >= s["separation"]["safety_distance_m"]
    assert a["cross_swarm_samples"] == 0
    assert all(g["reached"] for g in s["goals"].values()), s["goals"]
    # each UAV heard its own swarm only, and refused nothing (no foreign sample reached it)
    for uav, swarm_ids in ((1, {2, 3}), (2, {1, 3}), (11, {12, 13}), (13, {11, 12})):
        stats = json.loads((run_dir / f"uav{uav}.json").read_text())
        assert {int(k) for k in stats["neighbours"]} == swarm_ids
        assert stats["net"]["rejected"] == {}
    assert (run_dir / "two_swarms.png").stat().st_size > 20_000

    # without the feed the head-on pairs collide, and the run says so by its exit code (3)
    _, off = run("two_swarms.yaml", tmp_path / "no_feed", "world.airspace.feed=false", exit_code=3)
    a = off["world"]["airspace"]
    assert a["feed"] is False and a["traffic_messages"] == 0
    assert a["conflicts"] >= 3  # every head-on pair loses separation
    assert a["min_separation_m"] < off["separation"]["safety_distance_m"]
    assert a["cross_swarm_samples"] == 0
