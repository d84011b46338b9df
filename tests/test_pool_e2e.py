"""Many UAVs on one machine: pooled virtual UAVs (``fleet.pool``), several to a process and each
still its own UAV; and a large run that goes on without a few late UAVs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from mrswarm.results.analysis import load_stats
from mrswarm.scenario import ScenarioError, load_scenario
from tests.conftest import wait_for
from tests.gcs_helpers import run_dir, start_run, stop_run

ROOT = Path(__file__).resolve().parents[1]
MINI = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"


def _run(out: Path, sets: list[str], timeout: float = 240) -> subprocess.CompletedProcess[str]:
    args = [sys.executable, "-m", "mrswarm", "run", str(MINI), "--out", str(out), "--no-live"]
    for s in sets:
        args += ["--set", s]
    return subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=timeout)


@pytest.mark.e2e
def test_pooled_uavs_fly_the_mission_each_as_its_own_uav(tmp_path: Path) -> None:
    res = _run(tmp_path, ["fleet.pool=2"])
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    rd = next(d for d in tmp_path.iterdir() if d.is_dir())
    run = json.loads((rd / "run.json").read_text())
    # two processes host the four UAVs; no process of their own
    assert run["pools"] == {"pool1": [1, 2], "pool2": [3, 4]}
    assert {n for n in run["pids"] if n.startswith(("uav", "pool"))} == {"pool1", "pool2"}
    summary = json.loads((rd / "summary.json").read_text())
    assert summary["uavs_recorded"] == 4
    assert summary["coverage"]["final"] > 0.3 and summary["separation"]["collisions"] == 0
    assert summary["separation"]["min_m"] > 1.0
    assert summary["degraded"] == []  # each pooled UAV's records checked by its own name, and whole
    # each UAV its own agent, its own FCU vehicle, its own swarm node under its own certificate
    status = {u: json.loads((rd / f"uav{u}.json").read_text()) for u in (1, 2, 3, 4)}
    assert all(st["uav"] == u and st["phase"] in ("mission", "done") for u, st in status.items()), \
        {u: st["phase"] for u, st in status.items()}
    assert all(st["net"]["sent"]["pose"] > 50 for st in status.values())
    # each reaches its vehicle through the pool's in-process link: the same MAVLink, nothing lost, no socket
    links = {u: st["fcu_inproc"] for u, st in status.items()}
    assert all(ln["to_fcu"]["datagrams"] > 100 and ln["to_agent"]["datagrams"] > 100 and not ln["to_fcu"]["dropped"]
               and not ln["to_agent"]["dropped"] for ln in links.values()), links
    assert all(st["fcu_link"]["foreign_source"] == 0 and st["fcu_link"]["bad"] == 0 for st in status.values())
    # one Zenoh session per pool, as pool-<n>, whose certificate speaks for its two UAVs: each pose
    # reaching the pool is taken in once, for both
    sessions = {u: st["pool_session"] for u, st in status.items()}
    assert {u: s["name"] for u, s in sessions.items()} == {1: "pool 1", 2: "pool 1", 3: "pool 2", 4: "pool 2"}
    assert all(len(s["uavs"]) == 2 and s["received"]["pose"] > 50 and not s["rejected"] for s in sessions.values()), sessions
    roster = json.loads((rd / "keys" / "roster.json").read_text())
    assert roster["nodes"]["pool-1.e2e"]["uavs"] == [1, 2] and roster["nodes"]["pool-2.e2e"]["uavs"] == [3, 4]
    assert summary["security"]["mode"] == "mtls" and not summary["security"].get("refused")
    # every UAV saw the three others, pool-mates as well as the other pool's
    assert summary["network"]["transport_age_links"]["links"] == 12
    # a pool's per-neighbour counters are written once, in the pool's file its UAVs' counters files name;
    # read back, each UAV has the three others and never itself
    assert {u: st.get("neighbours_in") for u, st in status.items()} == {
        1: "neighbours_pool1.json", 2: "neighbours_pool1.json", 3: "neighbours_pool2.json", 4: "neighbours_pool2.json"}
    assert all("neighbours" not in st for st in status.values())
    stats = load_stats(rd)
    assert {u: set(stats[u]["neighbours"]) for u in (1, 2, 3, 4)} == {
        u: {str(o) for o in (1, 2, 3, 4) if o != u} for u in (1, 2, 3, 4)}
    assert all(nb["received"] > 50 for u in (1, 2, 3, 4) for nb in stats[u]["neighbours"].values())


@pytest.mark.e2e
def test_a_pool_that_dies_is_an_event_of_each_of_its_uavs_and_the_other_pool_flies_on(tmp_path: Path) -> None:
    proc = start_run(MINI, tmp_path, ["fleet.pool=2", "duration=30"])
    try:
        rd = run_dir(tmp_path, 60)
        assert wait_for(lambda: (rd / "run.json").exists() and "pool1" in json.loads((rd / "run.json").read_text())["pids"],
                        60, 0.2)
        assert wait_for(lambda: all((rd / f"uav{u}.json").exists() and json.loads((rd / f"uav{u}.json").read_text())["phase"]
                                    == "mission" for u in (1, 2, 3, 4)), 90, 0.5)
        pid = json.loads((rd / "run.json").read_text())["pids"]["pool1"]
        os.killpg(pid, signal.SIGKILL)
        proc.wait(180)
    finally:
        stop_run(proc)
    run = json.loads((rd / "run.json").read_text())
    exits = {e["name"]: e for e in run["events"] if e["event"] == "exited"}
    assert {"uav1", "uav2"} <= set(exits), run["events"]
    assert all(exits[n]["signal"] == "SIGKILL" and "in pool1" in exits[n]["detail"] for n in ("uav1", "uav2"))
    assert not {"uav3", "uav4"} & set(exits)
    # the other pool flew on to the end of the mission
    assert all(json.loads((rd / f"uav{u}.json").read_text())["phase"] in ("mission", "done") for u in (3, 4))


def test_a_pool_is_refused_where_it_cannot_run_with_the_field_named(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="fleet.pool"):
        load_scenario(MINI, ["fleet.pool=2", "runtime=docker"])
    chaos = tmp_path / "chaos.yaml"
    chaos.write_text(MINI.read_text() + "faults:\n  - {kind: kill_uav, uav: 2, at: 5}\n")
    with pytest.raises(ScenarioError, match=r"faults\.0: kill_uav acts on a UAV's process"):
        load_scenario(chaos, ["fleet.pool=2"])
    assert load_scenario(MINI, ["fleet.pool=3"]).fleet.pool == 3  # type: ignore[union-attr]


@pytest.mark.e2e
def test_the_run_goes_on_without_a_late_uav_and_it_joins_when_ready(tmp_path: Path) -> None:
    """A few slow UAVs (here one of ten, stopped before it is ready) do not abort a large run:
    the others take off and fly, the late one is recorded, and it joins once it is ready."""
    proc = start_run(MINI, tmp_path, ["fleet.count=10", "duration=25"])
    try:
        rd = run_dir(tmp_path, 60)
        assert wait_for(lambda: (rd / "run.json").exists() and "uav10" in json.loads((rd / "run.json").read_text())["pids"],
                        60, 0.05)
        pid = json.loads((rd / "run.json").read_text())["pids"]["uav10"]
        os.killpg(pid, signal.SIGSTOP)
        assert wait_for(lambda: bool(json.loads((rd / "run.json").read_text()).get("late")), 120, 0.5)
        os.killpg(pid, signal.SIGCONT)
        proc.wait(240)
    finally:
        stop_run(proc)
    assert proc.returncode == 0, (tmp_path / "run.stdout").read_text()[-3000:]
    summary = json.loads((rd / "summary.json").read_text())
    assert summary["takeoff"]["late"] == {"10": "ready"}
    assert summary["uavs_recorded"] == 10
    # it flew with the others once it was ready
    assert json.loads((rd / "uav10.json").read_text())["mission_started_at"] is not None


def test_auto_pools_a_large_fleet_one_pool_per_core_and_keeps_small_ones_a_process_each() -> None:
    cores = len(os.sched_getaffinity(0))
    assert load_scenario(MINI, ["fleet.count=10"]).pool_size == 1
    big = load_scenario(MINI, ["fleet.count=60", "fleet.spawn.spacing=6"])
    assert big.pool_size == -(-60 // cores)
    assert len(big.pools(big.virtual_uav_configs(big.network, None))) == cores
    assert load_scenario(MINI, ["fleet.count=60", "fleet.spawn.spacing=6", "runtime=docker"]).pool_size == 1
    assert load_scenario(MINI, ["fleet.count=60", "fleet.spawn.spacing=6", "fleet.pool=1"]).pool_size == 1
