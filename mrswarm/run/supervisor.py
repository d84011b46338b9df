"""Watching the run's processes: a process that exits is an event of the experiment, not its end.

Every tick the runner asks the :class:`Supervisor` what exited. Each exit becomes a
:class:`~mrswarm.records.summary.ProcessEvent` (time, exit code or signal, a UAV's last pose), and:

* the **discovery server** and the **edge router** are started again with exponential backoff
  (0.5 s, doubling up to 10 s; the delay starts again from 0.5 s once a service has stayed up
  30 s). Their state comes back by itself: every node re-announces itself to the discovery
  server each beacon period, and every Zenoh node dials its configured edge router again.
* the runner's **flight recorder** (mrswarm/recorder/run_recorder.py) too, from 0.1 s: its file
  is sealed where it stopped, and the new recorder continues in the next file (``run-2.mcap``);
  the runner records when it records again (an event ``resumed``), so the gap is known.
* a **UAV** that exits is *lost*: the runner goes on without it (its neighbours expire it
  within the liveliness lease and re-split the coverage). With ``fleet.restart: on-failure``,
  a UAV that exited with a non-zero code or a signal is started again (same backoff, at most
  :data:`MAX_UAV_RESTARTS` times); it comes back on the ground at its spawn point and the runner
  sends it ``start`` so it rejoins the mission.

A planned restart (the fault schedule's ``restart_*``) goes through :meth:`Supervisor.restart_now`,
so it is recorded once and not mistaken for a crash.
"""

from __future__ import annotations

import logging
import re
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import msgspec

from mrswarm.records.summary import RECORDER, SERVICES, ProcessEvent, uav_of

log = logging.getLogger(__name__)

BACKOFF_FIRST_S = 0.5
FIRST_BACKOFF_S = {RECORDER: 0.1}  # a recorder that is down loses data: back at once, then the usual backoff
BACKOFF_MAX_S = 10.0
STABLE_AFTER_S = 30.0  # up this long: the next failure starts the backoff from the beginning again
MAX_UAV_RESTARTS = 3
LOG_TAIL_BYTES = 16384  # how much of a failed process's log is read for its last error
_LOGGED_ERROR = re.compile(r" (?:ERROR|CRITICAL) [\w.]+: (.+)$")  # groundfloor.process.LOG_FORMAT
_RAISED = re.compile(r"^(?:[\w.]+\.)?\w*(?:Error|Exception|Exit)\b.*$")  # a traceback's last line


def is_service(name: str) -> bool:
    """Restarted whenever it exits: the discovery server, every swarm's edge router (``router-<swarm>``
    for the other swarms of an airspace, docs/world.md) and the flight recorder. Not the world service: a restarted world
    would start its experiment again (the fire lit anew), so its exit stays an event."""
    return name in SERVICES or name.startswith("router-")


def signal_name(code: int | None) -> str | None:
    """``SIGKILL`` for an exit code of -9 (Popen's convention for "killed by a signal")."""
    if code is None or code >= 0:
        return None
    try:
        return signal.Signals(-code).name
    except ValueError:
        return f"signal {-code}"


def last_error(log_path: Path | None) -> str:
    """The last error a process wrote to its log: a record logged as ERROR or CRITICAL (its
    message), or the last line of a traceback; "" if there is none or the log cannot be read.

    Why: "uav3 exited (exit code 2)" leaves the user to find and open the log; the line that
    says why (a taken port, a bad key file) is what they need, next to the exit."""
    if log_path is None:
        return ""
    try:
        with open(log_path, "rb") as f:
            f.seek(0, 2)
            f.seek(max(0, f.tell() - LOG_TAIL_BYTES))
            lines = f.read().decode(errors="replace").splitlines()
    except OSError:
        return ""
    for line in reversed(lines):
        line = line.rstrip()
        m = _LOGGED_ERROR.search(line)
        if m:
            return m.group(1)[:300]
        if _RAISED.match(line):
            return line[:300]
    return ""


class Processes(Protocol):
    """What the supervisor watches: the runtime (mrswarm.run.runtime.Runtime), or :class:`RunnerChildren`."""

    def pids(self) -> dict[str, int]: ...

    def exited(self) -> dict[str, int]: ...

    def restart(self, name: str, grace: float = 3.0) -> None: ...


class OwnChild(Protocol):
    """A process the runner starts itself, beside the runtime's (the flight recorder)."""

    @property
    def pid(self) -> int: ...

    def poll(self) -> int | None: ...

    def restart(self, grace: float = 3.0) -> None: ...


class RunnerChildren:
    """The runtime's processes and the runner's own, as one set for the supervisor."""

    def __init__(self, runtime: Processes, own: dict[str, OwnChild]):
        self.runtime = runtime
        self.own = own

    def pids(self) -> dict[str, int]:
        return {**self.runtime.pids(), **{n: c.pid for n, c in self.own.items()}}

    def exited(self) -> dict[str, int]:
        out = dict(self.runtime.exited())
        for n, c in self.own.items():
            code = c.poll()
            if code is not None:
                out[n] = code
        return out

    def restart(self, name: str, grace: float = 3.0) -> None:
        if name in self.own:
            self.own[name].restart(grace)
        else:
            self.runtime.restart(name, grace)


@dataclass
class _Watch:
    pid: int
    started: float  # wall
    backoff: float = BACKOFF_FIRST_S
    restarts: int = 0
    due: float | None = None  # wall time of a scheduled restart


class Supervisor:
    """Turns process exits into events, and restarts what should come back."""

    def __init__(self, runtime: Processes, restart_uavs: bool = False, clock: Callable[[], float] = time.time,
                 pools: dict[str, tuple[int, ...]] | None = None,
                 last_pose: Callable[[int], list[float] | None] = lambda uav: None,
                 log_of: Callable[[str], Path | None] = lambda name: None):
        """``last_pose``: a UAV's last pose the runner received; ``log_of``: a process's log file,
        where a failed process's last error is read from."""
        self.runtime = runtime
        self.restart_uavs = restart_uavs
        self.clock = clock
        # pool processes (pool1, ...) -> the UAVs each hosts: a pool's exit or restart is an event of each
        self.pools = dict(pools or {})
        self._pool_of = {u: name for name, uavs in self.pools.items() for u in uavs}
        self.last_pose = last_pose
        self.log_of = log_of
        self.events: list[ProcessEvent] = []
        self.down: dict[str, float] = {}  # name -> wall time it was seen exited, until it is back
        self._watch: dict[str, _Watch] = {}
        self._new: list[ProcessEvent] = []  # recorded by restart_now, returned by the next check

    def adopt(self) -> None:
        """Start watching every process the runtime has started (after the launch)."""
        now = self.clock()
        for name, pid in self.runtime.pids().items():
            if name not in self._watch:
                self._watch[name] = _Watch(pid, now, backoff=FIRST_BACKOFF_S.get(name, BACKOFF_FIRST_S))

    def check(self) -> list[ProcessEvent]:
        """New events since the last call: exits seen now, restarts done now."""
        now = self.clock()
        new, self._new = self._new, []
        found: list[ProcessEvent] = []  # exits seen now, restarts done now
        exited = self.runtime.exited()
        if exited:
            pids = self.runtime.pids()
            for name, code in exited.items():
                w = self._watch.get(name)
                pid = pids.get(name)
                if w is None or name in self.down or (pid and pid != w.pid):
                    # not ours, an exit already handled, or running again (a new pid). An exited
                    # container's pid is 0: without that test, no container's exit was ever an event
                    continue
                found.append(self._exited(name, code, now, w))
        for name, w in self._watch.items():
            if w.due is not None and now >= w.due:
                w.due = None
                restarted = self._restart(name, now, w)
                if restarted is not None:
                    found.append(restarted)
        found = [e for ev in found for e in self._per_uav(ev)]  # a pool's event is one of each of its UAVs
        self.events += found
        return new + found

    def process_of(self, uav: int) -> str:
        """The process a UAV runs in: ``uav<N>``, or the pool hosting it."""
        return self._pool_of.get(uav, f"uav{uav}")

    def _per_uav(self, ev: ProcessEvent) -> list[ProcessEvent]:
        uavs = self.pools.get(ev.name)
        if uavs is None:
            return [ev]
        where = f"in {ev.name}"
        return [msgspec.structs.replace(ev, name=f"uav{u}", detail=f"{where}; {ev.detail}" if ev.detail else where,
                                        last_pose=self.last_pose(u) if ev.event == "exited" else ev.last_pose)
                for u in uavs]

    def _exited(self, name: str, code: int | None, now: float, w: _Watch) -> ProcessEvent:
        self.down[name] = now
        uav = uav_of(name) if name not in self.pools else None
        ev = ProcessEvent(t=now, name=name, event="exited", exit_code=code, signal=signal_name(code),
                          last_pose=self.last_pose(uav) if uav is not None else None)
        if now - w.started >= STABLE_AFTER_S:
            w.backoff = FIRST_BACKOFF_S.get(name, BACKOFF_FIRST_S)
        failed = code is None or code != 0
        if failed:
            ev.error = last_error(self.log_of(name))
        hosts_uavs = uav is not None or name in self.pools
        if is_service(name) or (hosts_uavs and self.restart_uavs and failed and w.restarts < MAX_UAV_RESTARTS):
            w.due = now + w.backoff
            ev.detail = f"restart in {w.backoff:g} s"
            w.backoff = min(BACKOFF_MAX_S, 2 * w.backoff)
        log.info("%s exited (%s)%s%s", name, ev.signal or f"code {code}", f": {ev.error}" if ev.error else "",
                 f"; {ev.detail}" if ev.detail else "")
        return ev

    def _restart(self, name: str, now: float, w: _Watch) -> ProcessEvent | None:
        try:
            self.runtime.restart(name)
        except Exception as exc:  # noqa: BLE001 - a failed restart is retried, never the end of the run
            w.due = now + w.backoff
            w.backoff = min(BACKOFF_MAX_S, 2 * w.backoff)
            log.info("restarting %s failed: %s", name, exc)
            return ProcessEvent(t=now, name=name, event="restart_failed", detail=f"{type(exc).__name__}: {exc}"[:200])
        w.pid = self.runtime.pids()[name]
        w.started = self.clock()
        w.restarts += 1
        self.down.pop(name, None)
        return ProcessEvent(t=w.started, name=name, event="restarted", detail=f"restart {w.restarts}")

    def restart_now(self, name: str) -> ProcessEvent | None:
        """A planned restart (stop, start again), recorded as one event."""
        w = self._watch.get(name)
        if w is None:
            return None
        w.due = None
        ev = self._restart(name, self.clock(), w)
        if ev is not None:
            ev.detail = "planned restart" if ev.event == "restarted" else ev.detail
            self.events.append(ev)
            self._new.append(ev)
        return ev

    def restarting(self, name: str) -> bool:
        """Down, with a restart scheduled (``uav<N>``: its process, or its pool)."""
        uav = uav_of(name)
        name = self.process_of(uav) if uav is not None else name
        w = self._watch.get(name)
        return name in self.down and w is not None and w.due is not None
