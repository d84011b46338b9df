"""The figures of a run, drawn from run folders made the way a run makes them (tests/test_results.py's helpers):
legends outside the data, twenty UAVs in twenty colours, the mission area drawn, axes that end with the mission,
a wide map above its plot rather than squashed beside it, and no shutdown second in pose_age.png."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.colors import to_rgb  # noqa: E402

from mrswarm.records.summary import RunInfo  # noqa: E402
from mrswarm.results.analysis import analyse_run  # noqa: E402
from mrswarm.results.plots import PALETTE, plot_pose_age, pose_age_figure, run_figure  # noqa: E402
from mrswarm.results.run_data import WorldData  # noqa: E402
from mrswarm.results.world_plots import world_figure  # noqa: E402
from mrswarm.scenario import load_scenario  # noqa: E402
from tests.test_results import ROOT, T0, record  # noqa: E402
from uav_stack.phases import AgentPhase  # noqa: E402


def run_folder(tmp_path: Path, scenario: str, tracks: dict[int, np.ndarray], sets: list[str] | None = None,
               seconds: float = 30.0) -> tuple[Any, Any]:
    """A run folder of ``scenario`` (with ``sets``) whose UAVs flew ``tracks`` (x, y per step of 0.1 s at 10 m), analysed."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    scn = load_scenario(ROOT / "scenarios" / scenario, sets)
    (run_dir / "scenario.yaml").write_text((ROOT / "scenarios" / scenario).read_text())
    t = T0 + np.arange(0.0, seconds, 0.1)
    for uav, xy in tracks.items():
        xyz = np.concatenate([xy[: len(t)], np.full((len(t), 1), 10.0)], axis=1)
        record(run_dir, uav, xyz, [AgentPhase.MISSION] * len(t), t)
    info = RunInfo(scenario=scn.name, started=T0 - 10, mission_start=T0)
    summary, data = analyse_run(run_dir, scn, info)
    assert data is not None
    return scn, data


def inside(inner: Any, outer: Any) -> bool:
    return bool(inner.x0 >= outer.x0 - 1 and inner.x1 <= outer.x1 + 1 and inner.y0 >= outer.y0 - 1 and inner.y1 <= outer.y1 + 1)


def overlaps(a: Any, b: Any) -> bool:
    return bool(a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1)


def test_twenty_uavs_in_twenty_colours_with_the_legend_outside_the_map(tmp_path: Path) -> None:
    t = np.arange(0.0, 30.0, 0.1)
    tracks = {u: np.stack([-90.0 + 9 * u + 0 * t, -70.0 + 4.0 * t], axis=1) for u in range(1, 21)}  # 20 lanes north
    scn, data = run_folder(tmp_path, "coverage.yaml", tracks, ["fleet.count=20"])
    fig = run_figure(scn, data)
    try:
        fig.canvas.draw()
        ax_map, ax_time = fig.axes[0], fig.axes[1]
        uav_lines = [ln for ln in ax_map.get_lines() if ln.get_label().startswith("UAV ")]
        assert len(uav_lines) == 20 and len({ln.get_color() for ln in uav_lines}) == 20
        rgb = np.array([to_rgb(c) for c in PALETTE])
        d = np.linalg.norm(rgb[:, None] - rgb[None], axis=2) + np.eye(len(rgb)) * 9
        assert d.min() > 0.15  # no two of the twenty alike (RGB distance; tab20's pairs of one hue are ~0.3 to 0.5 apart
        r = fig.canvas.get_renderer()
        for ax in (ax_map, ax_time):
            leg = ax.get_legend()
            assert leg is not None and not overlaps(leg.get_window_extent(r), ax.get_window_extent(r))  # outside the data
            assert inside(leg.get_window_extent(r), fig.bbox)  # and on the page
        # the mission area is drawn, and the time axis ends with the mission (30 s recorded)
        assert any(ln.get_label() == "mission area" for ln in ax_map.get_lines())
        assert ax_time.get_xlim() == pytest.approx((0.0, 29.9), abs=0.15)
    finally:
        plt.close(fig)


def test_a_shortened_plume_run_draws_no_wind_turn_that_did_not_happen(tmp_path: Path) -> None:
    t = np.arange(0.0, 40.0, 0.1)
    tracks = {1: np.stack([-50 + 2.0 * t, -40 + 0 * t], axis=1), 2: np.stack([-50 + 2.0 * t, -20 + 0 * t], axis=1)}
    scn, data = run_folder(tmp_path, "plume.yaml", tracks, ["duration=40"], seconds=40.0)
    data.world = WorldData(error_curve=np.array([[s, 30.0 - 0.5 * s, 28.0 - 0.5 * s] for s in range(40)], dtype=float))
    fig = world_figure(scn, data)
    try:
        ax_map, ax_time = fig.axes[0], fig.axes[1]
        assert ax_time.get_xlim()[1] <= 40.0  # not stretched to the wind's turn at 60 s
        labels = [h.get_label() for h in ax_time.get_legend().legend_handles] if ax_time.get_legend() else []
        assert not [lb for lb in labels if "wind turns" in lb]
        map_labels = [h.get_label() for h in ax_map.get_legend().legend_handles]
        assert "search area" in map_labels and "plume from 0 s" in map_labels and "plume from 60 s" not in map_labels
    finally:
        plt.close(fig)


def test_a_map_much_wider_than_tall_goes_above_its_plot(tmp_path: Path) -> None:
    """Two swarms on three lanes 24 m apart over 80 m: side by side, the map was a strip."""
    t = np.arange(0.0, 16.0, 0.1)
    tracks = {u: np.stack([(-40 + 5 * t) * (1 if u < 10 else -1), y + 0 * t], axis=1)
              for u, y in ((1, -12), (2, 0), (3, 12), (11, -12), (12, 0), (13, 12))}
    scn, data = run_folder(tmp_path, "two_swarms.yaml", tracks, seconds=16.0)
    fig = world_figure(scn, data)
    try:
        fig.canvas.draw()
        r = fig.canvas.get_renderer()
        m, p = fig.axes[0].get_window_extent(r), fig.axes[1].get_window_extent(r)
        assert m.y0 > p.y1  # the map above the plot
        assert m.width > 0.8 * fig.bbox.width  # across the page
    finally:
        plt.close(fig)


def test_pose_age_ends_with_the_mission_not_with_the_shutdown(tmp_path: Path) -> None:
    from mrswarm.results.analysis import load_ages
    from mrswarm.results.netem_report import pose_age_report

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    # one UAV's ages per second, -5 .. 40 s, with the shutdown's 100 ms in its last second (40 s)
    rows = ["t_wall,transport_p50_ms,transport_mean_ms,use_p50_ms,aoi_mean_ms,aoi_max_ms"]
    for s in range(-5, 41):
        aoi = 100.0 if s == 40 else 10.0
        rows.append(f"{T0 + s},{4.0},{4.5},{5.0},{aoi},{aoi * 1.5}")
    (run_dir / "age_uav1.csv").write_text("\n".join(rows) + "\n")
    got = pose_age_report(load_ages(run_dir), T0, T0 + 39.5)
    assert got is not None
    _, series = got
    plot_pose_age(tmp_path / "pose_age.png", series, [], 39.5)
    assert (tmp_path / "pose_age.png").stat().st_size > 10_000
    fig = pose_age_figure(series, [], 39.5)
    try:
        for ax in fig.axes:
            assert ax.get_xlim() == pytest.approx((0.0, 39.5))
            for ln in ax.get_lines():
                y = np.asarray(ln.get_ydata(), dtype=float)
                assert not len(y) or np.nanmax(y) < 50.0  # the shutdown's 100 ms is not drawn
    finally:
        plt.close(fig)
