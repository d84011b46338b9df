"""Recording never stops a flight process: real write errors from the kernel (uav_stack/recorder.py).

/dev/full answers every write with ENOSPC; a path under a regular file cannot be created
(EEXIST) until the file makes way for a folder. (A full and a read-only tmpfs: tests/test_disk_e2e.py.)
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from uav_stack.recorder import (
    MAX_BACKLOG_BYTES,
    TRAJECTORY_COLUMNS,
    AppendLog,
    RecordHealth,
    SwappedJsonFile,
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


@pytest.fixture
def sigio_ignored() -> Iterator[None]:
    """As in a UAV process (uav_stack.runtime.StopFlag.install): SIGIO ignored, so the counters
    file may be swapped (uav_stack.recorder._sigio_harmless)."""
    before = signal.signal(signal.SIGIO, signal.SIG_IGN)
    yield
    signal.signal(signal.SIGIO, before)


READER = r"""
import json, sys, time
path, end = sys.argv[1], time.monotonic() + float(sys.argv[2])
seen, bad = [], 0
while time.monotonic() < end:
    try:
        with open(path, "rb") as f:
            seen.append(json.loads(f.read())["seq"])
    except FileNotFoundError:
        continue
    except ValueError:
        bad += 1
print(json.dumps({"reads": len(seen), "bad": bad, "in_order": seen == sorted(seen), "last": seen[-1] if seen else None}))
"""


def test_a_swapped_counters_file_is_always_whole_for_a_reader_and_allocates_nothing(tmp_path: Path, sigio_ignored: None) -> None:
    """The counters file a UAV replaces every second: a reader in another process, reading it as
    fast as it can while it is replaced thousands of times a second, only ever gets a whole
    version, in order; the two files trade names (two inodes in turn, a new one only for a
    reader caught holding the spare); closing leaves the file with its last version and removes
    the spare."""
    path = tmp_path / "uav7.json"
    counters = SwappedJsonFile(path)
    health = RecordHealth()
    alone = set()
    for seq in range(100):  # nobody reading: two files in turn, none new
        assert counters.write({"seq": seq, "pad": "x" * 3000}, health, 0.0)
        alone.add(os.stat(path).st_ino)
    assert counters.swapping, "this file system refused the swap: the test cannot tell it works"
    assert len(alone) == 2 and counters.fresh_spares == 0, alone
    reader = subprocess.Popen([sys.executable, "-c", READER, str(path), "2.0"], stdout=subprocess.PIPE, text=True)
    inodes = set()
    while reader.poll() is None and seq < 200_000:
        seq += 1
        # versions of different lengths: a shorter one must not keep the tail of a longer one
        assert counters.write({"seq": seq, "pad": "x" * (3000 - 7 * (seq % 300))}, health, float(seq))
        inodes.add(os.stat(path).st_ino)
    out = json.loads(reader.communicate(timeout=30)[0])
    assert out["reads"] > 100 and out["bad"] == 0 and out["in_order"], out
    assert len(inodes) <= 2 + counters.fresh_spares  # a new file only for a reader caught holding the spare
    assert (tmp_path / ".uav7.json.spare").exists()
    counters.close()
    assert json.loads(path.read_text())["seq"] == seq
    assert sorted(p.name for p in tmp_path.iterdir()) == ["uav7.json"] and health.files_not_written == 0


def test_a_swapped_file_comes_back_when_its_folder_is_emptied_and_counts_what_it_cannot_write(
        tmp_path: Path, sigio_ignored: None) -> None:
    """Someone deletes the run's files under a flying UAV: the next write puts the counters file
    back; while its folder cannot hold it, each write is counted, and none raises."""
    run = tmp_path / "run"
    run.mkdir()
    counters = SwappedJsonFile(run / "uav1.json")
    health = RecordHealth()
    for k in range(3):
        assert counters.write({"uav": 1, "k": k}, health, float(k))
    for p in run.iterdir():
        p.unlink()
    assert counters.write({"uav": 1, "k": 3}, health, 3.0)
    assert json.loads((run / "uav1.json").read_text()) == {"uav": 1, "k": 3}
    assert counters.write({"uav": 1, "k": 4}, health, 4.0)  # and it swaps again
    assert json.loads((run / "uav1.json").read_text()) == {"uav": 1, "k": 4}
    for p in run.iterdir():
        p.unlink()
    run.rmdir()
    run.write_text("a file where the run folder was\n")
    assert not counters.write({"uav": 1, "k": 5}, health, 5.0)
    assert not counters.write({"uav": 1, "k": 6}, health, 6.0)
    assert health.files_not_written == 2 and health.errors
    run.unlink()
    run.mkdir()
    assert counters.write({"uav": 1, "k": 7}, health, 7.0)
    assert json.loads((run / "uav1.json").read_text()) == {"uav": 1, "k": 7}
    counters.close()
    assert [p.name for p in run.iterdir()] == ["uav1.json"]


HOLDER = r"""
import json, sys
f = open(sys.argv[1], "rb")
first = f.read()
print("opened", flush=True)
sys.stdin.readline()  # held open while the file is replaced many times
f.seek(0)
print(json.dumps({"same": f.read() == first, "seq": json.loads(first)["seq"]}), flush=True)
"""


def test_a_reader_that_holds_the_counters_file_open_keeps_its_version(tmp_path: Path, sigio_ignored: None) -> None:
    """A slow reader (a script that opens the file, then pauses) must not see it change under
    it: the file it holds becomes the spare after the next swap, and the writer, finding it
    still open, writes into a new spare instead."""
    path = tmp_path / "uav2.json"
    counters = SwappedJsonFile(path)
    for seq in range(3):
        assert counters.write({"seq": seq, "pad": "y" * (500 + seq)})
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    assert holder.stdout is not None and holder.stdin is not None
    assert holder.stdout.readline().strip() == "opened"
    for seq in range(3, 13):
        assert counters.write({"seq": seq, "pad": "z" * (9 - seq % 7)})
    holder.stdin.write("\n")
    holder.stdin.flush()
    out = json.loads(holder.stdout.readline())
    holder.wait(timeout=10)
    assert out == {"same": True, "seq": 2}
    assert counters.swapping and counters.fresh_spares == 1
    assert json.loads(path.read_text())["seq"] == 12
    counters.close()
    assert [p.name for p in tmp_path.iterdir()] == ["uav2.json"]


def test_where_sigio_would_end_the_process_the_file_is_replaced_the_classic_way(tmp_path: Path) -> None:
    before = signal.signal(signal.SIGIO, signal.SIG_DFL)
    try:
        counters = SwappedJsonFile(tmp_path / "uav3.json")
        assert not counters.swapping
        for k in range(5):
            assert counters.write({"k": k})
        counters.close()
    finally:
        signal.signal(signal.SIGIO, before)
    assert json.loads((tmp_path / "uav3.json").read_text()) == {"k": 4}
    assert [p.name for p in tmp_path.iterdir()] == ["uav3.json"]


def test_no_descriptor_is_left_open_when_a_fresh_spare_cannot_be_made(tmp_path: Path, sigio_ignored: None) -> None:
    """A reader holds the spare, and its name has become a folder: the fresh spare cannot be
    made. The write still lands (the temporary-file way), and no file descriptor is left open."""
    path = tmp_path / "uav4.json"
    counters = SwappedJsonFile(path)
    fds_before = len(os.listdir("/proc/self/fd"))
    for seq in range(3):
        assert counters.write({"seq": seq})
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    assert holder.stdout is not None and holder.stdin is not None
    assert holder.stdout.readline().strip() == "opened"
    assert counters.write({"seq": 3})  # the held version becomes the spare
    counters.spare.unlink()
    counters.spare.mkdir()  # (the holder keeps its file)
    assert counters.write({"seq": 4}) and counters.write({"seq": 5})
    holder.stdin.write("\n")
    holder.stdin.flush()
    assert json.loads(holder.stdout.readline()) == {"same": True, "seq": 2}
    holder.wait(timeout=10)
    holder.stdin.close()
    holder.stdout.close()
    assert json.loads(path.read_text())["seq"] == 5
    counters.close()
    assert len(os.listdir("/proc/self/fd")) == fds_before
