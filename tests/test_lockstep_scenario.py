"""``time: lockstep`` in a scenario: what the lock-step clock cannot step is refused naming the field;
what it can is pooled, through the edge router, every pose direct (swarmnet/lockstep.py)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest

from groundfloor.schema import ConfigError, convert
from mrswarm.scenario import Network, Scenario, ScenarioError, load_scenario, parse_scenario
from tests.test_scenario import BASE as REAL_TIME_BASE

ROOT = Path(__file__).resolve().parents[1]

BASE = REAL_TIME_BASE + "time: lockstep\n"  # test_scenario's small fleet, in lock-step time

DATA: dict[str, Any] = {
    "name": "t", "duration": 10, "origin": {"lat": 46.6, "lon": 14.2, "alt": 440},
    "mission": {"type": "coverage", "area": {"x_min": 0, "x_max": 50, "y_min": 0, "y_max": 50}},
    "fleet": {"count": 3}, "time": "lockstep",
}


def scenario(**changes: Any) -> dict[str, Any]:
    """DATA with top-level fields replaced (None: left out) or, for ``a__b``, nested ones."""
    data = copy.deepcopy(DATA)
    for key, value in changes.items():
        *parents, last = key.split("__")
        at = data
        for p in parents:
            at = at.setdefault(p, {})
        if value is None:
            at.pop(last, None)
        else:
            at[last] = value
    return data


VIRTUAL_LIST = [{"id": 1, "start": [0, 0]}, {"id": 2, "start": [20, 0]}]

REFUSED = [
    pytest.param(scenario(fleet=None, uavs=[*VIRTUAL_LIST[:1], {"id": 2, "start": [20, 0], "fcu": "udpin:127.0.0.1:14540"}]),
                 "uavs", "UAV(s) [2]", id="external-uav"),
    pytest.param(scenario(runtime="docker"), "runtime", "container", id="docker"),
    pytest.param(scenario(fleet=None, uavs=VIRTUAL_LIST), "uavs", "give a fleet", id="explicit-uavs"),
    pytest.param(scenario(fleet__pool=1), "fleet.pool", "process per UAV", id="pool-1"),
    pytest.param(scenario(faults=[{"at": 5, "kind": "kill_uav", "uav": 2}]), "faults.0", "kill_uav", id="kill-uav"),
    pytest.param(scenario(faults=[{"at": 5, "kind": "gps_jump", "uav": 2, "offset": [8, 0], "duration": 4},
                                  {"at": 6, "kind": "stop_uav", "uav": 3, "duration": 2}]), "faults.1", "stop_uav",
                 id="stop-uav"),
    pytest.param(scenario(fleet__rtf=0.5), "fleet.rtf", "(0.5)", id="rtf"),
    pytest.param(scenario(fleet__restart="on-failure"), "fleet.restart", "restarted pool", id="restart"),
    pytest.param(scenario(other_swarms=[{"swarm": "beta", "fleet": {"count": 2, "first_id": 10,
                                                                    "spawn": {"center": [200, 200]}}}]),
                 "other_swarms", "second swarm", id="other-swarms"),
    pytest.param(scenario(network={"mode": "peer"}), "network.mode", "peer mode", id="peer"),
    pytest.param(scenario(network={"connectivity": "discovery"}), "network.mode", "over discovery", id="discovery"),
    pytest.param(scenario(network={"pose_feed": "edge"}), "network.pose_feed", "edge feed", id="edge-feed"),
    pytest.param(scenario(network={"interest": {"radius_m": 50}}), "network.interest", "spatial interest", id="interest"),
    pytest.param(scenario(network={"interest": {"radius_m": 50}, "pose_feed": "edge"}), "network.interest",
                 "spatial interest", id="interest-edge"),
]


@pytest.mark.parametrize("data, field, why", REFUSED)
def test_what_lockstep_cannot_step_is_refused_naming_the_field(data: dict[str, Any], field: str, why: str) -> None:
    with pytest.raises(ConfigError) as ei:
        convert(data, Scenario)
    assert ei.value.path == field, str(ei.value)
    assert why in ei.value.msg and "time: lockstep" in ei.value.msg
    assert str(ei.value).startswith(f"{field}: ")
    with pytest.raises(ScenarioError) as se:  # as a file's loader reports it: where, then the field
        parse_scenario(data, "s.yaml")
    assert str(se.value).startswith(f"s.yaml: {field}: ")


@pytest.mark.parametrize("override, field", [
    ("runtime=docker", "runtime"), ("fleet.pool=1", "fleet.pool"), ("fleet.rtf=0.5", "fleet.rtf"),
    ("fleet.restart=on-failure", "fleet.restart"), ("network.mode=peer", "network.mode"),
    ("network.pose_feed=edge", "network.pose_feed"), ("network.interest={radius_m: 30}", "network.interest"),
])
def test_overrides_are_refused_like_the_file(tmp_path: Path, override: str, field: str) -> None:
    p = tmp_path / "s.yaml"
    p.write_text(BASE)
    with pytest.raises(ScenarioError) as ei:
        load_scenario(p, [override])
    msg = str(ei.value)
    assert msg.startswith(f"{p}: {field}: ") and "time: lockstep" in msg
    # the same override without lock-step time is no refusal of lock-step's
    if override not in ("fleet.restart=on-failure",):
        try:
            load_scenario(p, [override, "time=real"])
        except ScenarioError as exc:
            assert "time: lockstep" not in str(exc)


def test_a_plain_fleet_in_lockstep_is_pooled_through_the_edge_router_with_direct_poses(tmp_path: Path) -> None:
    p = tmp_path / "s.yaml"
    p.write_text(BASE)
    s = load_scenario(p)
    assert s.time == "lockstep"
    assert s.pool_size >= 2  # three UAVs: pooled all the same, only pools follow the clock
    assert s.network.topology == ("rendezvous", "client", "direct")
    one = load_scenario(p, ["fleet.count=1"])  # even a lone UAV: a pool of its own
    assert one.pool_size >= 2 and one.network.topology == ("rendezvous", "client", "direct")
    big = load_scenario(p, ["fleet.count=60"])  # above the mesh's size the pose feed stays direct all the same
    assert big.pool_size >= 2 and big.network.topology == ("rendezvous", "client", "direct")
    assert load_scenario(p, ["fleet.pool=3"]).pool_size == 3  # a pool size given is kept
    # faults that do not act on a UAV's process are the pools' to take
    faulty = load_scenario(p, ["faults=[{at: 5, kind: gps_jump, uav: 2, offset: [8, 0], duration: 4}]"])
    assert faulty.pool_size >= 2 and [f.kind for f in faulty.faults] == ["gps_jump"]
    # what a scenario may choose and lock-step accepts
    same = load_scenario(p, ["network.mode=client", "network.connectivity=rendezvous", "network.pose_feed=direct"])
    assert same.network.topology == ("rendezvous", "client", "direct")


def test_time_defaults_to_real_and_a_bad_value_is_refused_naming_the_field(tmp_path: Path) -> None:
    p = tmp_path / "s.yaml"
    p.write_text(BASE.replace("time: lockstep\n", ""))
    s = load_scenario(p)
    assert s.time == "real"
    assert s.pool_size == 1 and s.network.topology == ("discovery", "peer", "direct")  # three UAVs in real time: a mesh
    # what lock-step refuses, real time keeps
    assert load_scenario(p, ["fleet.rtf=0.5", "fleet.pool=1", "network.mode=peer"]).time == "real"
    for bad in ("fast", "Lockstep", "lock-step"):
        with pytest.raises(ScenarioError) as ei:
            load_scenario(p, [f"time={bad}"])
        assert str(ei.value) == f"{p}: time: must be one of real, lockstep, got {bad!r}"
    for bad in ("true", "1"):  # YAML makes these a bool and an int
        with pytest.raises(ScenarioError, match=r": time: must be a string"):
            load_scenario(p, [f"time={bad}"])
    with pytest.raises(ConfigError) as ce:
        convert(scenario(time="simulated"), Scenario)
    assert ce.value.path == "time"


def test_sized_for_lockstep_keeps_the_pose_feed_direct() -> None:
    net = Network()
    assert net.sized_for(60).topology == ("rendezvous", "client", "edge")  # a large fleet in real time: the edge feed
    assert net.sized_for(3, pooled=True).topology == ("rendezvous", "client", "edge")
    assert net.sized_for(60, lockstep=True).topology == ("rendezvous", "client", "direct")
    assert net.sized_for(3, pooled=True, lockstep=True).topology == ("rendezvous", "client", "direct")
    assert Network(pose_feed="edge").sized_for(3, pooled=True, lockstep=True).topology[2] == "edge"  # a choice is kept


def test_the_shipped_scenarios_load_in_lockstep_or_name_what_it_cannot_step() -> None:
    """Every shipped scenario either takes ``time=lockstep`` or is refused with one field named."""
    fields = {"uavs", "runtime", "fleet.pool", "fleet.rtf", "fleet.restart", "other_swarms", "world", "network.mode",
              "network.pose_feed", "network.interest"}
    accepted = 0
    for path in sorted((ROOT / "scenarios").glob("*.yaml")):
        try:
            s = load_scenario(path, ["time=lockstep"])
        except ScenarioError as exc:
            msg = str(exc)
            if "time: lockstep" in msg:
                field = msg.removeprefix(f"{path}: ").split(": ", 1)[0]
                assert field in fields or field.startswith("faults."), msg
            continue
        accepted += 1
        assert s.pool_size >= 2 and s.network.topology == ("rendezvous", "client", "direct"), path.name
    assert accepted >= 1  # coverage.yaml, at least
