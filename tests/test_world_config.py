"""The world in scenarios and configurations: errors that name the field, what each UAV gets,
the world service's configuration, and the command lines (``mrswarm world``, ``mrswarm agent --zones``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from discovery.options import ProxyOptions
from mrswarm.run.world_setup import uav_configs, world_service_config
from mrswarm.scenario import ScenarioError, load_scenario
from swarmnet.keyspace import SwarmKeys, check_swarm, traffic_key
from swarmnet.security.acl import uav_puts, uav_receives
from swarmnet.security.credentials import Credentials
from uav_stack.config import NetworkConfig
from uav_stack.runtime import agent_main

ROOT = Path(__file__).resolve().parents[1]
SCN = ROOT / "scenarios"


@pytest.mark.parametrize(("scenario", "override", "field"), [
    ("plume.yaml", "world.sensors=[]", "mission.plume.sensor"),
    ("plume.yaml", "mission.plume.wind_sensor=anemometer", "mission.plume.wind_sensor"),
    ("wildfire.yaml", "world.actuators=[]", "mission.wildfire.spray"),
    ("wildfire.yaml", "world.fire.cell_m=0.05", "world.fire.cell_m"),
    ("wildfire.yaml", "world.zones.0.polygon=[[0, 0], [1, 1]]", "world.zones.0.polygon"),
    ("plume.yaml", "world.plume.model=puff", "world.plume"),
    ("two_swarms.yaml", "other_swarms.0.uavs.0.id=1", "other_swarms"),
    ("two_swarms.yaml", "other_swarms.0.swarm=airspace", "other_swarms.0.swarm"),
    ("two_swarms.yaml", "other_swarms.0.swarm=alpha", "other_swarms"),
])
def test_bad_world_settings_name_the_field(scenario: str, override: str, field: str) -> None:
    with pytest.raises(ScenarioError) as err:
        load_scenario(SCN / scenario, [override])
    assert f"{scenario}: {field}" in str(err.value), str(err.value)


def test_airspace_is_not_a_swarm_name() -> None:
    with pytest.raises(ValueError, match="airspace"):
        check_swarm("airspace")
    assert traffic_key("alpha") == "mrs/airspace/alpha/traffic"


def test_every_uav_of_every_swarm_gets_the_world_it_needs(tmp_path: Path) -> None:
    scn = load_scenario(SCN / "two_swarms.yaml")
    # what the runtime returns for each swarm: its own edge router, discovery key and credentials
    nets = {s: NetworkConfig(connectivity="discovery", endpoints=(f"tls/127.0.0.1:{port}",),
                             discovery=ProxyOptions(server="127.0.0.1:7450", key=k * 32), security=Credentials(keys=f"/k/{s}"))
            for s, k, port in (("alpha", "a", 7447), ("bravo", "b", 7448))}
    cfgs = {c.agent.uav: c.agent for c in uav_configs(scn, nets, None)}
    assert sorted(cfgs) == [1, 2, 3, 11, 12, 13]
    for u, swarm in ((1, "alpha"), (3, "alpha"), (11, "bravo"), (13, "bravo")):
        a = cfgs[u]
        assert a.swarm == swarm and a.network == nets[swarm]  # its own router, key and credentials
        assert a.traffic
    assert cfgs[12].mission.goal == (-40.0, 0.0)
    keys: dict[str, Path | None] = {"alpha": tmp_path / "ka", "bravo": tmp_path / "kb"}
    world = world_service_config(scn, nets, keys, None)
    assert world is not None and [s.name for s in world.swarms] == ["alpha", "bravo"]
    for s in world.swarms:  # a client of the swarm's edge router, with the swarm's key directory (it speaks as edge)
        assert s.network.mode == "client" and s.network.endpoints == nets[s.name].endpoints
        assert s.network.security == Credentials(keys=str(keys[s.name]))
    off = load_scenario(SCN / "two_swarms.yaml", ["world.airspace.feed=false"])
    assert not any(c.agent.traffic for c in uav_configs(off, nets, None))
    fire = load_scenario(SCN / "wildfire.yaml")
    a = uav_configs(fire, {"alpha": nets["alpha"]}, None)[0].agent
    assert [z.name for z in a.avoidance.zones] == ["village"]
    assert [s.name for s in a.sensors] == ["fire", "tank", "alarm"] and a.actuators[0].capacity_l == 15.0
    assert a.mission.type == "wildfire" and a.mission.wildfire is not None and not a.traffic


def test_access_control_lets_a_uav_act_and_read_its_own_readings_and_its_swarms_traffic() -> None:
    keys = SwarmKeys("alpha")
    assert "mrs/alpha/3/act/*" in uav_puts(keys, 3)
    assert not any("sense" in k or "airspace" in k for k in uav_puts(keys, 3))  # only the edge puts those
    receives = uav_receives(keys, 3)
    assert "mrs/alpha/3/sense/*" in receives and "mrs/airspace/alpha/traffic" in receives
    assert "mrs/alpha/*/sense/*" not in receives and "mrs/airspace/bravo/traffic" not in receives


def test_mrswarm_world_refuses_a_scenario_without_world_or_without_credentials() -> None:
    def world(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "mrswarm", "world", *args], capture_output=True, text=True, timeout=60,
                              cwd=ROOT)

    res = world(str(SCN / "coverage.yaml"), "--connect", "tcp/127.0.0.1:9", "--insecure")
    assert res.returncode == 2 and "coverage.yaml: no world section" in res.stderr
    res = world(str(SCN / "two_swarms.yaml"), "--connect", "tls/127.0.0.1:9", "--keys", "/nonexistent/alpha")
    assert res.returncode == 2 and "no --keys for swarm bravo" in res.stderr


def test_agent_zones_flag_rejects_a_file_without_zones(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "z.yaml"
    bad.write_text("name: nothing here\n")
    with pytest.raises(SystemExit) as ex:
        agent_main(["--fcu", "udpin:127.0.0.1:0", "--swarm", "alpha", "--uav", "3", "--origin", "46.6,14.2,446",
                    "--insecure", "--zones", str(bad)])
    assert ex.value.code == 2
    assert f"--zones {bad}: expected a list of zones, or a scenario with world.zones" in capsys.readouterr().err
