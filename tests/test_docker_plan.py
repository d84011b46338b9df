"""The same network plan deployed through the process runtime and the Docker runtime: the containers run
the processes' command lines but for placement, and the containerised edge router applies spatial interest."""

from __future__ import annotations

from pathlib import Path

import pytest

from deploy.docker_runtime import DockerRuntime
from deploy.process_runtime import ProcessRuntime
from mrswarm.run.keys import run_identities, throwaway_keys
from mrswarm.scenario import load_scenario
from tests.conftest import wait_for
from tests.docker_support import docker_image, no_leftovers  # noqa: F401
from tests.test_network_plan import COVERAGE, EDGE, without_addresses, without_placement

pytestmark = pytest.mark.docker


def test_the_docker_runtime_runs_the_process_runtimes_services_and_applies_spatial_interest(
        docker_image: str, tmp_path: Path, no_leftovers: None) -> None:
    scn = load_scenario(COVERAGE, [*EDGE, f"docker.image={docker_image}"])
    keys = throwaway_keys(tmp_path / "keys", scn.swarm, run_identities(scn.swarm, [1, 2, 3]))
    plan = scn.network_plan({scn.swarm: keys})
    local = ProcessRuntime(tmp_path / "local")
    try:
        local_nets = local.start_network(plan)
        local_argv = {n: c.argv for n, c in local.children.items()}
    finally:
        local.stop(grace=5.0)
    rt = DockerRuntime(tmp_path / "docker", settings=scn.docker, swarm=scn.swarm)
    try:
        docker_nets = rt.start_network(plan)
        commands = {n: list(b.container.attrs["Config"]["Cmd"]) for n, b in rt.boxes.items()}
        router = rt.boxes["router"].container

        def router_says() -> str:
            return str(router.logs(stdout=True, stderr=True).decode())

        # the router in its container filters the feed with the scenario's interest
        assert wait_for(lambda: "interest radius 30 m (+5), far 0.5 Hz" in router_says(), 20.0, 0.5), router_says()
        assert "window 4 ms" in router_says()
    finally:
        rt.stop()
    assert list(commands) == list(local_argv) == ["discovery", "router"]
    for name, argv in commands.items():
        assert without_placement(argv) == without_placement(local_argv[name]), name
    assert without_addresses(docker_nets[scn.swarm]) == without_addresses(local_nets[scn.swarm])
    assert docker_nets[scn.swarm].interest == scn.network.interest  # the UAV containers listen for their near feeds
