"""The results of a run folder: analysis, figures and summary.json, from files written the way a run writes them.

The run folders here are made with the UAVs' own recorder (uav_stack/recorder.py) and the
scenario files the runner saves, from trajectories whose outcome is known: two UAVs flying
head-on that pass 0.6 m apart (a collision), and a coverage mission whose UAVs sweep part of
the field. ``mrswarm results`` then runs as a user would, as a real subprocess.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest

from groundfloor.histogram import LogHistogram
from mrswarm.records.summary import RunInfo, RunSummary
from mrswarm.results.summarise import ResultsError, rebuild_results, summarise_run
from mrswarm.scenario import Scenario, load_scenario
from uav_stack.phases import AgentPhase
from uav_stack.recorder import TrajectoryRecorder, links_file_name

ROOT = Path(__file__).resolve().parents[1]
T0 = 1_700_000_000.0  # wall time of the mission start in the synthetic runs


def record(run_dir: Path, uav: int, xyz: np.ndarray, phases: list[AgentPhase], t: np.ndarray, rtf: float = 1.0) -> None:
    rec = TrajectoryRecorder(run_dir / f"uav{uav}.csv")
    for k in range(len(t)):
        x, y, z = xyz[k]
        rec.write(float(t[k]), (float(t[k]), float((t[k] - t[0]) * rtf), float(x), float(y), float(z), 0.0, 0.0, 0.0, 0.0,
                                str(phases[k]), "OFFBOARD", 1, rtf))
    rec.close()


def stats(run_dir: Path, uav: int, ages_s: list[float], lost: int, received: int, use_s: float = 0.05,
          links_inside: bool = False) -> None:
    """What a UAV writes: the transport age of its poses (all from UAV 9) and their age at use; the
    per-link ages in their own file, or (``links_inside``, as runs before that file did) in the counters."""
    h, use = LogHistogram(), LogHistogram()
    for a in ages_s:
        h.add(a)
        use.add(use_s)
    links = {"9": h.to_dict()}
    (run_dir / f"uav{uav}.json").write_text(json.dumps({
        "net": {"transport_age": h.to_dict(), "use_age": use.to_dict(), "sent": {"pose": 100}, "received": {"pose": received},
                "rejected": {"malformed": 1}, **({"transport_age_links": links} if links_inside else {})},
        "neighbours": {"9": {"lost": lost, "received": received}},
    }))
    if not links_inside:
        (run_dir / links_file_name(uav)).write_text(json.dumps({"uav": uav, "written_at": T0, "transport_age_links": links}))


def save_scenario(run_dir: Path, source: Path) -> Scenario:
    """The run folder's scenario.yaml: the scenario file itself (the runner saves the validated scenario; both load alike)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    shutil.copy(source, run_dir / "scenario.yaml")
    return load_scenario(run_dir / "scenario.yaml")


@pytest.fixture
def head_on_dir(tmp_path: Path) -> Path:
    """Two UAVs flying at each other at 5 m/s along y = +-0.3 m: they pass 0.6 m apart at t = 4 s, at x = 0."""
    run_dir = tmp_path / "head_on-run"
    scn = save_scenario(run_dir, ROOT / "scenarios" / "head_on.yaml")
    t = T0 + np.arange(0.0, 10.0, 0.1)
    x = -20.0 + 5.0 * (t - T0)
    for uav, sign in ((1, 1.0), (2, -1.0)):
        xyz = np.stack([sign * x, np.full_like(t, 0.3 * sign), np.full_like(t, 10.0)], axis=1)
        record(run_dir, uav, xyz, [AgentPhase.MISSION] * len(t), t, rtf=1.0 if uav == 1 else 0.5)
        stats(run_dir, uav, [0.02] * 50 + [0.04] * 50, lost=1, received=99, links_inside=uav == 2)  # both formats
    RunInfo(scenario=scn.name, started=T0 - 20, pids={"uav1": 1, "uav2": 2}, mission_start=T0, exit_codes={"uav1": 0, "uav2": 0},
            stopped=T0 + 11).write(run_dir / "run.json")
    return run_dir


def test_head_on_summary_reports_the_collision_where_and_when_it_happened(head_on_dir: Path) -> None:
    s = rebuild_results(head_on_dir)
    sep = s.separation
    assert sep and sep.min_m == pytest.approx(0.6, abs=0.01) and sep.min_pair == [1, 2]
    assert sep.min_at_s == pytest.approx(4.0, abs=0.1)
    assert sep.collisions == 1 and sep.collision_pairs[0].pair == [1, 2]
    assert sep.time_below_safety_s == pytest.approx(1.0, abs=0.25)  # closer than 5 m for 4.9 m / 5 m/s
    assert s.encounter and s.encounter.meeting_point == pytest.approx([0.0, 0.0], abs=0.05)
    assert s.goals and s.goals["1"].reached and s.goals["2"].reached  # each ends 2.5 m past the other's start
    assert s.rtf and s.rtf.per_uav == {"1": pytest.approx(1.0), "2": pytest.approx(0.5)}
    net = s.network
    assert net and net.transport_age_ms.n == 200 and net.transport_age_ms.p50 is not None and 20 <= net.transport_age_ms.p50 <= 22
    assert net.use_age_ms.n == 200 and net.use_age_ms.p50 == pytest.approx(50.0, rel=0.05) and net.negative_ages == {}
    links = net.transport_age_links
    assert links and links.links == 2 and {lk.link for lk in links.worst} == {"9->1", "9->2"}
    assert (head_on_dir / "transport_links.csv").read_text().splitlines()[0] == "link,n,p50_ms,p99_ms,max_ms"
    assert net.pose_loss == pytest.approx(0.01) and net.messages_rejected == {"malformed": 2}
    assert not s.coverage  # not a coverage mission: no such key
    assert (head_on_dir / "head_on.png").stat().st_size > 10_000 and s.plot == str(head_on_dir / "head_on.png")
    # summary.json is what was returned, with the keys users read, and nothing half-written beside it
    on_disk = json.loads((head_on_dir / "summary.json").read_text())
    assert on_disk == s.to_dict() and RunSummary.load(head_on_dir / "summary.json") == s
    assert {"scenario", "run_dir", "uavs_planned", "uavs_recorded", "interrupted", "separation", "goals", "encounter", "rtf",
            "network", "processes", "duration_s", "plot", "aborted"} <= set(on_disk)
    assert "coverage" not in on_disk and on_disk["aborted"] is None and on_disk["processes"] == {"uav1": 0, "uav2": 0}
    assert sorted(p.name for p in head_on_dir.iterdir() if p.name.startswith(".")) == []


def test_two_uavs_below_the_safety_distance_are_an_incident_with_the_pair_the_minimum_and_the_duration(tmp_path: Path) -> None:
    """Head-on along y = +-1.5 m: they pass 3 m apart, no collision, but 0.8 s closer than the 5 m safety distance
    (4 m of closing at 10 m/s)."""
    run_dir = tmp_path / "near-miss-run"
    scn = save_scenario(run_dir, ROOT / "scenarios" / "head_on.yaml")
    t = T0 + np.arange(0.0, 10.0, 0.1)
    x = -20.0 + 5.0 * (t - T0)
    for uav, sign in ((1, 1.0), (2, -1.0)):
        record(run_dir, uav, np.stack([sign * x, np.full_like(t, 1.5 * sign), np.full_like(t, 10.0)], axis=1),
               [AgentPhase.MISSION] * len(t), t)
    RunInfo(scenario=scn.name, started=T0 - 20, mission_start=T0).write(run_dir / "run.json")
    s = rebuild_results(run_dir)
    assert s.separation and s.separation.collisions == 0 and s.separation.min_m == pytest.approx(3.0, abs=0.01)
    (inc,) = s.incidents
    assert inc.kind == "below_safety_distance" and inc.pair == [1, 2] and inc.uav == 1
    assert inc.min_m == pytest.approx(3.0, abs=0.01) and inc.min_at_s == pytest.approx(4.0, abs=0.1)
    assert inc.duration_s == pytest.approx(0.8, abs=0.15) and inc.t_s == pytest.approx(3.6, abs=0.15)
    assert s.safety_events == 1  # `mrswarm run` exits with 3
    on_disk = json.loads((run_dir / "summary.json").read_text())["incidents"][0]
    assert {k: on_disk[k] for k in ("kind", "pair", "min_m")} == {"kind": "below_safety_distance", "pair": [1, 2], "min_m": 3.0}
    assert "z_m" not in on_disk  # a pair's incident has no one height
    # printed in words: the pair, when, for how long, how close
    from rich.console import Console

    from mrswarm.results.summary_table import print_summary

    console = Console(width=300, record=True)
    print_summary(console, s)
    text = console.export_text()
    assert re.search(r"UAVs 1 and 2 below the safety distance at 3\.[67] s for 0\.[789] s \(closest 3\.00 m\)", text), text
    assert "0.8 s below the 5 m safety distance" in text


def test_coverage_summary_counts_only_cells_seen_while_working(tmp_path: Path) -> None:
    """Two UAVs fly along y = -15 and y = +15 across the 60 x 40 m field; UAV 2 reports HOVER (not working) for its first half."""
    run_dir = tmp_path / "cov-run"
    scn = save_scenario(run_dir, ROOT / "tests" / "scenarios" / "mini_coverage.yaml")
    t = T0 + np.arange(0.0, 12.0, 0.1)
    x = -30.0 + 5.0 * (t - T0)
    record(run_dir, 1, np.stack([x, np.full_like(t, -15.0), np.full_like(t, 6.0)], axis=1), [AgentPhase.MISSION] * len(t), t)
    # UAV 2 flies the same kind of line but reports HOVER (not working) for its first half
    ph = [AgentPhase.HOVER if k < len(t) // 2 else AgentPhase.MISSION for k in range(len(t))]
    record(run_dir, 2, np.stack([x, np.full_like(t, 15.0), np.full_like(t, 6.0)], axis=1), ph, t)
    RunInfo(scenario=scn.name, started=T0 - 5, mission_start=T0).write(run_dir / "run.json")
    s = rebuild_results(run_dir)
    cov = s.coverage
    assert cov
    # 3 m cells (half the 6 m sensor radius), 20 x 13 of them, centres at x = -28.5 .. 28.5, y = -18.5 .. 17.5.
    # UAV 1 passes within 6 m of 4 rows (-18.5 .. -9.5): 80 cells. UAV 2 of 3 rows (11.5 .. 17.5), but only from
    # where it started working (x = 0) on: 3 x 10 cells, and at most 2 per row behind it within its radius.
    assert 110 / 260 <= cov.final <= 116 / 260
    curve = [c for _, c in cov.curve]
    assert all(b >= a for a, b in pairwise(curve)) and cov.time_to_90_s is None
    assert s.separation and s.separation.min_m == pytest.approx(30.0) and s.separation.collisions == 0
    assert not s.goals and not s.encounter  # not a goto mission
    assert (run_dir / "mini_coverage.png").stat().st_size > 10_000


def test_a_run_interrupted_before_its_mission_is_analysed_from_its_first_record(head_on_dir: Path) -> None:
    RunInfo(scenario="head_on", started=T0 - 20, interrupted=True).write(head_on_dir / "run.json")  # no mission_start
    s = rebuild_results(head_on_dir)
    assert s.interrupted and s.separation and s.separation.min_at_s == pytest.approx(4.0, abs=0.1)
    assert s.duration_s == pytest.approx(9.9, abs=0.01)
    assert json.loads((head_on_dir / "summary.json").read_text())["interrupted"] is True


def test_a_figure_that_cannot_be_written_does_not_lose_the_numbers(head_on_dir: Path) -> None:
    (head_on_dir / "head_on.png").mkdir()  # savefig cannot replace a folder
    s = summarise_run(head_on_dir, load_scenario(head_on_dir / "scenario.yaml"))
    assert s.plot_error and not s.plot
    on_disk = json.loads((head_on_dir / "summary.json").read_text())
    assert on_disk["separation"]["collisions"] == 1 and "plot_error" in on_disk


def test_a_folder_without_trajectories_says_so(tmp_path: Path) -> None:
    run_dir = tmp_path / "empty-run"
    save_scenario(run_dir, ROOT / "scenarios" / "head_on.yaml")
    RunInfo(scenario="head_on", started=T0, aborted="timed out after 31 s waiting for ready").write(run_dir / "run.json")
    s = rebuild_results(run_dir)
    assert s.error == "no trajectory was recorded" and s.aborted == "timed out after 31 s waiting for ready"
    on_disk = json.loads((run_dir / "summary.json").read_text())
    assert on_disk["uavs_recorded"] == 0 and on_disk["aborted"] == s.aborted and "separation" not in on_disk


def test_bad_folders_are_refused_naming_what_is_wrong(tmp_path: Path, head_on_dir: Path) -> None:
    with pytest.raises(ResultsError, match="no scenario.yaml"):
        rebuild_results(tmp_path)
    with pytest.raises(ResultsError, match="not a folder"):
        rebuild_results(tmp_path / "nothing")
    (head_on_dir / "run.json").write_text('{"scenario": "head_on", "started": "yesterday"}')
    with pytest.raises(ResultsError, match=r"run.json.*started"):
        rebuild_results(head_on_dir)


def test_mrswarm_results_rebuilds_the_summary_from_the_cli(head_on_dir: Path, tmp_path: Path) -> None:
    res = subprocess.run([sys.executable, "-m", "mrswarm", "results", str(head_on_dir)], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "collisions" in res.stdout and "encounter" in res.stdout
    assert json.loads((head_on_dir / "summary.json").read_text())["separation"]["collisions"] == 1
    res = subprocess.run([sys.executable, "-m", "mrswarm", "results", str(tmp_path / "nothing")], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "not a folder" in res.stdout + res.stderr


def test_the_analysis_does_not_load_matplotlib() -> None:
    code = "import sys, mrswarm.results.analysis, mrswarm.results.summarise; sys.exit(int('matplotlib' in sys.modules))"
    assert subprocess.run([sys.executable, "-c", code], cwd=ROOT, timeout=60).returncode == 0


def test_mrswarm_results_alone_lists_the_recent_runs_with_their_outcome(head_on_dir: Path, tmp_path: Path) -> None:
    cwd = tmp_path / "work"
    (cwd / "results").mkdir(parents=True)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "200"}
    res = subprocess.run([sys.executable, "-m", "mrswarm", "results"], cwd=cwd, capture_output=True, text=True, timeout=60,
                         env=env)
    assert res.returncode == 0 and "no run folders in results/" in res.stdout, res.stdout + res.stderr
    rebuild_results(head_on_dir)
    shutil.move(str(head_on_dir), cwd / "results" / head_on_dir.name)
    res = subprocess.run([sys.executable, "-m", "mrswarm", "results"], cwd=cwd, capture_output=True, text=True, timeout=60,
                         env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    assert f"results/{head_on_dir.name}" in res.stdout
    assert "2 UAVs, 10 s, closest 0.60 m, 1 collision, 1 incident" in res.stdout, res.stdout
