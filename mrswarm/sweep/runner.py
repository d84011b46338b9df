"""Flying a campaign: every slot not yet complete, one at a time or side by side when the machine has room.

The campaign folder (``--out``) holds ``campaign.yaml`` (the campaign as flown), ``runs/`` (a
folder per slot, :mod:`mrswarm.sweep.slots`), the tables and the plots. Running the same command
again resumes: a complete run is never flown again, an interrupted one is. A lock
(``.sweep.lock``) keeps two sweeps out of one campaign folder.

Stopping: the first SIGINT, SIGTERM or SIGHUP starts no further run and is forwarded to every
running one, which stops its UAVs and writes its summary as an interrupted run (the next sweep
flies it again); a second signal is forwarded too (the runs stop faster). The tables and plots
are then written from the complete runs, and the sweep says how to resume.

Where and how a run flies is the launcher's business (:class:`~mrswarm.sweep.launch.Launcher`: a
child ``mrswarm run`` here, a job on a Docker Swarm in :mod:`mrswarm.sweep.swarm_jobs`); the
schedule only asks it to start, poll and signal runs, and asks
:class:`~mrswarm.sweep.capacity.Capacity` whether another fits, from each run's need. A run in
simulated rather than wall-clock time would be one more launcher (its runs' command line and
need: CPU-bound, as many cores as it is given), refusing, as the swarm launcher does, a scenario
with an external flight controller; the slots, resume, tables and progress stay as they are.
"""

from __future__ import annotations

import fcntl
import os
import shlex
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from rich.console import Console

from groundfloor.errors import MrswarmError
from groundfloor.process import usable_cores
from mrswarm.records.summary import write_atomic
from mrswarm.run.resources import check_resources
from mrswarm.run.signals import StopSignals
from mrswarm.sweep.campaign import Plan, Slot, campaign_yaml
from mrswarm.sweep.capacity import Capacity, ClusterCapacity, Need, exclusive_problem
from mrswarm.sweep.launch import Flight, Launcher, LocalLauncher, RunOptions
from mrswarm.sweep.progress import Estimator, SweepProgress, duration
from mrswarm.sweep.slots import SlotRecord, SlotState, attempt_of, slot_dir, status
from mrswarm.sweep.table import CAMPAIGN_COPY

TICK_S = 0.5
LOCK_FILE = ".sweep.lock"

EXIT_OK = 0  # every run complete, none failed
EXIT_FAILED = 1  # every run flown, some failed (their runner gave up, or they recorded nothing)
EXIT_USAGE = 2  # bad campaign, grid or scenario; a campaign folder of another campaign; locked


class SweepError(MrswarmError):
    """The campaign cannot be flown into this folder (exit 2)."""


@dataclass
class Pending:
    slot: Slot
    folder: Path
    record: SlotRecord


class Sweep:
    def __init__(self, plan: Plan, out: Path, console: Console, *, parallel: int | str = 1, retry_failed: bool = False,
                 opts: RunOptions | None = None, live: bool = True, signals: StopSignals | None = None,
                 resume_command: str = "", err: Console | None = None, launcher: Launcher | None = None) -> None:
        self.plan = plan
        self.out = out
        self.console = console
        self.err = err or Console(stderr=True)
        self.retry_failed = retry_failed
        self.opts = opts or RunOptions(record=plan.campaign.record)
        self.live = live
        self.signals = signals or StopSignals()
        self.resume_command = resume_command
        self.launcher: Launcher = launcher or LocalLauncher(plan.scenario_path, self.opts)
        self.local = isinstance(self.launcher, LocalLauncher)
        if self.local:
            self.limit = usable_cores() if parallel == "auto" else int(parallel)
            self.capacity: Capacity = Capacity(self.limit)
        else:
            self.limit = self._cluster_limit() if parallel == "auto" else int(parallel)
            self.capacity = ClusterCapacity(self.limit)
        self.estimator = Estimator()
        self._lock: IO[str] | None = None

    def _cluster_limit(self) -> int:
        """Jobs submitted at once on a swarm by default: as many as the cluster's cores hold at the largest need."""
        from mrswarm.sweep.swarm_jobs import SwarmJobs

        assert isinstance(self.launcher, SwarmJobs)
        need = max(Capacity(1).need(s.scenario, "").cores for s in self.plan.slots)
        return max(1, int(self.launcher.cores // max(need, 0.1)))

    # ---- before flying: the folder, the slots' state, the machine -----------------------------------------------
    def check(self) -> tuple[list[Pending], int, int]:
        """The slots to fly (in order), and how many are complete (ok, failed). Raises SweepError."""
        plan = self.plan
        cells = {s.cell.index: s for s in plan.slots}.values()
        if self.local and self.limit > 1:
            for s in plan.slots:
                problem = exclusive_problem(s.scenario)
                if problem:
                    raise SweepError(f"{plan.scenario_path}: {problem}")
        if self.local and not self.opts.force:
            for s in cells:
                problem = check_resources(s.scenario)
                if problem:
                    raise SweepError(f"{plan.scenario_path}: {s.cell.label}: {problem}")
        if not self.local:
            from mrswarm.sweep.swarm_jobs import SwarmJobs

            assert isinstance(self.launcher, SwarmJobs)
            for s in cells:
                problem = self.launcher.problem(s.scenario, self.capacity.need(s.scenario, str(s.cell.index)))
                if problem:
                    raise SweepError(f"{plan.scenario_path}: {s.cell.label}: --on swarm: {problem}")
            left = self.launcher.leftovers()
            if left:
                names = " ".join(sv.name for sv in left)
                raise SweepError(f"{len(left)} job(s) of this campaign are still in the swarm (a sweep stopped without "
                                 f"removing them): let them end, or remove them with `docker service rm {names}`")
        todo: list[Pending] = []
        ok = failed = 0
        for s in plan.slots:
            folder = slot_dir(self.out, s.name)
            st = status(folder)
            rec = st.record
            if rec is not None and rec.digest != s.digest:
                raise SweepError(f"{folder}: flown with another scenario than this campaign gives it ({s.label}): the "
                                 "scenario file, the campaign's `set` or the grid changed since; fly into another --out")
            if rec is None:
                rec = SlotRecord(cell=s.cell.values, seed=s.seed, overrides=list(s.overrides), digest=s.digest)
            if st.state != SlotState.PENDING and st.run_dir is not None:
                a = attempt_of(rec, st.run_dir)
                if a is not None and a.wall_s is not None:
                    self.estimator.flown(s, a.wall_s)
                    if a.cpu_s is not None and a.wall_s > 0:
                        self.capacity.measured(str(s.cell.index), a.cpu_s / a.wall_s)
            if st.state == SlotState.OK or (st.state == SlotState.FAILED and not self.retry_failed):
                ok += st.state == SlotState.OK
                failed += st.state == SlotState.FAILED
                continue
            todo.append(Pending(s, folder, rec))
        return todo, ok, failed

    def _take_lock(self) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        f = open(self.out / LOCK_FILE, "a+")  # noqa: SIM115 - held for the whole sweep
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            pid = f.read().strip()
            f.close()
            raise SweepError(f"{self.out}: another sweep is flying this campaign{f' (pid {pid})' if pid else ''}") from None
        f.seek(0)
        f.truncate()
        f.write(f"{os.getpid()}\n")
        f.flush()
        self._lock = f

    def _release_lock(self) -> None:
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    # ---- flying ------------------------------------------------------------------------------------------------
    def run(self) -> int:
        """Fly what is left of the campaign; the exit code (0, 1, 2, or 128 + the stop signal)."""
        try:
            self._take_lock()
            todo, ok, failed = self.check()
        except (SweepError, OSError) as exc:
            self.err.print(f"[red]error:[/] {exc}", highlight=False, soft_wrap=True)
            self._release_lock()
            return EXIT_USAGE
        try:
            return self._fly(todo, ok, failed)
        finally:
            self._release_lock()

    def _fly(self, todo: list[Pending], ok: int, failed: int) -> int:
        plan = self.plan
        write_atomic(self.out / CAMPAIGN_COPY, campaign_yaml(plan).encode())
        total = len(plan.slots)
        for note in plan.notes:
            self.console.print(f"[yellow]note:[/] {plan.scenario_path}: {note}", highlight=False, soft_wrap=True)
        cells, seeds = len(plan.cells), len(plan.campaign.seed_list)
        head = (f"[bold]{plan.name}[/]: {cells} cell{'s' if cells != 1 else ''} x {seeds} seed{'s' if seeds != 1 else ''} "
                f"= {total} runs of {plan.scenario_path}, into {self.out}")
        if ok + failed:
            head += f"; {ok + failed} complete already, {len(todo)} to fly"
        self.console.print(head, highlight=False, soft_wrap=True)
        if not todo:  # nothing left to fly: the report again
            return self._end(ok + failed, failed, total)
        if not self.local:
            self.console.print(f"on {self.launcher.where}: up to {self.limit} jobs at once, each placed by Swarm on a "
                               f"node with room for it", highlight=False)
        elif self.limit > 1:
            self.console.print(f"parallel: up to {self.limit} runs at once when the machine has room "
                               f"({self.capacity.cores} cores)", highlight=False)
        running: list[Flight] = []
        forwarded = 0
        done, n_failed = ok + failed, failed
        from mrswarm.sweep.report import refresh_tables

        with SweepProgress(self.console, total, done, self.live) as progress:
            while todo or running:
                busy_now = self.capacity.sample()
                for r in running:
                    if busy_now is not None:
                        r.busy.append(busy_now)
                    r.attempt.concurrent = max(r.attempt.concurrent, len(running))
                if len(self.signals.received) > forwarded:  # forward each new stop signal to every run
                    sig = self.signals.received[forwarded]
                    forwarded += 1
                    for r in running:
                        r.signal(sig)
                for r in [r for r in running if r.poll()]:
                    running.remove(r)
                    st = status(r.folder)
                    if st.state == SlotState.PENDING:  # interrupted, killed, or never started: flown again next time
                        code = r.attempt.exit_code
                        how = "interrupted" if self.signals.requested else "ended without a complete summary"
                        progress.say(f"[yellow]{r.slot.label}: {how}[/] ({f'exit {code}, ' if code is not None else ''}"
                                     f"{r.log_path}); the next sweep flies it again")
                        continue
                    done += 1
                    if r.attempt.wall_s is not None:
                        self.estimator.flown(r.slot, r.attempt.wall_s)
                        if r.attempt.cpu_s is not None and r.attempt.wall_s > 0:
                            self.capacity.measured(str(r.slot.cell.index), r.attempt.cpu_s / r.attempt.wall_s)
                    if st.state == SlotState.FAILED:
                        n_failed += 1
                        progress.say(f"[red]{r.slot.label}: failed[/] ({st.why}; {st.run_dir})")
                    else:
                        progress.say(f"{r.slot.label}: done in {duration(r.attempt.wall_s or 0)}{_headline(st.summary)}")
                    try:
                        refresh_tables(self.out)
                    except OSError as exc:
                        progress.say(f"[yellow]warning:[/] cannot write the tables: {exc}")
                progress.waiting = ""
                while todo and not self.signals.requested:
                    nxt = todo[0]
                    need = self.capacity.need(nxt.slot.scenario, str(nxt.slot.cell.index))
                    why = self.capacity.admits(need, [self._need(r) for r in running])
                    if why:
                        progress.waiting = why if len(running) < self.limit else ""
                        break
                    todo.pop(0)
                    try:
                        launch = self.launcher.start(nxt.slot, nxt.folder, nxt.record, need)
                    except Exception as exc:  # noqa: BLE001 - OSError here, a docker API error on a swarm: say it, stop
                        progress.say(f"[red]error:[/] cannot start a run in {nxt.folder}: {exc}")
                        todo.clear()
                        break
                    self.capacity.started()
                    running.append(launch)
                    if not progress.live:
                        progress.say(f"{nxt.slot.label}: flying ({nxt.folder})")
                if self.signals.requested and todo and not running:
                    break
                progress.update(done, n_failed, running, self.estimator.time_left([p.slot for p in todo], running,
                                                                                   max(1, len(running))))
                time.sleep(TICK_S)
        return self._end(done, n_failed, total)

    def _need(self, r: Flight) -> Need:
        return self.capacity.need(r.slot.scenario, str(r.slot.cell.index))

    def _end(self, done: int, failed: int, total: int) -> int:
        from mrswarm.sweep.report import build_report

        try:
            paths = build_report(self.out, console=self.console)
        except OSError as exc:
            self.console.print(f"[yellow]warning:[/] cannot write the report: {exc}")
            paths = []
        if paths:
            self.console.print(results_line(self.out, paths), highlight=False, soft_wrap=True)
        if self.signals.requested:
            left = total - done
            self.console.print(f"[yellow]{self.signals.names[0]}:[/] stopped with {done} of {total} runs complete; "
                               f"{left} left. Resume with:\n    {self.resume_command}", highlight=False, soft_wrap=True)
            return self.signals.exit_code
        if failed:
            self.console.print(f"[red]{failed} of {total} runs failed[/] (their runner gave up; see runs.csv, column why); "
                               "--retry-failed flies them again", highlight=False)
            return EXIT_FAILED
        if done < total:
            self.console.print(f"[red]{total - done} of {total} runs did not complete[/] (see their attempt logs); the next "
                               f"sweep flies them again:\n    {self.resume_command}", highlight=False, soft_wrap=True)
            return EXIT_FAILED
        return EXIT_OK


def _headline(summary: dict[str, object] | None) -> str:
    """A run's result in a few words: coverage time, minimum separation, RTF."""
    from mrswarm.sweep.table import summary_value

    if summary is None:
        return ""
    out = []
    t90 = summary_value(summary, "coverage.time_to_90_s")
    final = summary_value(summary, "coverage.final")
    if final is not None:
        out.append(f"90 % covered at {t90:.1f} s" if t90 is not None else f"covered {100 * final:.0f} %")
    sep = summary_value(summary, "separation.min_during_mission_m")
    if sep is not None:
        out.append(f"min separation {sep:.1f} m")
    rtf = summary_value(summary, "rtf.mean")
    if rtf is not None:
        out.append(f"RTF {rtf:.3f}")
    return f": {', '.join(out)}" if out else ""


def results_line(folder: Path, paths: list[Path]) -> str:
    """``results in DIR: runs.csv, cells.csv, overview.png, plots/ (5)``."""
    top = [p.name for p in paths if p.parent == folder]
    inner = [p for p in paths if p.parent != folder]
    return f"results in {folder}: " + ", ".join(top) + (f", plots/ ({len(inner)} figures)" if inner else "")


def resume_command(argv: list[str]) -> str:
    return "mrswarm sweep " + " ".join(shlex.quote(a) for a in argv)
