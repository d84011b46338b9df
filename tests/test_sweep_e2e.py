"""``mrswarm sweep`` for real: N = 2, 3 x 2 seeds of a short coverage mission from one command, SIGINT to the
sweep mid-campaign, a rerun that skips the complete runs and flies the interrupted one again, the tables with
their intervals, the plots, and ``--report`` rebuilding them from the folder alone."""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
from scipy import stats as sps

from tests.conftest import wait_for
from tests.run_helpers import TAG, kill_survivors, wait_no_survivors

ROOT = Path(__file__).resolve().parents[1]
MINI = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"

pytestmark = pytest.mark.e2e


def _sweep(args: list[str], log: Path, tag: str) -> subprocess.Popen[bytes]:
    env = dict(os.environ, **{TAG: tag})
    with open(log, "ab") as f:
        return subprocess.Popen([sys.executable, "-m", "mrswarm", "sweep", *args], cwd=ROOT, stdout=f, stderr=subprocess.STDOUT,
                                env=env)


def _summary(run_dir: Path) -> dict[str, object] | None:
    try:
        return json.loads((run_dir / "summary.json").read_text())
    except (OSError, ValueError):
        return None


def _runs(slot: Path) -> list[Path]:
    return sorted(d for d in slot.iterdir() if d.is_dir()) if slot.is_dir() else []


def test_a_sweep_survives_sigint_and_a_rerun_and_writes_its_table_and_plots(tmp_path: Path) -> None:
    campaign = tmp_path / "n.yaml"
    campaign.write_text(f"scenario: {MINI}\nset: {{duration: 6}}\ngrid: {{fleet.count: [2, 3]}}\nseeds: 2\n"
                        "metrics: [coverage.final, separation.min_during_mission_m, rtf.mean, cpu_cores]\n")
    out = tmp_path / "camp"
    log = tmp_path / "sweep.log"
    tag = uuid.uuid4().hex
    args = [str(campaign), "--out", str(out), "--no-live", "--no-record"]
    first, second = out / "runs" / "count-2_seed-0", out / "runs" / "count-3_seed-0"
    try:
        proc = _sweep(args, log, tag)
        # the first run complete, the second one flying: then Ctrl-C to the sweep alone
        assert wait_for(lambda: any(_summary(d) for d in _runs(first)) and any((d / "run.json").exists() for d in _runs(second)),
                        timeout=120, period=0.2), log.read_text()
        time.sleep(2.0)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=90) == 130, log.read_text()
        said = log.read_text()
        assert "Resume with:" in said and f"--out {out}" in said
        assert wait_no_survivors(tag, timeout=15) == [], "a process of the interrupted run outlived the sweep"
        done = _runs(first)
        assert len(done) == 1 and _summary(done[0])["interrupted"] is False  # type: ignore[index]
        (cut,) = _runs(second)
        assert _summary(cut)["interrupted"] is True  # type: ignore[index]  # stopped, summarised, to be flown again
        assert not (out / "runs" / "count-2_seed-1").exists()  # nothing started after the signal
        kept = (done[0] / "summary.json").stat().st_mtime_ns

        # the rerun: the complete run is not flown again, the interrupted one is, and the rest
        rerun = _sweep(args, log, tag)
        assert rerun.wait(timeout=300) == 0, log.read_text()
    finally:
        kill_survivors(tag)
    assert "1 complete already, 3 to fly" in log.read_text()
    assert _runs(first) == done and (done[0] / "summary.json").stat().st_mtime_ns == kept
    again = _runs(second)
    assert len(again) == 2 and _summary(again[-1])["interrupted"] is False  # type: ignore[index]
    attempts = json.loads((second / "slot.json").read_text())["attempts"]
    assert [a["exit_code"] for a in attempts] == [130, 0]
    for slot in ("count-2_seed-1", "count-3_seed-1"):
        assert len(_runs(out / "runs" / slot)) == 1

    # one row per run with its overrides and seed; per cell, the mean and its t interval over the two seeds
    with open(out / "runs.csv") as f:
        rows = list(csv.DictReader(f))
    assert sorted((r["fleet.count"], r["seed"], r["status"]) for r in rows) == [
        ("2", "0", "ok"), ("2", "1", "ok"), ("3", "0", "ok"), ("3", "1", "ok")]
    for r in rows:
        assert 0.0 < float(r["coverage.final"]) <= 1.0 and float(r["rtf.mean"]) > 0.9
        assert float(r["cpu_s"]) > 0.0 and float(r["wall_s"]) > 6.0
        assert r["run_dir"].startswith(f"runs/count-{r['fleet.count']}_seed-{r['seed']}/")
    with open(out / "cells.csv") as f:
        cells = {(c["fleet.count"], c["metric"]): c for c in csv.DictReader(f)}
    for n in ("2", "3"):
        xs = [float(r["coverage.final"]) for r in rows if r["fleet.count"] == n]
        c = cells[(n, "coverage.final")]
        assert (int(c["runs"]), int(c["n"]), c["confidence"]) == (2, 2, "0.95")
        assert float(c["mean"]) == pytest.approx(sum(xs) / 2, rel=1e-5)
        if xs[0] != xs[1]:
            lo, hi = sps.t.interval(0.95, 1, loc=sum(xs) / 2, scale=sps.sem(xs))
            assert (float(c["ci_low"]), float(c["ci_high"])) == (pytest.approx(lo, rel=1e-4), pytest.approx(hi, rel=1e-4))
        else:
            assert float(c["ci_low"]) == pytest.approx(xs[0]) == float(c["ci_high"])
        sep = cells[(n, "separation.min_during_mission_m")]
        assert float(sep["ci_low"]) <= float(sep["mean"]) <= float(sep["ci_high"])
    # three UAVs cover more of the same field than two in the same time
    assert float(cells[("3", "coverage.final")]["mean"]) > float(cells[("2", "coverage.final")]["mean"])

    pngs = [out / "overview.png", *(out / "plots" / f"{m}.png" for m in
                                    ("coverage.final", "separation.min_during_mission_m", "rtf.mean", "cpu_cores"))]
    for p in pngs:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10_000, p

    # --report rebuilds the same table from the folder alone
    table = (out / "runs.csv").read_text()
    for p in [out / "runs.csv", out / "cells.csv", *pngs]:
        p.unlink()
    report = subprocess.run([sys.executable, "-m", "mrswarm", "sweep", "--report", str(out)], cwd=ROOT, capture_output=True,
                            text=True, timeout=120)
    assert report.returncode == 0, report.stdout + report.stderr
    assert (out / "runs.csv").read_text() == table
    assert all(p.exists() for p in pngs)
    assert not math.isnan(float(cells[("2", "rtf.mean")]["mean"]))


def test_a_run_flies_without_what_the_stack_image_leaves_out(tmp_path: Path) -> None:
    """A sweep's job on a swarm is ``mrswarm run --no-record`` inside the stack image, which has no matplotlib, mcap or
    websockets (deploy/images.py): the same run here, with those modules made unimportable, completes with its summary."""
    from deploy.images import IMAGE_EXCLUDES

    blocker = (
        "import importlib.abc, runpy, sys\n"
        f"LEFT_OUT = {tuple(IMAGE_EXCLUDES)!r}\n"
        "class LeftOut(importlib.abc.MetaPathFinder):\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] in LEFT_OUT:\n"
        "            raise ModuleNotFoundError(f'No module named {name!r} (left out of the image)')\n"
        "sys.meta_path.insert(0, LeftOut())\n"
        "sys.argv = ['mrswarm', *sys.argv[1:]]\n"
        "runpy.run_module('mrswarm', run_name='__main__')\n"
    )
    tag = f"noimg-{uuid.uuid4().hex[:6]}"
    out = tmp_path / "out"
    try:
        res = subprocess.run([sys.executable, "-c", blocker, "run", str(MINI), "--set", "duration=4", "--set", "fleet.count=2",
                              "--out", str(out), "--no-live", "--no-record"], cwd=ROOT, capture_output=True, text=True,
                             env=dict(os.environ, **{TAG: tag}), timeout=180)  # fmt: skip
        left = wait_no_survivors(tag, 5.0)
    finally:
        kill_survivors(tag)
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    assert not left, "processes outlived the run"
    (summary,) = out.glob("*/summary.json")
    s = json.loads(summary.read_text())
    assert s["uavs_recorded"] == 2 and s["aborted"] is None
