"""End to end: the coverage mission under netem presets, and a profile change from the CLI mid-run.

Real processes: `mrswarm run` launches the router and one process per virtual UAV, each
with its own Zenoh session and a netem shim on its receive path.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import wait_for
from tests.test_run_e2e import MINI, ROOT, only_run_dir, run_cli

pytestmark = pytest.mark.e2e
COVERAGE = ROOT / "scenarios" / "coverage.yaml"


def fly_coverage(tmp_path: Path, preset: str, duration: float = 40.0) -> dict[str, Any]:
    res = run_cli([str(COVERAGE), "--set", f"network.netem.preset={preset}", "--set", f"duration={duration}"], tmp_path,
                  timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    run_dir = only_run_dir(tmp_path)
    s = json.loads((run_dir / "summary.json").read_text())
    assert s["uavs_recorded"] == 10
    sep = s["separation"]
    assert sep["collisions"] == 0
    assert sep["min_m"] >= sep["safety_distance_m"], sep  # separation never below the safety distance
    assert sep["time_below_safety_s"] == 0.0
    ne = s["network"]["netem"]
    assert len(ne["links"]) == 90 and {r["class"] for r in ne["links"]} == {"v2v"}  # every directed pair, per link
    assert all(r["sent"] > 100 and r["delivered"] > 0 for r in ne["links"])
    assert [c["uavs"] for c in ne["configs"]] == [list(range(1, 11))]
    age = s["network"]["pose_age_over_time"]
    assert len(age["t_s"]) >= duration and (run_dir / "pose_age.png").stat().st_size > 10_000
    return s


def test_coverage_with_10_uavs_under_5g_campus(tmp_path: Path) -> None:
    s = fly_coverage(tmp_path, "5g-campus")
    v2v = s["network"]["netem"]["classes"]["v2v"]
    assert 9.0 <= v2v["delay_ms"]["mean"] <= 12.0  # 9.81 ms one way, plus the odd handover hold
    assert v2v["loss"] < 0.03  # 0.8 % in bursts of 2
    assert s["network"]["transport_age_ms"]["p50"] < 60
    assert s["coverage"]["final"] > 0.3


def test_coverage_with_10_uavs_under_degraded(tmp_path: Path) -> None:
    s = fly_coverage(tmp_path, "degraded")
    v2v = s["network"]["netem"]["classes"]["v2v"]
    assert 95.0 <= v2v["delay_ms"]["mean"] <= 110.0  # 100 ms +- 30 ms, plus 1.5 ms serialisation at 256 kbit/s
    assert 0.06 <= v2v["loss"] <= 0.14  # 10 % in bursts
    assert v2v["dropped_by"].keys() == {"loss"}
    assert 0.06 <= s["network"]["pose_loss"] <= 0.14  # the neighbour tables see the same loss as sequence gaps
    assert s["network"]["transport_age_ms"]["p50"] >= 100
    assert s["coverage"]["final"] > 0.3


def age_rows(run_dir: Path, uav: int) -> list[dict[str, float]]:
    with open(run_dir / f"age_uav{uav}.csv", newline="") as f:
        return [{k: float(v) if v else float("nan") for k, v in r.items()} for r in csv.DictReader(f)]


def uav_phase(run_dir: Path, uav: int) -> str:
    try:
        return json.loads((run_dir / f"uav{uav}.json").read_text())["phase"]
    except (OSError, ValueError, KeyError):
        return "?"


def test_profile_change_from_the_cli_takes_effect_within_one_second(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "mrswarm", "run", str(MINI), "--out", str(tmp_path), "--no-live",
                             "--set", "network.netem.preset=lan", "--set", "duration=25"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert wait_for(lambda: any(tmp_path.glob("*/network.json")), 60.0)
        run_dir = only_run_dir(tmp_path)
        assert wait_for(lambda: all(uav_phase(run_dir, u) == "mission" for u in (1, 2, 3, 4)), 120.0), "mission never started"
        time.sleep(4.0)  # a few seconds of the lan profile first
        t_cli = time.time()
        res = subprocess.run([sys.executable, "-m", "mrswarm", "netem", "set", "--run", str(run_dir), "--class", "v2v",
                              "--delay", "400ms"], cwd=ROOT, capture_output=True, text=True, timeout=60)
        cli_s = time.time() - t_cli
        assert res.returncode == 0, res.stdout + res.stderr
        assert "4/4 UAVs applied it" in res.stdout
        out, _ = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, out[-3000:]
    s = json.loads((run_dir / "summary.json").read_text())
    change = [c for c in s["network"]["netem"]["changes"] if c["source"] == "cli"]
    assert len(change) == 1 and change[0]["uavs"] == 4
    t_sent = change[0]["t_sent"]
    assert change[0]["latency_max_s"] <= 1.0  # published -> applied on every UAV
    print(f"CLI wall time {cli_s:.2f} s; published -> applied on all 4 UAVs in {change[0]['latency_max_s'] * 1000:.0f} ms")
    for u in (1, 2, 3, 4):
        rows = age_rows(run_dir, u)
        before = [r for r in rows if t_sent - 3.0 <= r["t_wall"] <= t_sent and r["poses"] > 0]
        after = [r for r in rows if t_sent + 2.0 <= r["t_wall"] and r["poses"] > 0]  # each row covers the second before it
        assert before and after
        assert max(r["transport_mean_ms"] for r in before) < 200
        # every pose delivered from 1 s after the command on carries the new 400 ms delay
        assert min(r["transport_mean_ms"] for r in after) >= 400 - 40
