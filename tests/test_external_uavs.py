"""UAVs whose flight controller is external (a real autopilot, a SITL, a Pixhawk): in a scenario, in a run, in its results.

The scenario's schema and its errors; the analysis of a run folder holding a UAV the run did not
simulate (the real UAV's records beside a virtual one's: this once crashed ``encounter_report``
with ``KeyError: 1``), and of one whose agent recorded on its companion computer (its trajectory
then comes from the flight recording). End to end, with real processes and real UDP MAVLink: a
standalone virtual FCU process (``python -m uav_stack.fcu``, PX4 flavour) stands in for the real
autopilot, since CI has none; ``mrswarm run scenarios/head_on_external.yaml`` starts the agent
against it, or waits for one a "companion" (this test) starts from the configuration the run
wrote, and the summary counts the external UAV's separation and encounter.
"""

from __future__ import annotations

import asyncio
import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from websockets.asyncio.client import connect
from websockets.typing import Origin

from mrswarm.recorder.capture import Sample
from mrswarm.recorder.export import export_jsonl
from mrswarm.recorder.mcap_writer import McapWriter
from mrswarm.recorder.records import Translator
from mrswarm.records.summary import RunInfo
from mrswarm.results.summarise import rebuild_results
from mrswarm.scenario import ScenarioError, load_scenario
from swarmnet.messages import AgentState, Pose, Realm, encode_pose, encode_state
from tests.conftest import free_port, wait_for
from tests.run_helpers import BackgroundRun
from uav_stack.config import NetworkConfig
from uav_stack.phases import AgentPhase
from uav_stack.recorder import TrajectoryRecorder

ROOT = Path(__file__).resolve().parents[1]
HEAD_ON = ROOT / "scenarios" / "head_on.yaml"
EXTERNAL = ROOT / "scenarios" / "head_on_external.yaml"
T0 = 1_700_000_000.0


# ---- the scenario ---------------------------------------------------------------------------------
def test_head_on_external_flies_one_external_and_one_virtual_uav() -> None:
    s = load_scenario(EXTERNAL)
    one, two = s.uav_list()
    assert (one.external, one.fcu, one.realm, one.agent, one.wait_s) == (True, "udpin:127.0.0.1:14540", "physical", "runner",
                                                                         120.0)
    assert (two.external, two.realm) == (False, "virtual")
    home = s.start_geodetic(one)  # the autopilot's home goes where the UAV starts: here the origin
    assert (home.lat, home.lon, home.alt) == pytest.approx((s.origin.lat, s.origin.lon, s.origin.alt))
    net = NetworkConfig(endpoints=("tls/127.0.0.1:7447",))
    assert [c.agent.uav for c in s.virtual_uav_configs(net, "/r")] == [2]  # no virtual FCU for UAV 1
    agent, = s.external_agent_configs(net, "/r")
    assert (agent.uav, agent.fcu, agent.realm, agent.record_dir, agent.network) == (1, "udpin:127.0.0.1:14540", "physical",
                                                                                   "/r", net)
    assert agent.mission.type == "goto" and agent.mission.goal == (40.0, 0.0) and agent.gcs.mavlink_endpoints
    sitl = load_scenario(EXTERNAL, ["uavs.0.fcu=tcp:127.0.0.1:5760", "uavs.0.realm=virtual"])  # a SITL flown as virtual
    assert sitl.external_agent_configs(net, None)[0].realm == "virtual"


@pytest.mark.parametrize("override,message", [
    ("uavs.0.fcu=udpin:14540", "uavs.0.fcu: udpin:14540: expected udpin:HOST:PORT"),
    ("uavs.0.fcu=COM3", "uavs.0.fcu: COM3: unknown scheme"),
    ("uavs.0.rtf=0.5", "uavs.0.rtf: the real-time factor of a virtual FCU; UAV 1's flight controller is external"),
    ("uavs.0.flavour=ardupilot", "uavs.0.flavour: the autopilot a virtual FCU emulates"),
    ("uavs.0.heading=90", "uavs.0.heading: a virtual FCU's initial heading"),
    ("uavs.0.agent=pilot", "uavs.0.agent: must be one of runner, companion, got 'pilot'"),
    ("uavs.0.wait_s=0", "uavs.0.wait_s: must be a number in (0, 3600]"),
    ("uavs.1.realm=physical", "uavs.1.realm: only for a UAV whose flight controller is external: give its fcu"),
    ("uavs.1.agent=companion", "uavs.1.agent: only for a UAV whose flight controller is external"),
    ("uavs.1.wait_s=10", "uavs.1.wait_s: only for a UAV whose flight controller is external"),
    ("runtime=docker", "uavs.0.fcu: UAV 1's flight controller is external: its agent runs as a process"),
    ("faults=[{kind: kill_uav, at: 5, uav: 1}]", "faults.0: UAV 1's flight controller is external: faults are injected into "
                                                  "virtual UAVs only"),
])
def test_a_bad_external_uav_is_refused_naming_the_field(override: str, message: str) -> None:
    with pytest.raises(ScenarioError) as ex:
        load_scenario(EXTERNAL, [override])
    assert str(ex.value).startswith(f"{EXTERNAL}: ") and message in str(ex.value), ex.value


# ---- the analysis -------------------------------------------------------------------------------
def record(run_dir: Path, uav: int, xyz: np.ndarray, t: np.ndarray) -> None:
    rec = TrajectoryRecorder(run_dir / f"uav{uav}.csv")
    for k in range(len(t)):
        x, y, z = xyz[k]
        rec.write(float(t[k]), (float(t[k]), float(t[k] - t[0]), float(x), float(y), float(z), 0.0, 0.0, 0.0, 0.0,
                                str(AgentPhase.MISSION), "OFFBOARD", 1, 1.0))
    rec.close()


def head_on_tracks() -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """UAV 1 from (0, 0.3) east and UAV 2 from (40, -0.3) west at 5 m/s, 10 m up: 0.6 m apart at x = 20, t = 4 s."""
    t = T0 + np.arange(0.0, 8.0, 0.1)
    x = 5.0 * (t - T0)
    return t, {1: np.stack([x, np.full_like(t, 0.3), np.full_like(t, 10.0)], axis=1),
               2: np.stack([40.0 - x, np.full_like(t, -0.3), np.full_like(t, 10.0)], axis=1)}


def run_folder(tmp_path: Path, scenario: dict[str, object]) -> Path:
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "scenario.yaml").write_text(yaml.safe_dump(scenario))
    RunInfo(scenario=str(scenario["name"]), started=T0 - 20, mission_start=T0, stopped=T0 + 9).write(run_dir / "run.json")
    return run_dir


def test_a_real_uavs_records_beside_a_virtual_one_count_and_do_not_crash_the_encounter(tmp_path: Path) -> None:
    """The run flew only virtual UAV 2; the real UAV 1's own records were copied into the folder."""
    data = yaml.safe_load(HEAD_ON.read_text())
    data["uavs"] = [{"id": 2, "start": [40, 0], "goal": [0, 0], "heading": 270}]
    run_dir = run_folder(tmp_path, data)
    t, xyz = head_on_tracks()
    for uav in (1, 2):
        record(run_dir, uav, xyz[uav], t)
    s = rebuild_results(run_dir)
    assert s.uavs_recorded == 2 and s.uavs_planned == 1
    assert s.separation and s.separation.min_pair == [1, 2] and s.separation.min_m == pytest.approx(0.6, abs=0.01)
    assert s.separation.collisions == 1
    enc = s.encounter
    assert enc and enc.meeting_point == pytest.approx([20.0, 0.0], abs=0.05)
    # UAV 1 is not in the scenario: its start is its first recorded position (0, 0.3); UAV 2's its spawn point
    assert enc.distance_from_start_m == pytest.approx({"1": 20.0, "2": 20.0}, abs=0.05)
    assert "external_uavs" not in json.loads((run_dir / "summary.json").read_text())  # the scenario lists none


def write_recording(path: Path, swarm: str, uav: int, xyz: np.ndarray, t: np.ndarray) -> None:
    """A flight recording of one UAV's shared poses and states, through the recorder's own translation and writer."""
    tr, w = Translator(swarm), McapWriter(path)
    for k in range(len(t)):
        x, y, z = (float(v) for v in xyz[k])
        pose = Pose(uav=uav, realm=Realm.PHYSICAL, seq=k, t_sim=float(t[k] - t[0]), t_wall=float(t[k]), x=x, y=y, z=z,
                    vx=0.0, vy=0.0, vz=0.0, yaw=0.0)
        state = AgentState(uav, Realm.PHYSICAL, k, float(t[k]), str(AgentPhase.MISSION), "goto")
        for rec in tr.translate([Sample(f"mrs/{swarm}/{uav}/state", encode_state(state), float(t[k])),
                                 Sample(f"mrs/{swarm}/{uav}/pose", encode_pose(pose), float(t[k]) + 0.002)]):
            w.write(rec)
    w.close()


def test_a_companions_trajectory_comes_from_the_flight_recording(tmp_path: Path) -> None:
    """UAV 1's agent ran on its companion computer and recorded there: the run folder has no uav1.csv, but the
    recording holds the poses it shared, and those count."""
    data = yaml.safe_load(EXTERNAL.read_text())
    data["uavs"][0]["agent"] = "companion"
    run_dir = run_folder(tmp_path, data)
    t, xyz = head_on_tracks()
    record(run_dir, 2, xyz[2], t)
    s = rebuild_results(run_dir)  # no recording yet: UAV 1 is missing, and the summary says what to do
    ext, = s.external_uavs or []
    assert (ext.uav, ext.agent, ext.trajectory) == (1, "companion", "none") and "copy uav1.csv from its companion" in ext.detail
    assert s.separation and s.separation.min_m is None and s.uavs_recorded == 1
    write_recording(run_dir / "run.mcap", str(data["swarm"]), 1, xyz[1], t)
    s = rebuild_results(run_dir)
    ext, = s.external_uavs or []
    assert (ext.realm, ext.fcu, ext.trajectory) == ("physical", "udpin:127.0.0.1:14540", "recording")
    assert s.uavs_recorded == 2 and s.separation and s.separation.min_pair == [1, 2]
    assert s.separation.min_m == pytest.approx(0.6, abs=0.02) and s.separation.collisions == 1
    assert s.encounter and s.encounter.distance_from_start_m == pytest.approx({"1": 20.0, "2": 20.0}, abs=0.1)
    assert s.goals and s.goals["1"].reached and s.goals["2"].reached
    assert not (run_dir / "uav1.csv").exists()  # nothing written in the agent's name
    on_disk = json.loads((run_dir / "summary.json").read_text())
    assert on_disk["external_uavs"][0]["trajectory"] == "recording"


# ---- end to end ---------------------------------------------------------------------------------
def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_fcu(remote_port: int, home: tuple[float, float, float], sysid: int = 1) -> subprocess.Popen[str]:
    """The stand-in for the real autopilot: a standalone virtual FCU process (PX4 flavour) sending to the agent's udpin port."""
    lat, lon, alt = home
    fcu = subprocess.Popen([sys.executable, "-m", "uav_stack.fcu", "--sysid", str(sysid), "--listen", "127.0.0.1:0",
                            "--remote", f"127.0.0.1:{remote_port}", f"--home={lat},{lon},{alt}", "--flavour", "px4",
                            "--duration", "300"],
                           cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    line = fcu.stdout.readline() if fcu.stdout else ""
    assert line.startswith("LISTEN"), line
    return fcu


def stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def web_map_uavs(run_dir: Path, want: set[int], timeout: float = 40.0) -> dict[int, dict[str, Any]]:
    """The UAVs ``mrswarm gcs web --run`` shows (its WebSocket's state pushes), once all of ``want`` are in one."""
    port = free_port()
    web = subprocess.Popen([sys.executable, "-m", "mrswarm", "gcs", "web", "--run", str(run_dir), "--port", str(port),
                            "--duration", str(timeout + 20)],
                           cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)

    async def read() -> dict[int, dict[str, Any]]:
        deadline = time.monotonic() + timeout
        last: dict[int, dict[str, Any]] = {}
        while time.monotonic() < deadline:
            try:
                async with connect(f"ws://127.0.0.1:{port}/ws", origin=Origin(f"http://127.0.0.1:{port}")) as ws:
                    while time.monotonic() < deadline:
                        m = json.loads(await asyncio.wait_for(ws.recv(), 5.0))
                        if m["type"] == "state":
                            last = {int(u["id"]): u for u in m["uavs"]}
                            if want <= set(last):
                                return last
            except (TimeoutError, OSError):
                await asyncio.sleep(0.3)  # not serving yet
        return last

    try:
        return asyncio.run(read())
    finally:
        stop(web)


def recorded_poses(run_dir: Path, uav: int) -> list[dict[str, Any]]:
    out = run_dir / "poses.jsonl"
    export_jsonl(run_dir / "run.mcap", out)
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    return [r for r in rows if r["kind"] == "pose" and r["uav"] == uav]


def check_head_on_summary(run_dir: Path, agent: str, trajectory: str) -> dict[str, object]:
    """What a user of Fig. 8 reads: the external UAV 1 is in the separation and the encounter, reached its goal, and flew
    in the recording under its own realm."""
    s = json.loads((run_dir / "summary.json").read_text())
    assert s["uavs_recorded"] == 2 and s["aborted"] is None, s
    ext, = s["external_uavs"]
    assert (ext["uav"], ext["realm"], ext["agent"], ext["trajectory"]) == (1, "physical", agent, trajectory), ext
    sep = s["separation"]
    assert sep["min_pair"] == [1, 2] and sep["collisions"] == 0
    assert 1.0 < sep["min_during_mission_m"] < 30.0  # they met: closer than the 40 m they started apart
    enc = s["encounter"]
    assert enc is not None and set(enc["distance_from_start_m"]) == {"1", "2"}
    assert 5.0 < enc["distance_from_start_m"]["1"] < 35.0  # UAV 1 flew out to meet UAV 2
    assert s["goals"]["1"]["reached"] and s["goals"]["2"]["reached"]
    poses = recorded_poses(run_dir, 1)
    assert len(poses) > 50 and {p["realm"] for p in poses} == {"physical"}
    assert max(float(p["z"]) for p in poses) > 8.0  # airborne at the mission altitude (10 m)
    return s


@pytest.mark.e2e
def test_fig8_with_an_external_fcu_counts_it_in_separation_encounter_trajectory_and_recording(tmp_path: Path) -> None:
    """``mrswarm run scenarios/head_on_external.yaml`` against a flight controller that is not the run's own: the runner
    starts UAV 1's agent against it, flies both, lands UAV 1, and every result counts it."""
    port = free_udp_port()
    scn = load_scenario(EXTERNAL)
    fcu = start_fcu(port, (scn.origin.lat, scn.origin.lon, scn.origin.alt))
    run = BackgroundRun(EXTERNAL, tmp_path / "out", sets=[f"uavs.0.fcu=udpin:127.0.0.1:{port}", "gcs.mavlink=false"])
    try:
        run.wait_mission(timeout=150)
        run_dir = run.run_dir()
        assert run_dir is not None
        shown = web_map_uavs(run_dir, {1, 2})  # the live map, as a ground station opens it during the run
        assert {u: v["realm"] for u, v in shown.items()} == {1: "physical", 2: "virtual"}, shown
        code = run.wait(240)
        assert code == 0, run.output[-3000:]
        assert f"UAV 1: agent against the external flight controller udpin:127.0.0.1:{port}" in run.output
        check_head_on_summary(run_dir, "runner", "agent")
        rows = (run_dir / "uav1.csv").read_text().splitlines()  # its agent's own trajectory, in the run folder
        assert rows[0].startswith("t_wall,") and len(rows) > 100
        assert rows[-1].split(",")[9] == "landed"  # landed by the runner before its agent stopped
        assert "external UAVs on the ground" in run.output
        info = json.loads((run_dir / "run.json").read_text())
        assert "uav1" in info["pids"] and info["exit_codes"]["uav1"] == 0
        argv = (run_dir / "logs" / "uav1.log").read_text()
        assert "uav_stack.flight: UAV 1: landing -> landed" in argv  # the agent's flight, in its own log
    finally:
        run.cleanup()
        stop(fcu)


@pytest.mark.e2e
def test_fig8_with_a_companion_agent_that_the_run_waits_for(tmp_path: Path) -> None:
    """``agent: companion``: the run writes UAV 1's configuration and waits; a companion (here this test, on this machine)
    starts the FCU and ``mrswarm agent --config`` with it, and the UAV counts from the poses it shared."""
    port = free_udp_port()
    scn = load_scenario(EXTERNAL)
    run = BackgroundRun(EXTERNAL, tmp_path / "out", sets=[f"uavs.0.fcu=udpin:127.0.0.1:{port}", "uavs.0.agent=companion",
                                                           "uavs.0.wait_s=90", "gcs.mavlink=false"])
    fcu = agent = None
    try:
        assert wait_for(lambda: run.run_dir() is not None and (run.run_dir() / "config" / "uav1.json").exists()  # type: ignore[operator]
                        or run.proc.poll() is not None, 60.0, 0.1), run.output[-3000:]
        run_dir = run.run_dir()
        assert run_dir is not None and run.proc.poll() is None, run.output[-3000:]
        config = run_dir / "config" / "uav1.json"
        assert config.stat().st_mode & 0o077 == 0  # it holds the discovery key
        assert wait_for(lambda: f"mrswarm agent --config {config}" in run.output, 20.0, 0.1), run.output[-3000:]
        fcu = start_fcu(port, (scn.origin.lat, scn.origin.lon, scn.origin.alt))
        agent = subprocess.Popen([sys.executable, "-m", "mrswarm", "agent", "--config", str(config), "--duration", "200"],
                                 cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
        code = run.wait(240)
        assert code == 0, run.output[-3000:]
        check_head_on_summary(run_dir, "companion", "recording")
        assert not (run_dir / "uav1.csv").exists()  # the companion recorded nothing here: the recording counted it
    finally:
        run.cleanup()
        for p in (agent, fcu):
            if p is not None:
                stop(p)


@pytest.mark.e2e
def test_a_companion_that_never_comes_ends_the_wait_in_time_saying_what_to_start(tmp_path: Path) -> None:
    run = BackgroundRun(EXTERNAL, tmp_path / "out", sets=["uavs.0.agent=companion", "uavs.0.wait_s=8", "gcs.mavlink=false"])
    try:
        t0 = time.monotonic()
        code = run.wait(120)
        assert code == 1, run.output[-3000:]
        assert time.monotonic() - t0 < 90
        out = " ".join(run.output.split())  # unfolded
        assert "run aborted: timed out after" in out and "UAV 1 (agent on its companion computer)" in out, out[-3000:]
        assert "its agent never joined the swarm: start `mrswarm agent --config" in out and "raise uavs[].wait_s (8 s)" in out
        run_dir = run.run_dir()
        assert run_dir is not None
        s = json.loads((run_dir / "summary.json").read_text())
        assert "UAV 1" in s["aborted"] and s["external_uavs"][0]["trajectory"] == "none"
    finally:
        run.cleanup()


@pytest.mark.e2e
def test_ctrl_c_mid_mission_lands_the_external_uav_before_stopping_its_agent(tmp_path: Path) -> None:
    """A real UAV is not left in the air by a stopped run: on the first Ctrl-C the runner lands it, then stops every process."""
    port = free_udp_port()
    scn = load_scenario(EXTERNAL)
    fcu = start_fcu(port, (scn.origin.lat, scn.origin.lon, scn.origin.alt))
    run = BackgroundRun(EXTERNAL, tmp_path / "out", sets=[f"uavs.0.fcu=udpin:127.0.0.1:{port}", "gcs.mavlink=false"])
    try:
        run.wait_mission(timeout=120, after=2.0)
        run.signal(signal.SIGINT)
        code = run.wait(120)
        assert code == 130, run.output[-3000:]
        out = " ".join(run.output.split())
        assert "landing UAV 1 (external flight controller) before stopping (stop again to skip)" in out, out[-3000:]
        assert "external UAVs on the ground" in out
        run_dir = run.run_dir()
        assert run_dir is not None
        last = (run_dir / "uav1.csv").read_text().splitlines()[-1].split(",")
        assert last[9] == "landed" and float(last[4]) < 0.5, last  # phase, z
        s = json.loads((run_dir / "summary.json").read_text())
        assert s["interrupted"] and s["external_uavs"][0]["trajectory"] == "agent"
    finally:
        run.cleanup()
        stop(fcu)
