"""One run of a sweep inside a Docker Swarm job's container:
``python -m mrswarm.sweep.job --result R --log L --stop S -- CMD``.

It runs ``CMD`` (``mrswarm run ... --out <slot>``) with its console output in ``L`` and writes
``R`` (:class:`JobResult`): first where it runs (the node's host name), so that the sweep knows
the campaign folder is shared with that node, then its exit code, wall time and CPU time (the
run and everything it waited for, ``wait4``).

Stopping: a signal number the sweep appends to ``S`` (a line each, in the shared campaign
folder) is sent to the run, which stops its UAVs and writes its summary as an interrupted run;
a second one makes it stop faster, as a second Ctrl-C does. The file, not the container's stop
signal, because Docker leaves a replicated job's task running when its service is removed. A
signal to the wrapper itself (the container stopped by hand) is forwarded the same way.
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from types import FrameType

import msgspec

from mrswarm.records.summary import write_atomic

POLL_S = 0.2  # the run's exit and the stop file, checked this often


class JobResult(msgspec.Struct):
    node: str  # the host name of the node the job ran on
    started: float  # wall
    ended: float | None = None
    exit_code: int | None = None  # as mrswarm run's (128 + N when signal N ended it)
    wall_s: float | None = None
    cpu_s: float | None = None


def read_result(path: Path) -> JobResult | None:
    try:
        return msgspec.json.decode(path.read_bytes(), type=JobResult)
    except (OSError, msgspec.DecodeError, msgspec.ValidationError):
        return None


def stop_signals(path: Path) -> list[int]:
    """The signal numbers in a stop file (none if it is not there)."""
    try:
        text = path.read_text()
    except OSError:
        return []
    out = []
    for line in text.splitlines():
        try:
            out.append(int(line))
        except ValueError:
            continue
    return [s for s in out if s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)]


def ask_stop(path: Path, sig: int) -> None:
    """The sweep's side: one more stop signal for the run."""
    with open(path, "a") as f:
        f.write(f"{int(sig)}\n")
        f.flush()
        os.fsync(f.fileno())


def _write(path: Path, r: JobResult) -> None:
    write_atomic(path, msgspec.json.encode(r) + b"\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mrswarm.sweep.job")
    ap.add_argument("--result", required=True, type=Path)
    ap.add_argument("--log", required=True, type=Path)
    ap.add_argument("--stop", type=Path, default=None, help="a file the sweep appends stop signals to (one number a line)")
    ap.add_argument("command", nargs=argparse.REMAINDER)
    args = ap.parse_args(argv)
    cmd = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not cmd:
        ap.error("name the command after --")
    result = JobResult(node=socket.gethostname(), started=time.time())
    _write(args.result, result)
    t0 = time.monotonic()
    with open(args.log, "ab") as log:
        child = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)

    def forward(signum: int, frame: FrameType | None) -> None:
        try:
            os.kill(child.pid, signum)
        except ProcessLookupError:
            pass

    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, forward)
    sent = 0
    while True:
        pid, status, usage = os.wait4(child.pid, os.WNOHANG)
        if pid:
            break
        asked = stop_signals(args.stop) if args.stop is not None else []
        for signum in asked[sent:]:
            forward(signum, None)
        sent = max(sent, len(asked))
        time.sleep(POLL_S)
    code = os.waitstatus_to_exitcode(status)
    child.returncode = code
    result.ended = time.time()
    result.exit_code = 128 - code if code < 0 else code
    result.wall_s = round(time.monotonic() - t0, 3)
    result.cpu_s = round(usage.ru_utime + usage.ru_stime, 3)
    _write(args.result, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
