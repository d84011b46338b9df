"""The scenario's ``faults:`` schedule and ``failsafe:`` section: validation, seeded times, the shipped chaos scenarios."""

from __future__ import annotations

from pathlib import Path

import pytest

from mrswarm.scenario import ScenarioError, load_scenario
from mrswarm.scenario.faults import INJECTED, NETWORK, SERVICE, UAV_PROCESS, plan
from uav_stack.config import NetworkConfig

ROOT = Path(__file__).resolve().parents[1]
MINI = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"


def test_the_shipped_chaos_scenario_has_ten_uavs_and_at_least_five_kinds_of_fault() -> None:
    scn = load_scenario(ROOT / "scenarios" / "chaos.yaml")
    assert len(scn.uav_list()) == 10 and scn.fleet is not None and scn.fleet.restart == "on-failure"
    kinds = {f.kind for f in scn.faults}
    assert len(kinds) >= 5
    for family in (UAV_PROCESS, SERVICE, INJECTED, NETWORK):  # every way of injecting one
        assert kinds & set(family)
    mini = load_scenario(ROOT / "tests" / "scenarios" / "mini_chaos.yaml")
    assert len({f.kind for f in mini.faults}) == 8


def test_a_window_gives_the_same_time_for_the_same_seed() -> None:
    scn = load_scenario(MINI, ["faults=[{window: [2, 18], kind: kill_router}, {window: [2, 18], kind: kill_discovery}]"])
    a, b = plan(scn.faults, scn.seed), plan(scn.faults, scn.seed)
    assert [p.at for p in a] == [p.at for p in b] and all(2 <= p.at <= 18 for p in a)
    assert a[0].at != a[1].at  # each entry draws its own time
    other = plan(scn.faults, scn.seed + 1)
    assert [p.at for p in other] != [p.at for p in a]
    assert [p.at for p in a] == sorted(p.at for p in a)


@pytest.mark.parametrize("fault, where, what", [
    ("{kind: kill_uav}", "faults.0.at", "give either 'at'"),
    ("{at: 1, kind: kill_uav}", "faults.0.uav", "required for kill_uav"),
    ("{at: 1, kind: kill_router, uav: 2}", "faults.0.uav", "not used by kill_router"),
    ("{window: [5, 3], kind: kill_router}", "faults.0.window", "needs from < to"),
    ("{at: 1, kind: partition, groups: [[1, 2]], duration: 2}", "faults.0.groups", "at least two non-empty groups"),
    ("{at: 1, kind: partition, groups: [[1, 2], [2, 3]], duration: 2}", "faults.0.groups", "a UAV is in two groups"),
    ("{at: 1, kind: gps_noise, uav: 1, sigma: 500, duration: 2}", "faults.0.sigma", "got 500"),
    ("{at: 1, kind: battery_drop, uav: 1, level: 1.5}", "faults.0.level", "got 1.5"),
    ("{at: 1, kind: kill_discovery}", "faults.0.kind", "needs network.connectivity: discovery"),
])
def test_bad_fault_entries_name_the_field(fault: str, where: str, what: str) -> None:
    sets = [f"faults=[{fault}]"]
    if "kill_discovery" in fault:
        sets.append("network.connectivity=rendezvous")
    with pytest.raises(ScenarioError) as e:
        load_scenario(MINI, sets)
    assert f"{MINI}: {where}" in str(e.value) and what in str(e.value)


def test_failsafe_thresholds_are_checked_together() -> None:
    with pytest.raises(ScenarioError, match="failsafe.swarm_link_action_s: must be larger than swarm_link_hold_s"):
        load_scenario(MINI, ["failsafe={swarm_link_hold_s: 5, swarm_link_action_s: 4}"])
    with pytest.raises(ScenarioError, match="failsafe.battery_critical: must not be above battery_low"):
        load_scenario(MINI, ["failsafe={battery_low: 0.1, battery_critical: 0.2}"])
    scn = load_scenario(MINI, ["failsafe.swarm_link_action=rtl"])
    cfgs = scn.virtual_uav_configs(NetworkConfig(), None)
    assert all(c.agent.failsafe.swarm_link_action == "rtl" for c in cfgs)
