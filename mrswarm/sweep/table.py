"""The campaign's results table: one row per run (``runs.csv``), one row per cell and metric (``cells.csv``).

Built from the campaign folder alone (``mrswarm sweep --report DIR``): every slot's ``slot.json``
(its grid values and seed, and what the sweep measured: wall and CPU time) and its complete
run's ``summary.json``. A metric is a dotted path into ``summary.json`` (``coverage.time_to_90_s``,
``network.transport_age_ms.p50``; a list counts its items: ``incidents``), or one of the sweep's
own measures of a run (:data:`SWEEP_MEASURES`). Statistics cover the runs that completed
(``status`` ok); a failed run (its runner gave up) is listed in ``runs.csv`` and counted in
``cells.csv`` (``failed``), but its numbers stay out of the means.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import yaml

from mrswarm.records.summary import RunSummary, write_atomic
from mrswarm.sweep.campaign import value_label
from mrswarm.sweep.slots import RUNS, SlotState, attempt_of, read_record, status
from mrswarm.sweep.stats import DEFAULT_LEVEL, Summary, summarise

RUNS_CSV = "runs.csv"
CELLS_CSV = "cells.csv"
CAMPAIGN_COPY = "campaign.yaml"


@dataclass(frozen=True)
class Metric:
    path: str
    label: str
    unit: str = ""
    scale: float = 1.0  # plotted value = raw value * scale (a fraction as a percentage)
    short: str = ""  # a table column's head

    @property
    def head(self) -> str:
        name = self.short or self.label
        return f"{name} ({self.unit})" if self.unit and self.unit != "cores" else name


# what runs.csv holds for every run (a column no run has a value for is left out), and how the plots name them
METRICS: tuple[Metric, ...] = (
    Metric("coverage.final", "area covered at the end", "%", 100.0, short="covered"),
    Metric("coverage.time_to_50_s", "time to 50 % coverage", "s", short="T50"),
    Metric("coverage.time_to_90_s", "time to 90 % coverage", "s", short="T90"),
    Metric("separation.min_during_mission_m", "minimum separation during the mission", "m", short="min separation"),
    Metric("separation.time_below_safety_s", "time below the safety distance", "s", short="below safety"),
    Metric("separation.collisions", "collisions", short="collisions"),
    Metric("incidents", "incidents"),
    Metric("lost_uavs", "UAV processes lost"),
    Metric("rtf.mean", "real-time factor, mean over UAVs", short="RTF"),
    Metric("rtf.min", "real-time factor, slowest UAV", short="RTF min"),
    Metric("takeoff.all_airborne_s", "time until all airborne", "s", short="airborne after"),
    Metric("network.transport_age_ms.p50", "pose transport age, median", "ms", short="transport p50"),
    Metric("network.transport_age_ms.p99", "pose transport age, p99", "ms", short="transport p99"),
    Metric("network.use_age_ms.p50", "pose age at use, median", "ms", short="age at use p50"),
    Metric("network.pose_loss", "pose loss", "%", 100.0, short="pose loss"),
    Metric("network.netem.total.loss", "netem loss", "%", 100.0, short="netem loss"),
    Metric("network.netem.total.delay_ms.mean", "netem delay, mean", "ms", short="netem delay"),
    Metric("uavs_recorded", "UAVs recorded"),
    Metric("duration_s", "mission time analysed", "s"),
    Metric("wall_s", "wall time of the run", "s", short="wall"),
    Metric("cpu_s", "CPU time of the run", "s", short="CPU time"),
    Metric("cpu_cores", "CPU of the run (cores)", "cores", short="CPU cores"),
    Metric("concurrent", "runs flying at once", short="at once"),
    Metric("machine_busy", "machine CPU in use while flying", "%", 100.0, short="machine busy"),
)
SWEEP_MEASURES = ("wall_s", "cpu_s", "cpu_cores", "concurrent", "machine_busy")  # measured by the sweep, not in summary.json
KNOWN = {m.path: m for m in METRICS}

DEFAULT_PLOTS: dict[str, tuple[str, ...]] = {
    "coverage": ("coverage.time_to_90_s", "coverage.final", "separation.min_during_mission_m",
                 "network.transport_age_ms.p50", "rtf.mean", "cpu_cores"),
    "goto": ("separation.min_during_mission_m", "separation.time_below_safety_s", "network.transport_age_ms.p50",
             "rtf.mean", "cpu_cores"),
}
DEFAULT_PLOTS_OTHER = ("separation.min_during_mission_m", "network.transport_age_ms.p50", "rtf.mean", "cpu_cores")


def metric(path: str) -> Metric:
    return KNOWN.get(path) or Metric(path, path)


def metric_problem(path: str) -> str:
    """"" if ``path`` names a number of summary.json (or a sweep measure), else what is wrong with it."""
    if path in SWEEP_MEASURES:
        return ""
    t: Any = msgspec.inspect.type_info(RunSummary)
    done: list[str] = []
    for part in path.split("."):
        t = _unwrap(t)
        if isinstance(t, msgspec.inspect.DictType):
            t = t.value_type
        elif isinstance(t, msgspec.inspect.StructType):
            names = {f.encode_name: f.type for f in t.fields}
            if part not in names:
                where = ".".join(done) or "summary.json"
                return (f"{path}: {where} has no {part!r} (there: "
                        f"{', '.join(sorted(names))}; or a sweep measure: {', '.join(SWEEP_MEASURES)})")
            t = names[part]
        else:
            return f"{path}: {'.'.join(done)} is a {type(t).__name__.removesuffix('Type').lower()}, not a section"
        done.append(part)
    t = _unwrap(t)
    if not isinstance(t, msgspec.inspect.IntType | msgspec.inspect.FloatType | msgspec.inspect.BoolType
                      | msgspec.inspect.ListType | msgspec.inspect.DictType):
        return f"{path}: not a number (a {type(t).__name__.removesuffix('Type').lower()})"
    return ""


def _unwrap(t: Any) -> Any:
    """The type inside ``X | None`` (and UNSET, which type_info already drops)."""
    if isinstance(t, msgspec.inspect.UnionType):
        inner = [u for u in t.types if not isinstance(u, msgspec.inspect.NoneType)]
        if len(inner) == 1:
            return inner[0]
        return next((u for u in inner if isinstance(u, msgspec.inspect.StructType)), inner[0])
    return t


def summary_value(summary: dict[str, Any], path: str) -> float | None:
    """The number at ``path`` in a summary.json (a list: its length; a boolean: 0 or 1); None if it is not there."""
    cur: Any = summary
    for part in path.split("."):
        if not isinstance(cur, dict) or part not in cur:
            return None
        cur = cur[part]
    if isinstance(cur, bool):
        return float(cur)
    if isinstance(cur, int | float):
        return float(cur) if math.isfinite(cur) else None
    if isinstance(cur, list | dict):
        return float(len(cur))
    return None


@dataclass
class Row:
    """One run of the campaign."""

    slot: str
    cell: dict[str, Any]
    seed: int
    state: SlotState
    run_dir: str  # relative to the campaign folder
    attempts: int
    values: dict[str, float | None]
    why: str = ""


@dataclass
class CellStats:
    values: dict[str, Any]  # grid key -> value
    ok: int
    failed: int
    pending: int
    stats: dict[str, Summary] = field(default_factory=dict)


@dataclass
class Table:
    """The campaign folder's runs and their statistics."""

    name: str
    grid: dict[str, list[Any]]  # key -> values, in the campaign's order
    rows: list[Row]
    cells: list[CellStats]
    columns: list[str]  # the metrics with a value in at least one run
    plots: list[str]  # the metrics to plot
    x: str | None  # the plots' horizontal axis
    level: float
    mission: str  # the runs' mission type
    seeds: int  # distinct seeds among the complete runs


def collect(campaign_dir: Path, extra: list[str] | None = None) -> Table:
    """Read every slot of ``campaign_dir`` (its ``runs/`` folder) and compute the cells' statistics. The plots show
    ``extra`` (``--metrics``), else the campaign's ``metrics``, else the defaults of the runs' mission type."""
    setup = _campaign_copy(campaign_dir)
    chosen = [str(m) for m in setup.get("metrics") or []] if isinstance(setup.get("metrics"), list) else []
    flag = list(extra or [])
    extra = list(dict.fromkeys([*flag, *chosen]))
    rows: list[Row] = []
    pending: dict[str, int] = {}
    mission = ""
    runs_dir = campaign_dir / RUNS
    folders = sorted(d for d in runs_dir.iterdir() if d.is_dir()) if runs_dir.is_dir() else []
    seen_keys: list[str] = []
    for folder in folders:
        st = status(folder)
        rec = st.record or read_record(folder)
        if rec is None:  # not a slot of a sweep
            continue
        for k in rec.cell:
            if k not in seen_keys:
                seen_keys.append(k)
        if st.state == SlotState.PENDING or st.run_dir is None or st.summary is None:
            key = _cell_key(rec.cell)
            pending[key] = pending.get(key, 0) + 1
            continue
        s = st.summary
        mission = mission or _mission_type(st.run_dir)
        a = attempt_of(rec, st.run_dir)
        values: dict[str, float | None] = {m.path: summary_value(s, m.path) for m in METRICS if m.path not in SWEEP_MEASURES}
        for p in extra:
            if p not in SWEEP_MEASURES:
                values[p] = summary_value(s, p)
        cpu = a.cpu_s if a is not None else None
        wall = a.wall_s if a is not None else None
        values.update(wall_s=wall, cpu_s=cpu, cpu_cores=cpu / wall if cpu is not None and wall else None,
                      concurrent=float(a.concurrent) if a is not None else None,
                      machine_busy=a.machine_busy if a is not None else None)
        rows.append(Row(slot=folder.name, cell=dict(rec.cell), seed=rec.seed, state=st.state,
                        run_dir=str(st.run_dir.relative_to(campaign_dir)), attempts=st.attempts, values=values, why=st.why))
    grid: dict[str, list[Any]] = dict(setup.get("grid") or {}) if isinstance(setup.get("grid"), dict) else {}
    for k in seen_keys:  # keys of slots the campaign file no longer lists (or no copy of it): in the order first seen
        if k not in grid:
            grid[k] = []
    for r in rows:
        for k, v in r.cell.items():
            if not any(value_label(v) == value_label(g) for g in grid[k]):
                grid[k].append(v)
    level = float(setup.get("confidence") or DEFAULT_LEVEL)
    columns = [m for m in dict.fromkeys([*(m.path for m in METRICS), *extra]) if any(r.values.get(m) is not None for r in rows)]
    wanted = flag or chosen or list(DEFAULT_PLOTS.get(mission, DEFAULT_PLOTS_OTHER))
    plots = [m for m in dict.fromkeys(wanted) if m in columns]
    cells = _cell_stats(rows, grid, pending, columns, level)
    x = setup.get("x") if setup.get("x") in grid else _default_x(grid)
    name = str(setup.get("name") or campaign_dir.name)
    return Table(name=name, grid=grid, rows=rows, cells=cells, columns=columns, plots=plots, x=x, level=level,
                 mission=mission, seeds=len({r.seed for r in rows if r.state == SlotState.OK}))


def _campaign_copy(campaign_dir: Path) -> dict[str, Any]:
    try:
        data = yaml.safe_load((campaign_dir / CAMPAIGN_COPY).read_text())
    except (OSError, yaml.YAMLError):
        return {}
    return data if isinstance(data, dict) else {}


def _mission_type(run_dir: Path) -> str:
    try:
        scn = yaml.safe_load((run_dir / "scenario.yaml").read_text())
        return str(scn["mission"]["type"])
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return ""


def _cell_key(cell: dict[str, Any]) -> str:
    return "\x1f".join(f"{k}={value_label(v)}" for k, v in sorted(cell.items()))


def _default_x(grid: dict[str, list[Any]]) -> str | None:
    """The first grid key whose values are all numbers, else the first key."""
    for k, vs in grid.items():
        if vs and all(isinstance(v, int | float) and not isinstance(v, bool) for v in vs):
            return k
    return next(iter(grid), None)


def _cell_stats(rows: list[Row], grid: dict[str, list[Any]], pending: dict[str, int], columns: list[str],
                level: float) -> list[CellStats]:
    """The cells in grid order (the first key slowest), each with its metrics' statistics over its complete runs."""
    by: dict[str, list[Row]] = {}
    cells: dict[str, dict[str, Any]] = {}
    for r in rows:
        key = _cell_key(r.cell)
        by.setdefault(key, []).append(r)
        cells[key] = r.cell
    out = []
    for key in sorted(cells, key=lambda k: _rank(grid, cells[k])):
        rs = by[key]
        ok = [r for r in rs if r.state == SlotState.OK]
        c = CellStats(values=cells[key], ok=len(ok), failed=len(rs) - len(ok), pending=pending.get(key, 0))
        for m in columns:
            c.stats[m] = summarise([r.values.get(m) for r in ok], level)
        out.append(c)
    return out


def _rank(grid: dict[str, list[Any]], cell: dict[str, Any]) -> tuple[int, ...]:
    """A cell's place in the grid's order (the first key slowest)."""
    return tuple([value_label(g) for g in vs].index(value_label(cell[k])) if k in cell and any(
        value_label(g) == value_label(cell[k]) for g in vs) else -1 for k, vs in grid.items())


def _num(v: float | None) -> str:
    if v is None:
        return ""
    return f"{v:.6g}" if abs(v) < 1e15 else repr(v)


def runs_csv(t: Table) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    keys = list(t.grid)
    w.writerow(["slot", *keys, "seed", "status", *t.columns, "attempts", "run_dir", "why"])
    for r in sorted(t.rows, key=lambda r: (_rank(t.grid, r.cell), r.seed)):
        w.writerow([r.slot, *(value_label(r.cell[k]) if k in r.cell else "" for k in keys), r.seed, r.state.value,
                    *(_num(r.values.get(m)) for m in t.columns), r.attempts, r.run_dir, r.why])
    return buf.getvalue()


def cells_csv(t: Table) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    keys = list(t.grid)
    w.writerow([*keys, "metric", "runs", "n", "mean", "median", "std", "ci_low", "ci_high", "confidence", "failed", "pending"])
    for c in t.cells:
        for m in t.columns:
            s = c.stats[m]
            w.writerow([*(value_label(c.values[k]) if k in c.values else "" for k in keys), m, s.runs, s.n, _num(s.mean),
                        _num(s.median), _num(s.std), _num(s.ci_low), _num(s.ci_high), f"{t.level:g}", c.failed, c.pending])
    return buf.getvalue()


def write_tables(campaign_dir: Path, t: Table) -> list[Path]:
    """``runs.csv`` and ``cells.csv`` in the campaign folder, each replaced atomically."""
    out = []
    for name, text in ((RUNS_CSV, runs_csv(t)), (CELLS_CSV, cells_csv(t))):
        path = campaign_dir / name
        write_atomic(path, text.encode())
        out.append(path)
    return out
