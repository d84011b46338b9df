"""The behaviour SDK without a flight: loading by name, parameter errors naming the field, the guard."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import msgspec
import pytest

from groundfloor.schema import ConfigError
from mrswarm.api import Behaviour, Context, GoTo, Land, Velocity
from mrswarm.scenario import ScenarioError, load_scenario
from uav_stack.behaviours.base import SelfState
from uav_stack.config import AgentConfig, MissionConfig
from uav_stack.geo import GeoPoint
from uav_stack.sdk import loader
from uav_stack.sdk.adapter import BehaviourMission, make_behaviour_mission

ROOT = Path(__file__).resolve().parents[1]
FLOCK = ROOT / "examples" / "flocking.yaml"


def agent_config(behaviour: str, params: dict[str, Any] | None = None, **mission: Any) -> AgentConfig:
    return AgentConfig(swarm="t", uav=2, origin=GeoPoint(46.0, 14.0, 400.0), fcu="udpin:127.0.0.1:14540",
                       mission=MissionConfig(type="behaviour", behaviour=behaviour, params=params or {}, **mission))


def me(t: float, x: float = 0.0, y: float = 0.0) -> SelfState:
    return SelfState(uav=2, pos=(x, y), vel=(0.0, 0.0), t=t)


@pytest.mark.parametrize(("override", "message"), [
    ("mission.params.speed=fast", "mission.params.speed: must be a number, got 'fast'"),
    ("mission.params.sped=3", "mission.params.sped: unknown field of Flocking.Params"),
    ("mission.behaviour=examples.nowhere:X", "mission.behaviour: cannot import 'examples.nowhere'"),
    ("mission.behaviour=examples.flocking:Nope", "mission.behaviour: module 'examples.flocking' has no 'Nope'"),
    ("mission.behaviour=no_such_name", "mission.behaviour: 'no_such_name' is neither an import path"),
    ("mission.behaviour=uav_stack.sdk.context:Context", "is not a Behaviour subclass"),
    ("mission.per_uav={9: {params: {speed: 1}}}", "mission.per_uav.9: no UAV 9 in the swarm"),
    ("mission.per_uav={2: {params: {radius: no}}}", "mission.per_uav.2.params.radius: must be a number"),
    ("mission.type=goto", "mission.type: a mission with a behaviour is of type behaviour"),
])
def test_a_bad_behaviour_or_parameter_is_refused_at_load_naming_the_field(override: str, message: str) -> None:
    with pytest.raises(ScenarioError) as err:
        load_scenario(FLOCK, [override])
    assert message in str(err.value)


def test_behaviour_alone_implies_its_type_and_per_uav_params_go_over_the_missions() -> None:
    from uav_stack.config import NetworkConfig

    scn = load_scenario(FLOCK, ["mission.per_uav={3: {params: {speed: 1.5}}}"])
    assert scn.mission.type == "behaviour"
    cfgs = {c.agent.uav: c.agent.mission for c in scn.virtual_uav_configs(NetworkConfig(), None)}
    assert cfgs[3].params["speed"] == 1.5 and cfgs[3].params["radius"] == 40.0
    assert cfgs[1].params["speed"] == 3.0
    assert {m.behaviour for m in cfgs.values()} == {"examples.flocking:Flocking"}


def test_registered_names_resolve_to_the_builtins() -> None:
    for name in loader.BUILTINS:
        assert issubclass(loader.resolve(name), Behaviour)


class Params(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    fail_from: float = math.inf  # s of mission from which step raises


class Scripted(Behaviour[Params]):
    Params = Params

    def step(self, ctx: Context) -> Velocity | GoTo | Land | None:
        if ctx.mission_t >= self.params.fail_from:
            raise ValueError("boom")
        return GoTo(10.0, 0.0, z=15.0)


def test_an_intent_becomes_the_velocity_and_altitude_the_agent_flies() -> None:
    m = make_behaviour_mission(agent_config("tests.test_sdk:Scripted"))
    v = m.velocity(me(0.0), (2,))
    assert v[0] > 0.0 and abs(v[1]) < 1e-9 and math.hypot(*v) <= 5.0
    assert m.altitude == 15.0 and m.request is None
    assert m.velocity(me(0.1, x=10.0), (2,)) == (0.0, 0.0)  # at the point: stopped


def test_repeated_exceptions_stop_the_behaviour_the_uav_holds_then_lands() -> None:
    m = make_behaviour_mission(agent_config("tests.test_sdk:Scripted", {"fail_from": 0.95}, max_faults=3, hold_s=5.0))
    t = 0.0
    for _ in range(10):  # 1 s of good steps
        m.velocity(me(t), (2,))
        t += 0.1
    assert m.state == "running" and m.steps == 10
    for _ in range(3):
        m.velocity(me(t, x=3.0), (2,))
        t += 0.1
    assert m.exceptions == 3 and m.state == "holding" and m.request is None
    assert m.incidents and m.incidents[0]["kind"] == "behaviour_stopped" and "ValueError: boom" in m.incidents[0]["detail"]
    steps = m.steps
    while t < 1.3 + 5.0:  # holding: the behaviour is not stepped again, the UAV stays where it stopped
        assert m.velocity(me(t, x=3.0), (2,)) == (0.0, 0.0)
        t += 0.1
    assert m.steps == steps
    m.velocity(me(t + 0.1, x=3.0), (2,))
    assert m.request == "land" and m.state == "landing"
    assert m.stats()["faults"]["exceptions"] == 3


class BadIntent(Behaviour):  # type: ignore[type-arg]
    def step(self, ctx: Context) -> Any:
        return (1.0, 2.0) if ctx.uav == 2 else Velocity(math.nan, 0.0)


def test_a_step_that_returns_no_intent_is_a_fault_not_a_crash() -> None:
    m = make_behaviour_mission(agent_config("tests.test_sdk:BadIntent", max_faults=2))
    assert m.velocity(me(0.0), (2,)) == (0.0, 0.0)
    m.velocity(me(0.1), (2,))
    assert m.bad_intents == 2 and m.state == "holding"
    assert "not an intent" in m.last_error


def test_messages_that_do_not_fit_their_type_are_rejected_and_counted() -> None:
    m: BehaviourMission = make_behaviour_mission(agent_config("tests.sdk_behaviours:Chatty"))
    m.receive(3, "test/ping", [1.0, 0, {"n": 4}], 1.5)
    m.receive(3, "test/ping", [1.0, 0, {"n": "four"}], 1.5)
    m.receive(3, "test/ping", "garbage", 1.5)
    m.receive(4, "test/ping", [1.0, 2, {"n": 5}], 1.2)
    c = m.stats()["topics"]["test/ping"]
    assert c["received"] == 2 and c["rejected"] == 2
    assert c["age_max_ms"] == 500.0
    m.velocity(me(2.0), (2, 3, 4))
    assert m.ctx.inbox("test/ping")[1].unicast and m.ctx.inbox("test/ping")[1].body.n == 5
    assert m.values["heard"] == 2.0


def test_a_class_that_is_not_usable_is_refused() -> None:
    class NoStep(Behaviour):  # type: ignore[type-arg]
        pass

    class BadTopic(Scripted):
        messages = {"bad topic!": Params}

    for cls in (NoStep, BadTopic):
        with pytest.raises(ConfigError):
            loader.check_class(cls)


AGENT = ["--fcu", "udpin:127.0.0.1:14540", "--swarm", "alpha", "--uav", "3", "--connect", "tcp/127.0.0.1:7447", "--insecure",
         "--origin", "47,8,500"]


def test_mrswarm_agent_flies_a_behaviour_named_on_its_command_line(tmp_path: Path) -> None:
    from uav_stack.runtime import parse_agent

    cfg, _ = parse_agent([*AGENT, "--behaviour", "examples.flocking:Flocking", "--params", '{"speed": 2.5}'])
    assert cfg.mission.type == "behaviour" and cfg.mission.behaviour == "examples.flocking:Flocking"
    assert cfg.mission.params == {"speed": 2.5}
    (tmp_path / "p.yaml").write_text("radius: 30\n")
    cfg, _ = parse_agent([*AGENT, "--behaviour", "examples.flocking:Flocking", "--params", f"@{tmp_path / 'p.yaml'}"])
    assert cfg.mission.params == {"radius": 30}
    path = tmp_path / "uav3.json"  # beside --config too: a companion's own behaviour
    path.write_text(cfg.to_json())
    got, _ = parse_agent(["--config", str(path), "--insecure", "--params", '{"speed": 1.0}'])
    assert got.mission.behaviour == "examples.flocking:Flocking" and got.mission.params == {"speed": 1.0}


@pytest.mark.parametrize(("flags", "message"), [
    (["--behaviour", "examples.nowhere:X"], "--behaviour: cannot import 'examples.nowhere'"),
    (["--behaviour", "examples.flocking:Flocking", "--params", '{"speed": "x"}'], "--params: speed: must be a number"),
    (["--behaviour", "examples.flocking:Flocking", "--params", "[1]"], "--params: expected a mapping"),
    (["--behaviour", "examples.flocking:Flocking", "--params", "@/nonexistent.yaml"], "--params: /nonexistent.yaml: cannot read"),
    (["--params", "{}"], "--params: for a behaviour: give --behaviour SPEC too"),
])
def test_a_bad_behaviour_flag_is_one_usage_line_naming_it(flags: list[str], message: str,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    from uav_stack.runtime import parse_agent

    with pytest.raises(SystemExit) as ex:
        parse_agent([*AGENT, *flags])
    assert ex.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and message in err, err


class Forever(Behaviour):  # type: ignore[type-arg]
    def step(self, ctx: Context) -> None:
        while True:
            pass


def test_a_step_that_never_returns_is_interrupted_and_stops_the_behaviour() -> None:
    m = make_behaviour_mission(agent_config("tests.test_sdk:Forever", budget_ms=1.0, max_faults=1))
    assert m.velocity(me(0.0), (2,)) == (0.0, 0.0)
    assert m.exceptions == 1 and m.state == "holding"
    assert "StepTimeout: step still running after 1 s" in m.last_error


def test_the_api_reference_covers_every_public_name() -> None:
    import mrswarm.api

    text = (ROOT / "docs" / "sdk.md").read_text()
    missing = [name for name in mrswarm.api.__all__ if name not in ("ENTRY_POINT_GROUP", "Intent", "NoParams")
               and f"`{name}" not in text]
    assert missing == []
    for member in ("neighbours_within", "send_to", "record", "mission_t", "sim_t", "battery", "inbox"):
        assert f"`{member}" in text, member


class ArmsATimer(Behaviour):  # type: ignore[type-arg]
    """As a stop signal's handler does during a step: arms the shutdown watchdog (signal.alarm)."""

    def step(self, ctx: Context) -> None:
        import signal

        signal.alarm(30)


def test_a_timer_armed_during_a_step_is_left_running() -> None:
    import signal

    m = make_behaviour_mission(agent_config("tests.test_sdk:ArmsATimer"))
    try:
        m.velocity(me(0.0), (2,))
        assert 25.0 < signal.getitimer(signal.ITIMER_REAL)[0] <= 30.0
    finally:
        signal.alarm(0)
    assert m.exceptions == 0
