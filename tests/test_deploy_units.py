"""Container deployment pieces that need no docker engine: scenario fields, the network plan,
the generated swarm stack (and that the committed deploy/stack.yml is what the generator makes),
and the replica entry point's choice of UAV by task slot."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from deploy.images import image_tag
from deploy.plan import CONTAINERS, NetworkPlan, SwarmPlan
from deploy.swarm import StackOptions, stack_spec, write_stack
from deploy.swarm_uav import SlotError, endpoint_host, load_fleet, pick
from mrswarm.cli.deploy import swarm_fleet
from mrswarm.scenario import ScenarioError, load_scenario

ROOT = Path(__file__).resolve().parents[1]
COVERAGE = ROOT / "scenarios" / "coverage.yaml"


def test_docker_fields_are_validated_with_their_names() -> None:
    scn = load_scenario(COVERAGE, ["runtime=docker", "docker.cpus=1.5", "docker.memory_mb=128"])
    assert (scn.runtime, scn.docker.cpus, scn.docker.memory_mb, scn.docker.multicast) == ("docker", 1.5, 128, "drop")
    for bad, field in (("docker.cpus=0", "docker.cpus"), ("docker.memory_mb=10", "docker.memory_mb"),
                       ("docker.multicast=sometimes", "docker.multicast"), ("docker.image=bad image", "docker.image"),
                       ("docker.gpus=1", "docker.gpus"), ("runtime=k8s", "runtime")):
        with pytest.raises(ScenarioError, match=field.replace(".", r"\.")):
            load_scenario(COVERAGE, [bad])


def test_network_plan_rendezvous_router_and_uav_endpoints() -> None:
    network = NetworkPlan((SwarmPlan("alpha"),), "rendezvous", "peer", "edge").place(CONTAINERS)
    (router,) = network.services
    assert router.name == "router" and router.argv()[-2:] == ["--feed", "alpha"]
    net = network.uav_network("alpha", {"router": "10.1.2.3"})
    assert net.endpoints == ("tcp/10.1.2.3:7447",) and net.pose_feed == "edge" and net.mode == "peer"
    with pytest.raises(ValueError, match="router"):
        network.uav_network("alpha", {})
    with pytest.raises(ValueError, match=r"discovery needs a key for swarms \['alpha'\]"):
        NetworkPlan((SwarmPlan("alpha"),), "discovery")


def test_stack_has_router_service_and_replicas_with_unique_ids() -> None:
    scn = load_scenario(COVERAGE)
    stack, fleet_json = stack_spec(swarm_fleet(scn, 7), StackOptions(image="img:1"))
    fleet = json.loads(fleet_json)
    assert [f["agent"]["uav"] for f in fleet] == [1, 2, 3, 4, 5, 6, 7]
    assert all(f["agent"]["network"]["endpoints"] == ["tls/router:7447"] for f in fleet)  # secured by default
    assert all(f["agent"]["network"]["security"] == {"keys": "/run/secrets", "identity": ""} for f in fleet)
    uav = stack["services"]["uav"]
    assert uav["deploy"]["replicas"] == 7 and uav["environment"]["MRSWARM_SLOT"] == "{{.Task.Slot}}"
    assert uav["deploy"]["resources"]["limits"] == {"cpus": "0.5", "memory": "256M"}
    assert uav["sysctls"]["net.ipv6.conf.all.disable_ipv6"] == 1
    assert stack["services"]["router"]["deploy"]["endpoint_mode"] == "dnsrr"
    assert stack["networks"]["swarm"] == {"external": True, "name": "mrswarm-alpha"}
    # credentials as Swarm secrets, never in the image: the router gets edge's pair, the replicas every UAV's
    assert {m["target"] for m in stack["services"]["router"]["secrets"]} == {"ca.pem", "roster.json", "edge.alpha.pem",
                                                                            "edge.alpha.key"}
    # the discovery server the beacon key, with which it checks every node's beacon token; each replica its UAV's token
    assert "beacon.key" in {m["target"] for m in stack["services"]["discovery"]["secrets"]}
    uav_secrets = {m["target"] for m in uav["secrets"]}
    assert {"uav-1.alpha.key", "uav-7.alpha.pem", "uav-7.alpha.beacon", "ca.pem"} <= uav_secrets
    assert "edge.alpha.key" not in uav_secrets and "beacon.key" not in uav_secrets
    assert stack["secrets"]["ca_pem"]["file"] == "./keys/ca.pem"  # the stack's key directory beside stack.yml
    insecure = stack_spec(swarm_fleet(load_scenario(COVERAGE, ["network.security=off"]), 2), StackOptions(image="img:1"))[0]
    assert "secrets" not in insecure and "--insecure" in insecure["services"]["router"]["command"]


def test_a_deployed_edge_router_batches_with_the_scenarios_feed_window() -> None:
    """``network.feed_window_ms`` reaches the edge router of a Swarm stack as it does a local run's."""
    fleet = swarm_fleet(load_scenario(COVERAGE, ["network.pose_feed=edge", "network.feed_window_ms=4"]), 2)
    argv = fleet.network.service("router").argv()
    assert argv[argv.index("--feed-window-ms") + 1] == "4"


EXAMPLE_KEY = "network.discovery.key=example-key-regenerate-for-real-deployments"


def test_committed_stack_file_is_what_the_generator_makes(tmp_path: Path) -> None:
    # the committed example carries a fixed example key; real deployments draw a fresh one
    write_stack(swarm_fleet(load_scenario(COVERAGE, [EXAMPLE_KEY]), 5), StackOptions(image=image_tag()), tmp_path)
    assert (tmp_path / "stack.yml").read_text() == (ROOT / "deploy" / "stack.yml").read_text(), \
        f"regenerate: mrswarm deploy swarm up --uavs 5 --dry-run --out deploy/ --set {EXAMPLE_KEY}"
    assert (tmp_path / "fleet.json").read_text() == (ROOT / "deploy" / "fleet.json").read_text()
    assert yaml.safe_load((ROOT / "deploy" / "stack.yml").read_text())["services"]["uav"]["deploy"]["replicas"] == 5


def test_replica_picks_its_uav_by_slot_and_refuses_a_slot_without_one() -> None:
    fleet = load_fleet(ROOT / "deploy" / "fleet.json")
    assert pick(fleet, 3).agent.uav == 3
    for slot in (0, 6, -1):
        with pytest.raises(SlotError, match="slot"):
            pick(fleet, slot)
    assert endpoint_host("tcp/router:7447") == ("router", 7447)
    assert endpoint_host("tcp/[fd00::1]:7447#iface=eth0") == ("fd00::1", 7447)


def test_the_wheel_for_the_images_leaves_no_package_of_the_project_out() -> None:
    """Every package directory of the project survives the copy the stack image's wheel is built from."""
    import fnmatch

    from deploy.images import WHEEL_SOURCE_IGNORE

    root = Path(__file__).resolve().parents[1]
    packages = [p.parent.relative_to(root) for top in ("groundfloor", "swarmnet", "discovery", "uav_stack", "world",
                                                       "deploy", "mrswarm") for p in (root / top).rglob("__init__.py")]
    assert any(str(p) == "mrswarm/results" for p in packages)
    dropped = [str(p) for p in packages if any(fnmatch.fnmatch(part, pat) for part in p.parts for pat in WHEEL_SOURCE_IGNORE)]
    assert dropped == []
