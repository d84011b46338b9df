"""Behaviours that use the world: no-fly zones in the avoidance, the firefighting state machine
(Lentzas' Table 1), plume seeking and source estimation, the traffic of the airspace feed.

The behaviours read sensors through the :class:`~uav_stack.sensors.Sensor` interface; here a
small sensor whose reading the test sets stands for the world service (the wire is tested in
test_world_delivery.py and end to end in test_world_e2e.py).
"""

from __future__ import annotations

import math
import random

import pytest

from swarmnet.messages import Traffic, TrafficReport
from tests.sim_pointmass import PointMassSim, SimAgent, SimConfig
from uav_stack.behaviours.avoidance import YIELD_MARGIN, CollisionAvoidance
from uav_stack.behaviours.base import Rect, SelfState
from uav_stack.behaviours.coverage import GoTo, RandomDirectionCoverage
from uav_stack.behaviours.firefighting import DEPART_GAP_S, FIGHTING, IDLE, ON_DUTY, RETURNING, FireFighter
from uav_stack.behaviours.plume import DETECTION_TOPIC, ESTIMATE_TOPIC, Detection, PlumeSearch, SourceEstimate
from uav_stack.behaviours.zones import ZoneField, ZoneShape, convex_hull
from uav_stack.config import Firefighting, PlumeSeeking
from uav_stack.geo import GeoPoint, LocalFrame
from uav_stack.sensors import Payload, SensorReading, TrafficTable


class SetSensor:
    """A sensor whose reading the test sets (what a driver or the world would deliver)."""

    def __init__(self, name: str):
        self.name = name
        self.reading: SensorReading | None = None

    def latest(self) -> SensorReading | None:
        return self.reading

    def set(self, t: float, value: float, points: tuple[tuple[float, float, float], ...] = ()) -> None:
        self.reading = SensorReading(self.name, t, value, points)


class Sprayer:
    def __init__(self) -> None:
        self.name = "spray"
        self.litres: list[float] = []

    def actuate(self, amount: float) -> None:
        self.litres.append(amount)


# ---- no-fly zones ----------------------------------------------------------------------------------------
SQUARE = ZoneShape(((-10, -10), (10, -10), (10, 10), (-10, 10)))
POCKET = ZoneShape(((-10, -15), (10, -15), (10, 15), (-10, 15), (-10, 10), (5, 10), (5, -10), (-10, -10)))  # open to the west


@pytest.mark.parametrize(("zone", "start", "goal"), [
    (SQUARE, (-40.0, 0.0), (40.0, 0.0)),  # square on: no sideways component to slide with
    (SQUARE, (0.0, -40.0), (3.0, 40.0)),
    (POCKET, (-40.0, 0.0), (40.0, 0.0)),  # a concave zone whose pocket faces the UAV
])
def test_a_uav_flies_round_a_zone_and_never_enters_it(zone: ZoneShape, start: tuple[float, float],
                                                      goal: tuple[float, float]) -> None:
    agent = SimAgent(1, start, GoTo(goal, 5.0, 1.0), CollisionAvoidance(5.0, 6.0, zones=ZoneField([zone], margin=3.0)))
    sim = PointMassSim([agent], SimConfig(loss=0.0), keep_trace=True)
    res = sim.run(60.0)
    assert 1 in res.done_at, "never reached its goal"
    assert not any(zone.contains((float(p[0, 0]), float(p[0, 1]))) for p in sim.trace)
    assert min(zone.distance((float(p[0, 0]), float(p[0, 1]))) for p in sim.trace) > 2.0


def test_zones_outrank_neighbours_and_apply_only_at_their_heights() -> None:
    """Pushed towards a zone by a neighbour, a UAV gives way along the zone's edge, not into it: boxed in between the
    neighbour and the zone's margin, into the margin, never closer to the zone than YIELD_MARGIN of it."""
    ca = CollisionAvoidance(5.0, 6.0, zones=ZoneField([ZoneShape(((0, -50), (20, -50), (20, 50), (0, 50)), 0.0, 50.0)],
                                                      margin=3.0))
    me = SelfState(1, (-4.0, 0.0), (0.0, 0.0), 0.0)
    from uav_stack.behaviours.base import NeighbourView

    intruder = NeighbourView(2, (-10.0, 0.0), (5.0, 0.0), 0.0, reciprocal=False)  # coming from the west, at us
    v = ca.adjust(me, (0.0, 0.0), [intruder], altitude=20.0).velocity
    assert v[0] <= (4.0 - 3.0 * YIELD_MARGIN) / 2.0 + 1e-6  # never faster towards the zone than 30 % of its margin allows
    assert abs(v[1]) > 1.0  # it gets out of the way sideways
    # above the zone's ceiling the zone does not apply
    free = ca.adjust(me, (5.0, 0.0), [], altitude=80.0).velocity
    assert free == pytest.approx((5.0, 0.0))
    blocked = ca.adjust(me, (5.0, 0.0), [], altitude=20.0).velocity
    assert blocked[0] <= 0.5 + 1e-6


def test_uavs_aimed_behind_a_wide_zone_go_round_its_nearer_end() -> None:
    """Square on to the middle of the village, a UAV north of the middle goes round the north end and one south of
    it round the south end: they part, rather than slide towards each other along the edge and meet head-on there,
    where the one nearer the edge cannot give way (the wildfire's 3.3 m with a 5 m safety distance)."""
    village = ZoneShape(((5, 35), (15, 35), (15, 65), (5, 65)))
    for y, north in ((52.0, True), (47.0, False), (64.0, True), (36.0, False)):
        ca = CollisionAvoidance(5.0, 6.0, zones=ZoneField([village], margin=3.0))
        me = SelfState(1, (-5.0, y), (5.0, 0.0), 0.0)
        v = ca.adjust(me, (5.0, 0.0), []).velocity  # towards the fire, straight behind the village
        assert (v[1] > 1.0) if north else (v[1] < -1.0), (y, v)
        assert v[0] <= (10.0 - 3.0) / 2.0 + 1e-6  # and not into the margin


def test_at_the_first_alarm_the_uavs_leave_the_hub_one_after_another_in_id_order() -> None:
    members = (1, 2, 3, 7)
    left: dict[int, float] = {}
    fighters = {}
    for uav in members:
        s = {n: SetSensor(n) for n in ("fire", "tank", "alarm")}
        cfg = Firefighting(hub=(0.0, 0.0), fire_hint=(50.0, 0.0), hub_radius=10.0)
        fighters[uav] = (FireFighter(cfg, 5.0, Payload(s, {"spray": Sprayer()}), 10.0, 6.0, random.Random(uav)), s)
    for k in range(120):
        t = 10.0 + 0.1 * k
        for uav, (ff, s) in fighters.items():
            s["alarm"].set(t, 3.0)
            s["tank"].set(t, 10.0)
            ff.velocity(SelfState(uav, (float(uav), 0.0), (0.0, 0.0), t), members)
            if ff.state == ON_DUTY and uav not in left:
                left[uav] = t
    assert [round(left[u] - 10.0, 1) for u in members] == [0.0, DEPART_GAP_S, 2 * DEPART_GAP_S, 3 * DEPART_GAP_S]
    # back at the hub and refilled, a UAV leaves again at once
    ff, s = fighters[7]
    ff._go(RETURNING, 30.0)
    for t in (30.0, 30.1):
        s["alarm"].set(t, 3.0)
        s["tank"].set(t, 10.0)
        ff.velocity(SelfState(7, (1.0, 0.0), (0.0, 0.0), t), members)
    assert ff.state == ON_DUTY


def test_convex_hull_of_a_concave_zone() -> None:
    assert set(convex_hull(POCKET.polygon)) == {(-10, -15), (10, -15), (10, 15), (-10, 15)}


# ---- the firefighting state machine (Table 1) ------------------------------------------------------------
def firefighter() -> tuple[FireFighter, dict[str, SetSensor], Sprayer]:
    s = {n: SetSensor(n) for n in ("fire", "tank", "alarm")}
    spray = Sprayer()
    cfg = Firefighting(hub=(0.0, 0.0), fire_hint=(50.0, 0.0), hub_radius=10.0, spray_rate_l_s=2.0)
    return FireFighter(cfg, 5.0, Payload(s, {"spray": spray}), 10.0, 6.0, random.Random(1)), s, spray


def step(ff: FireFighter, s: dict[str, SetSensor], t: float, pos: tuple[float, float], *, alarm: float, tank: float,
         cells: tuple[tuple[float, float, float], ...] = ()) -> tuple[float, float]:
    s["alarm"].set(t, alarm)
    s["tank"].set(t, tank)
    s["fire"].set(t, 15.0, cells)  # a 15 m footprint, these cells burning in it
    return ff.velocity(SelfState(1, pos, (0.0, 0.0), t))


def test_the_state_machine_follows_table_1() -> None:
    ff, s, spray = firefighter()
    # idle: no fire, or a tank not full -> stays at the hub
    assert step(ff, s, 1.0, (1.0, 0.0), alarm=0, tank=10.0) == (0.0, 0.0) and ff.state == IDLE
    assert step(ff, s, 2.0, (1.0, 0.0), alarm=3, tank=5.0) == (0.0, 0.0) and ff.state == IDLE
    # fire detected, tank full -> on duty, towards the fire the detection system reported
    v = step(ff, s, 3.0, (1.0, 0.0), alarm=3, tank=10.0)
    assert ff.state == ON_DUTY and v[0] > 4.0 and abs(v[1]) < 1e-6
    # fire not found -> on duty; fire found under the UAV -> fire fighting, spraying
    step(ff, s, 4.0, (30.0, 0.0), alarm=3, tank=10.0)
    assert ff.state == ON_DUTY and not spray.litres
    step(ff, s, 5.0, (49.0, 0.0), alarm=3, tank=10.0, cells=((50.0, 0.0, 80.0),))
    assert ff.state == FIGHTING and spray.litres
    step(ff, s, 5.5, (49.5, 0.0), alarm=3, tank=9.0, cells=((50.0, 0.0, 40.0),))
    assert ff.state == FIGHTING and sum(spray.litres) == pytest.approx(0.2 + 1.0)  # 2 l/s: 0.1 s, then 0.5 s
    # local fire taken out (the camera sees no burning cell) -> on duty, towards what the swarm knows
    ff.receive(2, "fire/cells", [80.0, 10.0, 15.0, [[85.0, 10.0]], 5.6], 5.6)
    v = step(ff, s, 6.0, (50.0, 0.0), alarm=2, tank=8.0)
    assert ff.state == ON_DUTY and v[0] > 0 and v[1] > 0  # to the cell another UAV shared
    # tank empty -> returning; at the hub -> idle; refilled with fire burning -> on duty again
    step(ff, s, 7.0, (84.0, 10.0), alarm=2, tank=0.0, cells=((85.0, 10.0, 50.0),))
    assert ff.state == RETURNING
    v = step(ff, s, 8.0, (40.0, 0.0), alarm=2, tank=0.0)
    assert ff.state == RETURNING and v[0] < 0
    step(ff, s, 20.0, (3.0, 0.0), alarm=2, tank=0.0)
    assert ff.state == IDLE
    step(ff, s, 25.0, (3.0, 0.0), alarm=2, tank=10.0)
    assert ff.state == ON_DUTY
    # global fire taken out -> returning
    step(ff, s, 26.0, (10.0, 0.0), alarm=0, tank=10.0)
    assert ff.state == RETURNING
    assert [(a, b) for _, a, b in ff.transitions] == [
        (IDLE, ON_DUTY), (ON_DUTY, FIGHTING), (FIGHTING, ON_DUTY), (ON_DUTY, RETURNING), (RETURNING, IDLE),
        (IDLE, ON_DUTY), (ON_DUTY, RETURNING)]


def test_shared_cells_are_cleared_by_a_footprint_that_no_longer_sees_them_and_bad_bodies_are_ignored() -> None:
    ff, s, _ = firefighter()
    ff.receive(2, "fire/cells", [60.0, 0.0, 15.0, [[60.0, 0.0], [65.0, 0.0]], 1.0], 1.0)
    assert len(ff.known) == 2
    ff.receive(3, "fire/cells", [62.0, 0.0, 15.0, [[65.0, 0.0]], 2.0], 2.0)
    assert [(x, y) for x, y, _ in ff.known.values()] == [(65.0, 0.0)]
    for bad in (None, 3, [1, 2], [1, 2, 3, "x", 5], [1, 2, 3, [["a", 1]], 5], [math.nan, 0, 1, [], 1], [0, 0, 1, [[1]], 1]):
        ff.receive(4, "fire/cells", bad, 3.0)
    assert len(ff.known) == 1


# ---- plume ------------------------------------------------------------------------------------------------
def test_the_source_estimate_is_the_most_upwind_detections_under_the_current_wind() -> None:
    est = SourceEstimate(memory_s=30.0, k=2)
    assert est.estimate(0.0, 0.0) is None
    for x, y in ((10.0, 1.0), (4.0, -1.0), (30.0, 0.0), (6.0, 1.0)):
        est.add(Detection(x, y, 1.0, 0.0))  # wind to the east: upwind is west
    assert est.estimate(2.0, 5.0) == pytest.approx((5.0, 0.0))
    # detections made under another wind do not count; old ones are forgotten
    assert est.estimate(2.0, 90.0) is None
    assert est.estimate(40.0, 0.0) is None


def plume_search(strategy: str, ps: float = 0.3) -> tuple[PlumeSearch, SetSensor, SetSensor]:
    pol, wind = SetSensor("pollutant"), SetSensor("wind")
    cfg = PlumeSeeking(strategy=strategy, stop_probability=ps)  # type: ignore[arg-type]
    ps_ = PlumeSearch(cfg, Rect(-50, 50, -50, 50), 4.0, Payload({"pollutant": pol, "wind": wind}), random.Random(2))
    return ps_, pol, wind


def test_seeking_surges_against_the_wind_casts_when_it_loses_the_plume_and_shares() -> None:
    ps, pol, wind = plume_search("seek")
    me = SelfState(1, (20.0, 0.0), (0.0, 0.0), 1.0)
    wind.set(1.0, 0.0)
    pol.set(1.0, 1.0)
    v = ps.velocity(me)
    assert ps.state == "surge" and v == pytest.approx((-4.0, 0.0))
    out = ps.outbox()
    assert (DETECTION_TOPIC, [20.0, 0.0, 1.0, 0.0]) in out and any(t == ESTIMATE_TOPIC for t, _ in out)
    pol.set(1.2, 0.0)
    v = ps.velocity(SelfState(1, (19.0, 0.0), (-4.0, 0.0), 1.2))
    assert ps.state == "cast" and abs(v[1]) > abs(v[0])  # across the wind
    # another UAV's detection further upwind moves the estimate
    ps.receive(2, DETECTION_TOPIC, [2.0, 0.5, 1.1, 0.0], 1.3)
    ps.velocity(SelfState(1, (19.0, 2.0), (0.0, 4.0), 1.3))
    assert ps.estimate is not None and ps.estimate[0] < 20.0
    for bad in (None, [1, 2], ["a", 1, 2, 3], [math.inf, 0, 1, 0], [0, 0, -100, 0]):
        ps.receive(3, DETECTION_TOPIC, bad, 1.4)  # ignored, never raised


def test_the_stop_rule_of_the_e_puck_experiment() -> None:
    always, pol, wind = plume_search("stop", ps=1.0)
    wind.set(0.0, 0.0)
    pol.set(0.0, 1.0)
    assert always.velocity(SelfState(1, (0.0, 0.0), (0.0, 0.0), 0.1)) == (0.0, 0.0) and always.state == "stopped"
    pol.set(0.2, 0.0)  # out of the plume (it turned away): moves on
    v = always.velocity(SelfState(1, (0.0, 0.0), (0.0, 0.0), 0.3))
    assert always.state == "search" and math.hypot(*v) > 1.0
    never, pol, wind = plume_search("stop", ps=0.0)
    wind.set(0.0, 0.0)
    for k in range(20):
        pol.set(0.1 * k, 1.0)
        assert math.hypot(*never.velocity(SelfState(1, (0.0, 0.0), (0.0, 0.0), 0.1 * k))) > 1.0


def test_random_search_stays_a_random_direction_search() -> None:
    assert isinstance(plume_search("seek")[0].search, RandomDirectionCoverage)


# ---- the airspace feed in a UAV's frame --------------------------------------------------------------------
def test_traffic_reports_land_in_the_uavs_frame_and_expire() -> None:
    origin = GeoPoint(46.6167, 14.2650, 446.0)
    frame = LocalFrame(origin)
    lat, lon, alt = frame.to_geodetic(30.0, -12.0, 15.0)
    table = TrafficTable(LocalFrame(origin), forget_after=5.0)
    table.update(Traffic(0, 100.0, (TrafficReport(7, 100.0, lat, lon, alt, -5.0, 0.0, 0.0),)))
    table.update(Traffic(1, 99.0, (TrafficReport(7, 99.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),)))  # older: ignored
    (t,) = table.current(101.0)
    assert (t.x, t.y, t.z) == pytest.approx((30.0, -12.0, 15.0), abs=0.01)
    assert (t.vx, t.vy) == (-5.0, 0.0) and t.age(101.0) == pytest.approx(1.0)
    assert table.current(106.0) == []
