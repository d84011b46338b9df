"""The world's models against hand-computed cases: cone membership, Gaussian plume values,
fire ignition timing with and without wind, fuel, suppression, targets, tanks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uav_stack.config import ActuatorSpec
from world.config import ConePlume, Fire, FuelPatch, GaussianPlume, Rect, Target, Wind, WorldConfig
from world.fire import BURNING, BURNT, EXTINGUISHED, UNBURNT, FireGrid
from world.model import World
from world.plume import PlumeModel, briggs_sigmas
from world.targets import MovingTarget

# ---- the cone of Reina et al.: theta_d = 10, theta_w = 45, theta_r = 100 after T_r = 60 s ------------------
SEED_WIND = Wind(direction_deg=10.0, turn_deg=100.0, turn_after_s=60.0)
CONE = ConePlume(source=(0.0, 0.0), width_deg=45.0)


def cone_at(points: list[tuple[float, float]], t: float) -> list[float]:
    pts = np.array([(x, y, 15.0) for x, y in points])
    return list(PlumeModel(CONE, SEED_WIND).read(pts, t))


def polar(r: float, deg: float) -> tuple[float, float]:
    return (r * math.cos(math.radians(deg)), r * math.sin(math.radians(deg)))


def test_cone_membership_by_hand() -> None:
    # before T_r the axis points at 10 degrees and the cone spans 10 +- 22.5 = [-12.5, 32.5]
    inside = [polar(30, 10), polar(30, 32), polar(30, -12), polar(5, 0), polar(100, 30)]
    outside = [polar(30, 33), polar(30, -13), polar(30, 190), polar(30, 90), polar(1, 120)]
    assert cone_at(inside, 0.0) == [1.0] * 5
    assert cone_at(outside, 0.0) == [0.0] * 5
    assert cone_at([(0.0, 0.0)], 0.0) == [1.0]  # the source itself


def test_the_cone_turns_100_degrees_counter_clockwise_after_60_s() -> None:
    # after T_r the axis is at 110 degrees: [87.5, 132.5]
    assert cone_at([polar(30, 10)], 59.9) == [1.0]
    assert cone_at([polar(30, 10), polar(30, 110), polar(30, 88), polar(30, 132), polar(30, 87), polar(30, 133)], 60.0) \
        == [0.0, 1.0, 1.0, 1.0, 0.0, 0.0]


def test_cone_range_limits_it() -> None:
    pts = np.array([(*polar(49, 10), 0.0), (*polar(51, 10), 0.0)])
    assert list(PlumeModel(ConePlume(source=(0, 0), range_m=50.0), SEED_WIND).read(pts, 0.0)) == [1.0, 0.0]


def test_gaussian_plume_by_hand() -> None:
    """Class D, Q = 10 g/s, u = 4 m/s towards north, source at (100, 0) at H = 15 m; receptor
    200 m downwind, 20 m across, at 15 m: sy = 0.08*200/sqrt(1.02), sz = 0.06*200/sqrt(1.3)."""
    g = GaussianPlume(source=(100.0, 0.0), height_m=15.0, rate_g_s=10.0, stability="D")
    wind = Wind(speed=4.0, direction_deg=90.0)
    sy = 0.08 * 200 / math.sqrt(1 + 0.0001 * 200)
    sz = 0.06 * 200 / math.sqrt(1 + 0.0015 * 200)
    by_hand = 10 / (2 * math.pi * 4 * sy * sz) * math.exp(-(20**2) / (2 * sy**2)) * (1 + math.exp(-(30**2) / (2 * sz**2)))
    pts = np.array([(80.0, 200.0, 15.0), (100.0, -50.0, 15.0), (100.0, 200.0, 15.0)])  # 20 m across, upwind, on the axis
    c = PlumeModel(g, wind).read(pts, 0.0)
    assert c[0] == pytest.approx(by_hand * 1000, rel=1e-9)  # mg/m^3
    assert c[1] == 0.0
    assert c[2] > c[0]
    sy2, sz2 = briggs_sigmas(np.array([1000.0]), "F")
    assert sy2[0] == pytest.approx(40 / math.sqrt(1.1)) and sz2[0] == pytest.approx(16 / 1.3)


# ---- fire: hand-computed ignition times ----------------------------------------------------------------
CALM = Wind()


def fire(wind: Wind = CALM, **kw: object) -> FireGrid:
    """A 9 x 9 grid of 10 m cells, fire lit in the middle (45, 45); neighbours within 12 m: the 4 adjacent ones."""
    args: dict[str, object] = {"area": Rect(0, 90, 0, 90), "ignite": ((45.0, 45.0),), "cell_m": 10.0, "heat_rate": 10.0,
                               "spread_heat": 50.0, "burnout_heat": 150.0, "spread_distance_m": 12.0, "wind_factor": 0.1,
                               "step_s": 0.1}
    args.update(kw)
    g = FireGrid(Fire(**args), wind)  # type: ignore[arg-type]
    g.ignite()
    return g


def ignition_time(g: FireGrid, x: float, y: float) -> float:
    c = g.cell_of(x, y)
    assert c is not None
    return float(g.t_ignited[c])


def test_fire_without_wind_spreads_after_spread_heat_over_heat_rate() -> None:
    g = fire()
    g.advance(20.0)
    # 50 heat units at 10 per second: the four neighbours at 5 s, theirs at 10 s; diagonals (14 m) via two hops
    for x, y in ((55, 45), (35, 45), (45, 55), (45, 35)):
        assert ignition_time(g, x, y) == pytest.approx(5.0)
    assert ignition_time(g, 65, 45) == pytest.approx(10.0)
    assert ignition_time(g, 55, 55) == pytest.approx(10.0)
    # burnt out at 150 heat units: 15 s after its ignition
    c = g.cell_of(45, 45)
    assert c is not None and g.state[c] == BURNT and g.t_over[c] == pytest.approx(15.0)


def test_fire_with_wind_spreads_faster_downwind_and_slower_upwind() -> None:
    # wind 5 m/s towards east, k = 0.1 s/m: w = 1.5 downwind, 0.5 upwind, 1 across
    g = fire(Wind(speed=5.0, direction_deg=0.0))
    g.advance(20.0)
    assert ignition_time(g, 55, 45) == pytest.approx(math.ceil(50 / 1.5 / 10 / 0.1 - 1e-9) * 0.1)  # 3.4 s
    assert ignition_time(g, 35, 45) == pytest.approx(10.0)  # 50 / 0.5 = 100 units
    assert ignition_time(g, 45, 55) == pytest.approx(5.0)
    assert ignition_time(g, 45, 35) == pytest.approx(5.0)
    # a wind with k u >= 1 never spreads upwind
    g = fire(Wind(speed=10.0, direction_deg=0.0))
    g.advance(14.0)
    c = g.cell_of(35, 45)
    assert c is not None and g.state[c] == UNBURNT


def test_fuel_density_slows_ignition_and_zero_fuel_stops_the_fire() -> None:
    # the column x in [50, 60] has half the fuel, x >= 70 none
    patches = (FuelPatch(polygon=((50, 0), (60, 0), (60, 90), (50, 90)), density=0.5),
               FuelPatch(polygon=((70, 0), (90, 0), (90, 90), (70, 90)), density=0.0))
    g = fire(patches=patches)
    g.advance(60.0)
    assert ignition_time(g, 55, 45) == pytest.approx(10.0)  # (50 / 0.5) / 10
    c = g.cell_of(75, 45)
    assert c is not None and g.state[c] == UNBURNT and g.fuel[c] == 0.0
    # a half-fuel cell burns out at 0.5 * 150 = 75 units: 7.5 s after it caught
    c = g.cell_of(55, 45)
    assert c is not None and g.t_over[c] == pytest.approx(17.5)


def test_spraying_extinguishes_a_cell_and_wets_its_neighbours() -> None:
    g = fire(suppression_per_l=40.0)
    g.advance(2.0)  # the lit cell holds 20 heat units
    c = g.cell_of(45, 45)
    assert c is not None and g.state[c] == BURNING and g.heat[c] == pytest.approx(20.0)
    # a 3 m disc holds one cell centre: 0.25 l x 40 = 10 units, not enough
    assert g.spray(45, 45, 0.25, 3.0) == 0
    assert g.heat[c] == pytest.approx(10.0) and g.state[c] == BURNING
    assert g.spray(45, 45, 0.5, 3.0) == 1
    assert g.state[c] == EXTINGUISHED
    g.advance(30.0)
    assert g.counts()["ignited"] == 1  # put out before it could spread
    # soaked cells need more heat: spraying a neighbour first delays its ignition
    g = fire(suppression_per_l=40.0)
    g.spray(55, 45, 1.25, 3.0)  # 50 units of water on the east neighbour: it needs 100 heat units
    g.advance(20.0)
    assert ignition_time(g, 55, 45) == pytest.approx(10.0)
    assert g.out_at is None


def test_fire_reports_when_it_is_out() -> None:
    g = fire(area=Rect(0, 10, 0, 10), ignite=((5.0, 5.0),))
    g.advance(20.0)
    assert g.out_at == pytest.approx(15.0)
    assert g.burnt_area_m2 == 100.0


# ---- targets, tanks --------------------------------------------------------------------------------------
def test_a_target_follows_its_path() -> None:
    sq = MovingTarget(Target(id=1, path=((0, 0), (10, 0), (10, 10), (0, 10)), speed=2.0, loop=True))
    assert sq.position(0) == (0, 0)
    assert sq.position(2.5) == pytest.approx((5, 0))
    assert sq.position(7.5) == pytest.approx((10, 5))
    assert sq.position(20 + 2.5) == pytest.approx((5, 0))  # a lap is 40 m, 20 s
    back = MovingTarget(Target(id=2, path=((0, 0), (10, 0)), speed=1.0, loop=False))
    assert back.position(13) == pytest.approx((7, 0))


def test_a_tank_releases_at_most_its_rate_and_refills_at_the_hub() -> None:
    spray = ActuatorSpec(name="spray", capacity_l=3.0, rate_l_s=1.0, refill_at=(0.0, 0.0), refill_radius_m=5.0,
                         refill_rate_l_s=0.5)
    w = World(WorldConfig(actuators=(spray,)))
    u = ("alpha", 1)
    assert w.actuate(u, "spray", 5.0, 50, 50, now=100.0) == (1.0, 0)  # one second's worth at most
    assert w.actuate(u, "spray", 5.0, 50, 50, now=100.5) == (0.5, 0)
    assert w.actuate(u, "spray", 5.0, 50, 50, now=102.0) == (1.0, 0)
    assert w.actuate(u, "spray", 5.0, 50, 50, now=104.0) == (0.5, 0)  # what was left
    assert w.tank_level(u) == 0.0
    assert w.actuate(u, "spray", 1.0, 50, 50, now=106.0) == (0.0, 0)
    w.refill({u: (60.0, 0.0)}, 2.0)
    assert w.tank_level(u) == 0.0  # not at the hub
    w.refill({u: (3.0, 0.0)}, 2.0)
    assert w.tank_level(u) == pytest.approx(1.0)
