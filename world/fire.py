"""A spreading wildfire on a grid: Lentzas' heat model with fuel density and wind, and suppression.

Lentzas' thesis (swarm firefighting in ARGoS, section 3.3) gives every tree a heat value: a
burning tree heats up by one unit per tick; past ``spread_time`` it sets the unburnt trees
within ``spread_distance`` alight; at ``max_burn`` it has burnt out. The thesis names the
missing wind as the model's main limit. Here the trees are the cells of a grid (``cell_m``),
time is continuous (steps of ``step_s``), and each cell ``j`` has a fuel density ``f_j`` in
[0, 1] (0: nothing to burn). Per step:

1. every burning cell heats up: ``h_i += heat_rate * step_s``;
2. a burning cell with ``h_i >= burnout_heat * f_i`` has burnt out (more fuel, longer fire);
3. an unburnt cell ``j`` with ``f_j > 0`` catches fire when a burning cell ``i`` within
   ``spread_distance_m`` has ``h_i >= (spread_heat + wet_j) / (f_j * w_ij)``, with the wind term
   ``w_ij = 1 + wind_factor * wind_speed * cos(phi_ij - theta_wind)`` (``phi_ij``: the direction
   from ``i`` to ``j``); ``w_ij <= 0`` never spreads (far upwind of a strong wind). Without
   wind, or for ``i`` and ``j`` across the wind, ``w = 1``: the thesis' model.

So with fuel 1 the neighbour downwind of a fire lit at ``t = 0`` catches at
``spread_heat / (heat_rate * (1 + k u))`` seconds, the one upwind at
``spread_heat / (heat_rate * (1 - k u))`` (never if ``k u >= 1``), rounded up to a step.

**Suppression**: ``L`` litres sprayed on the disc of radius ``r`` around a point spread evenly
over the cells whose centres lie in it: each gets ``L / n`` litres, which take
``suppression_per_l * L / n`` heat from a burning cell (at ``h <= 0`` it is **extinguished**
for good) and soak an unburnt one (its ``wet`` raises the heat it needs to catch fire).
"""

from __future__ import annotations

import math

import numpy as np

from uav_stack.behaviours.zones import inside_polygon
from world.config import Fire, Wind

UNBURNT, BURNING, BURNT, EXTINGUISHED = 0, 1, 2, 3


class FireGrid:
    """The fire model's state (module docstring); ``t`` is experiment time, s."""

    def __init__(self, cfg: Fire, wind: Wind):
        self.cfg = cfg
        self.wind = wind
        a = cfg.area
        c = cfg.cell_m
        self.nx = max(1, math.ceil((a.x_max - a.x_min) / c))
        self.ny = max(1, math.ceil((a.y_max - a.y_min) / c))
        self.xs = a.x_min + c * (np.arange(self.nx) + 0.5)  # cell centres, m
        self.ys = a.y_min + c * (np.arange(self.ny) + 0.5)
        gx, gy = np.meshgrid(self.xs, self.ys)  # arrays are [iy, ix]
        self.fuel = np.full((self.ny, self.nx), cfg.fuel)
        for patch in cfg.patches:
            inside = np.array([inside_polygon((x, y), patch.polygon) for x, y in zip(gx.ravel(), gy.ravel(), strict=True)])
            self.fuel[inside.reshape(gx.shape)] = patch.density
        self.state = np.full((self.ny, self.nx), UNBURNT, dtype=np.int8)
        self.heat = np.zeros((self.ny, self.nx))
        self.wet = np.zeros((self.ny, self.nx))
        self.t_ignited = np.full((self.ny, self.nx), np.nan)
        self.t_over = np.full((self.ny, self.nx), np.nan)  # burnt out or extinguished
        self.t = 0.0
        self.started = False
        self.out_at: float | None = None  # when the last burning cell went out
        self.sprayed_l = 0.0
        r = cfg.spread_distance_m / c
        k = int(math.floor(r + 1e-9))
        # (dy, dx, direction from the burning cell to the neighbour, rad) within the spread distance
        self.offsets = [(dy, dx, math.atan2(dy, dx)) for dy in range(-k, k + 1) for dx in range(-k, k + 1)
                        if (dx or dy) and math.hypot(dx, dy) <= r + 1e-9]

    # -- geometry ---------------------------------------------------------------------------------
    def cell_of(self, x: float, y: float) -> tuple[int, int] | None:
        """``(iy, ix)`` of the cell holding ``(x, y)``, None outside the grid."""
        a = self.cfg.area
        ix = int(math.floor((x - a.x_min) / self.cfg.cell_m))
        iy = int(math.floor((y - a.y_min) / self.cfg.cell_m))
        if 0 <= ix < self.nx and 0 <= iy < self.ny:
            return iy, ix
        return None

    def centre(self, iy: int, ix: int) -> tuple[float, float]:
        return float(self.xs[ix]), float(self.ys[iy])

    # -- time ---------------------------------------------------------------------------------------
    def ignite(self, points: tuple[tuple[float, float], ...] | None = None) -> None:
        """Set the configured cells (or ``points``) alight now."""
        self.started = True
        for x, y in points if points is not None else self.cfg.ignite:
            c = self.cell_of(x, y)
            if c is not None and self.fuel[c] > 0.0 and self.state[c] == UNBURNT:
                self.state[c] = BURNING
                self.heat[c] = 0.0
                self.t_ignited[c] = self.t

    def advance(self, t: float) -> None:
        """Run whole steps until experiment time ``t`` (s)."""
        dt = self.cfg.step_s
        while self.t + dt <= t + 1e-9:
            self.step()

    def step(self) -> None:
        cfg = self.cfg
        dt = cfg.step_s
        self.t = round(self.t + dt, 9)
        burning = self.state == BURNING
        if not burning.any():
            return
        self.heat[burning] += cfg.heat_rate * dt
        out = burning & (self.heat >= cfg.burnout_heat * self.fuel)
        self.state[out] = BURNT
        self.t_over[out] = self.t
        burning &= ~out
        self._spread(burning)
        if not (self.state == BURNING).any() and self.out_at is None:
            self.out_at = self.t

    def _spread(self, burning: np.ndarray) -> None:
        cfg = self.cfg
        heat = np.where(burning, self.heat, -np.inf)
        can = (self.state == UNBURNT) & (self.fuel > 0.0)
        if not can.any():
            return
        need = (cfg.spread_heat + self.wet) / np.where(self.fuel > 0.0, self.fuel, 1.0)  # before the wind term
        th = math.radians(self.wind.direction_at(self.t))
        ku = cfg.wind_factor * self.wind.speed
        catch = np.zeros_like(can)
        ny, nx = self.ny, self.nx
        for dy, dx, phi in self.offsets:
            w = 1.0 + ku * math.cos(phi - th)
            if w <= 0.0:
                continue
            # source i = j - (dy, dx): heat of the source cell shifted onto its neighbour j
            src = np.full((ny, nx), -np.inf)
            ys, yd = (slice(0, ny - dy), slice(dy, ny)) if dy >= 0 else (slice(-dy, ny), slice(0, ny + dy))
            xs, xd = (slice(0, nx - dx), slice(dx, nx)) if dx >= 0 else (slice(-dx, nx), slice(0, nx + dx))
            src[yd, xd] = heat[ys, xs]
            catch |= can & (src * w >= need - 1e-9)
        if catch.any():
            self.state[catch] = BURNING
            self.heat[catch] = 0.0
            self.t_ignited[catch] = self.t
            self.out_at = None

    # -- suppression ----------------------------------------------------------------------------------
    def spray(self, x: float, y: float, litres: float, radius: float) -> int:
        """Spray ``litres`` on the disc of ``radius`` m around ``(x, y)``; returns the cells extinguished."""
        if litres <= 0.0:
            return 0
        ix0 = max(0, int(math.floor((x - radius - self.cfg.area.x_min) / self.cfg.cell_m)))
        ix1 = min(self.nx, int(math.ceil((x + radius - self.cfg.area.x_min) / self.cfg.cell_m)) + 1)
        iy0 = max(0, int(math.floor((y - radius - self.cfg.area.y_min) / self.cfg.cell_m)))
        iy1 = min(self.ny, int(math.ceil((y + radius - self.cfg.area.y_min) / self.cfg.cell_m)) + 1)
        if ix0 >= ix1 or iy0 >= iy1:
            return 0
        gx, gy = np.meshgrid(self.xs[ix0:ix1], self.ys[iy0:iy1])
        disc = (gx - x) ** 2 + (gy - y) ** 2 <= radius * radius
        n = int(disc.sum())
        if n == 0:
            c = self.cell_of(x, y)  # a disc smaller than a cell: the cell under the point
            if c is None:
                return 0
            iy0, ix0 = c
            iy1, ix1 = iy0 + 1, ix0 + 1
            disc = np.ones((1, 1), dtype=bool)
            n = 1
        self.sprayed_l += litres
        dose = self.cfg.suppression_per_l * litres / n
        st = self.state[iy0:iy1, ix0:ix1]
        heat = self.heat[iy0:iy1, ix0:ix1]
        burning = disc & (st == BURNING)
        heat[burning] -= dose
        done = burning & (heat <= 0.0)
        heat[done] = 0.0
        st[done] = EXTINGUISHED
        self.t_over[iy0:iy1, ix0:ix1][done] = self.t
        self.wet[iy0:iy1, ix0:ix1][disc & (st == UNBURNT)] += dose
        if done.any() and not (self.state == BURNING).any() and self.out_at is None:
            self.out_at = self.t
        return int(done.sum())

    # -- what the sensors and the records read ---------------------------------------------------------
    def burning_cells(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centres x, y (m) and heat of every burning cell."""
        iy, ix = np.nonzero(self.state == BURNING)
        return self.xs[ix], self.ys[iy], self.heat[iy, ix]

    def counts(self) -> dict[str, int]:
        return {"burning": int((self.state == BURNING).sum()), "burnt": int((self.state == BURNT).sum()),
                "extinguished": int((self.state == EXTINGUISHED).sum()),
                "ignited": int(np.isfinite(self.t_ignited).sum())}

    @property
    def burnt_area_m2(self) -> float:
        """Area of every cell that caught fire (burning, burnt out or extinguished), m^2."""
        return float(np.isfinite(self.t_ignited).sum()) * self.cfg.cell_m**2
