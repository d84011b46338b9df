"""The plume and wildfire missions on the SDK: ``mission.type: plume`` and ``wildfire`` fly the built-in
behaviours of ``uav_stack/sdk/sensing.py`` through the guarded adapter, read their sensors and
spray through the Context, share their messages as SDK messages, and show their state.

Each UAV's mission is the one its agent builds from the shipped scenario (``make_mission``); the
sensors are ones whose reading the test sets (the world service's side is tested in
test_world_delivery.py, the algorithms in test_world_behaviours.py, the whole in test_world_e2e.py).
No agent drives these missions, so what they broadcast waits in the adapter's outbox, in the
envelope an agent sends, and the test delivers it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from mrswarm.scenario import load_scenario
from tests.test_world_behaviours import SetSensor, Sprayer
from uav_stack.agent import make_mission
from uav_stack.behaviours.base import SelfState
from uav_stack.behaviours.firefighting import CELLS_TOPIC, DEPART_GAP_S, FIGHTING, IDLE, ON_DUTY
from uav_stack.behaviours.plume import DETECTION_TOPIC, ESTIMATE_TOPIC
from uav_stack.behaviours.zones import zone_field
from uav_stack.config import AgentConfig, NetworkConfig
from uav_stack.sdk.adapter import BehaviourMission
from uav_stack.sdk.sensing import PlumeSource, Wildfire, estimate_in
from uav_stack.sensors import Payload

SCN = Path(__file__).resolve().parents[1] / "scenarios"


def configs(scenario: str, *sets: str) -> list[AgentConfig]:
    return [c.agent for c in load_scenario(SCN / scenario, list(sets)).virtual_uav_configs(NetworkConfig(), None)]


def fly(m: BehaviourMission, uav: int, t: float, pos: tuple[float, float], members: tuple[int, ...] = ()) -> tuple[float, float]:
    return m.velocity(SelfState(uav, pos, (0.0, 0.0), t), members or (uav,))


# ---- wildfire ----------------------------------------------------------------------------------------------
def firefighters(n: int = 2) -> list[tuple[BehaviourMission, dict[str, SetSensor], Sprayer]]:
    out = []
    for c in configs("wildfire.yaml")[:n]:
        s = {name: SetSensor(name) for name in ("fire", "tank", "alarm")}
        spray = Sprayer()
        a = c.avoidance
        m = make_mission(c, Payload(dict(s), {"spray": spray}), zone_field(a.zones, a.zone_margin))
        assert isinstance(m, BehaviourMission) and isinstance(m.behaviour, Wildfire)
        out.append((m, s, spray))
    return out


def sense(s: dict[str, SetSensor], t: float, *, alarm: float, tank: float,
          cells: tuple[tuple[float, float, float], ...] = ()) -> None:
    s["alarm"].set(t, alarm)
    s["tank"].set(t, tank)
    s["fire"].set(t, 15.0, cells)  # a 15 m footprint, these cells burning in it


def test_the_wildfire_mission_flies_through_the_sdk_sprays_with_the_context_and_shares_its_cells() -> None:
    (m, s, spray), (other, s2, _) = firefighters()
    assert m.behaviour.params.capacity_l == 15.0 and m.behaviour.params.spray_radius_m == 6.0  # the scenario's spray
    hub = (-25.0, 50.0)
    sense(s, 1.0, alarm=0, tank=15.0)
    assert fly(m, 1, 1.0, hub) == (0.0, 0.0) and m.status == IDLE  # the state detail the agent shows
    sense(s, 1.1, alarm=3, tank=15.0)
    v = fly(m, 1, 1.1, hub)
    assert m.status == ON_DUTY and v[0] > 4.0  # east, to the reported fire
    # a burning cell under the UAV: fire fighting, the spray asked through ctx.actuate
    sense(s, 1.2, alarm=3, tank=15.0, cells=((40.0, 50.0, 80.0),))
    fly(m, 1, 1.2, (39.0, 50.0))
    assert m.status == FIGHTING and spray.litres and sum(spray.litres) == pytest.approx(0.2)
    # what the camera sees goes out once a second as an SDK message: [sent_at, 0 (broadcast), FireCells as a list]
    assert [(topic, body[2][3]) for topic, body in m.outbox()] == [(CELLS_TOPIC, [])]  # at 1.0: nothing burning
    sense(s, 2.2, alarm=3, tank=14.0, cells=((40.0, 50.0, 60.0),))
    fly(m, 1, 2.2, (39.5, 50.0))
    assert m.status == FIGHTING and sum(spray.litres) == pytest.approx(0.2 + 1.0)  # 2 l/s, at most 0.5 s a step
    out = m.outbox()
    assert [topic for topic, _ in out] == [CELLS_TOPIC]
    sent_at, dst, fields = out[0][1]
    assert dst == 0 and sent_at == 2.2 and fields[:3] == [39.5, 50.0, 15.0] and [list(c) for c in fields[3]] == [[40.0, 50.0]]
    # another UAV takes it in and, idle no more, flies to that cell, not to the hint
    other.receive(1, CELLS_TOPIC, out[0][1], 2.3)
    sense(s2, 2.3, alarm=3, tank=15.0)
    fly(other, 2, 2.3, (30.0, 60.0), (1, 2))
    assert other.status == IDLE  # the second to leave at the first alarm: 1.5 s after it (DEPART_GAP_S)
    v = fly(other, 2, 2.3 + DEPART_GAP_S, (30.0, 60.0), (1, 2))
    assert other.status == ON_DUTY and v[0] > 0.0 and v[1] < 0.0  # south-east, to (40, 50)
    c = other.stats()["topics"][CELLS_TOPIC]
    assert c["received"] == 1 and c["rejected"] == 0
    # a body that is not a FireCells is rejected and counted, never raised
    for bad in (None, [1.0, 0, [1, 2, 3, "x", 5]], [1.0, 0, [1, 2, 3, [[1, 2]] * 49, 5]], [1.0, 0, {"x": 1}]):
        other.receive(1, CELLS_TOPIC, bad, 2.5)
    assert other.stats()["topics"][CELLS_TOPIC]["rejected"] == 4
    assert not m.stats()["faults"]["exceptions"] and m.stats()["values"]["sprayed_l"] == pytest.approx(1.2)


def test_a_burning_cell_in_the_no_fly_zone_is_skipped_through_ctx_blocked() -> None:
    (m, s, _), (other, _, _) = firefighters()
    village = (10.0, 50.0)  # inside the zone of the scenario
    other.receive(2, CELLS_TOPIC, [1.0, 0, [10.0, 50.0, 15.0, [list(village), [60.0, 50.0]], 1.0]], 1.0)
    m.receive(2, CELLS_TOPIC, [1.0, 0, [10.0, 50.0, 15.0, [list(village), [60.0, 50.0]], 1.0]], 1.0)
    assert m.ctx.blocked(*village) and not m.ctx.blocked(60.0, 50.0)
    sense(s, 1.0, alarm=3, tank=15.0)
    v = fly(m, 1, 1.0, (0.0, 50.0))  # the village's cell is nearer, but unreachable: to (60, 50)
    assert m.status == ON_DUTY and v[0] > 4.0 and abs(v[1]) < 1e-6


def test_actuating_what_the_uav_does_not_have_is_refused_and_counted() -> None:
    (m, _, spray), = firefighters(1)
    assert not m.ctx.actuate("foam", 1.0) and not m.ctx.actuate("spray", float("nan")) and not m.ctx.actuate("spray", -1)
    assert m.ctx.actuate("spray", 0.5) and spray.litres == [0.5]
    assert m.stats()["actuate_errors"] == 1


# ---- plume -------------------------------------------------------------------------------------------------
def test_the_plume_mission_flies_through_the_sdk_and_its_estimate_reaches_the_world_in_the_envelope() -> None:
    c = configs("plume.yaml")[0]
    pol, wind = SetSensor("pollutant"), SetSensor("wind")
    m = make_mission(c, Payload({"pollutant": pol, "wind": wind}))
    assert isinstance(m, BehaviourMission) and isinstance(m.behaviour, PlumeSource)
    assert m.behaviour.params.strategy == "seek" and m.behaviour.params.area == c.mission.area
    wind.set(1.0, 0.0)  # the air carries the pollutant east
    pol.set(1.0, 1.0)  # in the plume
    v = fly(m, c.uav, 1.0, (20.0, 0.0))
    assert m.status == "surge" and v == pytest.approx((-c.speed, 0.0))  # upwind, at the cruise speed
    out: dict[str, Any] = dict(m.outbox())
    assert set(out) == {DETECTION_TOPIC, ESTIMATE_TOPIC}
    assert out[DETECTION_TOPIC][2] == [20.0, 0.0, 1.0, 0.0]
    e = estimate_in(out[ESTIMATE_TOPIC])  # as the world service reads it
    assert e is not None and (e.x, e.y) == (20.0, 0.0)
    assert estimate_in([20.0, 0.0, 1.0]) is None and estimate_in([1.0, 0, ["a", 0, 1]]) is None
    # another UAV's detection further upwind, as an SDK message, moves the estimate
    m.receive(2, DETECTION_TOPIC, [1.1, 0, [2.0, 0.5, 1.1, 0.0]], 1.2)
    pol.set(1.2, 0.0)
    fly(m, c.uav, 1.2, (19.0, 0.0))
    assert m.status == "cast"
    est = m.behaviour.algorithm.estimate
    assert est is not None and est[0] < 20.0
    assert m.stats()["topics"][DETECTION_TOPIC]["received"] == 1


def test_the_stop_strategy_is_the_mission_setting_passed_as_the_behaviours_params() -> None:
    c = configs("plume.yaml", "mission.plume.strategy=stop", "mission.plume.stop_probability=1.0")[0]
    pol, wind = SetSensor("pollutant"), SetSensor("wind")
    m = make_mission(c, Payload({"pollutant": pol, "wind": wind}))
    assert isinstance(m, BehaviourMission)
    wind.set(0.0, 0.0)
    pol.set(0.0, 1.0)
    assert fly(m, c.uav, 0.1, (0.0, 0.0)) == (0.0, 0.0) and m.status == "stopped"
