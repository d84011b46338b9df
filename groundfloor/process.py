"""A process's life: it dies with its parent, stops on a signal, and its output never ends it.

**Dying with the parent.** Linux sends a process the signal it asked for with
``prctl(PR_SET_PDEATHSIG)`` when the thread that started it ends, even when that parent was
killed with SIGKILL, so no child outlives a runner, a test or a launcher. Two ways to ask:

* :func:`die_with_parent_preexec`: the ``preexec_fn`` of a ``subprocess.Popen``, run in the
  child between fork and exec (no start-up race: a child whose parent is already gone exits);
* :func:`die_with_parent`: from the child's own code, first thing (a process started by
  something that gave it ``--die-with-parent``).

Elsewhere than on Linux both do nothing.

**Stop signals.** :func:`on_stop_signals` installs one handler for SIGTERM and SIGINT (and
returns the handlers it replaced); :func:`stop_event` gives a ``threading.Event`` they set. A
handler only records the request: the process's own loop looks at it and stops from there.

**Output.** :func:`say` prints a line and drops it if it cannot be written (a full disk under the
log file); :func:`setup_logging` sends log records to stderr or a file, and falls back to stderr
when the file cannot be opened. Neither ever ends the process.
"""

from __future__ import annotations

import functools
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from types import FrameType
from typing import Any

log = logging.getLogger(__name__)

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)

SignalHandler = Callable[[int, FrameType | None], Any]


@functools.cache
def _prctl() -> Callable[..., int] | None:
    """libc's ``prctl`` (resolved once, in the parent: a child between fork and exec only calls it), or None."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    try:
        fn: Callable[..., int] = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    return fn


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity; the machine's count where there is none)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def die_with_parent(sig: int = signal.SIGTERM) -> None:
    """Ask Linux to send this process ``sig`` when the process that launched it dies."""
    prctl = _prctl()
    if prctl is not None:
        prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)


def die_with_parent_preexec(parent: int, sig: int = signal.SIGTERM) -> Callable[[], None]:
    """A ``preexec_fn`` that makes the child get ``sig`` when ``parent`` (this process) dies.

    Runs in the child between fork and exec, so no start-up race: if the parent is already gone
    by then, the child exits at once instead of running as an orphan.
    """
    prctl = _prctl()

    def set_pdeathsig() -> None:
        if prctl is not None:
            prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
        if os.getppid() != parent:
            os._exit(1)

    return set_pdeathsig


def on_stop_signals(handler: SignalHandler, signals: Iterable[int] = STOP_SIGNALS) -> dict[int, Any]:
    """Install ``handler`` for each of ``signals`` (main thread only); the handlers it replaced, by signal."""
    return {sig: signal.signal(sig, handler) for sig in signals}


def stop_event(signals: Iterable[int] = STOP_SIGNALS) -> threading.Event:
    """An event that any of ``signals`` sets (installed now, in the main thread)."""
    stop = threading.Event()
    on_stop_signals(lambda *_: stop.set(), signals)
    return stop


def say(line: str) -> None:
    """A line on standard output; one that cannot be written (a full disk under the log) is dropped, not fatal."""
    try:
        print(line, flush=True)
    except OSError:
        pass


LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def setup_logging(level: str = "WARNING", log_file: str | None = None, *, unknown: int = logging.WARNING) -> None:
    """Log records at ``level`` (a name; ``unknown`` if it names no level) to stderr, or to ``log_file``
    (its folder made if missing; stderr, with a warning, if it cannot be opened)."""
    handlers: list[logging.Handler] = [logging.StreamHandler(sys.stderr)]
    problem = ""
    if log_file:
        try:
            Path(log_file).parent.mkdir(parents=True, exist_ok=True)
            handlers = [logging.FileHandler(log_file)]
        except OSError as exc:
            problem = f"cannot write the log file {log_file} ({exc.strerror or exc}): logging to stderr"
    logging.basicConfig(level=getattr(logging, level.upper(), unknown), handlers=handlers, format=LOG_FORMAT)
    if problem:
        log.warning("%s", problem)
