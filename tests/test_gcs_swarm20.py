"""A 20-UAV mission seen and commanded from `mrswarm gcs`: watch in tmux, hold/resume, land --all, record/plot."""

from __future__ import annotations

import json
import math
import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mrswarm.gcs.session import open_observer, resolve_target
from tests.conftest import wait_for
from tests.gcs_helpers import ROOT, gcs, run_dir, start_run, stop_run

pytestmark = pytest.mark.e2e
SCENARIO = ROOT / "tests" / "scenarios" / "gcs_swarm20.yaml"
IDS = list(range(1, 21))
TMUX = shutil.which("tmux")


class Tmux:
    """A private tmux server (its own socket), so nothing else's sessions are touched."""

    def __init__(self, name: str):
        self.sock = name
        self.session = name

    def _tmux(self, *args: str) -> str:
        return subprocess.run([TMUX, "-L", self.sock, *args], capture_output=True, text=True, timeout=20).stdout  # type: ignore[list-item]

    def start(self, cols: int = 170, rows: int = 45) -> None:
        subprocess.run([TMUX, "-L", self.sock, "new-session", "-d", "-s", self.session, "-x", str(cols), "-y", str(rows)],  # type: ignore[list-item]
                       check=True, timeout=20, env={**os.environ, "TERM": "xterm-256color"})

    def keys(self, *keys: str) -> None:
        self._tmux("send-keys", "-t", self.session, *keys)

    def screen(self) -> str:
        return self._tmux("capture-pane", "-p", "-t", self.session)

    def kill(self) -> None:
        subprocess.run([TMUX, "-L", self.sock, "kill-server"], capture_output=True, timeout=20)  # type: ignore[list-item]


def _rows(screen: str) -> dict[int, list[str]]:
    """Table rows of the watch screen: id -> cells."""
    out = {}
    for line in screen.splitlines():
        cells = line.split()
        if len(cells) > 5 and cells[0].isdigit() and cells[1] in ("V", "P"):
            out[int(cells[0])] = cells
    return out


def test_gcs_watches_holds_resumes_and_lands_a_20_uav_mission(tmp_path: Path) -> None:
    assert TMUX is not None, "tmux not found: scripts/test installs it (apt-get install tmux)"
    run = start_run(SCENARIO, tmp_path, [])
    tmux = Tmux(f"mrswarm-gcs-{os.getpid()}")
    rec: subprocess.Popen[str] | None = None
    obs = None
    try:
        rdir = run_dir(tmp_path)
        obs = open_observer(resolve_target(str(rdir), [], None))

        def phase(u: int) -> str | None:
            v = obs.uavs.get(u)
            return v.state.phase if v is not None and v.state is not None else None

        def all_in(ph: str) -> bool:
            obs.poll()
            return all(phase(u) == ph for u in IDS)

        assert wait_for(lambda: all_in("mission"), 180, 0.2), {u: phase(u) for u in IDS}
        mission_at = time.monotonic()
        recording = tmp_path / "gcs.jsonl"
        rec = subprocess.Popen([sys.executable, "-m", "mrswarm", "gcs", "record", str(recording), "--run", str(rdir),
                                "--duration", "300", "--quiet"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               text=True, start_new_session=True)

        # ---- watch, live in a terminal -------------------------------------------------------------
        tmux.start()
        root, python = shlex.quote(str(ROOT)), shlex.quote(sys.executable)
        cmd = f"cd {root} && PYTHONPATH={root} {python} -m mrswarm gcs watch --run {shlex.quote(str(rdir))}"
        tmux.keys(cmd, "Enter")
        def live_rows() -> bool:
            rows = _rows(tmux.screen())
            return len(rows) == 20 and all(r[2] == "mission" and "OFFBOARD" in r for r in rows.values())

        assert wait_for(live_rows, 30, 0.3), tmux.screen()
        screen = tmux.screen()
        rows = _rows(screen)
        assert "20 UAVs seen, 20 alive" in screen
        first = {u: r[5:7] for u, r in rows.items()}  # x, y: the table is live, positions change

        def moved() -> int:
            now = _rows(tmux.screen())
            return sum(u in now and now[u][5:7] != first[u] for u in IDS)

        assert wait_for(lambda: moved() >= 15, 8, 0.5), tmux.screen()
        tmux.keys("s")  # next sort column: phase
        assert wait_for(lambda: "sort phase" in tmux.screen(), 5, 0.2), tmux.screen()

        # ---- hold, then resume, mid-mission ---------------------------------------------------------
        # (once the swarm has left the spawn grid for its lanes: a held UAV still avoids traffic)
        time.sleep(max(0.0, mission_at + 15.0 - time.monotonic()))
        held_ids = (1, 20)  # opposite corners of the fleet
        res = gcs(["hold", "--run", str(rdir), "--uav", "1,20", "--json"])
        assert res.returncode == 0, res.stdout + res.stderr
        acks = [json.loads(line) for line in res.stdout.splitlines()]
        assert [(a["uav"], a["status"]) for a in acks] == [(1, "ok"), (20, "ok")]
        points = {a["uav"]: tuple(float(v) for v in a["message"].split("(")[1].rstrip(")").split(",")[:2]) for a in acks}
        # the watch shows the override (sorted by phase, the two held UAVs come first)
        assert wait_for(lambda: sum(r[2] == "hold" and r[3] == "hold" for r in _rows(tmux.screen()).values()) == 2, 10, 0.3), \
            tmux.screen()
        # Held UAVs stop following their lanes and stay at their hold points. Collision avoidance
        # still runs (a safety layer, not the swarm behaviour): a neighbour whose lane crosses the
        # hold point pushes the held UAV ahead of it (ORCA: the held UAV takes its half of every
        # avoidance), tens of metres at worst, and it comes back once the lane is clear.
        settled: dict[int, float] = {}
        excursion = {u: 0.0 for u in held_ids}
        deadline = time.monotonic() + 45.0
        while time.monotonic() < deadline and len(settled) < len(held_ids):
            time.sleep(0.25)
            obs.poll()
            for u in held_ids:
                p, v = obs.uavs[u].pose, obs.uavs[u]
                assert p is not None and v.state is not None and (v.state.phase, v.state.override) == ("hold", "hold")
                d = math.hypot(p.x - points[u][0], p.y - points[u][1])
                excursion[u] = max(excursion[u], d)
                if d < 1.5 and math.hypot(p.vx, p.vy) < 0.5 and u not in settled:
                    settled[u] = d
        assert set(settled) == set(held_ids), (settled, excursion)
        assert max(excursion.values()) < 80.0, excursion  # pushed, never wandering off with the mission
        assert all(phase(u) == "mission" for u in IDS if u not in held_ids)  # the rest carries on
        res = gcs(["resume", "--run", str(rdir), "--uav", "1,20"])
        assert res.returncode == 0, res.stdout + res.stderr
        assert wait_for(lambda: all_in("mission"), 10, 0.2)
        time.sleep(3.0)
        obs.poll()
        for u in held_ids:  # the behaviour flies them again
            p = obs.uavs[u].pose
            assert p is not None and math.hypot(p.x - points[u][0], p.y - points[u][1]) > 3.0, (u, p, points[u])

        # ---- unknown ids are refused before anything is sent ---------------------------------------
        res = gcs(["hold", "--run", str(rdir), "--uav", "3,99"])
        assert res.returncode == 2 and "unknown UAV id 99" in res.stderr

        # ---- land --all: every one of the 20 acknowledges, every one lands ----------------------------
        res = gcs(["land", "--run", str(rdir), "--all", "--json", "--timeout", "10"])
        assert res.returncode == 0, res.stdout + res.stderr
        acks = [json.loads(line) for line in res.stdout.splitlines()]
        assert sorted(a["uav"] for a in acks) == IDS
        # "already landing": the answer to the CLI's re-send, if a busy machine delayed the first ack
        assert all(a["status"] == "ok" and a["message"] in ("landing", "already landing") for a in acks), acks
        assert wait_for(lambda: all_in("landed"), 90, 0.2), {u: phase(u) for u in IDS}
        assert wait_for(lambda: sum(r[2] == "landed" for r in _rows(tmux.screen()).values()) == 20, 10, 0.3), tmux.screen()
        tmux.keys("q")  # quits (keys typed in the same read would be swallowed: wait for the shell)
        time.sleep(1.5)
        tmux.keys("echo watch-exited-$?", "Enter")
        assert wait_for(lambda: "watch-exited-0" in tmux.screen(), 10, 0.3), tmux.screen()

        # ---- the recording (appended, flushed every second) survives a crash and plots -------------
        # a crash of the recorder loses at most the last second: kill it hard
        time.sleep(1.5)
        os.killpg(rec.pid, 9)
        rec.wait(10)
        kinds = {}
        for line in recording.read_text().splitlines():
            k = json.loads(line)["kind"]
            kinds[k] = kinds.get(k, 0) + 1
        assert kinds.get("pose", 0) > 1000 and kinds.get("state", 0) > 100 and kinds.get("ack", 0) >= 20, kinds
        res = gcs(["plot", str(recording)])
        assert res.returncode == 0, res.stderr
        assert recording.with_suffix(".png").stat().st_size > 20_000
    finally:
        tmux.kill()
        if obs is not None:
            obs.close()
        if rec is not None and rec.poll() is None:
            rec.kill()
            rec.wait(10)
        stop_run(run)
