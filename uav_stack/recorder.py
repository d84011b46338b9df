"""Run data written so that a crash loses at most a second.

Each UAV writes its own trajectory (CSV, appended and flushed every second) and its
counters (JSON, replaced atomically every second) into the run's results folder; the
runner merges them afterwards.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, TextIO

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


def write_json_atomic(path: str | Path, data: dict[str, Any]) -> None:
    path = Path(path)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data))
    os.replace(tmp, path)
