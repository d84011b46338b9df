"""Run data written so that a crash loses at most a second.

Each UAV writes its own trajectory (CSV, appended and flushed every second) and its
counters (JSON, replaced atomically every second) into the run's results folder; the
runner merges them afterwards.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, TextIO

import msgspec

TRAJECTORY_COLUMNS = ("t_wall", "t_sim", "x", "y", "z", "vx", "vy", "vz", "yaw", "phase", "mode", "armed", "rtf")


class TrajectoryRecorder:
    def __init__(self, path: str | Path, flush_every: float = 1.0):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.exists()
        self._f: TextIO = open(self.path, "a", buffering=64 * 1024)  # noqa: SIM115 (open until close())
        if new:
            self._f.write(",".join(TRAJECTORY_COLUMNS) + "\n")
        self.flush_every = flush_every
        self._last_flush = 0.0

    def write(self, now: float, row: tuple[Any, ...]) -> None:
        self._f.write(",".join(f"{v:.3f}" if isinstance(v, float) else str(v) for v in row) + "\n")
        if now - self._last_flush >= self.flush_every:
            self.flush(now)

    def flush(self, now: float = 0.0) -> None:
        self._f.flush()
        self._last_flush = now

    def close(self) -> None:
        if not self._f.closed:
            self._f.flush()
            self._f.close()


_encode = msgspec.json.Encoder().encode  # ~10x faster than json.dumps on the counters; NaN becomes null


def write_json_atomic(path: str | Path, data: dict[str, Any]) -> None:
    """Replace ``path`` with ``data`` as JSON (temporary file, then rename: a reader never sees half)."""
    tmp = f"{path}.tmp"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        os.write(fd, _encode(data))
    finally:
        os.close(fd)
    os.replace(tmp, path)
