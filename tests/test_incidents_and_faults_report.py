"""Incidents and the per-fault table, from a synthetic run folder (the same files a run writes).

Two UAVs fly level at 6 m; UAV 2's motors stop at t = 10 s and it falls; UAV 1 was killed at
t = 4 s and restarted at t = 4.5 s, out of its mission until t = 8 s. `mrswarm results` must list
the incidents, the lost UAV, the fault rows (detection, recovery, coverage lost) and say the run
had safety events (exit code 3 of `mrswarm run`).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from mrswarm.records.summary import FaultRecord, ProcessEvent, RunInfo
from mrswarm.results.incidents import find_incidents
from mrswarm.results.summarise import rebuild_results
from uav_stack.recorder import TrajectoryRecorder

ROOT = Path(__file__).resolve().parents[1]
T0 = 1_700_000_000.0


def fall(t: np.ndarray, t_cut: float, z0: float = 6.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Height, vertical speed and armed flag of a UAV whose motors stop at ``t_cut`` (free fall with drag)."""
    z, vz, armed = np.full_like(t, z0), np.zeros_like(t), np.ones_like(t, dtype=int)
    v, h = 0.0, z0
    for k in range(1, len(t)):
        dt = t[k] - t[k - 1]
        if t[k] >= t_cut:
            armed[k] = 0
            if h > 0.0:
                v += (-9.81 - 0.25 * v) * dt
                h = max(0.0, h + v * dt)
                if h == 0.0:
                    v = 0.0
        z[k], vz[k] = h, v
    return z, vz, armed


def test_a_fall_is_found_as_motors_stopped_uncontrolled_descent_and_ground_impact() -> None:
    t = T0 + np.arange(0.0, 20.0, 0.1)
    z, vz, armed = fall(t, T0 + 10.0)
    got = find_incidents(2, t, z, vz, armed, T0)
    kinds = [i.kind for i in got]
    assert kinds == ["motors_stopped_in_air", "uncontrolled_descent", "ground_impact"]
    assert got[0].t_s == pytest.approx(10.0, abs=0.11) and got[2].vz_ms < -6.0
    # a normal landing at 0.7 m/s, then disarmed on the ground: no incident
    land_z = np.clip(6.0 - 0.7 * np.maximum(0.0, t - T0 - 5.0), 0.0, None)
    land_vz = np.where((land_z > 0) & (t > T0 + 5.0), -0.7, 0.0)
    on_ground = (land_z <= 0.0) & (t > T0 + 15.0)
    assert find_incidents(1, t, land_z, land_vz, np.where(on_ground, 0, 1), T0) == []


def test_heights_count_from_the_uavs_own_ground_not_the_origin() -> None:
    """A real autopilot's home 1.5 m above the swarm origin (a PX4 SITL's, as seen): standing disarmed there before
    and after a flight is no incident; a fall from the air there still is."""
    t = T0 + np.arange(0.0, 30.0, 0.1)
    ground = 1.5
    flying = (t > T0 + 5.0) & (t < T0 + 20.0)
    z = np.where(flying, ground + 10.0, ground)
    assert find_incidents(1, t, z, np.zeros_like(t), flying.astype(int), T0) == []
    fz, fvz, farmed = fall(t, T0 + 10.0)
    farmed[:20] = 0  # on the ground, disarmed, at its first records
    fz[:20] = 0.0
    got = find_incidents(1, t, fz + ground, fvz, farmed, T0)
    assert [i.kind for i in got] == ["motors_stopped_in_air", "uncontrolled_descent", "ground_impact"]


def test_the_summary_lists_incidents_lost_uavs_and_one_row_per_fault(tmp_path: Path) -> None:
    run_dir = tmp_path / "mini_coverage-run"
    run_dir.mkdir()
    shutil.copy(ROOT / "tests" / "scenarios" / "mini_coverage.yaml", run_dir / "scenario.yaml")
    t = T0 + np.arange(0.0, 20.0, 0.1)
    z2, vz2, armed2 = fall(t, T0 + 10.0)
    for uav, y in ((1, -10.0), (2, 10.0)):
        rec = TrajectoryRecorder(run_dir / f"uav{uav}.csv")
        for k, tk in enumerate(t):
            if uav == 1 and T0 + 4.0 < tk < T0 + 4.5:
                continue  # the process was dead
            phase = "mission"
            if uav == 1 and T0 + 4.0 <= tk < T0 + 8.0:
                phase = "takeoff"  # restarted: climbing again
            z, vz, armed = (6.0, 0.0, 1) if uav == 1 else (float(z2[k]), float(vz2[k]), int(armed2[k]))
            rec.write(float(tk), (float(tk), float(tk - T0), -20.0 + 2.0 * (tk - T0), y, z, 2.0, 0.0, vz, 0.0, phase, "OFFBOARD",
                                  armed, 1.0))
        rec.close()
    kill = FaultRecord(index=0, kind="kill_uav", at_s=4.0, targets=[1], injected=T0 + 4.0, ok=True, detail="SIGKILL sent",
                       detected=T0 + 4.1, recovered=T0 + 8.0)
    router = FaultRecord(index=1, kind="kill_router", at_s=12.0, injected=T0 + 12.0, ok=True, detected=T0 + 12.05,
                         recovered=T0 + 13.0)
    late = FaultRecord(index=2, kind="kill_discovery", at_s=19.5)  # the run ended first
    events = [ProcessEvent(t=T0 + 4.05, name="uav1", event="exited", exit_code=-9, signal="SIGKILL",
                           last_pose=[-12.0, -10.0, 6.0]),
              ProcessEvent(t=T0 + 4.5, name="uav1", event="restarted", detail="restart 1"),
              ProcessEvent(t=T0 + 12.02, name="router", event="exited", exit_code=-9, signal="SIGKILL"),
              ProcessEvent(t=T0 + 12.6, name="router", event="restarted")]
    RunInfo(scenario="mini_coverage", started=T0 - 10, mission_start=T0, stopped=T0 + 20, events=events,
            faults=[kill, router, late]).write(run_dir / "run.json")

    s = rebuild_results(run_dir)
    kinds = {(i.uav, i.kind) for i in s.incidents}
    assert kinds == {(2, "motors_stopped_in_air"), (2, "uncontrolled_descent"), (2, "ground_impact")}
    assert s.safety_events == 3
    (lost,) = s.lost_uavs
    assert (lost.uav, lost.signal, lost.restarted_s, lost.injected) == (1, "SIGKILL", 4.5, True)
    assert lost.last_pose == [-12.0, -10.0, 6.0]
    assert [(o.name, o.down_s, o.restarted_s) for o in s.services] == [("router", 12.02, 12.6)]
    rows = {r.kind: r for r in s.faults}
    assert rows["kill_uav"].detection_s == pytest.approx(0.1) and rows["kill_uav"].recovery_s == pytest.approx(4.0)
    # UAV 1 was out of its mission for 4 s: 4 s x 5 m/s (cruise) x 12 m (sensor diameter) / (60 x 40 m) = 10 %
    assert rows["kill_uav"].coverage_lost == pytest.approx(4.0 * 5.0 * 12.0 / 2400.0, abs=0.01)
    assert rows["kill_router"].coverage_lost == 0.0 and rows["kill_router"].collisions == 0
    assert rows["kill_discovery"].detail.startswith("not injected") and rows["kill_discovery"].recovery_s is None
