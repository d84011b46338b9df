"""What the world service writes into a run folder (read back by ``mrswarm.results.world_report``).

Flushed every second, so an interrupted run keeps what happened:

- ``world.json``: the service's counters (readings per sensor type, actuations, traffic), its
  CPU time, experiment time 0 (``t0``, wall s) and when it last wrote;
- ``world_fire.csv``: once a second, the cells burning, burnt out, extinguished and ever
  ignited, the burnt area and the litres sprayed;
- ``world_fire.npz``: the grid (fuel, final state, ignition and out times per cell), at the end
  and every 10 s;
- ``world_plume.csv``: once a second, the source and the wind direction;
- ``world_estimates.csv``: every source estimate a UAV broadcast (``plume/estimate``);
- ``world_actuations.csv``: every actuator request: who, where the world placed it, litres
  asked and released, cells extinguished.

A write the disk refuses (full, read-only) never stops the service: it is counted (``unwritten``,
in ``world.json`` once the disk takes it again) and logged once a minute.
"""

from __future__ import annotations

import csv
import logging
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import numpy as np

from groundfloor.files import replacing, write_json_atomic
from world.model import World

SAMPLE_S = 1.0
GRID_EVERY_S = 10.0
log = logging.getLogger(__name__)


class WorldRecorder:
    def __init__(self, run_dir: Path, world: World):
        self.dir = run_dir
        self.world = world
        self._files: list[IO[str]] = []
        self.fire = self._csv("world_fire.csv", ["t_s", "burning", "burnt", "extinguished", "ignited", "burnt_area_m2",
                                                 "sprayed_l"]) if world.fire is not None else None
        self.plume = self._csv("world_plume.csv", ["t_s", "source_x", "source_y", "wind_deg"]) \
            if world.plume is not None else None
        self.estimates = self._csv("world_estimates.csv", ["t_wall", "swarm", "uav", "x", "y"])
        self.actuations = self._csv("world_actuations.csv", ["t_wall", "swarm", "uav", "actuator", "x", "y", "asked_l",
                                                             "released_l", "extinguished"])
        self._next = 0.0
        self._next_grid = 0.0
        self.unwritten = 0  # writes the disk refused
        self._warned = -math.inf

    def _guard(self, write: Callable[[], None]) -> None:
        try:
            write()
        except OSError as exc:
            self.unwritten += 1
            if time.monotonic() - self._warned >= 60.0:
                self._warned = time.monotonic()
                log.warning("world records degraded (%s); the service goes on, counting it", exc.strerror or exc)

    def _csv(self, name: str, header: list[str]) -> Any:
        f = open(self.dir / name, "w", newline="")  # noqa: SIM115 - open until close()
        self._files.append(f)
        w = csv.writer(f)
        w.writerow(header)
        return w

    def estimate(self, t_wall: float, swarm: str, uav: int, x: float, y: float) -> None:
        self._guard(lambda: self.estimates.writerow([f"{t_wall:.3f}", swarm, uav, f"{x:.2f}", f"{y:.2f}"]))

    def actuation(self, t_wall: float, swarm: str, uav: int, actuator: str, x: float, y: float, asked: float,
                  released: float, extinguished: int) -> None:
        self._guard(lambda: self.actuations.writerow([f"{t_wall:.3f}", swarm, uav, actuator, f"{x:.2f}", f"{y:.2f}",
                                                      f"{asked:.4f}", f"{released:.4f}", extinguished]))

    def sample(self, now: float, stats: dict[str, Any]) -> None:
        """Once a second: a row per model, the counters, flushed; the fire grid every 10 s."""
        if now < self._next:
            return
        self._next = now + SAMPLE_S
        self._guard(lambda: self._sample(now, stats))

    def _sample(self, now: float, stats: dict[str, Any]) -> None:
        w = self.world
        if w.started:
            t = w.time(now)
            if self.fire is not None and w.fire is not None:
                c = w.fire.counts()
                self.fire.writerow([f"{t:.2f}", c["burning"], c["burnt"], c["extinguished"], c["ignited"],
                                    f"{w.fire.burnt_area_m2:.1f}", f"{w.fire.sprayed_l:.3f}"])
            if self.plume is not None and w.plume is not None:
                sx, sy = w.plume.source
                self.plume.writerow([f"{t:.2f}", sx, sy, f"{w.wind.direction_at(t):.2f}"])
        for f in self._files:
            f.flush()
        self.write_stats(stats)
        if w.fire is not None and now >= self._next_grid:
            self._next_grid = now + GRID_EVERY_S
            self.write_grid()

    def write_stats(self, stats: dict[str, Any]) -> None:
        write_json_atomic(self.dir / "world.json", {**stats, "unwritten": self.unwritten} if self.unwritten else stats,
                          indent=1)

    def write_grid(self) -> None:
        fire = self.world.fire
        if fire is None:
            return
        with replacing(self.dir / "world_fire.npz") as f:
            np.savez_compressed(f, xs=fire.xs, ys=fire.ys, fuel=fire.fuel, state=fire.state, t_ignited=fire.t_ignited,
                                t_over=fire.t_over, t=np.array(fire.t), cell_m=np.array(fire.cfg.cell_m))

    def close(self, stats: dict[str, Any]) -> None:
        self._guard(lambda: self.write_stats(stats))
        self._guard(self.write_grid)
        for f in self._files:
            self._guard(f.close)
        self._files.clear()
