"""network.netem in scenario files: validated with the field named, passed to the UAV processes in their JSON config."""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest

from mrswarm.scenario import ScenarioError, load_scenario
from uav_stack.config import NetworkConfig, VirtualUavConfig
from uav_stack.runtime import make_node

ROOT = Path(__file__).resolve().parents[1]
COVERAGE = ROOT / "scenarios" / "coverage.yaml"


def test_a_preset_reaches_every_uav_process_with_the_scenario_seed() -> None:
    scn = load_scenario(COVERAGE, ["network.netem.preset=5g-campus", "network.netem.v2v.delay.ms=12"])
    configs = scn.virtual_uav_configs(NetworkConfig(endpoints=("tcp/127.0.0.1:7447",)), None)
    assert len(configs) == 10
    for c in configs:
        back = msgspec.json.decode(c.to_json(), type=VirtualUavConfig)  # what the UAV process reads
        assert back.agent.network.netem == {"seed": 7, "preset": "5g-campus", "v2v": {"delay": {"ms": 12}}}
    node = make_node(configs[0].agent)  # not opened: no network needed
    assert node.netem is not None and node.netem.config.seed == 7
    v2v = node.netem.config.class_profile("v2v")
    assert v2v is not None and v2v.delay is not None and (v2v.delay.ms, v2v.delay.jitter_ms) == (12.0, 2.0)


def test_without_netem_the_uav_has_no_shim() -> None:
    scn = load_scenario(COVERAGE)
    c = scn.virtual_uav_configs(NetworkConfig(endpoints=("tcp/127.0.0.1:7447",)), None)[0]
    assert c.agent.network.netem is None and make_node(c.agent).netem is None


@pytest.mark.parametrize("override, field", [
    ("network.netem.v2v={delay: {ms: 50, jitter_ms: 10}}", "v2v.delay.distribution"),
    ("network.netem.preset=6g", "preset"),
    ("network.netem.links=[{src: 1, dst: 2, loss: {model: bernoulli, p: 1.2}}]", "links.0.loss.p"),
    ("network.netem.v2v.loss={model: bernoulli, p: 0.01, correlation: 0.25}", "v2v.loss.correlation"),
])
def test_bad_netem_is_reported_with_the_field(override: str, field: str) -> None:
    with pytest.raises(ScenarioError) as err:
        load_scenario(COVERAGE, [override])
    assert f"network.netem.{field}: " in str(err.value)
