"""Records on a real small disk (a tmpfs this test mounts and unmounts; root, as scripts/test runs).

* The results disk fills up mid-run: no UAV process dies, recording degrades with a counter,
  catches up once there is space again (nothing lost within the in-memory backlog), no file is
  left half-written or as a temporary. In the same run an operator's `kill` drops a UAV from the
  sky: an incident, and the run exits 3.
* A 512 KiB results disk that fills up and stays full: every process of the run lives on (the
  edge router and the recorder never restart), the run ends with its summary printed and written
  where it can be, listing what is missing (``degraded``), and exits 1. The same for a results
  disk turned read-only mid-run.
* The flight recorder on a full disk keeps what the disk refuses in memory and writes it when
  the disk takes it again; beyond its backlog it seals its file and goes on in the next one.
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
import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import psutil
import pytest

from mrswarm.recorder import recording
from mrswarm.recorder.reader import Recording, read_recording
from mrswarm.recorder.run_recorder import STATUS_PREFIX
from swarmnet.connectivity import Rendezvous
from swarmnet.observer import SwarmObserver
from tests.conftest import router  # noqa: F401 (a fixture)
from tests.run_helpers import ROOT, BackgroundRun, survivors, wait_no_survivors
from tests.test_recorder import SWARM, _fly, _uavs

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


def run_on_a_disk_that_fails(tmp_path: Path, name: str, fail: str) -> tuple[int, str, dict, Path]:
    """``mrswarm run`` of 2 UAVs with ``--out`` on a 512 KiB tmpfs that fails mid-mission (``fail``: "full" fills
    it and leaves it full, "ro" puts a read-only bind mount of it over it: what the processes open from then on is
    read-only, as when a failing disk is remounted so; Linux refuses a plain read-only remount with files open for
    writing); (exit code, output, summary, run folder)."""
    disk = tmp_path / name
    with tmpfs(disk, "512k") as disk:
        run = BackgroundRun(MINI, disk / "out", ["fleet.count=2", "duration=25"], log=tmp_path / f"{name}.stdout")
        try:
            run.wait_mission(after=3.0)
            run_dir = run.run_dir()
            assert run_dir is not None
            pids = json.loads((run_dir / "run.json").read_text())["pids"]
            if fail == "full":
                fill(disk / "filler")
            else:
                subprocess.run(["mount", "--bind", str(disk), str(disk)], check=True, capture_output=True, timeout=30)
                subprocess.run(["mount", "-o", "remount,bind,ro", str(disk)], check=True, capture_output=True, timeout=30)
            time.sleep(8.0)  # the edge router writes its counters every second; a crash loop would show by now
            for name_, pid in pids.items():
                assert alive(pid), f"{name_} died on the {fail} disk"
            code = run.wait(180)
            assert not wait_no_survivors(run.tag, 10.0)
            out = run.output
            s = json.loads(summary_path(run_dir, out).read_text())
            return code, out, s, run_dir
        finally:
            run.cleanup()
            if fail == "ro":  # the bind mount; the tmpfs under it goes with the context
                subprocess.run(["umount", str(disk)], capture_output=True, timeout=30)


def summary_path(run_dir: Path, out: str) -> Path:
    """summary.json in the run folder, else where the runner said it wrote it instead."""
    if (run_dir / "summary.json").exists():
        return run_dir / "summary.json"
    fallback = Path("/tmp") / f"mrswarm-{run_dir.name}-summary.json"
    assert fallback.exists(), f"summary.json written nowhere:\n{out[-3000:]}"
    return fallback


@pytest.mark.parametrize("fail", ["full", "ro"])
def test_a_small_results_disk_that_fails_mid_run_degrades_the_run_and_stops_nothing(tmp_path: Path, fail: str) -> None:
    code, out, s, run_dir = run_on_a_disk_that_fails(tmp_path, fail, fail)
    try:
        assert code == 1, f"exit {code}\n{out[-3000:]}"  # docs/reliability.md: degraded records, no safety event
        assert "Traceback" not in out, out[-3000:]
        flat = " ".join(out.split())
        assert "summary: mini_coverage" in flat and "degraded" in flat  # printed on the terminal in any case
        assert s["degraded"] and s["uavs_recorded"] == 2, s["degraded"]
        assert s["separation"]["collisions"] == 0
        # no service went down: the edge router and the recorder wrote nothing and lived on
        assert s["services"] == [] and not any(e for e in s.get("lost_uavs", [])), (s["services"], s["lost_uavs"])
        assert all(c == 0 for c in s["processes"].values()), s["processes"]
        assert s["write_error"].endswith("instead"), s["write_error"]  # summary.json: in the temporary folder
        why = {"full": "No space left on device", "ro": "Read-only file system"}[fail]
        assert any(why in d for d in s["degraded"]), s["degraded"]
        assert any("summary.json not written" in d for d in s["degraded"])
    finally:
        (Path("/tmp") / f"mrswarm-{run_dir.name}-summary.json").unlink(missing_ok=True)


def statuses(lines: list[bytes]) -> list[dict]:
    return [json.loads(line[len(STATUS_PREFIX):]) for line in lines if line.startswith(STATUS_PREFIX.encode())]


def test_the_recorder_keeps_what_a_full_disk_refuses_and_writes_it_when_the_disk_takes_it(router: str,  # noqa: F811
                                                                                          tmp_path: Path) -> None:
    with tmpfs(tmp_path / "disk", "256k") as disk:
        path = disk / "run.mcap"
        proc = subprocess.Popen([sys.executable, "-m", "mrswarm", "gcs", "record", str(path), "--connect", router, "--swarm",
                                 SWARM, "--quiet", "--status"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                start_new_session=True)
        nodes = _uavs(router, 2)
        stamps: dict[int, list[tuple[int, float]]] = defaultdict(list)
        try:
            deadline = time.monotonic() + 20
            while not (path.exists() and path.stat().st_size) and time.monotonic() < deadline:
                time.sleep(0.05)
            _fly(nodes, 1.5, stamps)
            fill(disk / "filler")
            t_full = time.time()
            _fly(nodes, 3.0, stamps)  # every flush is refused: the records wait in memory
            assert proc.poll() is None, "the recorder died on the full disk"
            (disk / "filler").unlink()
            _fly(nodes, 2.5, stamps)  # the next flush writes them all
            t_second = time.time()
            fill(disk / "filler")
            _fly(nodes, 1.5, stamps)  # full again until the end: what is not flushed by then is counted, not written
            os.killpg(proc.pid, 15)
            output, _ = proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, 9)
                proc.wait(10)
            for nd in nodes:
                nd.close()
        assert proc.returncode == 0, output.decode(errors="replace")[-3000:]
        end = statuses(output.splitlines())[-1]
        assert end.get("end") and end["unwritten"] > 0 and end["files"] == [str(path)], end
        rec = Recording(path)
        recorded: dict[int, set[int]] = defaultdict(set)
        for m in read_recording(path, rec):
            if m.schema == "mrswarm.Pose":
                recorded[json.loads(m.data)["uav"]].add(m.sequence)
        assert rec.complete and rec.error is None  # sealed at its last flush: a closed file
        for u, sent in stamps.items():
            during = {seq for seq, t in sent if t_full + 0.5 < t < t_second - 1.2}  # published while the disk was full
            assert len(during) > 20 and len(during - recorded[u]) <= 1, f"UAV {u}: {sorted(during - recorded[u])[:10]}"


def test_a_recorder_whose_backlog_overflows_seals_its_file_and_goes_on_in_the_next(router: str,  # noqa: F811
                                                                                  tmp_path: Path,
                                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(recording, "MAX_BACKLOG_BYTES", 4096)
    monkeypatch.setattr(recording, "RETRY_S", 0.5)
    with tmpfs(tmp_path / "disk", "256k") as disk:
        nodes = _uavs(router, 2)
        obs = SwarmObserver(SWARM, Rendezvous((router,), mode="client"), node_id=7, role="gcs", name="rec").open()
        seen: list[dict] = []
        done = threading.Event()
        counts: dict[str, int] = {}
        th = threading.Thread(target=lambda: counts.update(record_swarm_until(obs, disk / "run.mcap", done, seen)), daemon=True)
        stamps: dict[int, list[tuple[int, float]]] = defaultdict(list)
        try:
            th.start()
            assert wait_until(lambda: any("file" in st for st in seen), 20.0)
            _fly(nodes, 1.5, stamps)
            fill(disk / "filler")
            _fly(nodes, 4.0, stamps)
            assert any(st.get("sealed") == str(disk / "run.mcap") for st in seen), seen
            (disk / "filler").unlink()
            assert wait_until(lambda: any(st.get("file") == str(disk / "run-2.mcap") for st in seen), 5.0), seen
            t_back = time.time()
            _fly(nodes, 2.0, stamps)
            done.set()
            th.join(30)
        finally:
            done.set()
            obs.close()
            for nd in nodes:
                nd.close()
        assert counts["unwritten"] > 0 and seen[-1]["unwritten"] == counts["unwritten"]
        for f in ("run.mcap", "run-2.mcap"):
            rec = Recording(disk / f)
            assert sum(1 for _ in read_recording(disk / f, rec)) > 0 and rec.complete and rec.error is None, (f, rec)
        later = {m.sequence for m in read_recording(disk / "run-2.mcap") if m.schema == "mrswarm.Pose"}
        assert {seq for seq, t in stamps[1] if t > t_back + 0.5} - later == set()


def record_swarm_until(obs: SwarmObserver, path: Path, done: threading.Event, seen: list[dict]) -> dict[str, int]:
    return recording.record_swarm(obs, path, stop=done.is_set, status=seen.append)


def wait_until(pred: object, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():  # type: ignore[operator]
            return True
        time.sleep(0.05)
    return False
