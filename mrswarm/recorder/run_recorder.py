"""The runner's flight recorder: ``mrswarm gcs record --mcap <run>/run.mcap --run <run>`` beside the UAVs.

It is its own process, a ground-station client of the run's edge router like any other: a
recorder that falls behind or dies never slows or stops the run, its CPU is measured apart, and
it records what crossed the network with the arrival times at the edge. The runner starts it once
the router is up and before the first UAV (so the first pose is recorded), and stops it after
the UAVs and after ``run.json`` is written (so the file keeps the run's final counters).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

MCAP_NAME = "run.mcap"
START_TIMEOUT = 20.0  # s for the recorder to import, join the swarm and create its file
STOP_TIMEOUT = 20.0  # s to write the last chunk, the attachments and the summary


class RunRecorder:
    """A running recorder process; :meth:`stop` finishes its file."""

    def __init__(self, proc: subprocess.Popen[bytes], path: Path):
        self.proc = proc
        self.path = path

    @classmethod
    def start(cls, run_dir: Path, timeout: float = START_TIMEOUT) -> RunRecorder:
        """Start recording the run in ``run_dir`` (its network.json must exist); returns once the file exists.

        Raises RuntimeError if the recorder exits or creates no file within ``timeout`` s.
        """
        path = run_dir / MCAP_NAME
        (run_dir / "logs").mkdir(exist_ok=True)
        argv = [sys.executable, "-m", "mrswarm", "gcs", "record", str(path), "--mcap", "--run", str(run_dir), "--quiet",
                "--die-with-parent"]
        with open(run_dir / "logs" / "recorder.log", "ab") as log:  # the child keeps its own descriptor
            proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        rec = cls(proc, path)
        deadline = time.monotonic() + timeout
        while not (path.exists() and path.stat().st_size > 0):
            if proc.poll() is not None:
                raise RuntimeError(f"the recorder exited with code {proc.returncode} (see {run_dir / 'logs' / 'recorder.log'})")
            if time.monotonic() > deadline:
                rec.stop(timeout=2.0)
                raise RuntimeError(f"the recorder created no {path.name} within {timeout:.0f} s")
            time.sleep(0.05)
        return rec

    @property
    def pid(self) -> int:
        return self.proc.pid

    def stop(self, timeout: float = STOP_TIMEOUT) -> int | None:
        """SIGTERM (the recorder then finishes its file), SIGKILL after ``timeout`` s; returns the exit code."""
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(self.proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                self.proc.wait(5)
        return self.proc.returncode
