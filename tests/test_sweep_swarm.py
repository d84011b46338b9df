"""``mrswarm sweep --on swarm`` on a real two-node Docker Swarm on this machine (``mrswarm deploy cluster``): every
run a replicated job placed by Swarm, the runs spread over both nodes, their results in the shared campaign folder,
the table and plots written by the sweep, and no job left in the swarm afterwards."""

from __future__ import annotations

import atexit
import csv
import json
import os
import secrets
import subprocess
import sys
from pathlib import Path

import pytest

from deploy import cluster
from tests.docker_support import docker_image  # noqa: F401

ROOT = Path(__file__).resolve().parents[1]
MINI = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"

pytestmark = [pytest.mark.docker, pytest.mark.e2e, pytest.mark.netns]


def test_a_sweep_spreads_its_runs_over_the_nodes_of_a_swarm(docker_image: str, tmp_path: Path) -> None:  # noqa: F811
    tag = secrets.token_hex(2)
    root, prefix = Path(f"/var/tmp/mrsc-sweep-{tag}"), f"ms{tag}"
    atexit.register(cluster.down, root, prefix)  # even if pytest itself is interrupted
    out = tmp_path / "camp"
    try:
        up = subprocess.run([sys.executable, "-m", "mrswarm", "deploy", "cluster", "up", "--nodes", "2", "--image",
                             docker_image, "--root", str(root), "--prefix", prefix], cwd=ROOT, capture_output=True, text=True,
                            timeout=600)
        assert up.returncode == 0, up.stderr[-3000:]
        cl = cluster.load(root)
        env = dict(os.environ, DOCKER_HOST=cl.manager.docker_host)
        sweep = subprocess.run([sys.executable, "-m", "mrswarm", "sweep", str(MINI), "--grid", "fleet.count=2,3", "--seeds", "2",
                                "--set", "duration=6", "--on", "swarm", "--image", docker_image, "--parallel", "4",
                                "--out", str(out), "--no-live", "--no-record"], cwd=ROOT, capture_output=True, text=True,
                               env=env, timeout=900)
        assert sweep.returncode == 0, sweep.stdout[-4000:] + sweep.stderr[-3000:]
        manager = cluster.node_client(cl.manager)
        assert [s.name for s in manager.services.list()] == []  # every job removed once its run was in
    finally:
        cluster.down(root, prefix)

    with open(out / "runs.csv") as f:
        rows = list(csv.DictReader(f))
    assert sorted((r["fleet.count"], r["seed"], r["status"]) for r in rows) == [
        ("2", "0", "ok"), ("2", "1", "ok"), ("3", "0", "ok"), ("3", "1", "ok")]
    where = []
    for r in rows:
        slot = out / "runs" / r["slot"]
        (attempt,) = json.loads((slot / "slot.json").read_text())["attempts"]
        assert attempt["exit_code"] == 0 and attempt["cpu_s"] > 0.0 and attempt["wall_s"] > 6.0
        where.append(attempt["where"])
        summary = json.loads((out / r["run_dir"] / "summary.json").read_text())
        assert summary["interrupted"] is False and summary["uavs_recorded"] == int(r["fleet.count"])
        assert summary["separation"]["collisions"] == 0
        assert (out / r["run_dir"] / "uav1.csv").stat().st_uid == os.getuid()  # written as the user who swept
    assert set(where) == {f"swarm:{n.name}" for n in cl.nodes}, where  # both nodes flew runs
    assert (out / "overview.png").stat().st_size > 10_000
    with open(out / "cells.csv") as f:
        cov = [c for c in csv.DictReader(f) if c["metric"] == "coverage.final"]
    assert [(c["fleet.count"], c["n"]) for c in cov] == [("2", "2"), ("3", "2")] and all(c["ci_low"] for c in cov)
