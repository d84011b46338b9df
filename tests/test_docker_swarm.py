"""Several edge servers, tested on a single-node Docker Swarm: `mrswarm deploy swarm up --uavs 5`
brings up the router service and 5 UAV replicas (unique ids from the task slots); they
discover each other through the rendezvous service only (multicast on the overlay is
dropped, checked with probes), take off and fly on command; `down` removes everything."""

from __future__ import annotations

import json
import math
import secrets
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from deploy.dockerutil import L_ROLE, L_RUN
from swarmnet.observer import SwarmObserver
from swarmnet.security.credentials import Credentials
from swarmnet.security.identity import NodeName
from tests.conftest import free_port, wait_for
from tests.docker_support import docker_client, docker_image  # noqa: F401
from uav_stack.config import NetworkConfig
from uav_stack.runtime import make_connectivity

ROOT = Path(__file__).resolve().parents[1]
PROBE = ["python3", "-m", "deploy.mcast_probe"]

pytestmark = [pytest.mark.docker, pytest.mark.e2e]


@pytest.fixture(scope="module")
def swarm_manager(docker_image: str) -> Iterator[Any]:
    """This engine as a swarm manager: a single-node swarm made here (and left after) if it is in none."""
    from deploy.swarm import init_swarm

    cl = docker_client()
    made = init_swarm(cl)
    yield cl
    if made:
        cl.swarm.leave(force=True)


def deploy_cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mrswarm", "deploy", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout)


def probe(cl: Any, image: str, network: str, what: list[str], name: str) -> Any:
    return cl.containers.run(image, [*PROBE, *what], name=name, network=network, detach=True,
                             labels={L_RUN: f"probe-{network}", L_ROLE: "probe"})


def result(c: Any) -> dict[str, Any]:
    code = c.wait(timeout=60)["StatusCode"]
    out = c.logs().decode()
    assert code == 0, out[-2000:]
    return json.loads(out.strip().splitlines()[-1])


def multicast_on(cl: Any, image: str, network: str) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    boxes = []
    try:
        tag = secrets.token_hex(3)
        lst = probe(cl, image, network, ["listen", "--seconds", "12"], f"mcl-{tag}")
        boxes.append(lst)
        boxes += [probe(cl, image, network, ["zenoh", "--name", z, "--seconds", "14"], f"mc{z}-{tag}") for z in ("za", "zb")]
        lst.reload()
        ip = lst.attrs["NetworkSettings"]["Networks"][network]["IPAddress"]
        boxes.append(probe(cl, image, network, ["send", "--to", ip, "--seconds", "8"], f"mcs-{tag}"))
        return result(boxes[0]), [result(b) for b in boxes[1:3]]
    finally:
        for b in boxes:
            b.remove(force=True)


def fly(port: int, swarm: str, ids: list[int], keys: Path) -> dict[int, tuple[float, float, float]]:
    """Command the swarm through the router's published port, like a ground station (as ``ctl``, with the stack's
    key directory); return where they went."""
    net = NetworkConfig(endpoints=(f"tls/127.0.0.1:{port}",), mode="client", security=Credentials(keys=str(keys)))
    with SwarmObserver(swarm, make_connectivity(net, NodeName("ctl", 0, swarm)), name="test-gcs") as obs:
        def phases_are(ok: set[str]) -> bool:
            obs.poll()
            return all(obs.phases().get(u) in ok for u in ids)

        assert wait_for(lambda: phases_are({"ready"}), 120.0, 0.2), obs.phases()
        starts = {u: (obs.uavs[u].pose.x, obs.uavs[u].pose.y) for u in ids if obs.uavs[u].pose is not None}
        obs.command("takeoff", ids)
        assert wait_for(lambda: phases_are({"hover"}), 90.0, 0.2), obs.phases()
        obs.command("start", ids)
        min_sep = math.inf
        farthest = dict.fromkeys(ids, 0.0)  # from its start, m: a coverage UAV may come back near it
        end = time.monotonic() + 20.0
        while time.monotonic() < end:
            obs.poll()
            pts = [(v.pose.x, v.pose.y, v.pose.z) for v in obs.uavs.values() if v.pose is not None and v.pose.z > 1.0]
            for u in ids:
                if u in starts and (p := obs.uavs[u].pose) is not None:
                    farthest[u] = max(farthest[u], math.dist(starts[u], (p.x, p.y)))
            for i in range(len(pts)):
                for j in range(i + 1, len(pts)):
                    min_sep = min(min_sep, math.dist(pts[i], pts[j]))
            time.sleep(0.1)
        assert all(obs.phases().get(u) in ("mission", "done") for u in ids), obs.phases()
        assert min_sep > 1.0, min_sep
        now = {u: (obs.uavs[u].pose.x, obs.uavs[u].pose.y, obs.uavs[u].pose.z) for u in ids}
        assert len(starts) == len(ids)
        for u in ids:
            assert farthest[u] > 10.0, (u, starts[u], farthest[u], now[u])  # it flew its mission
            assert now[u][2] > 5.0
        return now


def recorded_neighbours(cl: Any, image: str, volume: str, swarm: str) -> dict[int, dict[str, Any]]:
    script = ("import glob, json; print(json.dumps({json.load(open(p))['uav']: json.load(open(p)).get('neighbours', {}) "
              f"for p in glob.glob('/data/{swarm}/uav*.json')}}))")
    out = cl.containers.run(image, ["python3", "-c", script], volumes={volume: {"bind": "/data", "mode": "ro"}},
                            remove=True, network_mode="none")
    return {int(k): v for k, v in json.loads(out.decode().strip().splitlines()[-1]).items()}


def test_swarm_stack_with_five_replicas_discovers_flies_and_goes_down_cleanly(
        docker_image: str, swarm_manager: Any, tmp_path: Path) -> None:
    cl = swarm_manager
    swarm = f"t{secrets.token_hex(3)}"
    stack = f"mrswarm-{swarm}"
    port = free_port()
    up = deploy_cli("swarm", "up", "--uavs", "5", "--swarm", swarm, "--port", str(port), "--image", docker_image,
                    "--out", str(tmp_path / "stack"))
    try:
        assert up.returncode == 0, up.stdout[-3000:] + up.stderr[-3000:]
        assert json.loads(up.stdout)["services"] == {f"{stack}_discovery": 1, f"{stack}_router": 1, f"{stack}_uav": 5}
        stack_yml = (tmp_path / "stack" / "stack.yml").read_text()
        assert "{{.Task.Slot}}" in stack_yml and "replicas: 5" in stack_yml
        # cellular realism on the overlay: no multicast, no discovery by scouting; unicast works
        got, zs = multicast_on(cl, docker_image, stack)
        assert got["unicast"] > 20 and got["multicast"] == 0 and got["broadcast"] == 0, got
        assert all(z["heard"] == [] for z in zs), zs
        # the replicas got unique UAV ids 1..5 from their slots and fly as a swarm
        fly(port, swarm, [1, 2, 3, 4, 5], tmp_path / "stack" / "keys")  # made by `up` beside stack.yml
        time.sleep(1.5)  # counters are written every second
        nb = recorded_neighbours(cl, docker_image, f"{stack}_data", swarm)
        assert sorted(nb) == [1, 2, 3, 4, 5]
        for u, table in nb.items():  # each heard the 4 others: discovery worked for every pair
            assert sorted(int(k) for k in table) == sorted({1, 2, 3, 4, 5} - {u}), (u, table)
            assert all(n["received"] > 50 for n in table.values()), (u, table)
    finally:
        down = deploy_cli("swarm", "down", "--swarm", swarm, "--volumes")
    assert down.returncode == 0, down.stdout[-3000:] + down.stderr[-3000:]
    ns = f"com.docker.stack.namespace={stack}"
    assert not cl.services.list(filters={"label": ns})
    assert not cl.containers.list(all=True, sparse=True, filters={"label": ns})
    assert not cl.containers.list(all=True, sparse=True, filters={"label": f"{L_RUN}={stack}"})
    assert not [n for n in cl.networks.list(names=[stack]) if n.name == stack]
    assert not cl.configs.list(filters={"label": ns})
    assert not cl.volumes.list(filters={"label": ns})
