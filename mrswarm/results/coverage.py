"""Coverage of a mission area: its cells, and which of them a UAV's sensor has seen.

One rule for the numbers of record (mrswarm/results/analysis.py, from the recorded trajectories) and the
runner's live estimate (mrswarm/run/live.py, from the poses it receives): the area is cut into square cells
(``Mission.coverage_cell_m``: half the sensor radius, at least 0.5 m), and a cell is seen when its centre lies
within the sensor radius of a UAV working on its mission.
"""

from __future__ import annotations

import numpy as np

CELL_CHUNK = 2_000_000  # point x nearby-cell pairs compared at once: bounded memory, whatever the fleet


def cell_centres(area: tuple[float, float, float, float], cell: float) -> tuple[np.ndarray, np.ndarray]:
    """The centres east and north (m) of the cells of ``area`` (x0, x1, y0, y1, m), ``cell`` m on a side."""
    x0, x1, y0, y1 = area
    return np.arange(x0 + cell / 2, x1, cell), np.arange(y0 + cell / 2, y1, cell)


class CellGrid:
    """The cells of an area (centres ``xs`` east, ``ys`` north, ``cell`` m apart), row by row (cell
    ``iy * len(xs) + ix``, as :func:`coverage` reshapes them), and which of them lie within a radius
    of some points.

    Each point is compared only with the cells of the square around it that can hold a centre within
    the radius (7 x 7 cells at the default cell of half the sensor radius): the work grows with the
    points, not with the area (every cell against every point: 10^8 pairs for 100,000 cells and
    1,000 UAVs)."""

    def __init__(self, xs: np.ndarray, ys: np.ndarray, cell: float):
        self.xs, self.ys, self.cell = xs, ys, cell
        self.size = len(xs) * len(ys)

    def seen(self, pts: np.ndarray, radius: float) -> np.ndarray:
        """Per cell: its centre within ``radius`` m of one of ``pts`` (k, 2)."""
        out = np.zeros(self.size, dtype=bool)
        out[self.indices(pts, radius)] = True
        return out

    def indices(self, pts: np.ndarray, radius: float) -> np.ndarray:
        """The indices of the cells within ``radius`` m of one of ``pts`` (k, 2), with repeats."""
        xs, ys, nx, ny = self.xs, self.ys, len(self.xs), len(self.ys)
        pts = pts[np.isfinite(pts).all(axis=1)]  # a point nowhere sees nothing
        if not len(pts) or not nx or not ny:
            return np.zeros(0, dtype=np.intp)
        k = int(np.ceil(radius / self.cell)) + 1
        off = np.arange(-k, k + 1)
        found: list[np.ndarray] = []
        step = max(1, CELL_CHUNK // len(off) ** 2)
        for p0 in range(0, len(pts), step):
            chunk = pts[p0:p0 + step]
            cx = np.rint((chunk[:, 0] - xs[0]) / self.cell).astype(np.intp)[:, None] + off  # (k, 2k+1) columns near
            cy = np.rint((chunk[:, 1] - ys[0]) / self.cell).astype(np.intp)[:, None] + off
            okx, oky = (cx >= 0) & (cx < nx), (cy >= 0) & (cy < ny)
            dx2 = (xs[np.clip(cx, 0, nx - 1)] - chunk[:, 0:1]) ** 2
            dy2 = (ys[np.clip(cy, 0, ny - 1)] - chunk[:, 1:2]) ** 2
            inside = (dx2[:, None, :] + dy2[:, :, None] <= radius * radius) & okx[:, None, :] & oky[:, :, None]
            rows, cols = np.broadcast_to(cy[:, :, None], inside.shape), np.broadcast_to(cx[:, None, :], inside.shape)
            found.append(rows[inside] * nx + cols[inside])
        return np.concatenate(found)


def coverage(grid: np.ndarray, pos: np.ndarray, active: np.ndarray, area: tuple[float, float, float, float],
             radius: float, cell: float) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Fraction of the area's cells (``cell`` m on a side) seen, within ``radius`` m of an active UAV, by each grid
    time. Returns (coverage per grid step, first-visit wall time per cell or NaN, (cell x centres, cell y centres)).
    """
    xs, ys = cell_centres(area, cell)
    cells = CellGrid(xs, ys, cell)
    first = np.full(cells.size, np.inf)
    for k in range(pos.shape[1]):
        pts = pos[:, k, :2][active[:, k]]
        if len(pts):
            idx = cells.indices(pts, radius)
            idx = idx[first[idx] == np.inf]
            first[idx] = grid[k]
    frac = np.searchsorted(np.sort(first), grid, side="right") / cells.size
    first_visit = np.where(np.isinf(first), np.nan, first).reshape(len(ys), len(xs))
    return frac, first_visit, (xs, ys)


def time_to(frac: np.ndarray, grid: np.ndarray, t0: float, level: float) -> float | None:
    """Seconds from ``t0`` until ``frac`` first reaches ``level`` (None: never)."""
    idx = np.nonzero(frac >= level)[0]
    return float(grid[idx[0]] - t0) if len(idx) else None
