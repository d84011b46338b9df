"""The runner's live estimates: separation from poses of different instants compared at one time, and coverage by
the analysis' own rule."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from mrswarm.results.coverage import CellGrid, cell_centres, coverage
from mrswarm.run.live import LiveMetrics
from mrswarm.scenario import load_scenario
from swarmnet.messages import Pose, Realm
from swarmnet.observer import UavView
from uav_stack.phases import AgentPhase

ROOT = Path(__file__).resolve().parents[1]


def pose(uav: int, t: float, x: float, vx: float, y: float = 0.0) -> Pose:
    return Pose(uav=uav, realm=Realm.VIRTUAL, seq=0, t_sim=t, t_wall=t, x=x, y=y, z=15.0, vx=vx, vy=0.0, vz=0.0, yaw=0.0)


def observer(*poses: Pose) -> Any:
    """What update_separation reads of the runner's SwarmObserver: its views of the UAVs."""
    return SimpleNamespace(uavs={p.uav: UavView(uav=p.uav, pose=p) for p in poses})


def test_two_uavs_parting_are_not_reported_closer_than_they_were() -> None:
    """Two UAVs parting at 5 m/s each, 6 m apart at t = 100 s: the newest pose of one is of
    t = 100, the other's latest is of the period before (100 ms old). As received they look
    5.5 m apart; at one instant they were never closer than 6 m, which the summary reports."""
    metrics = LiveMetrics(load_scenario(ROOT / "scenarios" / "coverage.yaml"))
    a = pose(1, 100.0, x=3.0, vx=5.0)
    b = pose(2, 99.9, x=-2.5, vx=-5.0)  # at 100.0 it is at x = -3.0
    metrics.update_separation(observer(a, b))
    assert metrics.min_sep_now == pytest.approx(6.0, abs=1e-9)
    assert metrics.min_sep == pytest.approx(6.0, abs=1e-9)


def test_a_uav_gone_quiet_is_left_out_not_carried_on() -> None:
    """A UAV whose last pose is 5 s older than the others' (its process died in the air) is
    neither compared where it was nor flown on along its last velocity."""
    metrics = LiveMetrics(load_scenario(ROOT / "scenarios" / "coverage.yaml"))
    a = pose(1, 100.0, x=0.0, vx=0.0)
    b = pose(2, 100.0, x=20.0, vx=0.0)
    dead = pose(3, 95.0, x=1.0, vx=4.0)  # 1 m from UAV 1 when last heard; carried on, 21 m
    metrics.update_separation(observer(a, b, dead))
    assert metrics.min_sep_now == pytest.approx(20.0)


def test_the_live_coverage_is_what_the_analysis_finds_for_the_same_positions() -> None:
    """Every pose of a working UAV received: the live estimate shows the coverage its summary will report
    (the same cells, the same sensor radius), not a number of its own."""
    scn = load_scenario(ROOT / "scenarios" / "coverage.yaml")
    metrics = LiveMetrics(scn)
    path = [(-95.0, -75.0), (-60.0, -40.0), (0.0, 0.0), (3.0, 2.0), (40.0, 30.0), (99.0, 79.0)]
    working = SimpleNamespace(uavs={1: SimpleNamespace(state=SimpleNamespace(phase=AgentPhase.MISSION))})
    for k, (x, y) in enumerate(path):
        metrics.add_poses(working, [pose(1, float(k), x=x, vx=0.0, y=y)])
    pos = np.array([[(x, y, 15.0) for x, y in path]])
    frac, _, _ = coverage(np.arange(len(path), dtype=float), pos, np.ones((1, len(path)), dtype=bool),
                          scn.mission.area.as_tuple(), scn.mission.sensor_radius, scn.mission.coverage_cell_m)
    assert metrics.coverage is not None and 0.0 < metrics.coverage < 1.0
    assert metrics.coverage == pytest.approx(float(frac[-1]), abs=1e-12)


def definition(xs: np.ndarray, ys: np.ndarray, pts: np.ndarray, radius: float) -> np.ndarray:
    """The rule itself: every cell centre, row by row (north), against every point."""
    gx, gy = np.meshgrid(xs, ys)
    cells = np.stack([gx.ravel(), gy.ravel()], axis=1)
    return ((cells[:, None, :] - pts[None, :, :]) ** 2).sum(axis=2).min(axis=1) <= radius * radius


@pytest.mark.parametrize(("area", "cell", "radius"), [((-100.0, 100.0, -80.0, 80.0), 5.0, 10.0),
                                                       ((0.0, 37.0, -3.0, 41.0), 0.5, 1.0),
                                                       ((-50.0, 50.0, -50.0, 50.0), 5.0, 23.0)])
def test_the_cells_a_grid_finds_are_those_the_definition_sees(area: tuple[float, float, float, float], cell: float,
                                                              radius: float) -> None:
    """The grid's neighbourhood search marks exactly the cells whose centres lie within the radius of a
    point, as comparing every cell with every point does: points inside, on the edges, outside, NaN."""
    xs, ys = cell_centres(area, cell)
    grid = CellGrid(xs, ys, cell)
    rng = np.random.default_rng(3)
    x0, x1, y0, y1 = area
    for n in (1, 7, 300):
        pts = np.stack([rng.uniform(x0 - 2 * radius, x1 + 2 * radius, n),
                        rng.uniform(y0 - 2 * radius, y1 + 2 * radius, n)], axis=1)
        pts[: n // 3, 0] = np.round(pts[: n // 3, 0] / cell) * cell  # on cell borders: the rounding cases
        if n > 1:
            pts[1] = (np.nan, 0.0)
        expected = definition(xs, ys, pts[np.isfinite(pts).all(axis=1)], radius)
        assert np.array_equal(grid.seen(pts, radius), expected)
        assert expected.any() or n == 1
