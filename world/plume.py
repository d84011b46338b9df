"""Pollutant plumes: the diffusion cone of Reina et al. and a Gaussian plume carried by the wind.

Both answer "what does a sensor read at these points, at this experiment time?" for many
points at once (numpy arrays of shape ``(n, 3)``, ENU metres).

**Cone** (Reina et al., virtual sensing on e-pucks): the pollutant is present inside the cone
with its vertex at the source, opening ``width_deg`` around the wind's direction (theta_d,
turned by theta_r after T_r: :class:`~world.config.Wind`), out to ``range_m``. A point ``p``
reads 1 if ``|angle(p - source, wind)| <= width / 2`` (the source itself included), else 0.

**Gaussian**: the steady plume of a point source of ``Q`` g/s at height ``H``, in a wind of
speed ``u`` towards ``theta``. With ``x`` the distance downwind of the source and ``y`` across
it (both along the ground), at height ``z`` (reflection by the ground)::

    C = Q / (2 pi u sy sz) * exp(-y^2 / (2 sy^2)) * (exp(-(z-H)^2 / (2 sz^2)) + exp(-(z+H)^2 / (2 sz^2)))

for ``x > 0``, and 0 upwind. ``sy(x)``, ``sz(x)`` are Briggs' open-country formulas for the
stability class (Briggs 1973, as tabulated by Turner's Workbook of Atmospheric Dispersion
Estimates). ``C`` comes in g/m^3 and is read in mg/m^3.
"""

from __future__ import annotations

import math

import numpy as np

from world.config import ConePlume, GaussianPlume, Plume, Wind

# Briggs open country: sigma = a x (1 + b x)^c, for y and z per Pasquill class
_BRIGGS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "A": ((0.22, 0.0001, -0.5), (0.20, 0.0, 1.0)),
    "B": ((0.16, 0.0001, -0.5), (0.12, 0.0, 1.0)),
    "C": ((0.11, 0.0001, -0.5), (0.08, 0.0002, -0.5)),
    "D": ((0.08, 0.0001, -0.5), (0.06, 0.0015, -0.5)),
    "E": ((0.06, 0.0001, -0.5), (0.03, 0.0003, -1.0)),
    "F": ((0.04, 0.0001, -0.5), (0.016, 0.0003, -1.0)),
}


def briggs_sigmas(x: np.ndarray, stability: str) -> tuple[np.ndarray, np.ndarray]:
    """``(sigma_y, sigma_z)`` in m at ``x`` m downwind (x > 0)."""
    (ay, by, cy), (az, bz, cz) = _BRIGGS[stability]
    sy = ay * x * (1.0 + by * x) ** cy
    sz = az * x * (1.0 + bz * x) ** cz if bz else az * x
    return sy, sz


class PlumeModel:
    """Readings of a plume at points and times (experiment seconds)."""

    def __init__(self, plume: Plume, wind: Wind):
        self.plume = plume
        self.wind = wind

    @property
    def source(self) -> tuple[float, float]:
        return self.plume.source

    def read(self, pts: np.ndarray, t: float) -> np.ndarray:
        """The reading at each point of ``pts`` (n, 3): 0/1 in the cone, mg/m^3 for the Gaussian plume."""
        if isinstance(self.plume, ConePlume):
            return cone_reading(pts, self.plume, self.wind.direction_at(t))
        return gaussian_reading(pts, self.plume, self.wind.speed, self.wind.direction_at(t))


def cone_reading(pts: np.ndarray, cone: ConePlume, direction_deg: float) -> np.ndarray:
    dx = pts[:, 0] - cone.source[0]
    dy = pts[:, 1] - cone.source[1]
    r = np.hypot(dx, dy)
    th = math.radians(direction_deg)
    along = dx * math.cos(th) + dy * math.sin(th)
    # |angle| <= w/2  <=>  along >= r cos(w/2)  (for w < 360); the source itself (r = 0) is inside
    inside = along >= r * math.cos(math.radians(cone.width_deg) / 2.0) - 1e-9
    if cone.range_m is not None:
        inside &= r <= cone.range_m
    return inside.astype(float)


def gaussian_reading(pts: np.ndarray, g: GaussianPlume, wind_speed: float, direction_deg: float) -> np.ndarray:
    th = math.radians(direction_deg)
    dx = pts[:, 0] - g.source[0]
    dy = pts[:, 1] - g.source[1]
    x = dx * math.cos(th) + dy * math.sin(th)  # downwind
    y = -dx * math.sin(th) + dy * math.cos(th)  # across
    z = pts[:, 2]
    u = max(wind_speed, g.min_wind)
    out = np.zeros(len(pts))
    down = x > 1e-3
    if not down.any():
        return out
    xd = x[down]
    sy, sz = briggs_sigmas(xd, g.stability)
    h = g.height_m
    zd = z[down]
    c = (g.rate_g_s / (2.0 * math.pi * u * sy * sz) * np.exp(-(y[down] ** 2) / (2.0 * sy**2))
         * (np.exp(-((zd - h) ** 2) / (2.0 * sz**2)) + np.exp(-((zd + h) ** 2) / (2.0 * sz**2))))
    out[down] = c * 1000.0  # g/m^3 -> mg/m^3
    return out
