"""End to end: behaviours of the SDK flown by `mrswarm run` on virtual UAVs (real processes, secured network).

The three examples of examples/ assert their algorithm's outcome; a behaviour that raises or
overruns its budget mid-flight holds, then lands, with an incident in the summary, while the
others fly on.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mrswarm.testing import Flight, fly

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

pytestmark = pytest.mark.e2e


def in_mission_to_the_end(flight: Flight) -> None:
    assert flight.summary.get("aborted") is None, flight.summary.get("aborted")
    assert len(flight.trajectories) == flight.summary["uavs_planned"]
    for uav, tr in flight.trajectories.items():
        assert tr.phase[-1] in ("mission", "done"), (uav, tr.phase[-1])


def test_flocking_aligns_the_flock_within_60_s_without_collisions(tmp_path: Path) -> None:
    flight = fly(scenario=EXAMPLES / "flocking.yaml", out=tmp_path, sets=["duration=30"])
    in_mission_to_the_end(flight)
    assert flight.collisions == 0 and flight.incidents == []
    series = flight.order_series()
    # random headings at first: no order to begin with (over the first 2 s: the UAVs enter the mission
    # within a tick or two of each other on a quiet machine, seconds apart on a loaded one)
    assert min(phi for t, phi in series if t <= series[0][0] + 2.0) < 0.8
    reached = next(t for t, phi in series if phi >= 0.9)
    assert reached <= 60.0
    assert flight.order_parameter(last_s=10.0) >= 0.9  # and it stays
    assert all(flight.behaviour_stats(u)["faults"] == {"exceptions": 0, "overruns": 0, "bad_intents": 0}
               for u in flight.trajectories)


def test_consensus_brings_every_uav_to_the_agreed_point(tmp_path: Path) -> None:
    flight = fly(scenario=EXAMPLES / "consensus.yaml", out=tmp_path, sets=["duration=40"])
    in_mission_to_the_end(flight)
    assert flight.collisions == 0
    ids = sorted(flight.trajectories)
    estimates = {u: (flight.last_value(u, "estimate_x"), flight.last_value(u, "estimate_y")) for u in ids}
    xs = np.array([e[0] for e in estimates.values()], dtype=float)
    ys = np.array([e[1] for e in estimates.values()], dtype=float)
    agreed = (float(xs.mean()), float(ys.mean()))
    assert max(np.hypot(xs - agreed[0], ys - agreed[1])) < 0.5  # they agree
    # on the average of where they started (the mean is kept up to the asynchrony of the messages)
    starts = [(tr.x[0], tr.y[0]) for tr in flight.trajectories.values()]
    assert math.dist(agreed, np.mean(starts, axis=0)) < 3.0
    ring = 7.0
    for k, u in enumerate(ids):  # each at its slot of the ring around the agreed point
        a = 2.0 * math.pi * k / len(ids)
        slot = (agreed[0] + ring * math.cos(a), agreed[1] + ring * math.sin(a))
        x, y, _ = flight.trajectories[u].last
        assert math.dist((x, y), slot) < 2.0, (u, (x, y), slot)
    topics = flight.summary["behaviour"]["topics"]["consensus/estimate"]
    assert topics["sent"] > 0 and topics["received"] > 0 and topics["rejected"] == 0


def test_auction_assigns_every_target_exactly_once_over_unicast(tmp_path: Path) -> None:
    flight = fly(scenario=EXAMPLES / "auction.yaml", out=tmp_path, sets=["duration=40"])
    in_mission_to_the_end(flight)
    assert flight.collisions == 0
    targets = [(-40, 40), (-20, 45), (0, 50), (20, 45), (40, 40)]
    won = {u: flight.last_value(u, "target") for u in flight.trajectories}
    assert sorted(int(v) for v in won.values() if v is not None) == list(range(len(targets)))
    for u, k in won.items():  # and each flew to its own: every target reached by exactly one UAV
        assert k is not None
        x, y, _ = flight.trajectories[u].last
        assert math.dist((x, y), targets[int(k)]) < 2.0, (u, k, (x, y))
    for u in flight.trajectories:  # each target was awarded once: no UAV ever switched
        series = flight.values[u]["target"]
        assert len({v for _, v in series}) == 1
    topics = flight.summary["behaviour"]["topics"]
    assert topics["auction/bid"]["sent"] >= 5 and topics["auction/award"]["sent"] >= 5


def test_a_behaviour_that_raises_or_overruns_holds_then_lands_and_the_others_fly_on(tmp_path: Path) -> None:
    flight = fly("tests.sdk_behaviours:Faulty", out=tmp_path, uavs=4, duration=35, altitude=6.0,
                 params={"raise_on": [2], "slow_on": [3], "after_s": 4.0},
                 extra={"mission": {"hold_s": 3.0, "budget_ms": 20.0}})
    assert flight.summary.get("aborted") is None
    stopped = {i["uav"]: i for i in flight.incidents if i["kind"] == "behaviour_stopped"}
    assert sorted(stopped) == [2, 3]
    assert "RuntimeError: UAV 2 fails on purpose" in stopped[2]["detail"]
    assert "overrun" in stopped[3]["detail"]
    for uav in (2, 3):
        assert flight.trajectories[uav].phase[-1] == "landed"
        assert flight.trajectories[uav].last[2] < 0.5
        assert stopped[uav]["t_s"] >= 4.0
    for uav in (1, 4):  # the others fly on
        assert flight.trajectories[uav].phase[-1] == "mission"
        assert flight.trajectories[uav].last[2] > 4.0
    b = flight.summary["behaviour"]
    assert b["stopped"] == [2, 3] and b["faults"]["exceptions"] >= 3 and b["faults"]["overruns"] >= 3
    assert all(code == 0 for name, code in flight.summary["processes"].items() if name.startswith("uav")), \
        flight.summary["processes"]
    # no unsafe descent: a hold, then the autopilot's landing
    assert not [i for i in flight.incidents if i["kind"] != "behaviour_stopped"]


def test_a_behaviour_that_opts_out_of_avoidance_flies_its_intent_and_per_uav_params_apply(tmp_path: Path) -> None:
    """Two UAVs swap places head-on, each at its own altitude (UAV 2's from mission.per_uav): with avoidance off they
    fly straight through the crossing, and each climbs to the altitude its intent asks for."""
    scenario = {
        "name": "straight", "swarm": "sdkstraight", "seed": 1, "duration": 25,
        "origin": {"lat": 46.6167, "lon": 14.2650, "alt": 446.0},
        "flight": {"altitude": 8, "speed": 4.0, "safety_distance": 5.0, "collision_distance": 1.0},
        "mission": {"behaviour": "tests.sdk_behaviours:Straight", "params": {"altitude": 8.0},
                    "per_uav": {2: {"params": {"altitude": 14.0}}}},
        "uavs": [{"id": 1, "start": [-30, 0], "goal": [30, 0]}, {"id": 2, "start": [30, 0], "goal": [-30, 0]}],
    }
    flight = fly(scenario=scenario, out=tmp_path)
    in_mission_to_the_end(flight)
    one, two = flight.trajectories[1], flight.trajectories[2]
    assert math.dist(one.last[:2], (30, 0)) < 2.0 and math.dist(two.last[:2], (-30, 0)) < 2.0
    assert abs(one.last[2] - 8.0) < 1.0 and abs(two.last[2] - 14.0) < 1.0
    for uav in (1, 2):  # avoidance never acted: straight through the crossing
        assert flight.stats[uav]["agent"]["avoidance_active"] == 0
        assert max(abs(y) for y in flight.trajectories[uav].y) < 1.0
