"""Scenario files: the shipped ones load; bad ones are refused naming the file and the field."""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest

from mrswarm.scenario import ScenarioError, load_scenario
from uav_stack.config import NetworkConfig, VirtualUavConfig

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "scenarios").glob("*.yaml")))
def test_shipped_scenarios_load(name: str) -> None:
    s = load_scenario(ROOT / "scenarios" / name)
    assert s.uav_list()


def test_default_scenario_is_ten_uavs() -> None:
    s = load_scenario(ROOT / "scenarios" / "coverage.yaml")
    assert len(s.uav_list()) == 10 and s.mission.type == "coverage"


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "s.yaml"
    p.write_text(text)
    return p


BASE = """
name: t
duration: 10
origin: {lat: 46.6, lon: 14.2, alt: 440}
mission: {type: coverage, area: {x_min: 0, x_max: 50, y_min: 0, y_max: 50}}
fleet: {count: 3}
"""


@pytest.mark.parametrize(
    "text, expected",
    [
        (BASE.replace("duration: 10", "duration: -1"), "duration"),
        (BASE.replace("fleet: {count: 3}", "fleet: {count: 3, spwan: {}}"), "fleet.spwan: unknown field"),
        (BASE.replace("lat: 46.6", "lat: 123"), "origin.lat"),
        (BASE.replace("x_max: 50", "x_max: -5"), "mission.area"),
        (BASE.replace("type: coverage, ", "type: patrol, "), "mission.type"),
        (BASE + "uavs: [{id: 1, start: [0, 0]}]\n", "either 'fleet'"),
        (BASE.replace("fleet: {count: 3}", "uavs: [{id: 1, start: [0, 0]}, {id: 1, start: [9, 9]}]"), "duplicate UAV ids [1]"),
        (BASE.replace("fleet: {count: 3}", "fleet: {count: 3, spawn: {spacing: 1}}"), "closer than flight.safety_distance"),
        (BASE.replace("{type: coverage, area: {x_min: 0, x_max: 50, y_min: 0, y_max: 50}}", "{type: goto}"), "needs a goal"),
        ("name: [unclosed\n", ":1:"),
        ("- just\n- a list\n", "must be a YAML mapping"),
    ],
)
def test_bad_scenarios_name_the_file_and_field(tmp_path: Path, text: str, expected: str) -> None:
    p = write(tmp_path, text)
    with pytest.raises(ScenarioError) as ei:
        load_scenario(p)
    msg = str(ei.value)
    assert str(p) in msg and expected in msg


def test_overrides_are_validated_like_the_file(tmp_path: Path) -> None:
    p = write(tmp_path, BASE)
    s = load_scenario(p, ["fleet.count=5", "flight.speed=3.5"])
    assert len(s.uav_list()) == 5 and s.flight.speed == 3.5
    with pytest.raises(ScenarioError, match="flight.speed"):
        load_scenario(p, ["flight.speed=100"])
    with pytest.raises(ScenarioError, match="expected key.path=value"):
        load_scenario(p, ["flight.speed"])
    with pytest.raises(ScenarioError, match="not an index"):
        load_scenario(ROOT / "scenarios" / "head_on.yaml", ["uavs.7.rtf=0.5"])
    h = load_scenario(ROOT / "scenarios" / "head_on.yaml", ["uavs.1.rtf=0.4"])
    assert [u.rtf for u in h.uav_list()] == [1.0, 0.4]


def test_missing_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="cannot read"):
        load_scenario(tmp_path / "nope.yaml")


def test_per_uav_configs_round_trip_through_json() -> None:
    s = load_scenario(ROOT / "scenarios" / "head_on.yaml", ["uavs.1.rtf=0.7"])
    net = NetworkConfig(endpoints=("tcp/127.0.0.1:7447",))
    cfgs = s.virtual_uav_configs(net, record_dir="/tmp/x")
    assert [c.target_rtf for c in cfgs] == [1.0, 0.7]
    back = msgspec.json.decode(cfgs[1].to_json(), type=VirtualUavConfig)  # what the UAV process reads
    assert back == cfgs[1]
    assert back.agent.mission.goal == (-20.0, 0.0)


def test_network_defaults_to_discovery_and_client_mode_needs_the_router(tmp_path: Path) -> None:
    p = tmp_path / "s.yaml"
    p.write_text((ROOT / "tests" / "scenarios" / "mini_coverage.yaml").read_text())
    assert load_scenario(p).network.topology == ("discovery", "peer", "direct")
    assert load_scenario(p, ["network.mode=client"]).network.connectivity == "rendezvous"  # client mode implies the router
    with pytest.raises(ScenarioError, match="connectivity: rendezvous"):
        load_scenario(p, ["network.connectivity=discovery", "network.mode=client"])
    with pytest.raises(ScenarioError, match="two beacon periods"):
        load_scenario(p, ["network.discovery.period=2", "network.discovery.ttl=3"])
    with pytest.raises(ScenarioError, match="network.discovery.key"):
        load_scenario(p, ["network.discovery.key=short"])
    scn = load_scenario(p, ["network.discovery.key=0123456789abcdef0123"])
    assert scn.network.discovery.key == "0123456789abcdef0123"


def test_network_left_unset_follows_the_fleets_size(tmp_path: Path) -> None:
    """Above MESH_MAX_UAVS UAVs (every swarm counted) the unset choices become client mode and the edge
    feed, which flew 50 UAVs in real time on 2 cores where the peer mesh fell to RTF 0.46; what the
    scenario sets is kept."""
    from mrswarm.scenario import MESH_MAX_UAVS

    p = tmp_path / "s.yaml"
    p.write_text((ROOT / "scenarios" / "coverage.yaml").read_text())

    def net(*sets: str) -> tuple[str, str, str]:
        return load_scenario(p, ["fleet.spawn.spacing=6", *sets]).network.topology

    assert net(f"fleet.count={MESH_MAX_UAVS}") == ("discovery", "peer", "direct")
    assert net(f"fleet.count={MESH_MAX_UAVS + 1}") == ("rendezvous", "client", "edge")
    assert net("fleet.count=50", "network.mode=peer") == ("discovery", "peer", "edge")  # the mesh kept, poses batched
    assert net("fleet.count=50", "network.pose_feed=direct") == ("rendezvous", "client", "direct")
    assert net("fleet.count=50", "network.connectivity=discovery") == ("discovery", "peer", "edge")
    # a fault on the discovery server needs the discovery topology: kept
    fault = "faults=[{at: 5, kind: kill_discovery}]"
    assert net("fleet.count=50", fault)[:2] == ("discovery", "peer")
    # two swarms of 15 in one airspace: 30 UAVs on the machine
    bravo = "other_swarms=[{swarm: bravo, fleet: {count: 15, first_id: 101, spawn: {center: [0, 60]}}}]"
    assert net("fleet.count=15", bravo) == ("rendezvous", "client", "edge")
    assert net("fleet.count=12", bravo.replace("15", "13")) == ("discovery", "peer", "direct")


def test_ticks_are_aligned_by_default_whatever_the_network(tmp_path: Path) -> None:
    """``network.align_ticks`` is on unless the scenario turns it off: with direct poses the
    control then uses the instant's poses as soon as they are in, with the edge feed a round's
    poses share a few batches; a UAV process gets the value; what the scenario sets is kept."""
    from mrswarm.scenario import MESH_MAX_UAVS
    from uav_stack.config import NetworkConfig

    p = tmp_path / "s.yaml"
    p.write_text((ROOT / "scenarios" / "coverage.yaml").read_text())

    def aligned(*sets: str) -> list[bool]:
        scn = load_scenario(p, ["fleet.spawn.spacing=6", *sets])
        return [c.agent.align_ticks for c in scn.virtual_uav_configs(NetworkConfig(), None)]

    assert all(aligned(f"fleet.count={MESH_MAX_UAVS}"))
    assert all(aligned(f"fleet.count={MESH_MAX_UAVS + 1}"))
    assert not any(aligned("fleet.count=4", "network.align_ticks=false"))
    assert not any(aligned("fleet.count=50", "network.align_ticks=false"))
    assert all(aligned("fleet.count=4", "network.align_ticks=true"))
    assert all(aligned("fleet.count=4", "network.pose_feed=edge"))
    with pytest.raises(ScenarioError, match="align_ticks"):
        load_scenario(p, ["network.align_ticks=sometimes"])
