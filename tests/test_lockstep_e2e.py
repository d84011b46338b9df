"""End to end: lock-step time (``time: lockstep``) flown by ``mrswarm run``'s experiment on real pool
processes, a real TLS edge router and the runner leading the simulated clock.

What a researcher relies on: one seed gives one flight, to the centimetre and the row, however the
two pools' processes were scheduled; netem's delays are simulated time; the run says how fast its
clock went and its records read in simulated time from one epoch.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mrswarm.testing import Flight, fly
from swarmnet.lockstep import LOCKSTEP_EPOCH

ROOT = Path(__file__).resolve().parents[1]
COVERAGE = ROOT / "scenarios" / "coverage.yaml"
# six UAVs in two pools (one per core: the pools run side by side and finish their ticks in any order)
SETS = ["time=lockstep", "fleet.count=6", "duration=25", "mission.strategy=random", "fleet.pool=3"]

pytestmark = pytest.mark.e2e


def rows(flight: Flight) -> dict[int, np.ndarray]:
    return {u: np.column_stack([tr.t, tr.x, tr.y, tr.z, tr.vx, tr.vy]) for u, tr in flight.trajectories.items()}


def run_info(flight: Flight) -> dict:
    return json.loads((flight.run_dir / "run.json").read_text())


def test_one_seed_gives_one_flight_in_lockstep_and_another_seed_another(tmp_path: Path) -> None:
    a = fly(scenario=COVERAGE, out=tmp_path / "a", sets=[*SETS, "seed=3"])
    b = fly(scenario=COVERAGE, out=tmp_path / "b", sets=[*SETS, "seed=3"])
    c = fly(scenario=COVERAGE, out=tmp_path / "c", sets=[*SETS, "seed=4"])
    for f in (a, b, c):
        assert f.summary.get("aborted") is None, f.summary.get("aborted")
        assert f.collisions == 0
        assert len(f.trajectories) == 6
        info = run_info(f)
        assert set(info["pools"]) == {"pool1", "pool2"}
        ls = info["lockstep"]
        # the clock ran through takeoff and the whole mission, one tick per 0.1 s of simulated time
        assert ls["pools"] == [1, 2] and ls["ticks"] >= 250 and ls["sim_s"] == pytest.approx(ls["ticks"] * 0.1)
        assert ls["resends"] == 0 and ls["rejected"] == {}
        # records in simulated time from the epoch, the mission after the takeoff
        assert LOCKSTEP_EPOCH < info["takeoff_sent"] < info["mission_start"] < LOCKSTEP_EPOCH + ls["sim_s"]
        assert all(tr.phase[-1] in ("mission", "done") for tr in f.trajectories.values())
        # where a tick went, in each pool's loop (benchmarks/lockstep.py reports it): every step timed
        for uavs in info["pools"].values():
            st = f.stats[uavs[0]]["loop"]["lockstep"]
            assert ls["ticks"] - 5 <= st["steps"] <= ls["ticks"] and st["work_ms"] > 0.0 and st["wait_ms"] >= 0.0
            assert 0.0 < st["cpu_ms"] <= st["work_ms"] * 1.05 + 0.5  # the loop thread's CPU within its wall time
    ra, rb, rc = rows(a), rows(b), rows(c)
    assert ra.keys() == rb.keys()
    for u in ra:  # identical, row for row (the trajectory files hold mm and ms)
        n = min(len(ra[u]), len(rb[u]))
        assert n > 200 and abs(len(ra[u]) - len(rb[u])) <= 1, (u, len(ra[u]), len(rb[u]))
        np.testing.assert_array_equal(ra[u][:n], rb[u][:n], err_msg=f"UAV {u}")
    moved = [u for u in ra if not np.array_equal(ra[u][: min(len(ra[u]), len(rc[u]))],
                                                    rc[u][: min(len(ra[u]), len(rc[u]))])]
    assert moved, "another seed flew the same flight"


def test_netem_delays_are_simulated_time_in_lockstep_and_so_is_the_recording(tmp_path: Path) -> None:
    f = fly(scenario=COVERAGE, out=tmp_path, sets=[*SETS, "network.netem.preset=lte", "duration=15"], record=True)
    assert f.summary.get("aborted") is None, f.summary.get("aborted")
    age = f.summary["network"]["transport_age_ms"]
    # the LTE preset's one-way delay (tens of ms) in simulated time, whatever the wall clock did meanwhile
    assert 30.0 <= age["p50"] <= 120.0, age
    assert f.summary["network"]["negative_ages"] == {}
    # run.mcap plays in the run's time: every record between the epoch and the clock's end, each pose
    # logged at the instant it was put at (within a tick), not at the wall's date
    from mrswarm.recorder.reader import read_recording

    sim_s = run_info(f)["lockstep"]["sim_s"]
    msgs = list(read_recording(f.run_dir / "run.mcap"))
    assert len(msgs) > 1000
    assert all(LOCKSTEP_EPOCH * 1e9 <= m.log_time <= (LOCKSTEP_EPOCH + sim_s + 1.0) * 1e9 for m in msgs)
    lags = [(m.log_time - m.publish_time) / 1e9 for m in msgs if m.topic.endswith("/pose")]
    assert len(lags) >= 6 * 100 and all(-1e-6 <= lag <= 0.2 for lag in lags), (min(lags), max(lags))
    assert not any(m.topic.startswith("/raw/clock") for m in msgs)


def test_the_wildfire_world_in_lockstep_is_one_flight_per_seed_and_puts_fire_out(tmp_path: Path) -> None:
    """The world service steps with the pools: the fire, the sensors' rates and latencies and the
    sprays are simulated time, and one seed gives one fire as well as one flight."""
    sets = ["time=lockstep", "duration=60"]
    wildfire = ROOT / "scenarios" / "wildfire.yaml"
    a = fly(scenario=wildfire, out=tmp_path / "a", sets=sets)
    b = fly(scenario=wildfire, out=tmp_path / "b", sets=sets)
    for f in (a, b):
        assert f.summary.get("aborted") is None, f.summary.get("aborted")
        assert run_info(f)["lockstep"]["world"] is True
        w = f.summary["world"]
        assert w["fire"]["actuations"] > 0 and w["fire"]["cells_extinguished"] >= 1, w["fire"]
        for name, rate in (("fire", 5.0), ("tank", 2.0)):  # each sensor at its rate, no earlier than its latency
            d = w["sensors"][name]
            assert d["rate_hz_median"] == pytest.approx(rate, rel=0.1), (name, d)
            assert d["delay_ms_p50"] >= 1000 * d["latency_s"], (name, d)
        assert f.collisions == 0
    assert a.summary["world"]["fire"] == b.summary["world"]["fire"]
    ra, rb = rows(a), rows(b)
    for u in ra:
        n = min(len(ra[u]), len(rb[u]))
        assert n > 200, (u, n)
        np.testing.assert_array_equal(ra[u][:n], rb[u][:n], err_msg=f"UAV {u}")


def test_lockstep_flies_the_paths_real_time_flies(tmp_path: Path) -> None:
    """Lock-step is a faster clock, not another simulation: the same scenario in real time (each UAV its
    own process) and in lock-step (two pools) puts every UAV within a few decimetres of the same place
    5 s into its mission, while its neighbours' avoidance bends the paths. (A setpoint taken in a tick
    late, as lock-step once did, put some UAVs metres away.)"""
    sets = ["fleet.count=6", "duration=25"]
    real = fly(scenario=COVERAGE, out=tmp_path / "real", sets=sets)
    lock = fly(scenario=COVERAGE, out=tmp_path / "lock", sets=[*sets, "time=lockstep", "fleet.pool=3"])

    def five_s_in(tr) -> np.ndarray:
        t0 = tr.t[tr.phase.index("mission")]
        return np.array(tr.at(t0 + 5.0)[:2])

    assert set(real.trajectories) == set(lock.trajectories) == set(range(1, 7))
    moved = {u: float(np.linalg.norm(five_s_in(tr) - np.array([tr.x[0], tr.y[0]]))) for u, tr in lock.trajectories.items()}
    assert min(moved.values()) > 10.0, moved  # every UAV is under way by then
    apart = {u: float(np.linalg.norm(five_s_in(real.trajectories[u]) - five_s_in(lock.trajectories[u])))
             for u in real.trajectories}
    assert max(apart.values()) < 0.5, apart
