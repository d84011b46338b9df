"""End to end in containers: `mrswarm run --runtime docker` flies the coverage scenario with one
container per virtual UAV, meets the process runtime's pass criteria, and leaves nothing behind."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from itertools import pairwise
from pathlib import Path

import pytest

from deploy import multicast
from swarmnet.connectivity import LEAN_ZENOH_RUNTIME
from tests.conftest import wait_for
from tests.docker_support import containers_of, docker_image, no_leftovers  # noqa: F401

ROOT = Path(__file__).resolve().parents[1]
COVERAGE = ROOT / "scenarios" / "coverage.yaml"

pytestmark = [pytest.mark.docker, pytest.mark.e2e]


def only_run_dir(out: Path) -> Path:
    dirs = [d for d in out.iterdir() if d.is_dir()]
    assert len(dirs) == 1, dirs
    return dirs[0]


def no_seal_rules_left(network: str) -> bool:
    return not multicast._listed(network)


def test_coverage_in_five_containers_covers_without_collisions_and_leaves_nothing(
        docker_image: str, tmp_path: Path, no_leftovers: None) -> None:
    res = subprocess.run(
        [sys.executable, "-m", "mrswarm", "run", str(COVERAGE), "--runtime", "docker", "--out", str(tmp_path), "--no-live",
         "--set", "fleet.count=5", "--set", "duration=40", "--set", f"docker.image={docker_image}"],
        cwd=ROOT, capture_output=True, text=True, timeout=280)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    run_dir = only_run_dir(tmp_path)
    summary = json.loads((run_dir / "summary.json").read_text())
    # the process runtime's criteria (tests/test_run_e2e.py)
    assert summary["uavs_recorded"] == 5
    cov = summary["coverage"]
    curve = [c for _, c in cov["curve"]]
    assert cov["final"] > 0.0
    assert curve[-1] > curve[0] and all(b >= a for a, b in pairwise(curve))  # coverage only grows
    assert summary["separation"]["collisions"] == 0
    assert summary["separation"]["min_m"] > 1.0
    assert summary["rtf"]["min"] > 0.8
    assert summary["network"]["transport_age_ms"]["n"] > 100
    status = [json.loads(p.read_text()) for p in run_dir.glob("uav[0-9]*.json")]
    assert len(status) == 5
    assert {st["net"]["zenoh_runtime"] for st in status} == {LEAN_ZENOH_RUNTIME}  # a UAV in a container too
    # really containers: one per UAV plus the discovery server and the edge router (the runner's
    # way in), each with its own IP, multicast sealed. UAVs reach each other only through what
    # the discovery server relays: gossip is off and 1.9+ routers do not relay between peers.
    manifest = json.loads((run_dir / "containers.json").read_text())
    boxes = manifest["containers"]
    assert set(boxes) == {"discovery", "router", "uav1", "uav2", "uav3", "uav4", "uav5"}
    assert len({b["ip"] for b in boxes.values()}) == 7
    assert manifest["multicast_sealed"] is True
    assert manifest["exit_codes"] == {n: 0 for n in boxes}  # every UAV stopped cleanly on SIGTERM
    for n in boxes:
        assert (run_dir / "logs" / f"{n}.log").stat().st_size > 0
    assert "mission" in (run_dir / "logs" / "uav3.log").read_text()
    assert not containers_of(manifest["run"]), "containers left behind"
    assert no_seal_rules_left(manifest["network"])


def test_ctrl_c_removes_every_container_and_still_summarises(docker_image: str, tmp_path: Path,
                                                              no_leftovers: None) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "mrswarm", "run", str(COVERAGE), "--runtime", "docker", "--out", str(tmp_path), "--no-live",
         "--set", "fleet.count=3", "--set", "duration=120", "--set", f"docker.image={docker_image}"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert wait_for(lambda: any(tmp_path.glob("*/uav1.csv")), 90.0), "UAVs never started recording"
        time.sleep(3.0)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out[-3000:]
    run_dir = only_run_dir(tmp_path)
    assert json.loads((run_dir / "run.json").read_text())["interrupted"] is True
    assert (run_dir / "summary.json").exists()
    manifest = json.loads((run_dir / "containers.json").read_text())
    assert not containers_of(manifest["run"]), "containers left behind"
    assert no_seal_rules_left(manifest["network"])


def test_a_container_that_cannot_start_says_why_at_its_exit(docker_image: str, tmp_path: Path,
                                                            no_leftovers: None) -> None:
    """Every UAV is told to listen for ground stations on an address its container does not have
    (192.0.2.1, TEST-NET: nothing is sent there): each exits at start, and the runner reads why
    from the container's log as soon as it sees the exit, not only at the end of the run."""
    res = subprocess.run(
        [sys.executable, "-m", "mrswarm", "run", str(COVERAGE), "--runtime", "docker", "--out", str(tmp_path), "--no-live",
         "--set", "fleet.count=2", "--set", "duration=30", "--set", f"docker.image={docker_image}",
         "--set", "gcs.host=192.0.2.1", "--set", "gcs.listen_base=21000"],
        cwd=ROOT, capture_output=True, text=True, timeout=280)
    out = " ".join(res.stdout.split())
    assert "run aborted: every UAV process has exited" in out, res.stdout[-3000:] + res.stderr[-3000:]
    run_dir = only_run_dir(tmp_path)
    events = {e["name"]: e for e in json.loads((run_dir / "run.json").read_text())["events"]}
    for uav in (1, 2):
        why = (f"gcs.mavlink_endpoints: udpin:192.0.2.1:{21000 + uav}: cannot listen on 192.0.2.1:{21000 + uav}: "
               "Cannot assign requested address")
        assert (events[f"uav{uav}"]["exit_code"], events[f"uav{uav}"]["error"]) == (2, why)
        assert f"uav{uav} exited (exit code 2): {why}" in out
    manifest = json.loads((run_dir / "containers.json").read_text())
    assert not containers_of(manifest["run"]), "containers left behind"


def test_a_killed_container_is_lost_then_restarted_and_a_killed_router_comes_back(docker_image: str, tmp_path: Path,
                                                                                   no_leftovers: None) -> None:
    """The supervisor with containers: a UAV container killed with SIGKILL is an event and, with
    ``fleet.restart: on-failure``, runs again; the edge router's container, killed, is started
    again; the swarm flies on (the process runtime's chaos test, tests/test_chaos_e2e.py)."""
    import yaml

    scn = yaml.safe_load((ROOT / "tests" / "scenarios" / "mini_coverage.yaml").read_text())
    scn.update(duration=30, docker={"image": docker_image})
    scn["fleet"].update(count=3, restart="on-failure")
    scn["faults"] = [{"at": 4, "kind": "kill_uav", "uav": 2}, {"at": 8, "kind": "kill_router"}]
    path = tmp_path / "killed.yaml"
    path.write_text(yaml.safe_dump(scn))
    out_dir = tmp_path / "out"
    res = subprocess.run([sys.executable, "-m", "mrswarm", "run", str(path), "--runtime", "docker", "--out", str(out_dir),
                          "--no-live"], cwd=ROOT, capture_output=True, text=True, timeout=280)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    run_dir = only_run_dir(out_dir)
    summary = json.loads((run_dir / "summary.json").read_text())
    [lost] = summary["lost_uavs"]
    assert (lost["uav"], lost["signal"], lost["injected"]) == (2, "SIGKILL", True)
    assert lost["restarted_s"] is not None and lost["restarted_s"] > lost["t_s"]
    [outage] = summary["services"]
    assert outage["name"] == "router" and outage["restarted_s"] is not None
    assert summary["separation"]["collisions"] == 0 and summary["coverage"]["final"] > 0.0
    manifest = json.loads((run_dir / "containers.json").read_text())
    assert not containers_of(manifest["run"]), "containers left behind"


def test_bad_container_settings_fail_fast_with_the_field_name(tmp_path: Path) -> None:
    res = subprocess.run([sys.executable, "-m", "mrswarm", "run", str(COVERAGE), "--runtime", "docker", "--out",
                          str(tmp_path), "--set", "docker.memory_mb=8"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.returncode == 2
    assert "docker.memory_mb" in res.stdout + res.stderr
