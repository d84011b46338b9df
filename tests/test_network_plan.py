"""One network plan for every runtime (deploy/plan.py): the process runtime, the Docker runtime and a
Swarm stack run the same services with the same options, differing only in where they are placed;
every option reaches the command line in the unit of its flag; spatial interest reaches every runtime."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from msgspec.structs import replace

from deploy.plan import CONTAINERS, KEYS_IN_CONTAINER, LocalSite, NetworkPlan, SwarmPlan
from deploy.process_runtime import ProcessRuntime
from deploy.swarm import StackOptions, stack_spec
from discovery.options import DiscoveryServerOptions, FeedOptions, RouterOptions
from mrswarm.cli.deploy import swarm_fleet
from mrswarm.run.keys import run_identities, throwaway_keys
from mrswarm.scenario import load_scenario
from swarmnet.interest import Interest
from uav_stack.config import NetworkConfig

ROOT = Path(__file__).resolve().parents[1]
COVERAGE = ROOT / "scenarios" / "coverage.yaml"
KEY = "plan-test-key-0123456789abcdef"
# the coverage scenario on its default peer network (discovery server and edge router), with the edge feed,
# a window of its own and spatial interest: every service and every option of the plan in use
EDGE = ["fleet.count=3", f"network.discovery.key={KEY}", "network.pose_feed=edge", "network.feed_window_ms=4",
        "network.interest={radius_m: 30, far_rate_hz: 0.5}"]
PLACED_FLAGS = {"--listen", "--keys", "--key", "--identities", "--stats"}  # values a placement decides


def without_placement(argv: list[str]) -> list[str]:
    """A service's command line from ``-m`` on, with each value a placement decides left out (its flag kept):
    addresses, where the credentials are, how the discovery keys are handed over (a file or inline), counters."""
    args = argv[argv.index("-m"):]
    out: list[str] = []
    i = 0
    while i < len(args):
        if args[i] in PLACED_FLAGS:
            if args[i] != "--stats":  # a local router's counters, in the run folder
                out.append("--keys" if args[i] == "--key" else args[i])
            i += 2
        else:
            out.append(args[i])
            i += 1
    return out


def without_addresses(net: NetworkConfig) -> NetworkConfig:
    assert net.discovery is not None and net.security is not None
    return replace(net, endpoints=(), listen=(), discovery=replace(net.discovery, server="-"),
                   security=replace(net.security, keys="-"))


def test_the_process_and_docker_runtimes_and_a_stack_run_the_same_services_with_the_same_options(tmp_path: Path) -> None:
    scn = load_scenario(COVERAGE, EDGE)
    keys = throwaway_keys(tmp_path / "keys", scn.swarm, run_identities(scn.swarm, [1, 2, 3]))
    plan = scn.network_plan({scn.swarm: keys})
    containers = plan.place(CONTAINERS)  # as the Docker runtime and the Swarm stack place it
    rt = ProcessRuntime(tmp_path / "run")
    try:
        local_nets = rt.start_network(plan)  # real processes: the discovery server and the edge router
        local = {n: c.argv for n, c in rt.children.items()}
    finally:
        rt.stop(grace=5.0)
    docker = {s.name: ["python3", *s.argv()] for s in containers.services}  # what DockerRuntime hands each container
    assert list(local) == list(docker) == ["discovery", "router"]
    for name in local:
        assert without_placement(local[name]) == without_placement(docker[name]), name
    # the differences, each a placement: addresses, credentials, counters, how the keys are handed over
    router = docker["router"]
    assert router[router.index("--listen") + 1] == "tls/0.0.0.0:7447" and router[router.index("--keys") + 1] == KEYS_IN_CONTAINER
    lr = local["router"]
    assert lr[lr.index("--listen") + 1].startswith("tls/127.0.0.1:") and lr[lr.index("--keys") + 1] == str(keys)
    assert lr[lr.index("--stats") + 1] == str(tmp_path / "run" / "logs" / "router.stats.json") and "--stats" not in router
    ld, dd = local["discovery"], docker["discovery"]
    assert dd[dd.index("--key") + 1] == f"alpha={KEY}" and KEY not in " ".join(ld)  # not on a local command line
    assert (tmp_path / "run" / "config" / "discovery.keys").read_text() == f"alpha {KEY}\n"
    assert ld[ld.index("--identities") + 1] == str(keys) and dd[dd.index("--identities") + 1] == KEYS_IN_CONTAINER
    # the UAVs' side: the same network but for the addresses and where their credentials are
    docker_nets = containers.uav_networks({"discovery": "10.9.0.2", "router": "10.9.0.3"})
    assert without_addresses(local_nets["alpha"]) == without_addresses(docker_nets["alpha"])
    assert docker_nets["alpha"].endpoints == ("tls/10.9.0.3:7447",) and docker_nets["alpha"].listen == ("tls/0.0.0.0:7447",)
    assert local_nets["alpha"].listen == ("tls/127.0.0.1:0",) and local_nets["alpha"].interest is not None
    # a Swarm stack of the same scenario runs the very commands of the Docker runtime
    stack, _ = stack_spec(swarm_fleet(scn, 3), StackOptions(image="img:1"))
    assert {n: stack["services"][n]["command"] for n in docker} == docker


def test_each_option_reaches_the_command_line_in_its_flags_unit() -> None:
    """Seconds in the code; ``argv`` writes each flag's unit, once."""
    interest = Interest(radius_m=30.0, margin_m=5.0, far_rate_hz=0.5)
    feed = FeedOptions(swarm="alpha", window_s=0.0025, interest=interest)
    assert feed.argv() == ["--feed", "alpha", "--feed-window-ms", "2.5", "--interest-radius-m", "30.0",
                           "--interest-margin-m", "5.0", "--interest-far-hz", "0.5"]
    assert FeedOptions(swarm="alpha", window_s=0.0).argv() == ["--feed", "alpha", "--feed-window-ms", "0"]
    assert FeedOptions(swarm="*").argv() == ["--feed", "*"]  # the router's own default window
    router = RouterOptions(listen=("tls/127.0.0.1:7000",), keys="/k", stats="/s.json", feed=feed, connect=("tls/router:7447",))
    assert router.argv() == ["--listen", "tls/127.0.0.1:7000", "--keys", "/k", "--stats", "/s.json", *feed.argv(),
                             "--connect", "tls/router:7447"]
    assert RouterOptions(listen=("tcp/127.0.0.1:7000",)).argv() == ["--listen", "tcp/127.0.0.1:7000", "--insecure"]
    server = DiscoveryServerOptions(listen="127.0.0.1:7450", keys={"alpha": KEY, "bravo": KEY[::-1]}, ttl=2.5, rate=5000.0,
                                    identities=("/a", "/b"))
    assert server.argv() == ["--listen", "127.0.0.1:7450", "--key", f"alpha={KEY}", "--key", f"bravo={KEY[::-1]}",
                             "--ttl", "2.5", "--rate", "5000", "--identities", "/a", "--identities", "/b"]
    assert replace(server, keys_file="/f").argv()[:4] == ["--listen", "127.0.0.1:7450", "--keys", "/f"]
    # from the scenario: network.feed_window_ms (ms) is s in the plan and ms again on the router's command line
    for ms, flag in ((4.0, "4"), (2.5, "2.5"), (0.0, "0"), (12.5, "12.5")):
        plan = load_scenario(COVERAGE, [*EDGE, f"network.feed_window_ms={ms}"]).network_plan({"alpha": None})
        assert plan.feed_window_s == pytest.approx(ms / 1000.0)
        argv = plan.place(CONTAINERS).service("router").argv()
        assert argv[argv.index("--feed-window-ms") + 1] == flag
    plan = load_scenario(COVERAGE, [*EDGE, "network.discovery.ttl=5", "network.discovery.period=1.5",
                                    "network.lease_s=6"]).network_plan({"alpha": None})
    network = plan.place(CONTAINERS)
    argv = network.service("discovery").argv()
    assert argv[argv.index("--ttl") + 1] == "5.0" and argv[argv.index("--rate") + 1] == "5000"
    net = network.uav_network("alpha", {"discovery": "d", "router": "r"})
    assert net.discovery is not None and net.discovery.period == 1.5 and net.lease_s == 6.0
    assert "--insecure" in network.service("router").argv() and net.security is None


def test_spatial_interest_reaches_the_docker_runtime_and_a_stack() -> None:
    """The router of a container run or a stack filters with the scenario's interest, and its UAVs listen for their
    near feeds (``NetworkConfig.interest``), as in a run of processes."""
    scn = load_scenario(COVERAGE, EDGE)
    flags = ["--interest-radius-m", "30.0", "--interest-margin-m", "5.0", "--interest-far-hz", "0.5"]
    network = scn.network_plan({"alpha": None}).place(CONTAINERS)
    argv = network.service("router").argv()
    assert argv[argv.index("--interest-radius-m"):] == flags
    assert network.uav_network("alpha", {"discovery": "d", "router": "r"}).interest == scn.network.interest
    stack, fleet_json = stack_spec(swarm_fleet(scn, 2), StackOptions(image="img:1"))
    command = stack["services"]["router"]["command"]
    assert command[command.index("--interest-radius-m"):] == flags
    assert all(c["agent"]["network"]["interest"] == {"radius_m": 30.0, "margin_m": 5.0, "far_rate_hz": 0.5}
               for c in json.loads(fleet_json))


def test_more_swarms_in_one_airspace_get_a_router_each_and_share_the_discovery_server(tmp_path: Path) -> None:
    scn = load_scenario(ROOT / "scenarios" / "two_swarms.yaml")
    plan = scn.network_plan({"alpha": tmp_path / "ka", "bravo": tmp_path / "kb"})
    assert [(s.name, s.swarm, s.identity and s.identity.cn) for s in plan.services] == [
        ("discovery", "alpha", "edge.alpha"), ("router", "alpha", "edge.alpha"), ("router-bravo", "bravo", "edge.bravo")]
    local = plan.place(LocalSite(tmp_path))
    server = local.service("discovery").options
    assert isinstance(server, DiscoveryServerOptions)
    assert set(server.keys) == {"alpha", "bravo"} and len(set(server.keys.values())) == 2  # a key each, drawn for this run
    assert server.identities == (str(tmp_path / "ka"), str(tmp_path / "kb"))
    bravo = local.service("router-bravo").argv()
    assert bravo[bravo.index("--keys") + 1] == str(tmp_path / "kb") and "--feed" not in bravo  # direct feed
    nets = local.uav_networks({s.name: "127.0.0.1" for s in local.services})
    a, b = nets["alpha"], nets["bravo"]
    assert a.endpoints != b.endpoints and a.discovery is not None and b.discovery is not None
    assert a.discovery.server == b.discovery.server and a.discovery.key == server.keys["alpha"] != b.discovery.key
    assert a.security is not None and b.security is not None and b.security.keys == str(tmp_path / "kb")
    # a Swarm stack deploys the scenario's own swarm
    assert [s.name for s in scn.network_plan({"alpha": None}).services] == ["discovery", "router"]


def test_a_plan_refuses_what_no_runtime_can_run() -> None:
    with pytest.raises(ValueError, match="pose_feed 'edge'"):
        NetworkPlan((SwarmPlan("alpha"),), interest=Interest(radius_m=30.0))
    with pytest.raises(ValueError, match="each once"):
        NetworkPlan((SwarmPlan("alpha"), SwarmPlan("alpha")))
    with pytest.raises(ValueError, match="client mode"):
        NetworkPlan((SwarmPlan("alpha", discovery_key=KEY),), "discovery", "client")
    with pytest.raises(ValueError, match="swarm"):
        SwarmPlan("no spaces")
    scn = load_scenario(COVERAGE)
    with pytest.raises(ValueError, match="its own swarm, alpha"):
        scn.network_plan({})


def test_the_edge_is_told_the_pools_where_they_share_a_session_with_spatial_interest(tmp_path: Path) -> None:
    """``fleet.pool``: the router's feed gets each pool's UAVs (``--pool pool-<n>=<ids>``, numbered as
    the pools' certificates), so that it sends each pool one near batch; not without interest (no near
    feed), not with discovery (each pooled UAV keeps a session of its own there)."""
    pooled = ["fleet.count=5", "fleet.pool=2", "network.pose_feed=edge", "network.interest={radius_m: 30}"]
    scn = load_scenario(COVERAGE, [*pooled, "network.connectivity=rendezvous", "network.mode=client"])
    assert scn.pool_layout() == [("alpha", (1, 2)), ("alpha", (3, 4)), ("alpha", (5,))]
    plan = scn.network_plan({"alpha": None})
    router = plan.place(LocalSite(tmp_path)).service("router")
    assert isinstance(router.options, RouterOptions) and router.options.feed is not None
    assert [p.name for p in router.options.feed.pools] == ["pool-1", "pool-2", "pool-3"]
    argv = router.argv()
    assert [argv[i + 1] for i, a in enumerate(argv) if a == "--pool"] == ["pool-1=1-2", "pool-2=3-4", "pool-3=5"]
    assert "--pool" not in load_scenario(COVERAGE, [*pooled, "network.connectivity=discovery", "network.mode=peer",
                                                    f"network.discovery.key={KEY}"]).network_plan(
        {"alpha": None}).place(CONTAINERS).service("router").argv()  # discovery: a session per UAV
    no_interest = load_scenario(COVERAGE, ["fleet.count=5", "fleet.pool=2", "network.pose_feed=edge",
                                           "network.connectivity=rendezvous"]).network_plan({"alpha": None})
    assert "--pool" not in no_interest.place(CONTAINERS).service("router").argv()
