"""An outside Zenoh client joins a real run through its edge router, as docs/keyspace.md tells.

The test runs the documentation's own snippet (the Python block under "Connecting from
outside"), so the documented way in cannot drift from what works.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from swarmnet.messages import MAX_POSE_BYTES
from tests.conftest import wait_for

ROOT = Path(__file__).resolve().parents[1]
MINI = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"
DOC = ROOT / "docs" / "keyspace.md"

pytestmark = pytest.mark.e2e


def doc_snippet() -> str:
    text = DOC.read_text()
    section = text.split("## Connecting from outside", 1)[1]
    match = re.search(r"```python\n(.*?)```", section, re.S)
    assert match, "docs/keyspace.md: no python block under 'Connecting from outside'"
    return match.group(1)


def test_a_client_on_the_runs_edge_router_receives_every_uavs_poses(tmp_path: Path) -> None:
    snippet = doc_snippet()
    run = subprocess.Popen([sys.executable, "-m", "mrswarm", "run", str(MINI), "--out", str(tmp_path), "--no-live",
                            "--set", "duration=60"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # every UAV recording means every agent is up and publishing its pose
        assert wait_for(lambda: len(list(tmp_path.glob("*/uav*.csv"))) == 4 and any(tmp_path.glob("*/network.json")), 60.0), \
            "the run never started its four UAVs"
        run_dir = next(tmp_path.glob("*/network.json")).parent
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        res = subprocess.run([sys.executable, "-c", snippet, str(run_dir)], cwd=tmp_path, env=env, capture_output=True,
                             text=True, timeout=60)
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGINT)
        try:
            run.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            run.kill()
            run.communicate()
    assert res.returncode == 0, res.stderr[-3000:]
    per_uav: dict[int, int] = {}
    for line in res.stdout.splitlines():
        key, size, uav, *_ = line.split()
        assert key == f"mrs/e2e/{uav}/pose", line  # the key names the payload's UAV
        assert 0 < int(size) <= MAX_POSE_BYTES, line
        per_uav[int(uav)] = per_uav.get(int(uav), 0) + 1
    assert set(per_uav) == {1, 2, 3, 4}, res.stdout[-2000:]
    # 10 Hz for 5 s is 50 per UAV: a stream, not a stray pose (with room for a loaded machine)
    assert min(per_uav.values()) >= 20, per_uav
