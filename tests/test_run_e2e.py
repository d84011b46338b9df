"""End to end: `mrswarm run` launches real UAV processes, flies, stops them all, summarises."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from itertools import pairwise
from pathlib import Path

import pytest

from swarmnet.connectivity import LEAN_ZENOH_RUNTIME
from tests.conftest import wait_for

ROOT = Path(__file__).resolve().parents[1]
MINI = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"

pytestmark = pytest.mark.e2e


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is dead for our purpose
        return open(f"/proc/{pid}/stat").read().split()[2] != "Z"
    except OSError:
        return False


def run_cli(args: list[str], out: Path, timeout: float) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mrswarm", "run", *args, "--out", str(out), "--no-live"],
                          cwd=ROOT, capture_output=True, text=True, timeout=timeout)


def only_run_dir(out: Path) -> Path:
    dirs = [d for d in out.iterdir() if d.is_dir()]
    assert len(dirs) == 1, dirs
    return dirs[0]


def test_short_coverage_run_covers_without_collisions_and_leaves_nothing_behind(tmp_path: Path) -> None:
    res = run_cli([str(MINI)], tmp_path, timeout=180)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    run_dir = only_run_dir(tmp_path)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["uavs_recorded"] == 4
    cov = summary["coverage"]
    assert cov["final"] > 0.3
    curve = [c for _, c in cov["curve"]]
    assert curve[-1] > curve[0] and all(b >= a for a, b in pairwise(curve))  # coverage only grows
    assert summary["separation"]["collisions"] == 0
    assert summary["separation"]["min_m"] > 1.0
    assert summary["rtf"]["min"] > 0.8
    net = summary["network"]
    assert net["transport_age_ms"]["n"] > 100 and net["use_age_ms"]["n"] > 100
    # ages are never negative, from the first second on: stamped on arrival, on one host's clock
    assert net["negative_ages"] == {}
    for path in run_dir.glob("age_uav*.csv"):
        rows = list(csv.DictReader(path.open()))
        assert rows and all(float(r[k]) >= 0.0 for r in rows for k in ("transport_p50_ms", "transport_mean_ms", "use_p50_ms")
                            if r[k] != "")
    assert net["transport_age_links"]["links"] == 12  # 4 UAVs, every ordered pair
    # every UAV ran all of Zenoh on one worker thread (swarmnet.connectivity.lean_zenoh_runtime)
    status = [json.loads(p.read_text()) for p in run_dir.glob("uav[0-9]*.json")]
    assert len(status) == 4
    assert {st["net"]["zenoh_runtime"] for st in status} == {LEAN_ZENOH_RUNTIME}
    takeoff = summary["takeoff"]
    assert takeoff["acked_s"] is not None and takeoff["all_airborne_s"] > takeoff["acked_s"]
    assert (run_dir / "mini_coverage.png").stat().st_size > 10_000
    run = json.loads((run_dir / "run.json").read_text())
    # discovery is the default; the edge router runs beside it as the way in for ground stations; the flight
    # recorder is supervised with them
    assert set(run["pids"]) == {"discovery", "router", "recorder", "uav1", "uav2", "uav3", "uav4"}
    assert summary["degraded"] == [] and summary["stalls"] == [] and summary["recording"]["gaps"] == []
    assert not [n for n, pid in run["pids"].items() if alive(pid)], "processes left behind"
    assert "coverage" in res.stdout and "collisions" in res.stdout  # the printed summary
    # without a terminal: a line per stage and milestone, progress with the mission clock, coverage, separation and
    # RTF, and no line twice
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("[")]
    assert len(lines) == len(set(lines)), "\n".join(lines)
    assert {"[waiting for UAVs]", "[taking off]", "[mission]", "[stopping]"} <= set(lines), "\n".join(lines)
    assert sum("acknowledged by all 4" in ln for ln in lines) == 2  # takeoff, start: once each
    progress = [ln for ln in lines if ln.startswith("[mission] ") and " of 20 s" in ln]
    assert len(progress) >= 2, "\n".join(lines)
    assert all("coverage" in ln and "separation" in ln and "RTF 1.0" in ln for ln in progress[1:]), "\n".join(progress)


def test_ctrl_c_stops_every_process_and_still_summarises(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "mrswarm", "run", str(MINI), "--out", str(tmp_path), "--no-live",
                             "--set", "duration=120"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert wait_for(lambda: any(tmp_path.glob("*/uav1.csv")), 60.0), "UAVs never started recording"
        time.sleep(3.0)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out[-3000:]
    run_dir = only_run_dir(tmp_path)
    run = json.loads((run_dir / "run.json").read_text())
    assert run["interrupted"] is True
    assert not [n for n, pid in run["pids"].items() if alive(pid)], "processes left behind"
    assert (run_dir / "summary.json").exists()


def test_a_uav_that_cannot_start_is_lost_with_its_reason_and_the_others_fly(tmp_path: Path) -> None:
    """Another process holds UAV 3's ground-station port: UAV 3 exits at start with one line that
    names the setting; the runner prints that line with the exit, the summary keeps it, and the
    three others fly the mission (exit code 0)."""
    import socket

    from discovery.netutil import free_port

    base = free_port(socket.SOCK_DGRAM) - 3  # UAV i listens on base + i: UAV 3 on the held port
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        holder.bind(("127.0.0.1", base + 3))
        res = run_cli([str(MINI), "--set", f"gcs.listen_base={base}", "--set", "duration=10"], tmp_path, timeout=180)
    finally:
        holder.close()
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    why = f"gcs.mavlink_endpoints: udpin:127.0.0.1:{base + 3}: cannot listen on 127.0.0.1:{base + 3}: Address already in use"
    assert f"uav3 exited (exit code 2): {why}" in " ".join(res.stdout.split()), res.stdout[-3000:]
    run_dir = only_run_dir(tmp_path)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert [(lu["uav"], lu["exit_code"], lu["error"]) for lu in summary["lost_uavs"]] == [(3, 2, why)]
    assert summary["uavs_recorded"] == 3 and summary["coverage"]["final"] > 0.0
    assert summary["separation"]["collisions"] == 0


def test_bad_scenario_fails_fast_with_the_field_name(tmp_path: Path) -> None:
    res = run_cli([str(MINI), "--set", "flight.altitude=500"], tmp_path, timeout=60)
    assert res.returncode == 2
    assert "flight.altitude" in res.stdout + res.stderr


def test_two_uavs_that_pass_closer_than_the_safety_distance_are_an_incident_and_the_run_exits_3(tmp_path: Path) -> None:
    """Head-on without collision avoidance, on lanes 3 m apart: no collision (1 m), but under the 5 m safety distance."""
    lanes = ["flight.avoidance=false", "uavs.0.start=[-20, 1.5]", "uavs.0.goal=[20, 1.5]", "uavs.1.start=[20, -1.5]",
             "uavs.1.goal=[-20, -1.5]"]
    res = run_cli([str(ROOT / "scenarios" / "head_on.yaml"), *[a for s in lanes for a in ("--set", s)]], tmp_path, timeout=240)
    assert res.returncode == 3, res.stdout[-3000:] + res.stderr[-3000:]
    s = json.loads((only_run_dir(tmp_path) / "summary.json").read_text())
    assert s["separation"]["collisions"] == 0 and 2.0 < s["separation"]["min_m"] < 4.0, s["separation"]
    (inc,) = s["incidents"]
    assert inc["kind"] == "below_safety_distance" and inc["pair"] == [1, 2], inc
    assert inc["min_m"] == pytest.approx(s["separation"]["min_m"], abs=0.01) and 0.2 < inc["duration_s"] < 3.0, inc
    assert "UAVs 1 and 2 below the safety distance at" in " ".join(res.stdout.split())


def test_head_on_at_three_rtfs_meets_closer_to_the_slow_uav(tmp_path: Path) -> None:
    """The paper's Fig. 8: throttling the virtual UAV moves the meeting point towards its start."""
    meet_x = {}
    for rtf in (1.0, 0.7, 0.4):
        out = tmp_path / f"rtf{rtf}"
        res = run_cli([str(ROOT / "scenarios" / "head_on.yaml"), "--set", f"uavs.1.rtf={rtf}"], out, timeout=240)
        assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
        s = json.loads((only_run_dir(out) / "summary.json").read_text())
        assert s["separation"]["collisions"] == 0
        assert s["separation"]["min_m"] >= s["separation"]["safety_distance_m"]
        assert all(g["reached"] for g in s["goals"].values()), s["goals"]
        assert s["rtf"]["per_uav"]["2"] == pytest.approx(rtf, abs=0.05)
        meet_x[rtf] = s["encounter"]["meeting_point"][0]  # UAV 2 starts at x = +20, UAV 1 at x = -20
    assert abs(meet_x[1.0]) < 4.0  # equal speeds: they meet in the middle
    assert meet_x[1.0] < meet_x[0.7] < meet_x[0.4]
    assert meet_x[0.4] > 8.0
