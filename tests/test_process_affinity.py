"""UAV processes pinned to CPUs (``process.cpu_affinity``, deploy/process_runtime.py), with real processes.

Children are small Python programs started the way the process runtime starts every child; each
starts a thread, as a UAV's Zenoh session does, and writes down where the thread may run. The
tests check what a user relies on: each UAV process (all its threads) on one CPU, the fleet
spread evenly, a restarted UAV back on its CPU, the services left to the scheduler, and
``none`` leaving everything alone.
"""

from __future__ import annotations

import collections
import json
import os
import sys
from pathlib import Path

import pytest
import yaml

from deploy.process_runtime import ProcessRuntime
from deploy.settings import ProcessSettings
from mrswarm.scenario import ScenarioError, parse_scenario
from tests.conftest import wait_for

# a thread started after exec, as Zenoh's are, reports where it may run; then the child sleeps
REPORTER = """
import json, os, sys, threading, time
out = {}
def note():
    out["thread"] = sorted(os.sched_getaffinity(threading.get_native_id()))
t = threading.Thread(target=note); t.start(); t.join()
out["process"] = sorted(os.sched_getaffinity(0))
tmp = sys.argv[1] + ".tmp"
with open(tmp, "w") as f:
    json.dump(out, f)
os.replace(tmp, sys.argv[1])
time.sleep(120)
"""

CPUS = sorted(os.sched_getaffinity(0))
needs_two = pytest.mark.skipif(len(CPUS) < 2, reason="pinning needs a machine with two CPUs or more")


def spawn_reporters(rt: ProcessRuntime, tmp_path: Path, names: list[str]) -> dict[str, dict[str, list[int]]]:
    for name in names:
        (tmp_path / f"{name}.json").unlink(missing_ok=True)
        rt._spawn(name, [sys.executable, "-c", REPORTER, str(tmp_path / f"{name}.json")])
    assert wait_for(lambda: all((tmp_path / f"{n}.json").exists() for n in names), timeout=20.0)
    return {n: json.loads((tmp_path / f"{n}.json").read_text()) for n in names}


@needs_two
def test_spread_pins_each_uav_process_and_its_threads_to_one_cpu_in_turn(tmp_path: Path) -> None:
    rt = ProcessRuntime(tmp_path, settings=ProcessSettings(cpu_affinity="spread"))
    uavs = [f"uav{i}" for i in range(1, 2 * len(CPUS) + 2)]
    try:
        seen = spawn_reporters(rt, tmp_path, ["router", *uavs])
        for name in uavs:
            assert len(seen[name]["process"]) == 1, f"{name} not pinned: {seen[name]}"
            assert seen[name]["thread"] == seen[name]["process"], f"{name}'s thread left its CPU"
        # round-robin in the order of start: the counts per CPU differ by one at most
        per_cpu = collections.Counter(seen[n]["process"][0] for n in uavs)
        assert set(per_cpu) == set(CPUS) and max(per_cpu.values()) - min(per_cpu.values()) <= 1
        assert [seen[n]["process"][0] for n in uavs[:len(CPUS)]] == CPUS
        # the edge router is a service: the scheduler places it
        assert seen["router"]["process"] == CPUS
        # a restarted UAV comes back on the CPU it had, keeping the spread even
        before = seen["uav2"]["process"]
        (tmp_path / "uav2.json").unlink()
        rt.restart("uav2", grace=2.0)
        assert wait_for(lambda: (tmp_path / "uav2.json").exists(), timeout=20.0)
        assert json.loads((tmp_path / "uav2.json").read_text())["process"] == before
        assert rt.children["uav2"].starts == 2
    finally:
        rt.stop(grace=2.0)


def test_none_leaves_every_process_to_the_scheduler(tmp_path: Path) -> None:
    rt = ProcessRuntime(tmp_path, settings=ProcessSettings(cpu_affinity="none"))
    try:
        seen = spawn_reporters(rt, tmp_path, ["uav1", "uav2", "uav3"])
        assert all(s["process"] == CPUS and s["thread"] == CPUS for s in seen.values())
    finally:
        rt.stop(grace=2.0)


@needs_two
def test_a_runner_held_to_one_cpu_pins_nothing(tmp_path: Path) -> None:
    """Under ``taskset -c 0`` (or a container's one CPU) there is nothing to spread over: the
    UAVs run where the runner may, and nothing asks for a CPU the runner cannot have."""
    os.sched_setaffinity(0, {CPUS[-1]})
    try:
        rt = ProcessRuntime(tmp_path)
    finally:
        os.sched_setaffinity(0, CPUS)
    try:
        seen = spawn_reporters(rt, tmp_path, ["uav1", "uav2"])
        assert all(s["process"] == CPUS for s in seen.values())  # the runner's own affinity is back
        assert rt.cpu_of == {}
    finally:
        rt.stop(grace=2.0)


def test_the_scenario_names_a_wrong_affinity() -> None:
    text = """
name: t
duration: 10
origin: {lat: 46.6, lon: 14.2, alt: 446}
mission: {type: coverage, area: {x_min: -10, x_max: 10, y_min: -10, y_max: 10}}
fleet: {count: 2}
process: {cpu_affinity: sometimes}
"""
    with pytest.raises(ScenarioError, match=r"process\.cpu_affinity"):
        parse_scenario(yaml.safe_load(text), "t.yaml")
    scn = parse_scenario(yaml.safe_load(text.replace("sometimes", "none")), "t.yaml")
    assert scn.process.cpu_affinity == "none"
    default = parse_scenario(yaml.safe_load(text.replace("process: {cpu_affinity: sometimes}\n", "")), "t.yaml")
    assert default.process.cpu_affinity == "spread"
