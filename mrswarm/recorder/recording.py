"""The recording loop: capture a swarm, translate, write MCAP; used by ``mrswarm gcs record --mcap`` and the runner.

The loop drains the capture every :data:`POLL` s, writes every record, adds a SceneUpdate of the
swarm at 5 Hz and the recorder's own counters once a second, and flushes the file every second.
With a run folder (the runner's recorder), it also keeps the run's files inside the recording:
the scenario and network description at the start, the UAVs' counter files (``uav<N>.json``,
which hold the netem link statistics) every ``counters_every`` s as ``/uav/<N>/counters``, and at
the end every file ``mrswarm results`` needs besides the trajectories (``run.json``,
``uav<N>.json``, ``age_uav<N>.csv``, ``age_links_uav<N>.json``) as attachments.

A full or failing disk never ends the recording process. What the disk refuses waits in memory
(up to :data:`MAX_BACKLOG_BYTES`) and is written when the disk takes it again; beyond that the
file is sealed at its last flush and the recording goes on counting what it cannot write
(``unwritten``), trying every :data:`RETRY_S` s to continue in a new file beside it (``run-2.mcap``,
:func:`~mrswarm.recorder.run_recorder.next_segment`). ``status`` hears of every file begun and sealed, and of the totals.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from types import FrameType

from groundfloor.process import on_stop_signals
from mrswarm.recorder import schemas as sc
from mrswarm.recorder.capture import SwarmCapture
from mrswarm.recorder.mcap_writer import DiskError, McapWriter
from mrswarm.recorder.records import Record, Translator
from mrswarm.recorder.run_recorder import next_segment
from swarmnet.observer import SwarmObserver
from swarmnet.version import __version__
from uav_stack.recorder import LINKS_GLOB

POLL = 0.02  # s between two drains: the resolution of the arrival times
COUNTERS_EVERY = 5.0  # s between two readings of the UAVs' counter files
START_FILES = ("scenario.yaml", "network.json")
END_GLOBS = ("run.json", "uav*.json", "age_uav*.csv", LINKS_GLOB)
MEDIA_TYPES = {".json": "application/json", ".yaml": "application/yaml", ".csv": "text/csv"}
MAX_BACKLOG_BYTES = 8 * 1024 * 1024  # records kept in memory while the disk refuses them
RETRY_S = 2.0  # s between two tries to begin a new file after one was given up


class Segments:
    """The recording's files: the one being written, and what the disk refused (the process goes on)."""

    def __init__(self, path: Path, begin: Callable[[McapWriter], None], status: Callable[[dict[str, object]], None]):
        self.first = path
        self.begin_file = begin  # what a new file gets first (metadata, the run's start files)
        self.status = status
        self.writer: McapWriter | None = None
        self.files: list[str] = []
        self.unwritten = 0  # records given up for good
        self.disk_errors = 0  # refusals (a retried flush counts each time)
        self.last_error = ""
        self._retry_at = 0.0

    def open(self, path: Path) -> bool:
        """Begin ``path``; False (the file removed again) if the disk refuses its start."""
        try:
            w = McapWriter(path)
        except OSError as exc:
            self._failed(exc)
            return False
        try:
            self.begin_file(w)
        except OSError as exc:
            self._failed(exc)
            w.abandon()
            path.unlink(missing_ok=True)
            return False
        self.writer = w
        self.files.append(str(path))
        self.status({"file": str(path)})
        return True

    def _failed(self, exc: OSError) -> None:
        self.disk_errors += 1
        self.last_error = f"{exc.strerror or exc}"
        self._retry_at = time.monotonic() + RETRY_S

    def write(self, rec: Record) -> None:
        if self.writer is None:
            self.unwritten += 1
        else:
            self.writer.write(rec)

    def guard(self, action: Callable[[McapWriter], None]) -> None:
        """``action`` on the file being written; a refusal keeps its records in memory, too many seal the file."""
        w = self.writer
        if w is None:
            if time.monotonic() >= self._retry_at:
                self.open(next_segment(self.first))
            return
        try:
            action(w)
        except DiskError as exc:
            self._failed(exc)
            if w.backlog > MAX_BACKLOG_BYTES:
                self.give_up()

    def flush_now(self, w: McapWriter) -> None:
        """Flush when due, and say up to when the file holds the records (a restarted recorder's gap starts there)."""
        if w.maybe_flush():
            self.status({"flushed": round(time.time(), 3)})

    def give_up(self) -> None:
        """Seal the current file at its last flush; its records still in memory are unwritten."""
        w = self.writer
        if w is None:
            return
        self.writer = None
        self.unwritten += w.unflushed
        w.abandon()
        self.status({"sealed": str(w.path), "unwritten": self.unwritten, "error": self.last_error})

    def close(self) -> None:
        w = self.writer
        if w is None:
            return
        self.writer = None
        try:
            w.close()
        except DiskError as exc:
            self._failed(exc)
            self.unwritten += w.unflushed


class Stop:
    """Set by SIGTERM or SIGINT: the loop finishes the file and returns (a second signal is not needed)."""

    def __init__(self) -> None:
        self.requested = False
        self.signum: int | None = None

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        self.requested = True
        self.signum = signum

    def install(self) -> None:
        on_stop_signals(self)


def record_swarm(observer: SwarmObserver, path: str | Path, *, duration: float | None = None, run_dir: Path | None = None,
                 lockstep: bool = False, stop: Callable[[], bool] = lambda: False, counters_every: float = COUNTERS_EVERY,
                 report: Callable[[dict[str, int]], None] | None = None,
                 status: Callable[[dict[str, object]], None] = lambda st: None) -> dict[str, int]:
    """Record ``observer``'s swarm into the MCAP file ``path`` until ``duration`` s pass or ``stop()``; return the counts
    (with ``unwritten``: records a full or failing disk took none of). ``lockstep``: a lock-step run, recorded in
    its simulated time (the last clock step's; ``duration`` stays wall s)."""
    capture = SwarmCapture(observer)
    translator = Translator(observer.keys.swarm, lockstep)

    def begin(writer: McapWriter) -> None:
        writer.metadata("recording", {"swarm": observer.keys.swarm, "mrswarm": __version__, "started": f"{time.time():.3f}",
                                      "run_dir": str(run_dir) if run_dir is not None else ""})
        if run_dir is not None:
            for name in START_FILES:
                _attach(writer, run_dir / name)

    files = Segments(Path(path), begin, status)
    if not files.open(Path(path)):  # created once the subscriptions exist: its existence says "recording"
        raise OSError(f"{path}: cannot begin the recording: {files.last_error}")
    end = math.inf if duration is None else time.monotonic() + duration
    next_stats = next_counters = time.monotonic()
    counters_seen: dict[Path, float] = {}
    try:
        while time.monotonic() < end and not stop():
            for rec in translator.translate(capture.drain()):
                files.write(rec)
            now = translator.clock(time.time())
            scene = translator.scene(now)
            if scene is not None:
                files.write(scene)
            mono = time.monotonic()
            if mono >= next_stats:
                next_stats = mono + 1.0
                files.write(translator.stats_record(now))
                if report is not None:
                    report(dict(translator.received))
            if run_dir is not None and mono >= next_counters:
                next_counters = mono + counters_every
                for rec in counter_records(run_dir, counters_seen, now):
                    files.write(rec)
            files.guard(files.flush_now)
            time.sleep(POLL)
        for rec in translator.translate(capture.drain()):  # what arrived during the last sleep
            files.write(rec)
    finally:
        try:
            capture.close()
            if run_dir is not None:
                for rec in counter_records(run_dir, counters_seen, translator.clock(time.time())):
                    files.write(rec)
                for pattern in END_GLOBS:
                    for p in sorted(run_dir.glob(pattern)):
                        files.guard(partial(_attach, path=p))
        finally:
            files.close()
            status({"end": True, "files": files.files, "unwritten": files.unwritten, "disk_errors": files.disk_errors,
                    "error": files.last_error})
    return {**translator.received, **({"unwritten": files.unwritten} if files.unwritten else {})}


def _attach(writer: McapWriter, path: Path) -> None:
    try:
        data = path.read_bytes()
    except OSError:
        return
    media = MEDIA_TYPES.get(path.suffix, "application/octet-stream")
    writer.attach(path.name, data, media)


def counter_records(run_dir: Path, seen: dict[Path, float], now: float) -> list[Record]:
    """The UAVs' counter files that changed since last read, as ``/uav/<N>/counters`` records."""
    out = []
    for p in sorted(run_dir.glob("uav*.json")):
        stem = p.stem[3:]
        if not stem.isdigit():
            continue
        try:
            mtime = p.stat().st_mtime
            if seen.get(p) == mtime:
                continue
            data = p.read_bytes()
        except OSError:
            continue
        seen[p] = mtime
        ns = int(now * 1e9)
        out.append(Record(sc.uav_topic(int(stem), "counters"), "mrswarm.Counters", ns, int(mtime * 1e9), 0, data))
    return out
