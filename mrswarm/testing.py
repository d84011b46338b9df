"""Fly a behaviour on virtual UAVs, headless, and hand the run's results to assertions (docs/sdk.md).

::

    from mrswarm.testing import fly

    def test_flock(tmp_path):
        flight = fly("mypkg.flock:Flocking", uavs=5, duration=40, params={"speed": 3.0}, out=tmp_path)
        assert flight.collisions == 0
        assert flight.order_parameter(last_s=10) >= 0.9

Each call is a real ``mrswarm run`` (one process per UAV, the swarm's network secured, real
MAVLink to virtual flight controllers), in a results folder under ``out``. With pytest, list
this module as a plugin (``pytest_plugins = ["mrswarm.testing"]`` in a conftest.py) for the
``swarm_flight`` fixture: ``fly`` with ``out`` set to the test's temporary folder.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uav_stack.sdk.behaviour import Behaviour

ORIGIN = {"lat": 46.6167, "lon": 14.2650, "alt": 446.0}


@dataclass
class Trajectory:
    """One UAV's recorded flight: wall time (s), position (m, ENU), velocity (m/s), phase per row."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    phase: list[str]

    def at(self, t: float) -> tuple[float, float, float]:
        """The position (m) at the row nearest to wall time ``t``."""
        i = int(np.argmin(np.abs(self.t - t)))
        return (float(self.x[i]), float(self.y[i]), float(self.z[i]))

    @property
    def last(self) -> tuple[float, float, float]:
        return (float(self.x[-1]), float(self.y[-1]), float(self.z[-1]))


@dataclass
class Flight:
    """The results of one flight: its summary, the UAVs' trajectories, counters and recorded values."""

    run_dir: Path
    summary: dict[str, Any]
    trajectories: dict[int, Trajectory]
    stats: dict[int, dict[str, Any]]  # each UAV's last stats file (uav<N>.json)
    values: dict[int, dict[str, list[tuple[float, float]]]] = field(default_factory=dict)  # uav -> name -> (t, value)

    @property
    def mission_start(self) -> float:
        """Wall time the mission started (s)."""
        info = json.loads((self.run_dir / "run.json").read_text())
        return float(info.get("mission_start") or info["started"])

    @property
    def collisions(self) -> int:
        return int((self.summary.get("separation") or {}).get("collisions", 0))

    @property
    def incidents(self) -> list[dict[str, Any]]:
        return list(self.summary.get("incidents", []))

    def last_value(self, uav: int, name: str) -> float | None:
        """The last value a UAV's behaviour recorded under ``name`` (Context.record); None: none."""
        series = self.values.get(uav, {}).get(name)
        return series[-1][1] if series else None

    def behaviour_stats(self, uav: int) -> dict[str, Any]:
        """The ``behaviour`` section of a UAV's stats: faults, per-topic message counters, values."""
        return dict(self.stats.get(uav, {}).get("behaviour") or {})

    def in_mission(self) -> Iterator[tuple[int, Trajectory]]:
        """Each UAV's trajectory cut to its rows in the mission phases (mission, done)."""
        for uav, tr in sorted(self.trajectories.items()):
            keep = np.array([p in ("mission", "done") for p in tr.phase])
            if keep.any():
                yield uav, Trajectory(tr.t[keep], tr.x[keep], tr.y[keep], tr.z[keep], tr.vx[keep], tr.vy[keep],
                                      [p for p, k in zip(tr.phase, keep, strict=True) if k])

    def order_parameter(self, last_s: float | None = None, step_s: float = 0.5) -> float:
        """The flock's velocity alignment, ``|sum v_i| / sum |v_i|`` (1: all fly one way), over
        the UAVs in the mission, averaged over its last ``last_s`` seconds (None: its whole)."""
        series = self.order_series(step_s)
        if not series:
            return math.nan
        t_end = series[-1][0]
        vals = [phi for t, phi in series if last_s is None or t >= t_end - last_s]
        return float(np.mean(vals))

    def order_series(self, step_s: float = 0.5) -> list[tuple[float, float]]:
        """``(s after the mission start, order parameter)`` on a grid of ``step_s``, over the UAVs in
        the mission at that moment, from when two of them are: a UAV that reaches the mission late
        does not hide how the others began."""
        tracks = [tr for _, tr in self.in_mission() if len(tr.t)]
        if len(tracks) < 2:
            return []
        t0 = sorted(float(tr.t[0]) for tr in tracks)[1]
        t1 = max(float(tr.t[-1]) for tr in tracks)
        out = []
        start = self.mission_start
        for t in np.arange(t0, t1, step_s):
            here = [tr for tr in tracks if tr.t[0] <= t <= tr.t[-1]]
            if len(here) < 2:
                continue
            vx = np.array([np.interp(t, tr.t, tr.vx) for tr in here])
            vy = np.array([np.interp(t, tr.t, tr.vy) for tr in here])
            speed = np.hypot(vx, vy).sum()
            if speed > 1e-6:
                out.append((float(t - start), float(math.hypot(vx.sum(), vy.sum()) / speed)))
        return out


def behaviour_path(behaviour: str | type[Behaviour[Any]]) -> str:
    """``package.module:Class`` of a behaviour class (a string is taken as it is)."""
    if isinstance(behaviour, str):
        return behaviour
    return f"{behaviour.__module__}:{behaviour.__qualname__}"


def scenario_for(behaviour: str | type[Behaviour[Any]], *, uavs: int = 5, params: dict[str, Any] | None = None,
                 duration: float = 30.0, spacing: float = 10.0, altitude: float = 10.0, speed: float = 5.0,
                 name: str = "behaviour", extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """A scenario mapping that flies ``behaviour`` on ``uavs`` virtual UAVs spawned on a grid
    ``spacing`` m apart (``extra``: more top-level sections, or replacements: ``mission`` keys merge)."""
    scn: dict[str, Any] = {
        "name": name, "swarm": "sdktest", "seed": 1, "duration": duration, "origin": dict(ORIGIN),
        "flight": {"altitude": altitude, "speed": speed, "safety_distance": 5.0, "collision_distance": 1.0},
        "mission": {"behaviour": behaviour_path(behaviour), "params": dict(params or {})},
        "fleet": {"count": uavs, "spawn": {"pattern": "grid", "spacing": spacing, "center": [0, 0]}},
    }
    for k, v in (extra or {}).items():
        if k == "mission":
            scn["mission"].update(v)
        else:
            scn[k] = v
    return scn


def fly(behaviour: str | type[Behaviour[Any]] | None = None, *, out: Path, scenario: dict[str, Any] | str | Path | None = None,
        sets: list[str] | None = None, record: bool = False, log_level: str = "WARNING", **options: Any) -> Flight:
    """Fly a behaviour (or a scenario file or mapping) headless with the process runtime and return its results.

    ``options`` go to :func:`scenario_for` (``uavs``, ``params``, ``duration``, ``spacing``,
    ``altitude``, ``speed``, ``name``, ``extra``); ``sets`` are ``--set`` overrides; ``record``:
    also the flight recording (run.mcap)."""
    from rich.console import Console

    from mrswarm.run.experiment import Experiment
    from mrswarm.scenario import load_scenario

    if scenario is None:
        if behaviour is None:
            raise ValueError("fly: give a behaviour or a scenario")
        scenario = scenario_for(behaviour, **options)
    if isinstance(scenario, dict):
        import yaml

        out.mkdir(parents=True, exist_ok=True)
        path = out / f"{scenario.get('name', 'scenario')}.yaml"
        path.write_text(yaml.safe_dump(scenario, sort_keys=False))
        scn = load_scenario(path, sets)
    else:
        scn = load_scenario(Path(scenario), sets)
    exp = Experiment(scn, out, console=Console(quiet=True), live=False, log_level=log_level, record=record)
    summary = exp.run()
    return load_flight(exp.run_dir, summary.to_dict())


def load_flight(run_dir: Path, summary: dict[str, Any] | None = None) -> Flight:
    """The results of a finished run folder."""
    if summary is None:
        summary = json.loads((run_dir / "summary.json").read_text())
    trajectories: dict[int, Trajectory] = {}
    for path in sorted(run_dir.glob("uav*.csv")):
        if not path.stem[3:].isdigit():
            continue
        cols: dict[str, list[float]] = {k: [] for k in ("t_wall", "x", "y", "z", "vx", "vy")}
        phases: list[str] = []
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                try:
                    row = {k: float(r[k]) for k in cols}
                except (KeyError, ValueError, TypeError):
                    continue
                if all(math.isfinite(v) for v in row.values()):
                    for k, v in row.items():
                        cols[k].append(v)
                    phases.append(r.get("phase") or "")
        if phases:
            a = {k: np.array(v) for k, v in cols.items()}
            trajectories[int(path.stem[3:])] = Trajectory(a["t_wall"], a["x"], a["y"], a["z"], a["vx"], a["vy"], phases)
    stats: dict[int, dict[str, Any]] = {}
    for path in sorted(run_dir.glob("uav*.json")):
        if path.stem[3:].isdigit():
            try:
                stats[int(path.stem[3:])] = json.loads(path.read_text())
            except (OSError, ValueError):
                continue
    values: dict[int, dict[str, list[tuple[float, float]]]] = {}
    for path in sorted(run_dir.glob("behaviour_uav*.csv")):
        uav = int(path.stem[len("behaviour_uav"):])
        series: dict[str, list[tuple[float, float]]] = {}
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                try:
                    series.setdefault(r["name"], []).append((float(r["t_wall"]), float(r["value"])))
                except (KeyError, ValueError, TypeError):
                    continue
        values[uav] = series
    return Flight(run_dir, summary, trajectories, stats, values)


try:  # the pytest fixture, for a conftest.py's ``pytest_plugins = ["mrswarm.testing"]``
    import pytest

    @pytest.fixture
    def swarm_flight(tmp_path: Path) -> Callable[..., Flight]:
        """``fly`` with its results under the test's temporary folder."""

        def _fly(behaviour: str | type[Behaviour[Any]] | None = None, **kw: Any) -> Flight:
            kw.setdefault("out", tmp_path / "runs")
            return fly(behaviour, **kw)

        return _fly
except ImportError:  # pytest is only for tests
    pass
