"""Helpers for the resilience tests: a `mrswarm run` in the background whose every descendant can be found.

Each run gets a unique tag in its environment (``MRSWARM_TEST_TAG``); every process it starts
inherits it, so :func:`survivors` finds any of them still alive afterwards with psutil, even one
re-parented to init after its runner died.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import Any

import psutil

ROOT = Path(__file__).resolve().parents[1]
TAG = "MRSWARM_TEST_TAG"


def survivors(tag: str) -> list[psutil.Process]:
    """Live processes (not zombies) carrying ``tag`` in their environment."""
    out = []
    for p in psutil.process_iter(["pid", "status"]):
        try:
            if p.info["status"] == psutil.STATUS_ZOMBIE or p.pid == os.getpid():
                continue
            if p.environ().get(TAG) == tag:
                out.append(p)
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
            continue
    return out


def wait_no_survivors(tag: str, timeout: float = 10.0) -> list[psutil.Process]:
    deadline = time.monotonic() + timeout
    left = survivors(tag)
    while left and time.monotonic() < deadline:
        time.sleep(0.2)
        left = survivors(tag)
    return left


def kill_survivors(tag: str) -> None:
    for p in survivors(tag):
        try:
            p.kill()
        except psutil.NoSuchProcess:
            pass


class BackgroundRun:
    """``mrswarm run`` as a child process with its own tag, output captured to a file."""

    def __init__(self, scenario: Path, out: Path, sets: list[str] = (), extra: list[str] = (),  # type: ignore[assignment]
                 log: Path | None = None):
        """``log``: where the run's output goes (default: beside ``out``)."""
        self.out = out
        out.mkdir(parents=True, exist_ok=True)
        self.tag = uuid.uuid4().hex
        self.log_path = log or out.parent / f"{out.name}.stdout"
        args = [sys.executable, "-m", "mrswarm", "run", str(scenario), "--out", str(out), "--no-live", *extra]
        for s in sets:
            args += ["--set", s]
        env = dict(os.environ, **{TAG: self.tag})
        with open(self.log_path, "w") as log:
            self.proc = subprocess.Popen(args, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=env)
        self.started = time.time()

    @property
    def output(self) -> str:
        return self.log_path.read_text(errors="replace")

    def run_dir(self) -> Path | None:
        dirs = [d for d in self.out.iterdir() if d.is_dir()] if self.out.exists() else []
        return dirs[0] if len(dirs) == 1 else None

    def run_info(self) -> dict[str, Any]:
        d = self.run_dir()
        if d is None:
            return {}
        try:
            return json.loads((d / "run.json").read_text())
        except (OSError, ValueError):
            return {}

    def wait_mission(self, timeout: float = 90.0, after: float = 0.0) -> float:
        """Wait until the mission started (run.json says so) plus ``after`` s; the mission start (wall)."""
        deadline = time.time() + timeout
        while time.time() < deadline:
            start = self.run_info().get("mission_start")
            if start:
                time.sleep(max(0.0, start + after - time.time()))
                return float(start)
            if self.proc.poll() is not None:
                raise AssertionError(f"the run ended before its mission started:\n{self.output[-3000:]}")
            time.sleep(0.1)
        raise AssertionError(f"no mission start after {timeout:.0f} s:\n{self.output[-3000:]}")

    def signal(self, sig: int) -> None:
        os.kill(self.proc.pid, sig)

    def wait(self, timeout: float = 120.0) -> int:
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            kill_survivors(self.tag)
            raise AssertionError(f"the run did not end within {timeout:.0f} s:\n{self.output[-3000:]}") from None

    def cleanup(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)
        kill_survivors(self.tag)


def last_rows(run_dir: Path) -> dict[int, float]:
    """Wall time of the last trajectory row of each UAV."""
    import csv

    out = {}
    for path in run_dir.glob("uav*.csv"):
        with open(path, newline="") as f:
            rows = [r for r in csv.DictReader(f) if r.get("t_wall")]
        if rows:
            out[int(path.stem[3:])] = max(float(r["t_wall"]) for r in rows)
    return out
