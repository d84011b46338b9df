"""The runner under real signals: kill -9, SIGHUP, SIGTERM, Ctrl-C twice, Ctrl-C during the analysis.

Each case is a real `mrswarm run` of two virtual UAVs; they run side by side (one test, to keep
the suite short). For each: the run stops cleanly (exit 128 + the signal, no traceback), a
readable summary exists (written by the runner, or rebuilt by `mrswarm results` after kill -9),
no process of the run outlives it (psutil, through a tag in their environment), and at most a
second of trajectory is lost.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.run_helpers import ROOT, BackgroundRun, last_rows, survivors, wait_no_survivors

pytestmark = pytest.mark.e2e

MINI = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"
SETS = ["fleet.count=2", "duration=60"]


def summary_of(run_dir: Path) -> dict:
    return json.loads((run_dir / "summary.json").read_text())


def test_the_runner_stops_cleanly_on_every_signal_and_leaves_nothing_behind(tmp_path: Path) -> None:
    runs = {name: BackgroundRun(MINI, tmp_path / name, SETS) for name in ("kill9", "hup", "term", "int2")}
    runs["analysis"] = BackgroundRun(MINI, tmp_path / "analysis", ["fleet.count=2", "duration=4"])
    early = BackgroundRun(MINI, tmp_path / "int2_startup", SETS)
    in_analysis: list[float] = []

    def ctrl_c_during_analysis() -> None:  # as soon as the runner has stopped its UAVs (run.json says so)
        r = runs["analysis"]
        deadline = time.time() + 120
        while time.time() < deadline and r.proc.poll() is None:
            if r.run_info().get("stopped"):
                r.signal(signal.SIGINT)
                in_analysis.append(time.time())
                return
            time.sleep(0.01)

    watcher = threading.Thread(target=ctrl_c_during_analysis, daemon=True)
    watcher.start()
    try:
        # Ctrl-C twice, 20 ms apart, while the runner is still starting its processes
        deadline = time.time() + 60
        while early.run_dir() is None and time.time() < deadline:
            time.sleep(0.01)
        early.signal(signal.SIGINT)
        time.sleep(0.02)
        early.signal(signal.SIGINT)

        starts = {name: r.wait_mission(after=2.0) for name, r in runs.items() if name != "analysis"}
        sent = {}
        runs["kill9"].signal(signal.SIGKILL)
        sent["kill9"] = time.time()
        runs["hup"].signal(signal.SIGHUP)
        sent["hup"] = time.time()
        runs["term"].signal(signal.SIGTERM)
        sent["term"] = time.time()
        runs["int2"].signal(signal.SIGINT)
        time.sleep(0.02)
        runs["int2"].signal(signal.SIGINT)
        sent["int2"] = time.time()

        # kill -9: the children die with the runner (PR_SET_PDEATHSIG), `mrswarm results` rebuilds
        r = runs["kill9"]
        assert r.wait(10) == -signal.SIGKILL
        assert not wait_no_survivors(r.tag, 10.0), "processes outlived the killed runner"
        run_dir = r.run_dir()
        assert run_dir is not None
        info = json.loads((run_dir / "run.json").read_text())
        assert info["mission_start"] == pytest.approx(starts["kill9"], abs=0.01) and set(info["pids"]) >= {"uav1", "uav2"}
        res = subprocess.run([sys.executable, "-m", "mrswarm", "results", str(run_dir)], cwd=ROOT, capture_output=True, text=True,
                             timeout=120)
        assert res.returncode == 0, res.stdout + res.stderr
        s = summary_of(run_dir)
        assert s["uavs_recorded"] == 2 and s["separation"]["collisions"] == 0 and s["coverage"]["final"] > 0
        for uav, last in last_rows(run_dir).items():
            assert last >= sent["kill9"] - 1.0, f"UAV {uav}: {sent['kill9'] - last:.2f} s of records lost"
        # the results of a run whose runner died say so, with its last known time (not a complete 60 s run)
        assert s["interrupted"] is True and s["runner_lost"] is True, s
        assert s["interrupted_at_wall"] == pytest.approx(sent["kill9"], abs=1.5)
        assert s["interrupted_at_s"] == pytest.approx(sent["kill9"] - starts["kill9"], abs=1.5)
        assert "the runner died" in " ".join(res.stdout.split())

        for name, sig in (("hup", signal.SIGHUP), ("term", signal.SIGTERM), ("int2", signal.SIGINT)):
            r = runs[name]
            code = r.wait(60)
            assert code == 128 + sig, f"{name}: exit {code}\n{r.output[-3000:]}"
            assert "Traceback" not in r.output, r.output[-3000:]
            assert not wait_no_survivors(r.tag, 5.0), f"{name}: processes left behind"
            run_dir = r.run_dir()
            assert run_dir is not None
            info = json.loads((run_dir / "run.json").read_text())
            assert info["interrupted"] and info["stop_signals"][0] == sig.name, info
            s = summary_of(run_dir)
            assert s["interrupted"] and s["uavs_recorded"] == 2 and s["stop_signals"][0] == sig.name
            for uav, last in last_rows(run_dir).items():
                assert last >= sent[name] - 1.0, f"{name}: UAV {uav} lost {sent[name] - last:.1f} s of records"
        # the second Ctrl-C stops faster: the children get SIGKILL after 1 s, the figures are skipped
        info = runs["int2"].run_info()
        assert info["stop_signals"] == ["SIGINT", "SIGINT"] and info["stopped"] - sent["int2"] < 5.0

        # Ctrl-C once during the analysis: the summary and the figure are still written
        r = runs["analysis"]
        watcher.join(120)
        assert in_analysis, "the run never reached its analysis"
        code = r.wait(60)
        assert code == 130 and "Traceback" not in r.output, r.output[-3000:]
        run_dir = r.run_dir()
        assert run_dir is not None and summary_of(run_dir)["uavs_recorded"] == 2
        assert (run_dir / "mini_coverage.png").stat().st_size > 10_000
        assert not wait_no_survivors(r.tag, 5.0)

        # the start-up case: stopped without a traceback, nothing left behind
        code = early.wait(60)
        assert code == 130 and "Traceback" not in early.output, early.output[-3000:]
        assert not wait_no_survivors(early.tag, 5.0)
        run_dir = early.run_dir()
        if run_dir is not None:  # it got as far as creating its folder: its records are readable
            json.loads((run_dir / "run.json").read_text())
            summary_of(run_dir)
    finally:
        for r in [*runs.values(), early]:
            r.cleanup()
        assert not any(survivors(r.tag) for r in [*runs.values(), early])
