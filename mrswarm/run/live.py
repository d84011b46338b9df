"""What the runner knows while a run flies: its stage, the mission clock, and live estimates.

The live coverage and separation are estimates from the poses the runner receives over the
network (they can miss poses); the numbers of record come afterwards from the UAVs' own
trajectories (mrswarm/results/analysis.py).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from mrswarm.results.coverage import CellGrid, cell_centres
from mrswarm.results.run_data import AIRBORNE_Z
from mrswarm.scenario import Scenario
from swarmnet.messages import Pose
from swarmnet.observer import SwarmObserver
from uav_stack.phases import WORKING


class RunStage(str, Enum):
    """The runner's own sequence (not an agent's phase: see uav_stack.phases.AgentPhase)."""

    STARTING = "starting"
    WAITING = "waiting for UAVs"
    TAKING_OFF = "taking off"
    MISSION = "mission"
    STOPPING = "stopping"

    def __str__(self) -> str:
        return self.value


@dataclass
class RunProgress:
    """The runner's stage and, once the swarm got ``start``, the mission clock."""

    duration: float  # s of mission the scenario asks for
    stage: RunStage = RunStage.STARTING
    mission_start: float | None = None  # wall time of the "start" command
    detail: str = ""  # what the stage is doing (a command's acknowledgements so far, the takeoff time)
    milestones: list[str] = field(default_factory=list)  # what the run reached, in order (a log prints each once)
    clock: Callable[[], float] = time.time  # the run's clock: the wall's, or lock-step's simulated time

    def reached(self, text: str) -> None:
        """A milestone (every UAV acknowledged a command, all airborne): the detail now, and a line of its own in a log."""
        self.detail = text
        self.milestones.append(text)

    def elapsed(self, now: float | None = None) -> float | None:
        """Seconds since the mission started (None before)."""
        if self.mission_start is None:
            return None
        return (self.clock() if now is None else now) - self.mission_start


SEPARATION_STALE_S = 1.0  # s: a pose this much older than the newest is not carried forward (its UAV went quiet)


@dataclass
class LiveMetrics:
    """Coverage and separation estimated live from the poses the runner's observer receives."""

    scenario: Scenario
    cells: CellGrid | None = field(init=False, default=None)  # the area's cells, as the analysis cuts them
    covered: np.ndarray | None = field(init=False, default=None)  # per cell: seen by a working UAV
    min_sep: float = field(init=False, default=math.inf)  # m, lowest seen so far
    min_sep_now: float = field(init=False, default=math.inf)  # m, at the last update

    def __post_init__(self) -> None:
        m = self.scenario.mission
        if m.type == "coverage" and m.area is not None:
            self.cells = CellGrid(*cell_centres(m.area.as_tuple(), m.coverage_cell_m), m.coverage_cell_m)
            self.covered = np.zeros(self.cells.size, dtype=bool)

    def add_poses(self, obs: SwarmObserver, fresh: list[Pose]) -> None:
        """Mark the cells within the sensor radius of each fresh pose of a UAV working on its mission."""
        if self.cells is None or self.covered is None or not fresh:
            return
        pts = [(p.x, p.y) for p in fresh if (v := obs.uavs.get(p.uav)) and v.state and v.state.phase in WORKING]
        if pts:
            self.covered[self.cells.indices(np.array(pts), self.scenario.mission.sensor_radius)] = True

    def update_separation(self, obs: SwarmObserver) -> None:
        """Minimum 3-D distance between airborne UAVs (higher than AIRBORNE_Z), each at the time of the newest pose.

        Why: the latest poses of two UAVs can be a period apart (one has sent this instant's
        pose, the other not yet), and compared as they are, two UAVs closing at 10 m/s look
        1 m closer than they ever were at 10 Hz (a run's live 5.6 m against the 6.0 m its
        summary reported). So each pose is carried forward along its own velocity to the newest
        pose's stamp, as the summary compares positions of one instant. A pose more than
        :data:`SEPARATION_STALE_S` older than the newest (a UAV that stopped sending) is left out.
        """
        views = [v.pose for v in obs.uavs.values() if v.pose is not None and v.pose.z > AIRBORNE_Z]
        if len(views) < 2:
            return
        t = np.array([q.t_wall for q in views])
        newest = float(t.max())
        keep = t >= newest - SEPARATION_STALE_S
        dt = (newest - t[keep])[:, None]
        p = np.array([[q.x, q.y, q.z] for q in views])[keep] + np.array([[q.vx, q.vy, q.vz] for q in views])[keep] * dt
        if len(p) >= 2:
            d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=2)
            d[np.diag_indices(len(p))] = np.inf
            self.min_sep_now = float(d.min())
            self.min_sep = min(self.min_sep, self.min_sep_now)

    @property
    def coverage(self) -> float | None:
        """Fraction 0..1 of the mission area seen so far (None: not a coverage mission)."""
        return float(self.covered.mean()) if self.covered is not None else None
