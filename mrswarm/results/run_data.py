"""The series a run's figures are drawn from: computed once, by mrswarm/results/analysis.py and its reports, and
handed down to mrswarm/results/plots.py and mrswarm/results/world_plots.py (which compute nothing of their own).

:class:`RunData` holds the trajectories as recorded (:class:`Track`) and resampled on one grid of wall time, the
separation per step, the coverage map (:class:`CoverageMap`), the pose age per second (:class:`PoseAgeSeries`)
and, for a world scenario, what the world service recorded (:class:`WorldData`). No file is read here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mrswarm.records.summary import LinkAge

GRID_HZ = 10.0  # resampling rate of the trajectories
AIRBORNE_Z = 1.0  # m above the origin: below this a UAV is on the ground (no collision candidate, no fall)


@dataclass
class Track:
    """One UAV's recorded trajectory, sorted by wall time."""

    uav: int
    t: np.ndarray  # wall time, s
    t_sim: np.ndarray  # simulated time, s
    xyz: np.ndarray  # (n, 3) east, north, up, m
    phase: list[str]  # the agent's phase (uav_stack.phases.AgentPhase values)
    rtf: np.ndarray
    vz: np.ndarray | None = None  # vertical speed, up, m/s
    armed: np.ndarray | None = None  # 1 armed, 0 not


@dataclass
class PoseAgeSeries:
    """The per-second pose-age series behind :class:`~mrswarm.records.summary.PoseAgeOverTime`, kept for the plot."""

    grid: np.ndarray  # s since mission start, one per second
    series: dict[int, dict[str, np.ndarray]]  # per UAV: the columns of age_uav<N>.csv
    t0: float  # wall time of the mission start
    transport_med: np.ndarray  # ms, transport age p50, median over UAVs, per grid second (NaN: no UAV had a value)
    use_med: np.ndarray  # ms, age at use p50, median over UAVs
    aoi_med: np.ndarray  # ms


@dataclass
class WorldData:
    """What the world figure needs besides the trajectories."""

    fire_grid: dict[str, np.ndarray] | None = None  # world_fire.npz
    fire_curve: np.ndarray | None = None  # (n, 3): s, burnt area m^2, cells burning
    estimates: dict[int, np.ndarray] = field(default_factory=dict)  # UAV -> (n, 3): s, x, y
    error_curve: np.ndarray | None = None  # (n, 3): s, median m, best m
    cross_separation: np.ndarray | None = None  # m per grid step, between swarms
    sprays: np.ndarray | None = None  # (n, 2): x, y of every spray that released something


@dataclass
class CoverageMap:
    """When each cell of the mission area was first seen, and the coverage over the mission."""

    first_visit: np.ndarray  # (ny, nx) wall time of the first visit, NaN: never seen
    xs: np.ndarray  # cell centres east, m
    ys: np.ndarray  # cell centres north, m
    t: np.ndarray  # s since mission start
    fraction: np.ndarray  # covered fraction at each t


@dataclass
class RunData:
    """What the figures need besides the summary: the resampled trajectories and their derived series."""

    tracks: dict[int, Track]
    grid: np.ndarray  # wall time, GRID_HZ
    pos: np.ndarray  # (n_uav, n_grid, 3), NaN where a UAV has no data
    ids: list[int]  # UAV id of each row of pos
    min_separation: np.ndarray  # m per grid step
    t0: float  # wall time of the mission start (else of the first record)
    t_end: float  # wall time of the end of the analysed mission
    coverage: CoverageMap | None
    pose_age: PoseAgeSeries | None
    links: list[LinkAge]  # transport age per link, for transport_links.csv
    world: WorldData | None = None  # scenarios with a world section (mrswarm/results/world_report.py)
    closest: int | None = None  # grid step of the smallest separation of the run (None: never two UAVs airborne)
