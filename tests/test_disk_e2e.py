"""Records on a real small disk (a tmpfs this test mounts and unmounts; root, as scripts/test runs).

* The results disk fills up mid-run: no UAV process dies, recording degrades with a counter,
  catches up once there is space again (nothing lost within the in-memory backlog), no file is
  left half-written or as a temporary. In the same run an operator's `kill` drops a UAV from the
  sky: an incident, and the run exits 3.
* A read-only `--out`: exit 2, naming the option and the reason.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import itertools
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import psutil
import pytest

from tests.run_helpers import ROOT, BackgroundRun, survivors, wait_no_survivors

pytestmark = pytest.mark.e2e

MINI = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"


@contextlib.contextmanager
def tmpfs(where: Path, size: str, readonly: bool = False) -> Iterator[Path]:
    where.mkdir(parents=True, exist_ok=True)
    opts = f"size={size}" + (",ro" if readonly else "")
    subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(where)], check=True, capture_output=True, timeout=30)
    try:
        yield where
    finally:
        res = subprocess.run(["umount", str(where)], capture_output=True, timeout=30)
        if res.returncode != 0:
            subprocess.run(["umount", "-l", str(where)], capture_output=True, timeout=30)


def fill(path: Path) -> int:
    """Write until the disk is full (ENOSPC); the bytes written."""
    n = 0
    chunk = b"\0" * 65536
    with open(path, "wb", buffering=0) as f:
        while True:
            try:
                n += f.write(chunk)
            except OSError as exc:
                assert exc.errno == errno.ENOSPC
                chunk = chunk[: len(chunk) // 2]
                if not chunk:
                    return n


def alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def test_a_full_disk_never_stops_a_uav_and_a_motor_kill_in_flight_is_an_incident(tmp_path: Path) -> None:
    with tmpfs(tmp_path / "disk", "12m") as disk:
        run = BackgroundRun(MINI, disk / "out", ["fleet.count=2", "duration=25"])
        filler = disk / "filler"
        try:
            start = run.wait_mission(after=2.0)
            run_dir = run.run_dir()
            assert run_dir is not None
            pids = json.loads((run_dir / "run.json").read_text())["pids"]
            t_full = time.time()
            fill(filler)
            time.sleep(5.0)
            assert all(alive(pids[f"uav{u}"]) for u in (1, 2)), "a UAV process died on the full disk"
            json.loads((run_dir / "run.json").read_text())  # still whole
            filler.unlink()
            t_free = time.time()
            time.sleep(max(0.0, start + 12.0 - time.time()))
            res = subprocess.run([sys.executable, "-m", "mrswarm", "gcs", "kill", "--uav", "1", "--yes", "--run", str(run_dir)],
                                 cwd=ROOT, capture_output=True, text=True, timeout=60)
            assert res.returncode == 0, res.stdout + res.stderr
            code = run.wait(120)
            assert code == 3, f"exit {code}\n{run.output[-3000:]}"
            assert not wait_no_survivors(run.tag, 5.0)

            s = json.loads((run_dir / "summary.json").read_text())
            rec = s["records"]
            assert sorted(rec["uavs"]) == [1, 2] and rec["errors"].get("ENOSPC", 0) > 0 and rec["rows_dropped"] == 0, rec
            assert not list(disk.rglob("*.tmp")), "temporary files left behind"
            # recording caught up: no hole in either trajectory around the full disk
            for uav in (1, 2):
                with open(run_dir / f"uav{uav}.csv", newline="") as f:
                    t = sorted(float(r["t_wall"]) for r in csv.DictReader(f) if r.get("t_wall"))
                around = [b - a for a, b in itertools.pairwise(t) if t_full - 1.0 <= a <= t_free + 1.0]
                assert around and max(around) < 0.5, f"UAV {uav}: a {max(around):.1f} s hole in its records"
            # the operator's kill: motors stopped in the air, then the ground
            kinds = {(i["uav"], i["kind"]) for i in s["incidents"]}
            assert {(1, "motors_stopped_in_air"), (1, "ground_impact")} <= kinds, s["incidents"]
            assert not any(u == 2 for u, _ in kinds)
            assert "incidents" in run.output
        finally:
            run.cleanup()
            filler.unlink(missing_ok=True)
    assert not survivors(run.tag)


def test_a_read_only_out_is_a_usage_error_naming_it(tmp_path: Path) -> None:
    with tmpfs(tmp_path / "ro", "1m", readonly=True) as ro:
        res = subprocess.run([sys.executable, "-m", "mrswarm", "run", str(MINI), "--out", str(ro / "results"), "--no-live"],
                             cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.returncode == 2, res.stdout + res.stderr
    assert "--out" in res.stdout and "Read-only file system" in res.stdout
    assert "Traceback" not in res.stdout + res.stderr
    assert os.path.ismount(tmp_path / "ro") is False
