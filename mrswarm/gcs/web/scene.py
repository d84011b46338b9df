"""What the live map draws besides the UAVs: the run's mission area, zones and hub, and every UAV's trail so far.

From the run folder (``mrswarm gcs web --run DIR``): its ``scenario.yaml`` gives the mission area, the
no-fly zones and obstacles, the wildfire hub and the fire's forest; the trajectories the UAVs
record (``uav<N>.csv``, flushed every second) give each trail from the start of the run, so a page
opened mid-run, or a server started late, shows where the swarm has been. Then the live poses
extend the trails (:class:`Trails`), for every page that connects later too.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

TRAIL_STEP_M = 1.0  # a trail point every metre flown
TRAIL_MAX = 4000  # points kept per UAV; past that, every other point is dropped (the trail stays whole, coarser)


class Trails:
    """Each UAV's path as points at least :data:`TRAIL_STEP_M` apart, at most :data:`TRAIL_MAX` of them."""

    def __init__(self) -> None:
        self.points: dict[int, list[tuple[float, float]]] = {}

    def add(self, uav: int, x: float, y: float) -> None:
        if not (math.isfinite(x) and math.isfinite(y)):
            return
        pts = self.points.setdefault(uav, [])
        if pts and math.hypot(pts[-1][0] - x, pts[-1][1] - y) < TRAIL_STEP_M:
            return
        pts.append((round(x, 1), round(y, 1)))
        if len(pts) > TRAIL_MAX:
            del pts[1:-1:2]

    def to_json(self) -> dict[str, list[list[float]]]:
        return {str(u): [list(p) for p in pts] for u, pts in sorted(self.points.items())}


def recorded_trails(run_dir: Path, trails: Trails | None = None) -> Trails:
    """The trails of every ``uav<N>.csv`` of ``run_dir`` so far (a line cut by a write in progress is skipped)."""
    trails = trails or Trails()
    for path in sorted(run_dir.glob("uav*.csv")):
        try:
            uav = int(path.stem[3:])
        except ValueError:
            continue
        try:
            with open(path, newline="") as f:
                for row in csv.DictReader(f):
                    try:
                        trails.add(uav, float(row["x"]), float(row["y"]))
                    except (KeyError, TypeError, ValueError):
                        continue
        except OSError:
            continue
    return trails


def scene_of(run_dir: Path) -> dict[str, Any]:
    """The map's fixed layer from the run's scenario: ``area`` [x_min, x_max, y_min, y_max] (the mission's, or
    the fire's forest), ``zones`` (name, kind, polygon) and ``hub`` (x, y, radius); empty when there is none."""
    from mrswarm.scenario import ScenarioError, load_scenario

    try:
        scn = load_scenario(run_dir / "scenario.yaml")
    except ScenarioError:
        return {}
    out: dict[str, Any] = {"name": scn.name}
    m = scn.mission
    w = scn.world
    if m.area is not None:
        out["area"], out["area_label"] = list(m.area.as_tuple()), "search area" if m.type == "plume" else "mission area"
    elif w is not None and w.fire is not None:
        a = w.fire.area
        out["area"], out["area_label"] = [a.x_min, a.x_max, a.y_min, a.y_max], "forest"
    if w is not None and w.zones:
        out["zones"] = [{"name": z.name, "kind": z.kind, "polygon": [list(p) for p in z.polygon]} for z in w.zones]
    if m.wildfire is not None:
        out["hub"] = [*m.wildfire.hub, m.wildfire.hub_radius]
    return out
