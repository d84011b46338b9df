"""`mrswarm deploy cluster` without bringing a cluster up: bad input, a node's command line, idempotent down."""

from __future__ import annotations

import json
import secrets
import subprocess
import sys
from pathlib import Path

import pytest

from deploy import cluster, multicast

ROOT = Path(__file__).resolve().parents[1]


def deploy_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mrswarm", "deploy", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)


def test_bad_node_count_and_missing_cluster_are_clear_errors(tmp_path: Path) -> None:
    res = deploy_cli("cluster", "up", "--nodes", "0", "--root", str(tmp_path / "c"))
    assert res.returncode == 2 and "--nodes must be in 1..9, got 0" in res.stderr, res.stderr
    res = deploy_cli("cluster", "exec", "--root", str(tmp_path / "c"), "1", "--", "true")
    assert res.returncode == 2 and f"no cluster at {tmp_path / 'c'}" in res.stderr, res.stderr
    assert not (tmp_path / "c").exists()


def test_down_with_nothing_up_finds_nothing_and_succeeds(tmp_path: Path) -> None:
    res = deploy_cli("cluster", "down", "--root", str(tmp_path / "c"), "--prefix", f"mu{secrets.token_hex(2)}")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["namespaces"] == [] and not any(out["left"].values()), out


def test_a_node_runs_commands_in_its_namespaces_against_its_own_engine(monkeypatch: pytest.MonkeyPatch) -> None:
    node = cluster.Node(2, "mrscn2", "10.213.0.12", "/var/tmp/c/n2", pid=4242)
    argv = cluster.exec_argv(node, ["docker", "ps"], cwd="/work")
    assert argv[:6] == ["nsenter", "--target=4242", "--mount", "--net", "--uts", "--wd=/work"]
    assert "DOCKER_HOST=unix:///var/tmp/c/n2/docker.sock" in argv and argv[-2:] == ["docker", "ps"]
    # the node's dockerd keeps its overlay namespaces under its own exec root; sealing looks there
    monkeypatch.setenv(multicast.EXEC_ROOT_ENV, node.exec_root)
    assert multicast.overlay_netns("0123456789abcdef") == Path("/var/tmp/c/n2/exec/netns/1-0123456789")
    with pytest.raises(cluster.ClusterError, match="no dockerd"):
        cluster.exec_argv(cluster.Node(3, "mrscn3", "10.213.0.13", "/x"), ["true"])


def test_an_edge_per_server_is_pinned_there_linked_to_the_managers_and_secured_like_it(tmp_path: Path) -> None:
    from deploy.plan import edge_service
    from deploy.swarm import StackOptions, stack_spec
    from mrswarm.cli.deploy import swarm_fleet
    from mrswarm.scenario import load_scenario

    fleet = swarm_fleet(load_scenario(ROOT / "scenarios/coverage.yaml", []), 6)
    edges = ("n1", "n2", "n3")
    stack, _ = stack_spec(fleet, StackOptions(image="mrswarm:t", edges=edges))
    svc = stack["services"]
    assert [edge_service(h, edges) for h in ("n1", "n2", "n3", "elsewhere")] == ["router", "router-n2", "router-n3", "router"]
    assert svc["router"]["deploy"]["placement"]["constraints"] == ["node.hostname == n1"]
    assert svc["router"]["ports"][0]["published"] == 7447
    for host in ("n2", "n3"):
        edge = svc[f"router-{host}"]
        assert edge["deploy"]["placement"]["constraints"] == [f"node.hostname == {host}"]
        assert edge["command"][-2:] == ["--connect", "tls/router:7447"] and "ports" not in edge
        assert edge["secrets"] == svc["router"]["secrets"]  # edge.<swarm>'s pair, the CA and the roster
    env = svc["uav"]["environment"]
    assert env["MRSWARM_NODE"] == "{{.Node.Hostname}}" and env["MRSWARM_EDGES"] == "n1,n2,n3"
    assert set(svc["uav"]["depends_on"]) == {"discovery", "router", "router-n2", "router-n3"}
    # without edges: one router, and the stack is the one committed in deploy/stack.yml
    one, _ = stack_spec(fleet, StackOptions(image="mrswarm:t"))
    assert not any(name.startswith("router-") for name in one["services"])
    assert "MRSWARM_EDGES" not in one["services"]["uav"]["environment"]


def test_a_root_with_other_files_is_refused_and_never_removed(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("mine")
    res = deploy_cli("cluster", "up", "--nodes", "1", "--root", str(tmp_path), "--prefix", f"mu{secrets.token_hex(2)}")
    assert res.returncode == 2 and "holds other files" in res.stderr, res.stderr
    res = deploy_cli("cluster", "down", "--root", str(tmp_path), "--prefix", f"mu{secrets.token_hex(2)}")
    assert (tmp_path / "notes.txt").read_text() == "mine"
    assert json.loads(res.stdout)["left"]["files"] == [str(tmp_path)]  # reported, not removed
    assert res.returncode == 1
