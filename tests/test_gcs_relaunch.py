"""A swarm landed by `gcs land --all` keeps its run going, and `gcs start` relaunches it into the coverage."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from mrswarm.gcs.session import open_observer, resolve_target
from tests.conftest import wait_for
from tests.gcs_helpers import ROOT, gcs, run_dir, start_run, stop_run

pytestmark = pytest.mark.e2e
SCENARIO = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"
IDS = (1, 2, 3, 4)


def _coverage_at(curve: list[list[float]], t: float) -> float:
    """The coverage curve (s since mission start, fraction) at ``t``: the last point at or before it."""
    before = [c for s, c in curve if s <= t]
    return before[-1] if before else 0.0


def test_landed_swarm_keeps_the_run_going_and_start_relaunches_it_into_the_coverage(tmp_path: Path) -> None:
    # ended by Ctrl-C below, never by its duration; a field too large to be covered before that
    run = start_run(SCENARIO, tmp_path, ["duration=600", "mission.area.x_max=90", "mission.area.y_max=70"])
    obs = None
    try:
        rdir = run_dir(tmp_path)
        obs = open_observer(resolve_target(str(rdir), [], None))

        def phases() -> list[str | None]:
            obs.poll()
            return [obs.phases().get(u) for u in IDS]

        assert wait_for(lambda: phases() == ["mission"] * 4, 120, 0.2), phases()
        time.sleep(4.0)
        res = gcs(["land", "--run", str(rdir), "--all", "--json", "--timeout", "10"])
        assert res.returncode == 0, res.stdout + res.stderr
        assert wait_for(lambda: phases() == ["landed"] * 4, 60, 0.2), phases()
        all_landed = time.time()
        # an operator landed everyone: the run goes on (gcs.landing_ends_run is off by default)
        time.sleep(4.0)
        assert run.poll() is None and not (rdir / "summary.json").exists()
        res = gcs(["resume", "--run", str(rdir), "--uav", "1", "--json"])
        assert res.returncode == 1 and "start relaunches it" in res.stdout, res.stdout  # the hint, not a dead end
        relaunched = time.time()
        res = gcs(["start", "--run", str(rdir), "--all", "--json", "--timeout", "10"])
        assert res.returncode == 0, res.stdout + res.stderr
        acks = [json.loads(line) for line in res.stdout.splitlines()]
        assert sorted(a["uav"] for a in acks) == list(IDS)
        assert all(a["message"] == "taking off again, then back to the mission" for a in acks), acks
        assert wait_for(lambda: phases() == ["mission"] * 4, 60, 0.2), phases()
        # a script reads one UAV's telemetry through a pipe: one line per update, never wrapped at 80 columns
        res = gcs(["telemetry", "--run", str(rdir), "--uav", "2", "--follow", "--duration", "2.5"])
        assert res.returncode == 0, res.stderr
        lines = res.stdout.splitlines()
        assert len(lines) >= 3 and all(line.startswith("uav 2 phase=mission") for line in lines), lines
        assert max(len(line) for line in lines) > 80
        time.sleep(8.0)
        assert run.poll() is None and phases() == ["mission"] * 4  # still flying: Ctrl-C ends it below
    finally:
        if obs is not None:
            obs.close()
        stop_run(run)
    summary = json.loads((rdir / "summary.json").read_text())
    info = json.loads((rdir / "run.json").read_text())
    curve = summary["coverage"]["curve"]
    t_landed, t_start = all_landed - info["mission_start"], relaunched - info["mission_start"]
    on_ground = _coverage_at(curve, t_start) - _coverage_at(curve, t_landed)
    after = summary["coverage"]["final"] - _coverage_at(curve, t_start)
    assert on_ground < 0.01, curve  # nobody working while they were down ...
    assert after > 0.05, curve  # ... and the coverage rose again once they were back
    assert info["all_done_at"] is None  # the run did not end on its own: the landing was not its end condition
