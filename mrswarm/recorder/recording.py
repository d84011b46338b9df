"""The recording loop: capture a swarm, translate, write MCAP; used by ``mrswarm gcs record --mcap`` and the runner.

The loop drains the capture every :data:`POLL` s, writes every record, adds a SceneUpdate of the
swarm at 5 Hz and the recorder's own counters once a second, and flushes the file every second.
With a run folder (the runner's recorder), it also keeps the run's files inside the recording:
the scenario and network description at the start, the UAVs' counter files (``uav<N>.json``,
which hold the netem link statistics) every ``counters_every`` s as ``/uav/<N>/counters``, and at
the end every file ``mrswarm results`` needs besides the trajectories (``run.json``,
``uav<N>.json``, ``age_uav<N>.csv``, ``age_links_uav<N>.json``) as attachments.
"""

from __future__ import annotations

import math
import signal
import time
from collections.abc import Callable
from pathlib import Path
from types import FrameType

from mrswarm.recorder import schemas as sc
from mrswarm.recorder.capture import SwarmCapture
from mrswarm.recorder.mcap_writer import McapWriter
from mrswarm.recorder.records import Record, Translator
from swarmnet.observer import SwarmObserver
from swarmnet.version import __version__
from uav_stack.recorder import LINKS_GLOB

POLL = 0.02  # s between two drains: the resolution of the arrival times
COUNTERS_EVERY = 5.0  # s between two readings of the UAVs' counter files
START_FILES = ("scenario.yaml", "network.json")
END_GLOBS = ("run.json", "uav*.json", "age_uav*.csv", LINKS_GLOB)
MEDIA_TYPES = {".json": "application/json", ".yaml": "application/yaml", ".csv": "text/csv"}


class Stop:
    """Set by SIGTERM or SIGINT: the loop finishes the file and returns (a second signal is not needed)."""

    def __init__(self) -> None:
        self.requested = False
        self.signum: int | None = None

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        self.requested = True
        self.signum = signum

    def install(self) -> None:
        signal.signal(signal.SIGTERM, self)
        signal.signal(signal.SIGINT, self)


def record_swarm(observer: SwarmObserver, path: str | Path, *, duration: float | None = None, run_dir: Path | None = None,
                 stop: Callable[[], bool] = lambda: False, counters_every: float = COUNTERS_EVERY,
                 report: Callable[[dict[str, int]], None] | None = None) -> dict[str, int]:
    """Record ``observer``'s swarm into the MCAP file ``path`` until ``duration`` s pass or ``stop()``; return the counts."""
    capture = SwarmCapture(observer)
    translator = Translator(observer.keys.swarm)
    writer = McapWriter(path)  # created once the subscriptions exist: its existence says "recording"
    writer.metadata("recording", {"swarm": observer.keys.swarm, "mrswarm": __version__, "started": f"{time.time():.3f}",
                                  "run_dir": str(run_dir) if run_dir is not None else ""})
    if run_dir is not None:
        for name in START_FILES:
            _attach(writer, run_dir / name)
    end = math.inf if duration is None else time.monotonic() + duration
    next_stats = next_counters = time.monotonic()
    counters_seen: dict[Path, float] = {}
    try:
        while time.monotonic() < end and not stop():
            for rec in translator.translate(capture.drain()):
                writer.write(rec)
            now = time.time()
            scene = translator.scene(now)
            if scene is not None:
                writer.write(scene)
            mono = time.monotonic()
            if mono >= next_stats:
                next_stats = mono + 1.0
                writer.write(translator.stats_record(now))
                if report is not None:
                    report(dict(translator.received))
            if run_dir is not None and mono >= next_counters:
                next_counters = mono + counters_every
                for rec in counter_records(run_dir, counters_seen, now):
                    writer.write(rec)
            writer.maybe_flush()
            time.sleep(POLL)
        for rec in translator.translate(capture.drain()):  # what arrived during the last sleep
            writer.write(rec)
    finally:
        try:
            capture.close()
            if run_dir is not None:
                for rec in counter_records(run_dir, counters_seen, time.time()):
                    writer.write(rec)
                for pattern in END_GLOBS:
                    for p in sorted(run_dir.glob(pattern)):
                        _attach(writer, p)
        finally:
            writer.close()
    return dict(translator.received)


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
