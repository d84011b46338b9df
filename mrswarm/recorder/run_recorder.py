"""The runner's flight recorder: ``mrswarm gcs record --mcap <run>/run.mcap --run <run>`` beside the UAVs.

It is its own process, a ground-station client of the run's edge router like any other: a
recorder that falls behind or dies never slows or stops the run, its CPU is measured apart, and
it records what crossed the network with the arrival times at the edge. The runner starts it once
the router is up and before the first UAV (so the first pose is recorded), and stops it after
the UAVs and after ``run.json`` is written (so the file keeps the run's final counters).

It is supervised like the edge services (mrswarm/run/supervisor.py): when it dies, its file is sealed
at its last whole record (:func:`~mrswarm.recorder.mcap_writer.seal`: readable, and closed as a
finished file is) and a new recorder continues in the next file beside it (``run-2.mcap``, ...).
Its output comes to the runner through a pipe, which the runner copies into ``logs/recorder.log``
(as far as the disk takes it) and reads the recorder's status lines from: which files it began or
sealed, and how many records a full disk took none of.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any

MCAP_NAME = "run.mcap"


def _seal(path: str) -> None:
    """:func:`~mrswarm.recorder.mcap_writer.seal`, imported only here: a runner that records nothing (the image of a
    sweep's job, which leaves mcap out) never needs it."""
    from mrswarm.recorder.mcap_writer import seal

    seal(path)


def next_segment(path: Path) -> Path:
    """The next free file beside a recording: ``run.mcap`` -> ``run-2.mcap``, ``run-3.mcap``, ..."""
    n = 2
    while (p := path.with_name(f"{path.stem}-{n}{path.suffix}")).exists():
        n += 1
    return p


START_TIMEOUT = 20.0  # s for the recorder to import, join the swarm and create its file
STOP_TIMEOUT = 20.0  # s to write the last chunk, the attachments and the summary
STATUS_PREFIX = "recorder-status "  # a line of `gcs record --status`: the recorder's state, as JSON


class RunRecorder:
    """The run's recorder process (the current one); :meth:`restart` starts the next, :meth:`stop` finishes its file."""

    def __init__(self, run_dir: Path, path: Path, lockstep: bool = False):
        self.run_dir = run_dir
        self.lockstep = lockstep  # a lock-step run: recorded in its simulated time
        self.first = path  # run.mcap: the later files are named after it
        self.path = path  # the file the current process writes
        self.files: list[str] = []  # every file begun, in order
        self.unwritten = 0  # records a full disk took none of, over every process so far
        self.flushed: float | None = None  # wall: the current process's file holds the records up to then
        self.previous_flushed: float | None = None  # the same for the process before a restart
        self.log_unwritten = 0  # bytes of its output the disk did not take into logs/recorder.log
        self.proc: subprocess.Popen[bytes] | None = None
        self._lock = threading.Lock()
        self._begun = threading.Event()  # the current process has begun its file
        self._resumed_reported = True  # whether the current process's start was reported (poll_resumed)
        self._unwritten_done = 0  # from processes that have ended
        self._unwritten_now = 0  # the current process's, from its status lines
        self._log: IO[bytes] | None = None
        self._reader: threading.Thread | None = None

    @classmethod
    def start(cls, run_dir: Path, timeout: float = START_TIMEOUT, lockstep: bool = False) -> RunRecorder:
        """Start recording the run in ``run_dir`` (its network.json must exist); returns once the file is begun.
        ``lockstep``: the run's time is lock-step's, and so is the recording's.

        Raises RuntimeError if the recorder exits or begins no file within ``timeout`` s.
        """
        rec = cls(run_dir, run_dir / MCAP_NAME, lockstep)
        rec._spawn()
        deadline = time.monotonic() + timeout
        while not rec._begun.wait(0.05):
            if rec.proc is not None and rec.proc.poll() is not None:
                raise RuntimeError(f"the recorder exited with code {rec.proc.returncode} (see {rec.log_path})")
            if time.monotonic() > deadline:
                rec.stop(timeout=2.0)
                raise RuntimeError(f"the recorder began no {rec.path.name} within {timeout:.0f} s")
        rec._resumed_reported = True
        return rec

    @property
    def log_path(self) -> Path:
        return self.run_dir / "logs" / "recorder.log"

    def _spawn(self) -> None:
        try:
            self.log_path.parent.mkdir(exist_ok=True)
            self._log = self._log or open(self.log_path, "ab")  # noqa: SIM115 (closed by stop)
        except OSError:  # a full or read-only disk: the output is read all the same, and dropped
            self._log = None
        argv = [sys.executable, "-m", "mrswarm", "gcs", "record", str(self.path), "--mcap", "--run", str(self.run_dir),
                "--quiet", "--status", "--die-with-parent", *(["--lockstep"] if self.lockstep else [])]
        self._begun.clear()
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                start_new_session=True)
        self.proc = proc
        self._reader = threading.Thread(target=self._read, args=(proc, self.path), name="recorder-output", daemon=True)
        self._reader.start()

    def _read(self, proc: subprocess.Popen[bytes], path: Path) -> None:
        """Copy the process's output into its log; take in its status lines."""
        assert proc.stdout is not None
        for line in proc.stdout:
            log = self._log
            if log is not None:
                try:
                    log.write(line)
                    log.flush()
                except OSError:
                    self.log_unwritten += len(line)
            if line.startswith(STATUS_PREFIX.encode()):
                try:
                    st: dict[str, Any] = json.loads(line[len(STATUS_PREFIX):])
                except ValueError:
                    continue
                self._status(st, path)

    def _status(self, st: dict[str, Any], path: Path) -> None:
        with self._lock:
            if isinstance(st.get("file"), str):
                if st["file"] not in self.files:
                    self.files.append(st["file"])
                if Path(st["file"]) == path and path == self.path:
                    self._begun.set()
            if isinstance(st.get("flushed"), (int, float)) and path == self.path:
                self.flushed = float(st["flushed"])
            if isinstance(st.get("unwritten"), int) and path == self.path:
                self._unwritten_now = st["unwritten"]
            self.unwritten = self._unwritten_done + self._unwritten_now

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def poll(self) -> int | None:
        """The current process's exit code, None while it runs."""
        return self.proc.poll() if self.proc is not None else None

    def restart(self, grace: float = 3.0) -> None:
        """Seal the file of the process that died (or is stopped now) and start the next one into a new file; returns
        at once (:meth:`poll_resumed` says when it records)."""
        if self.proc is not None and self.proc.poll() is None:
            self._signal(signal.SIGTERM)
            try:
                self.proc.wait(grace)
            except subprocess.TimeoutExpired:
                self._signal(signal.SIGKILL)
                self.proc.wait(5)
        if self._reader is not None:
            self._reader.join(1.0)
        for f in self.files:
            _seal(f)  # a killed writer's file ends as a closed one (a closed one is left as it is)
        with self._lock:
            self._unwritten_done = self.unwritten
            self._unwritten_now = 0
            self.previous_flushed, self.flushed = self.flushed, None
            self.path = next_segment(self.first)
        self._resumed_reported = False
        self._spawn()

    def poll_resumed(self) -> str | None:
        """The new file, once, when a restarted recorder has begun it; None otherwise."""
        if self._resumed_reported or not self._begun.is_set():
            return None
        self._resumed_reported = True
        return str(self.path)

    def _signal(self, sig: int) -> None:
        assert self.proc is not None
        try:
            os.killpg(self.proc.pid, sig)
        except ProcessLookupError:
            pass

    def stop(self, timeout: float = STOP_TIMEOUT) -> int | None:
        """SIGTERM (the recorder then finishes its file), SIGKILL after ``timeout`` s; returns the exit code."""
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self._signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self._signal(signal.SIGKILL)
                self.proc.wait(5)
        if self._reader is not None:
            self._reader.join(2.0)
        if self.proc.returncode not in (0, 130):
            for f in self.files:
                _seal(f)
        if self._log is not None:
            try:
                self._log.close()
            except OSError:
                pass
            self._log = None
        return self.proc.returncode
