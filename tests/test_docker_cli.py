"""`mrswarm deploy ps|logs|down` find a run's containers by label and clean up after a runner
that died without stopping them (here: a runtime whose stop() is never called)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from deploy import multicast
from deploy.docker_runtime import ContainerSettings, DockerRuntime
from deploy.plan import NetworkPlan, SwarmPlan
from tests.conftest import wait_for
from tests.docker_support import containers_of, docker_client, docker_image, no_leftovers  # noqa: F401

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.docker


def deploy_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mrswarm", "deploy", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)


def test_ps_logs_and_down_after_a_runner_that_never_stopped(docker_image: str, tmp_path: Path,
                                                            no_leftovers: None) -> None:
    rt = DockerRuntime(tmp_path / "run", settings=ContainerSettings(image=docker_image), swarm="clitest")
    try:
        rt.start_network(NetworkPlan((SwarmPlan("clitest"),)))
        rt.start_container("idle", ["python3", "-c", "import time; time.sleep(300)"])
        network = rt.network.name
        ps = deploy_cli("ps")
        assert ps.returncode == 0, ps.stderr
        assert rt.run in ps.stdout and f"mrs-{rt.run}-router" in ps.stdout and network in ps.stdout
        assert wait_for(lambda: "listening" in deploy_cli("logs", "router", "--run", rt.run).stdout, 20.0, 0.5)
        ambiguous = deploy_cli("logs", "nosuchthing")
        assert ambiguous.returncode == 2 and "no mrswarm container" in ambiguous.stderr
        # the runner "dies" here: no rt.stop(). `down` must remove everything of the run.
        down = deploy_cli("down", "--run", rt.run)
        assert down.returncode == 0, down.stderr
        assert "removed 2 containers, 1 networks" in down.stdout
        assert not containers_of(rt.run)
        assert not docker_client().networks.list(names=[network])
        assert not multicast._listed(network)
    finally:
        rt.stop()  # no-op for what `down` already removed; cleans up if an assertion failed first
