"""Coverage of a mission area: its cells, and which of them a UAV's sensor has seen.

One rule for the numbers of record (mrswarm/results/analysis.py, from the recorded trajectories) and the
runner's live estimate (mrswarm/run/live.py, from the poses it receives): the area is cut into square cells
(``Mission.coverage_cell_m``: half the sensor radius, at least 0.5 m), and a cell is seen when its centre lies
within the sensor radius of a UAV working on its mission.
"""

from __future__ import annotations

import numpy as np

CELL_CHUNK = 2_000_000  # cells x points compared at once (~32 MB of float64 pairs): bounded memory, whatever the area


def cell_centres(area: tuple[float, float, float, float], cell: float) -> tuple[np.ndarray, np.ndarray]:
    """The centres east and north (m) of the cells of ``area`` (x0, x1, y0, y1, m), ``cell`` m on a side."""
    x0, x1, y0, y1 = area
    return np.arange(x0 + cell / 2, x1, cell), np.arange(y0 + cell / 2, y1, cell)


def cell_grid(xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """(n, 2) centres of every cell, row by row (north), as :func:`coverage` reshapes them."""
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def seen(cells: np.ndarray, pts: np.ndarray, radius: float) -> np.ndarray:
    """Per cell of ``cells`` (n, 2): within ``radius`` m of one of ``pts`` (k, 2), compared a chunk at a time."""
    out = np.zeros(len(cells), dtype=bool)
    step = max(1, CELL_CHUNK // len(pts))
    for c0 in range(0, len(cells), step):
        d2 = ((cells[c0:c0 + step, None, :] - pts[None, :, :]) ** 2).sum(axis=2).min(axis=1)
        out[c0:c0 + step] = d2 <= radius * radius
    return out


def coverage(grid: np.ndarray, pos: np.ndarray, active: np.ndarray, area: tuple[float, float, float, float],
             radius: float, cell: float) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Fraction of the area's cells (``cell`` m on a side) seen, within ``radius`` m of an active UAV, by each grid
    time. Returns (coverage per grid step, first-visit wall time per cell or NaN, (cell x centres, cell y centres)).
    """
    xs, ys = cell_centres(area, cell)
    cells = cell_grid(xs, ys)
    first = np.full(len(cells), np.inf)
    for k in range(pos.shape[1]):
        pts = pos[:, k, :2][active[:, k]]
        if len(pts):
            first[seen(cells, pts, radius) & (first == np.inf)] = grid[k]
    frac = np.searchsorted(np.sort(first), grid, side="right") / len(cells)
    first_visit = np.where(np.isinf(first), np.nan, first).reshape(len(ys), len(xs))
    return frac, first_visit, (xs, ys)


def time_to(frac: np.ndarray, grid: np.ndarray, t0: float, level: float) -> float | None:
    """Seconds from ``t0`` until ``frac`` first reaches ``level`` (None: never)."""
    idx = np.nonzero(frac >= level)[0]
    return float(grid[idx[0]] - t0) if len(idx) else None
