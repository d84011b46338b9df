"""One run of a sweep: ``mrswarm run SCENARIO --out <slot> --no-live --set ...`` in a child process.

Why a child process rather than an :class:`~mrswarm.run.experiment.Experiment` in the sweep's own:
a run of a sweep is then exactly what ``mrswarm run`` does (its input checks, its exit codes,
its stop on a signal, its summary), every run starts from a fresh interpreter (no Zenoh session,
thread or module state carried from one run to the next, no memory growing over hundreds of
runs), a run that crashes cannot take the campaign with it, and the CPU time of a run is the
operating system's account of that process and everything it waited for (``wait4``).

The child gets its own session (a Ctrl-C in the terminal reaches the sweep only, which forwards
it: each run sees one signal per Ctrl-C, as when it runs alone) and ``PR_SET_PDEATHSIG``: if the
sweep is killed outright, its runs get SIGTERM, stop their UAVs and write their summaries as
interrupted runs, which the next sweep flies again.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Protocol

from deploy.process_runtime import die_with_parent_preexec
from mrswarm.sweep.campaign import Slot
from mrswarm.sweep.capacity import Need
from mrswarm.sweep.slots import Attempt, SlotRecord, new_attempt, run_folders, write_record

LOG_TAIL_BYTES = 4096


@dataclass
class RunOptions:
    """What every run of the sweep is given besides its overrides."""

    record: bool = True  # the flight recording (run.mcap)
    force: bool = False  # mrswarm run --force: fly a fleet that looks too large for the machine
    log_level: str = "INFO"


def run_command(scenario: Path, slot: Slot, folder: Path, opts: RunOptions) -> list[str]:
    """The command line of one run: ``mrswarm run`` as a user would type it."""
    argv = [sys.executable, "-m", "mrswarm", "run", str(scenario), "--out", str(folder), "--no-live",
            "--log-level", opts.log_level]
    for o in slot.overrides:
        argv += ["--set", o]
    if not opts.record:
        argv.append("--no-record")
    if opts.force:
        argv.append("--force")
    return argv


class Flight(Protocol):
    """A run flying somewhere, as the schedule (mrswarm/sweep/runner.py) sees it."""

    slot: Slot
    folder: Path
    record: SlotRecord
    attempt: Attempt
    log_path: Path
    busy: list[float]

    @property
    def elapsed(self) -> float: ...

    def last_line(self) -> str: ...

    def signal(self, sig: int) -> None: ...

    def poll(self) -> bool: ...


class Launcher(Protocol):
    """Where the runs fly: this machine (:class:`LocalLauncher`), a Docker Swarm (mrswarm/sweep/swarm_jobs.py)."""

    where: str

    def start(self, slot: Slot, folder: Path, record: SlotRecord, need: Need) -> Flight: ...


@dataclass
class LocalLauncher:
    """Every run a child process of the sweep, on this machine."""

    scenario: Path
    opts: RunOptions
    where: str = "this machine"

    def start(self, slot: Slot, folder: Path, record: SlotRecord, need: Need) -> Flight:
        return start(self.scenario, slot, folder, record, self.opts)


def tail_line(path: Path) -> str:
    """The last line a run printed (its stage, its progress line)."""
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - LOG_TAIL_BYTES))
            tail = f.read().decode(errors="replace")
    except OSError:
        return ""
    lines = [ln.strip() for ln in tail.splitlines() if ln.strip()]
    return lines[-1] if lines else ""


@dataclass
class Launch:
    """A run flying: its child process, its slot's record and what the sweep measures of it."""

    slot: Slot
    folder: Path
    record: SlotRecord
    attempt: Attempt
    proc: subprocess.Popen[bytes]
    log_path: Path
    before: set[str]
    t0: float = field(default_factory=time.monotonic)
    busy: list[float] = field(default_factory=list)  # the machine's CPU share, sampled while it flies
    signals_sent: int = 0
    _log: IO[bytes] | None = None

    @property
    def elapsed(self) -> float:
        return time.monotonic() - self.t0

    def last_line(self) -> str:
        return tail_line(self.log_path)

    def signal(self, sig: int) -> None:
        """Forward a stop signal to the runner (it stops its UAVs and writes an interrupted summary)."""
        if self.proc.returncode is None:
            try:
                os.kill(self.proc.pid, sig)
                self.signals_sent += 1
            except ProcessLookupError:
                pass

    def poll(self) -> bool:
        """True once the run's process has exited (its attempt then holds the exit code, times and run folder)."""
        if self.proc.returncode is not None:
            return True
        try:
            pid, wstatus, usage = os.wait4(self.proc.pid, os.WNOHANG)
        except ChildProcessError:  # reaped elsewhere: no CPU account
            pid, wstatus, usage = self.proc.pid, 0, None
        if pid == 0:
            return False
        code = os.waitstatus_to_exitcode(wstatus) if usage is not None else None
        self.proc.returncode = code if code is not None else -1
        self._finish(code, usage.ru_utime + usage.ru_stime if usage is not None else None)
        return True

    def _finish(self, code: int | None, cpu: float | None) -> None:
        a = self.attempt
        a.ended = time.time()
        a.exit_code = 128 - code if code is not None and code < 0 else code  # killed by signal N: 128 + N, as a shell says
        a.wall_s = round(time.monotonic() - self.t0, 3)
        a.cpu_s = round(cpu, 3) if cpu is not None else None
        a.machine_busy = round(sum(self.busy) / len(self.busy), 4) if self.busy else None
        made = [d for d in run_folders(self.folder) if d.name not in self.before]
        a.run_dir = made[-1].name if made else None
        if self._log is not None:
            self._log.close()
            self._log = None
        write_record(self.folder, self.record)


def start(scenario: Path, slot: Slot, folder: Path, record: SlotRecord, opts: RunOptions) -> Launch:
    """Start one run of ``slot`` in ``folder`` (its slot folder), its console output into ``attempt-<n>.log``."""
    folder.mkdir(parents=True, exist_ok=True)
    before = {d.name for d in run_folders(folder)}
    attempt = new_attempt(record)
    write_record(folder, record)
    log_path = folder / f"attempt-{attempt.number}.log"
    log = open(log_path, "wb")  # noqa: SIM115 - closed when the run ends (Launch._finish)
    env = dict(os.environ, COLUMNS=os.environ.get("COLUMNS", "120"))
    try:
        proc = subprocess.Popen(run_command(scenario, slot, folder, opts), stdin=subprocess.DEVNULL, stdout=log,
                                stderr=subprocess.STDOUT, start_new_session=True, env=env,
                                preexec_fn=die_with_parent_preexec(os.getpid(), signal.SIGTERM))
    except OSError:
        log.close()
        raise
    return Launch(slot=slot, folder=folder, record=record, attempt=attempt, proc=proc, log_path=log_path, before=before,
                  _log=log)
