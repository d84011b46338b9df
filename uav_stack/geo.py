"""Geodetic <-> local ENU conversion on the WGS84 ellipsoid.

Every swarm shares one geodetic origin; each UAV converts its flight controller's
latitude/longitude/altitude into East-North-Up metres from that origin, so physical and
virtual UAVs live in one coordinate frame.

This is exact WGS84 (geodetic -> ECEF -> rotated into the origin's tangent plane, and
back with Bowring's iteration), written with ``math`` on scalars. pymap3d does the same but
costs about 2 MB of RSS and ~120 us per inverse conversion; an agent converts at 10-50 Hz
and we budget 2 % of a core per UAV, so it is not imported at run time. tests/test_geo.py
checks this module against closed-form WGS84 values and round trips.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
WGS84_B = WGS84_A * (1.0 - WGS84_F)
_EP2 = (WGS84_A**2 - WGS84_B**2) / WGS84_B**2


def geodetic_to_ecef(lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
    lat = math.radians(lat_deg)
    lon = math.radians(lon_deg)
    s, c = math.sin(lat), math.cos(lat)
    n = WGS84_A / math.sqrt(1.0 - WGS84_E2 * s * s)
    return ((n + alt_m) * c * math.cos(lon), (n + alt_m) * c * math.sin(lon), (n * (1.0 - WGS84_E2) + alt_m) * s)


def ecef_to_geodetic(x: float, y: float, z: float) -> tuple[float, float, float]:
    """Bowring's method, two refinements: sub-millimetre anywhere near the surface."""
    lon = math.atan2(y, x)
    p = math.hypot(x, y)
    if p < 1e-9:  # on the polar axis
        lat = math.copysign(math.pi / 2, z)
        return math.degrees(lat), math.degrees(lon), abs(z) - WGS84_B
    theta = math.atan2(z * WGS84_A, p * WGS84_B)
    lat = 0.0
    for _ in range(2):
        st, ct = math.sin(theta), math.cos(theta)
        lat = math.atan2(z + _EP2 * WGS84_B * st**3, p - WGS84_E2 * WGS84_A * ct**3)
        theta = math.atan2((1.0 - WGS84_F) * math.sin(lat), math.cos(lat))
    s = math.sin(lat)
    n = WGS84_A / math.sqrt(1.0 - WGS84_E2 * s * s)
    if abs(lat) < math.radians(80):
        alt = p / math.cos(lat) - n
    else:
        alt = z / s - n * (1.0 - WGS84_E2)
    return math.degrees(lat), math.degrees(lon), alt


@dataclass(frozen=True)
class GeoPoint:
    lat: float  # degrees
    lon: float  # degrees
    alt: float  # metres above mean sea level (treated as ellipsoid height)


class LocalFrame:
    """East-North-Up tangent plane anchored at a geodetic origin."""

    def __init__(self, origin: GeoPoint):
        self.origin = origin
        lat = math.radians(origin.lat)
        lon = math.radians(origin.lon)
        self._sl, self._cl = math.sin(lat), math.cos(lat)
        self._so, self._co = math.sin(lon), math.cos(lon)
        self._x0, self._y0, self._z0 = geodetic_to_ecef(origin.lat, origin.lon, origin.alt)

    def to_enu(self, lat: float, lon: float, alt: float) -> tuple[float, float, float]:
        x, y, z = geodetic_to_ecef(lat, lon, alt)
        dx, dy, dz = x - self._x0, y - self._y0, z - self._z0
        sl, cl, so, co = self._sl, self._cl, self._so, self._co
        e = -so * dx + co * dy
        n = -sl * co * dx - sl * so * dy + cl * dz
        u = cl * co * dx + cl * so * dy + sl * dz
        return e, n, u

    def to_geodetic(self, e: float, n: float, u: float) -> tuple[float, float, float]:
        sl, cl, so, co = self._sl, self._cl, self._so, self._co
        dx = -so * e - sl * co * n + cl * co * u
        dy = co * e - sl * so * n + cl * so * u
        dz = cl * n + sl * u
        return ecef_to_geodetic(self._x0 + dx, self._y0 + dy, self._z0 + dz)
