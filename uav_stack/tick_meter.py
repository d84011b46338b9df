"""The CPU a virtual UAV's tick spends in each of its parts, measured in the running process.

Why: a UAV's loop wakes ten times a second and runs each piece of its stack once, with the
caches that other processes evicted in between, so a piece costs several times what it costs in
a loop of its own (``benchmarks/tick_cost.py`` measures both). A profiler that charges a
microsecond to every call, or samples a few thousand times a second, shows where the calls
are, not what each part of the tick costs. This meter reads the thread's CPU clock
(``CLOCK_THREAD_CPUTIME_ID``, ns) around a fixed list of the tick's parts, about thirty calls
per tick, and writes, at the end of the run, the calls per tick and the CPU per tick (µs) of
each part, nested parts included in their callers.

Off unless asked for: ``MRSWARM_TICK_METER=<folder>`` in a virtual UAV's environment
(``python -m uav_stack.virtual_uav``) writes ``<folder>/tick_uav<N>.json``. It wraps bound
methods of the live objects (an instance attribute shadows the class's method), so nothing
changes in the code it measures; a part an object does not have is skipped.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from uav_stack.recorder import write_json_atomic

ENV = "MRSWARM_TICK_METER"
SENSE = "agent: sense (FCU in, own pose out)"  # once per tick, whole or in halves: the tick counter

# (label, path from the roots "fcu" and "agent", method): the parts of a tick, outermost first.
PARTS: tuple[tuple[str, str, str], ...] = (
    ("fcu: datagrams in (and steps due)", "fcu", "poll_io"),
    ("fcu: service (steps, heartbeat, wake-up)", "fcu", "service"),
    ("fcu: steps due (physics, supervisor, telemetry)", "fcu", "_advance"),
    ("fcu: physics step", "fcu.dyn", "step"),
    ("fcu: supervisor (failsafes, modes)", "fcu.vehicles[0]", "tick"),
    ("fcu: telemetry encoded and queued", "fcu.vehicles[0]", "send_due_telemetry"),
    ("fcu: a datagram handled (setpoints, commands)", "fcu", "_on_datagram"),
    ("fcu: datagrams sent", "fcu", "_flush"),
    (SENSE, "agent", "_sense"),
    ("agent: FCU link read and parsed", "agent.link", "poll"),
    ("agent: own pose published (Zenoh put)", "agent.node", "publish_pose"),
    ("agent: act (swarm in, control, reports)", "agent", "_act"),
    ("agent: swarm in (node poll, commands)", "agent", "react"),
    ("agent: swarm in: node poll (poses into the table)", "agent.node", "poll"),
    ("agent: swarm in: arrivals taken in", "agent.node", "_take_in"),
    ("agent: swarm in: silent neighbours expired", "agent.node.neighbours", "expire"),
    ("agent: control (behaviour, setpoint out)", "agent", "_control"),
    ("agent: control: flight (mission, avoidance, setpoint)", "agent", "_fly"),
    ("agent: control: the mission's velocity", "agent.mission", "velocity"),
    ("agent: control: neighbours taken (ages at use)", "agent.node", "take_neighbours"),
    ("agent: control: avoidance", "agent.avoidance", "adjust"),
    ("agent: control: setpoint sent", "agent.link", "send_velocity_ned"),
    ("agent: failsafes", "agent.failsafes", "step"),
    ("agent: trajectory row", "agent", "_record"),
    ("agent: counters file, flushes (1 Hz)", "agent", "write_stats"),
    ("agent: counters gathered (1 Hz)", "agent", "stats"),
    ("agent: telemetry published (2 Hz)", "agent.node", "publish_telemetry"),
    ("agent: state published (1 Hz)", "agent.node", "publish_state"),
    ("loop: poses of the instant expected", "agent.node", "expect_poses"),
    ("loop: sleep until the next instant (select)", "agent.node.waker", "wait"),
)


def _resolve(roots: dict[str, Any], path: str) -> Any:
    """``"fcu.vehicles[0]"`` -> that object, or None where the path ends early."""
    head, *rest = path.split(".")
    obj = roots.get(head)
    for part in rest:
        if obj is None:
            return None
        name, _, index = part.partition("[")
        obj = getattr(obj, name, None)
        if index and obj is not None:
            obj = obj[int(index.rstrip("]"))]
    return obj


def threads_cpu_ns(pid: int | str = "self") -> dict[int, tuple[str, int]]:
    """Each thread of process ``pid`` (default: this one): its name (``comm``) and the CPU (ns) it
    has run so far, from the scheduler's own account (``/proc/<pid>/task/*/schedstat``), by thread
    id. Empty where there is no such file (not Linux, or the process is gone)."""
    out: dict[int, tuple[str, int]] = {}
    try:
        tasks = list(Path(f"/proc/{pid}/task").iterdir())
    except OSError:
        return out
    for task in tasks:
        try:
            out[int(task.name)] = ((task / "comm").read_text().strip(), int((task / "schedstat").read_text().split()[0]))
        except (OSError, ValueError, IndexError):  # a thread that ended meanwhile
            pass
    return out


def thread_kind(tid: int, comm: str, loop_tid: int, loop_comm: str) -> str:
    """``"loop"`` (the thread the meter measures), ``"python"`` (another thread of the interpreter:
    a pose inlet's, which keeps the process's name) or ``"zenoh"`` (Zenoh's runtime, whose threads
    carry names of their own: ``app-0``, ``rx-0``, ...)."""
    if tid == loop_tid:
        return "loop"
    return "python" if comm == loop_comm else "zenoh"


class TickMeter:
    """Thread CPU per part of the tick, from :func:`attach` to :meth:`write`, into ``folder``;
    and the CPU per tick of the process's other threads (Zenoh's, the pose inlet's) beside it."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.totals: dict[str, list[int]] = {}  # label -> [calls, thread CPU ns]
        self._t0 = time.thread_time_ns()
        self._wall0 = time.monotonic()
        self._loop_tid = threading.get_native_id()
        self._threads0 = threads_cpu_ns()

    def threads(self, ticks: int) -> dict[str, float]:
        """µs of CPU per tick since the meter started, by :func:`thread_kind`; a thread started
        since counts from its start."""
        loop_comm = self._threads0.get(self._loop_tid, ("", 0))[0]
        out = {"loop": 0.0, "python": 0.0, "zenoh": 0.0}
        for tid, (comm, ns) in threads_cpu_ns().items():
            kind = thread_kind(tid, comm, self._loop_tid, loop_comm)
            out[kind] += (ns - self._threads0.get(tid, (comm, 0))[1]) / ticks / 1e3
        return {k: round(v, 1) for k, v in out.items()}

    def wrap(self, obj: Any, method: str, label: str) -> None:
        fn: Callable[..., Any] = getattr(obj, method)
        acc = self.totals.setdefault(label, [0, 0])
        clock = time.thread_time_ns

        def timed(*args: Any, **kwargs: Any) -> Any:
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                acc[0] += 1
                acc[1] += clock() - t0

        setattr(obj, method, timed)

    def report(self) -> dict[str, Any]:
        """Per tick: calls and µs of thread CPU for each part, and the whole thread's."""
        ticks = max(self.totals.get(SENSE, [0, 0])[0], 1)
        total_ns = time.thread_time_ns() - self._t0
        return {
            "ticks": ticks,
            "wall_s": round(time.monotonic() - self._wall0, 3),
            "thread_cpu_us_per_tick": round(total_ns / ticks / 1e3, 1),
            "threads_us_per_tick": self.threads(ticks),  # the loop's, again, from the scheduler; Zenoh's; other Python
            "parts": [{"part": label, "calls_per_tick": round(n / ticks, 3), "cpu_us_per_tick": round(ns / ticks / 1e3, 1),
                       "cpu_us_per_call": round(ns / n / 1e3, 1) if n else None}
                      for label, (n, ns) in self.totals.items()],
        }

    def write(self, name: str) -> None:
        """The report, as ``folder/name`` (replaced whole)."""
        write_json_atomic(self.folder / name, self.report())


def attach(agent: Any, fcu: Any) -> TickMeter | None:
    """A meter on every part in :data:`PARTS` that ``agent`` and ``fcu`` have, from now, writing
    into the folder :data:`ENV` names; None when it names none (the meter is off)."""
    value = os.environ.get(ENV, "")
    if not value:
        return None
    meter = TickMeter(Path(value))
    roots = {"agent": agent, "fcu": fcu}
    for label, path, method in PARTS:
        obj = _resolve(roots, path)
        if obj is not None and callable(getattr(obj, method, None)):
            meter.wrap(obj, method, label)
    return meter
