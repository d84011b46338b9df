"""One swarm across three edge servers: a real three-node Docker Swarm on this machine.

`mrswarm deploy cluster up --nodes 3` makes three docker engines in network namespaces (one
swarm, the stack image loaded into each); the stack of 9 virtual UAVs goes up from the manager
with at most 3 per node, so every node flies 3, and an edge router on every node, linked to the
manager's. A ground station on the manager commands them
through the edge router; every UAV must hear all 8 others (6 of them on other nodes), each
command must be acknowledged by the UAVs of every node, the mission must complete with no two
UAVs closer than the collision distance, and `cluster down` must leave nothing on the host."""

from __future__ import annotations

import atexit
import json
import math
import secrets
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from deploy import cluster
from tests.conftest import wait_for
from tests.docker_support import docker_image  # noqa: F401

ROOT = Path(__file__).resolve().parents[1]
UAVS = 9
COLLISION_DISTANCE = 1.0  # m, the scenario's flight.collision_distance
SMALL_FIELD = ["--set", "mission.area.x_min=-30", "--set", "mission.area.x_max=30", "--set", "mission.area.y_min=-20",
               "--set", "mission.area.y_max=20", "--set", "fleet.spawn.center=[0,-30]"]

pytestmark = [pytest.mark.docker, pytest.mark.e2e, pytest.mark.netns]


def deploy_cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mrswarm", "deploy", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout)


def host_rules() -> list[str]:
    """Host iptables rules that mention the cluster's subnets (there must never be any)."""
    out = subprocess.run(["iptables-save"], capture_output=True, text=True, timeout=30).stdout
    return [ln for ln in out.splitlines() if "10.213." in ln or "10.214." in ln]


def recorded_neighbours(node: cluster.Node, image: str, volume: str, swarm: str) -> dict[int, dict[str, Any]]:
    """The counters the UAVs of one node wrote into that node's data volume."""
    script = ("import glob, json; print(json.dumps({json.load(open(p))['uav']: json.load(open(p)).get('neighbours', {}) "
              f"for p in glob.glob('/data/{swarm}/uav*.json')}}))")
    out = cluster.node_client(node).containers.run(image, ["python3", "-c", script], remove=True, network_mode="none",
                                                   volumes={volume: {"bind": "/data", "mode": "ro"}})
    return {int(k): v for k, v in json.loads(out.decode().strip().splitlines()[-1]).items()}


def edge_links(on: Any, node: cluster.Node, stack: str) -> tuple[set[tuple[str, int]], dict[str, str]]:
    """The established TCP links of the edge router on ``node`` as (remote IP, remote port), and the
    stack's containers there (name -> overlay IP)."""
    fmt = "'{{range .Containers}}{{.Name}} {{.IPv4Address}} {{end}}'"
    script = ("for c in $(docker ps -q --filter label=org.mrswarm.role=router); do "
              'nsenter -t $(docker inspect -f "{{.State.Pid}}" $c) -n ss -tnH state established; done; echo ---; '
              f"docker network inspect {stack} --format {fmt}")
    res = on(node.index, "sh", "-c", script)
    assert res.returncode == 0, res.stderr
    links_txt, _, containers = res.stdout.partition("---")
    links = set()
    for ln in links_txt.splitlines():
        f = ln.split()
        if len(f) >= 4:
            ip, port = f[-1].rsplit(":", 1)
            links.add((ip, int(port)))
    words = containers.split()
    return links, {name: ip.split("/")[0] for name, ip in zip(words[::2], words[1::2], strict=False)}


def acks(res: subprocess.CompletedProcess[str]) -> dict[int, dict[str, Any]]:
    rows = [json.loads(ln) for ln in res.stdout.splitlines() if ln.startswith("{")]
    return {int(r["uav"]): r for r in rows}


def test_nine_uavs_on_three_edge_servers_see_each_other_obey_the_ground_station_and_leave_nothing(
        docker_image: str, tmp_path: Path) -> None:
    tag = secrets.token_hex(2)
    root, prefix = Path(f"/var/tmp/mrsc-test-{tag}"), f"mt{tag}"
    where = ["--root", str(root), "--prefix", prefix]
    atexit.register(cluster.down, root, prefix)  # even if pytest itself is interrupted
    swarm = f"c{tag}"
    stack = f"mrswarm-{swarm}"
    keys = tmp_path / "stack" / "keys"
    rules_before = host_rules()
    t0 = time.monotonic()
    try:
        up = deploy_cli("cluster", "up", "--nodes", "3", "--image", docker_image, *where)
        assert up.returncode == 0, up.stderr[-3000:]
        cl = cluster.load(root)
        assert [(n["role"], n["state"]) for n in json.loads(up.stdout)["nodes"]] == [
            ("manager", "ready"), ("worker", "ready"), ("worker", "ready")]
        seal = deploy_cli("cluster", "seal", "--swarm", swarm, "--image", docker_image, *where)
        assert seal.returncode == 0, seal.stderr[-3000:]

        def on(node: int, *argv: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
            return deploy_cli("cluster", "exec", *where, str(node), "--", *argv, timeout=timeout)

        swarm_up = on(1, sys.executable, "-m", "mrswarm", "deploy", "swarm", "up", "--uavs", str(UAVS), "--swarm", swarm,
                      "--max-per-node", "3", "--edge-per-node", "--image", docker_image, "--out", str(tmp_path / "stack"),
                      *SMALL_FIELD)
        assert swarm_up.returncode == 0, swarm_up.stdout[-3000:] + swarm_up.stderr[-3000:]
        # where the replicas run: 3 on each node (slot k flies UAV k)
        manager = cluster.node_client(cl.manager)
        tasks = [t for t in manager.services.get(f"{stack}_uav").tasks() if t["DesiredState"] == "running"]
        host_of = {x.id: x.attrs["Description"]["Hostname"] for x in manager.nodes.list()}
        node_of = {t["Slot"]: host_of[t["NodeID"]] for t in tasks}
        assert sorted(node_of) == list(range(1, UAVS + 1))
        assert Counter(node_of.values()) == {n.name: 3 for n in cl.nodes}, node_of

        # every node drops multicast on the overlay (its sentinel keeps the overlay's namespace sealed)
        net_id = manager.networks.get(stack).id
        for n in cl.nodes:
            ns = f'"$MRSWARM_DOCKER_EXEC_ROOT/netns/1-{net_id[:10]}"'
            rules = on(n.index, "sh", "-c", f"nsenter --net={ns} iptables -S FORWARD")
            assert rules.returncode == 0, (n.name, rules.stderr)
            assert f"mrswarm-seal:{stack}" in rules.stdout and "224.0.0.0/4" in rules.stdout, (n.name, rules.stdout)

        # the ground station on the manager: it reaches the router's published port on the node's address
        gcs = ["--connect", f"tls/{cl.manager.address}:7447", "--swarm", swarm, "--keys", str(keys)]
        watch_out = tmp_path / "watch.json"
        watcher = subprocess.Popen([sys.executable, "-m", "mrswarm", "deploy", "cluster", "exec", *where, "1", "--",
                                    sys.executable, "-m", "tests.cluster_watch", *gcs[:6], "--uavs", str(UAVS),
                                    "--out", str(watch_out)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            assert wait_for(lambda: Path(f"{watch_out}.ready").exists() or watcher.poll() is not None, 150.0, 0.5)
            assert Path(f"{watch_out}.ready").exists(), watcher.communicate(timeout=30)
            # `start` (take off, then fly the mission) to all 9, acknowledged by each: 3 on every node
            res = on(1, sys.executable, "-m", "mrswarm", "gcs", "start", *gcs, "--uav", f"1-{UAVS}", "--json", "--timeout",
                     "30", timeout=120)
            assert res.returncode == 0, (res.stdout[-3000:], res.stderr[-3000:])
            got = acks(res)
            assert sorted(got) == list(range(1, UAVS + 1)), res.stdout
            assert all(r["status"] == "ok" for r in got.values()), got
            assert Counter(node_of[u] for u in got) == {n.name: 3 for n in cl.nodes}
            _, err = watcher.communicate(timeout=260)
            assert watcher.returncode == 0, err.decode()[-3000:]
        finally:
            if watcher.poll() is None:
                watcher.kill()
                watcher.wait(timeout=10)
        seen = json.loads(watch_out.read_text())
        # the mission completed: every UAV reports done, having flown from where it started
        assert seen["phases"] == {str(u): "done" for u in range(1, UAVS + 1)}, seen["phases"]
        for u in range(1, UAVS + 1):
            assert math.dist(seen["start"][str(u)][:2], seen["end"][str(u)][:2]) > 5.0, (u, seen["start"], seen["end"])
        # no collision: never two airborne UAVs within the collision distance
        assert seen["min_separation"] is not None and seen["min_separation"] > COLLISION_DISTANCE, seen["min_separation"]

        time.sleep(1.5)  # counters are written every second
        heard: dict[int, dict[str, Any]] = {}
        for n in cl.nodes:
            mine = recorded_neighbours(n, docker_image, f"{stack}_data", swarm)
            assert sorted(mine) == sorted(u for u, h in node_of.items() if h == n.name), (n.name, sorted(mine))
            heard |= mine
        for u, table in heard.items():  # every UAV heard all 8 others, 6 of them on other nodes
            assert sorted(int(k) for k in table) == sorted(set(range(1, UAVS + 1)) - {u}), (u, table)
            assert all(nb["received"] > 50 for nb in table.values()), (u, table)

        # the edges: each worker's UAVs link to their own server's router, which links to the manager's;
        # no UAV of a worker holds a link to the manager's router
        seen_links = {n.name: edge_links(on, n, stack) for n in cl.nodes}
        manager_links, manager_boxes = seen_links[cl.manager.name]
        manager_router = next(ip for name, ip in manager_boxes.items() if f"{stack}_router." in name)
        for n in cl.nodes[1:]:
            links, boxes = seen_links[n.name]
            uav_ips = {ip for name, ip in boxes.items() if f"{stack}_uav." in name}
            edge_ip = next(ip for name, ip in boxes.items() if f"{stack}_router-{n.name}." in name)
            assert len(uav_ips) == 3, boxes
            assert {ip for ip, port in links if port == 7447} == {manager_router}, (n.name, links)  # it dialled the manager's
            assert {ip for ip, port in links if port != 7447} == uav_ips, (n.name, links, boxes)  # its own UAVs dialled it
            assert edge_ip in {ip for ip, _ in manager_links}, (n.name, manager_links)
            assert not uav_ips & {ip for ip, _ in manager_links}, (n.name, manager_links)  # not the manager's router

        for node in (3, 2, 1):  # workers first: their sentinels hold the overlay
            res = on(node, sys.executable, "-m", "mrswarm", "deploy", "swarm", "down", "--swarm", swarm, "--volumes")
            assert res.returncode == 0, res.stderr[-3000:]
    finally:
        down = deploy_cli("cluster", "down", *where, timeout=120)
        print(f"cluster test took {time.monotonic() - t0:.0f} s")
    assert down.returncode == 0, down.stdout[-3000:] + down.stderr[-3000:]
    left = cluster.leftovers(root, prefix)
    assert not any(left.values()), left
    assert host_rules() == rules_before == []


def test_a_failed_cluster_up_removes_what_it_made() -> None:
    """`up` fails after the namespaces, engines and swarm exist (the image to load is not there): it must
    say why and leave nothing behind, as `down` would."""
    tag = secrets.token_hex(2)
    root, prefix = Path(f"/var/tmp/mrsc-test-{tag}"), f"mt{tag}"
    atexit.register(cluster.down, root, prefix)
    res = deploy_cli("cluster", "up", "--nodes", "2", "--image", f"mrswarm-missing:{tag}", "--root", str(root),
                     "--prefix", prefix, timeout=180)
    assert res.returncode == 2, res.stdout + res.stderr
    assert "docker save" in res.stderr and f"mrswarm-missing:{tag}" in res.stderr, res.stderr
    assert "swarm formed" in res.stderr  # it got that far before failing
    left = cluster.leftovers(root, prefix)
    assert not any(left.values()), left
    again = deploy_cli("cluster", "down", "--root", str(root), "--prefix", prefix)  # idempotent
    assert again.returncode == 0 and json.loads(again.stdout)["namespaces"] == [], again.stdout + again.stderr
