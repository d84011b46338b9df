"""WGS84 conversions (uav_stack.geo) against closed-form values and round trips."""

from __future__ import annotations

import math

import pytest

from uav_stack.geo import WGS84_A, WGS84_B, WGS84_E2, GeoPoint, LocalFrame, ecef_to_geodetic, geodetic_to_ecef


def test_ecef_of_the_equator_and_the_pole() -> None:
    assert geodetic_to_ecef(0.0, 0.0, 0.0) == pytest.approx((WGS84_A, 0.0, 0.0), abs=1e-6)
    assert geodetic_to_ecef(0.0, 90.0, 100.0) == pytest.approx((0.0, WGS84_A + 100.0, 0.0), abs=1e-6)
    assert geodetic_to_ecef(90.0, 0.0, 0.0) == pytest.approx((0.0, 0.0, WGS84_B), abs=1e-6)
    assert ecef_to_geodetic(0.0, 0.0, -WGS84_B - 5.0) == pytest.approx((-90.0, 0.0, 5.0), abs=1e-6)


@pytest.mark.parametrize("lat", [-89.9, -46.6, 0.0, 14.3, 47.4, 85.0])
def test_geodetic_round_trip_is_sub_millimetre(lat: float) -> None:
    for lon, alt in ((-179.5, -300.0), (8.5, 488.0), (120.0, 9000.0)):
        back = ecef_to_geodetic(*geodetic_to_ecef(lat, lon, alt))
        assert back[0] == pytest.approx(lat, abs=1e-9) and back[1] == pytest.approx(lon, abs=1e-9)
        assert back[2] == pytest.approx(alt, abs=1e-3)


def test_local_frame_axes_and_scale() -> None:
    origin = GeoPoint(47.397742, 8.545594, 488.0)
    frame = LocalFrame(origin)
    assert frame.to_enu(origin.lat, origin.lon, origin.alt) == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)
    # a small step north/east covers the meridian / parallel radius of curvature times the angle
    phi = math.radians(origin.lat)
    w = math.sqrt(1.0 - WGS84_E2 * math.sin(phi) ** 2)
    m_north = WGS84_A * (1.0 - WGS84_E2) / w**3 * math.radians(1e-4)
    m_east = WGS84_A / w * math.cos(phi) * math.radians(1e-4)
    e, n, u = frame.to_enu(origin.lat + 1e-4, origin.lon, origin.alt)
    assert (e, n) == pytest.approx((0.0, m_north), abs=1e-3) and abs(u) < 1e-3
    e, n, u = frame.to_enu(origin.lat, origin.lon + 1e-4, origin.alt)
    assert (e, n) == pytest.approx((m_east, 0.0), abs=1e-3) and abs(u) < 1e-3
    assert frame.to_enu(origin.lat, origin.lon, origin.alt + 12.5)[2] == pytest.approx(12.5, abs=1e-6)


def test_local_frame_round_trip_over_a_swarm_area() -> None:
    frame = LocalFrame(GeoPoint(46.6167, 14.2650, 446.0))
    for enu in ((0.0, 0.0, 0.0), (1500.0, -800.0, 60.0), (-5000.0, 5000.0, 120.0)):
        assert frame.to_enu(*frame.to_geodetic(*enu)) == pytest.approx(enu, abs=1e-3)
