"""Recording never stops a flight process: real write errors from the kernel (uav_stack/recorder.py).

/dev/full answers every write with ENOSPC; a path under a regular file cannot be created
(EEXIST) until the file makes way for a folder. (A full and a read-only tmpfs: tests/test_disk_e2e.py.)
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

from uav_stack.recorder import (
    MAX_BACKLOG_BYTES,
    TRAJECTORY_COLUMNS,
    AppendLog,
    RecordHealth,
    TrajectoryRecorder,
    write_json_atomic,
)


def test_a_full_disk_is_counted_and_the_rows_wait_in_memory() -> None:
    health = RecordHealth()
    log = AppendLog("/dev/full", "a,b\n", health)
    for i in range(10):
        log.add(f"{i},{i}\n")
        log.flush(float(i))
    assert health.errors == {"ENOSPC": 10} and health.rows_dropped == 0 and "ENOSPC" in health.last_error
    # beyond the bounded backlog the oldest rows go, counted
    row = "x" * 99 + "\n"
    for _ in range(MAX_BACKLOG_BYTES // 100 + 50):
        log.add(row)
    assert 40 <= health.rows_dropped <= 70 and health.bytes_dropped >= 40 * 10
    log.close()


def test_recording_resumes_where_it_stopped_once_the_disk_takes_it(tmp_path: Path) -> None:
    blocker = tmp_path / "run"
    blocker.write_text("a file where the run folder should be\n")
    health = RecordHealth()
    rec = TrajectoryRecorder(blocker / "uav1.csv", health=health)
    rows = [(100.0 + k / 10, k / 10, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0, "mission", "OFFBOARD", 1, 1.0) for k in range(30)]
    for r in rows[:20]:
        rec.write(r[0], r)
    assert set(health.errors) <= {"EEXIST", "ENOTDIR"} and sum(health.errors.values()) >= 1, health.errors
    assert not write_json_atomic(blocker / "uav1.json", {"uav": 1}, health, 101.0)
    assert health.files_not_written == 1
    blocker.unlink()
    blocker.mkdir()  # the disk takes writes again
    for r in rows[20:]:
        rec.write(r[0], r)
    rec.close()
    with open(blocker / "uav1.csv", newline="") as f:
        got = list(csv.DictReader(f))
    assert list(got[0]) == list(TRAJECTORY_COLUMNS)
    assert [float(r["t_wall"]) for r in got] == [r[0] for r in rows]  # every row, once, in order
    assert write_json_atomic(blocker / "uav1.json", {"uav": 1}, health, 103.0)
    assert json.loads((blocker / "uav1.json").read_text()) == {"uav": 1}
    assert not list(blocker.glob(".*.tmp")) and health.rows_dropped == 0


def test_no_trajectory_row_waits_a_second_before_it_is_on_disk(tmp_path: Path) -> None:
    """A UAV killed outright (SIGKILL) loses less than a second of its trajectory: at 10 Hz the
    file is written out at the last tick before a row would have waited a whole second, not at
    the first tick after (which let the chaos test's killed UAV lose 1.04 s)."""
    rec = TrajectoryRecorder(tmp_path / "uav1.csv")
    t0 = 1_700_000_000.0
    worst = 0.0
    for k in range(200):  # 20 s of 10 Hz ticks, each a little late or early, as on a loaded machine
        now = t0 + k / 10 + (0.004 if k % 3 else -0.003)
        rec.write(now, (now, k / 10, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0, "mission", "OFFBOARD", 1, 1.0))
        with open(tmp_path / "uav1.csv", newline="") as f:
            on_disk = [float(r["t_wall"]) for r in csv.DictReader(f)]
        # a kill just before the next tick (now + 0.1 s) loses what came after the last row on disk
        worst = max(worst, now + 0.1 - (on_disk[-1] if on_disk else t0))
    rec.close()
    assert 0.9 <= worst < 1.0 + 0.01, worst  # under a second (the ticks' own jitter aside), and not far under
