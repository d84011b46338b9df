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
