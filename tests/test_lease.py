"""``network.lease_s``: how long a UAV's process may stay frozen before the swarm declares it gone.

A real UAV-side session (built by the UAV's own ``make_connectivity`` from a ``NetworkConfig``) in
its own process, a real router, real SIGSTOP: frozen for 2 s, a UAV with a 1 s lease is dropped
(its liveliness token goes), one with a 6 s lease is kept. This is what let 100 UAVs on 2 cores
take off (docs/scale.md): with the 3 s default the edge router closed live UAVs' sessions.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from groundfloor.schema import ConfigError, convert
from mrswarm.scenario import ScenarioError, load_scenario
from swarmnet.connectivity import Rendezvous, to_zenoh
from tests.conftest import wait_for
from uav_stack.config import NetworkConfig

ROOT = Path(__file__).resolve().parents[1]

UAV = """
import sys, time, zenoh
from swarmnet.connectivity import to_zenoh
from uav_stack.config import NetworkConfig
from uav_stack.runtime import make_connectivity
net = NetworkConfig(connectivity="rendezvous", endpoints=(sys.argv[1],), mode="client", lease_s=float(sys.argv[2]))
s = zenoh.open(to_zenoh(make_connectivity(net).zenoh_config()))
token = s.liveliness().declare_token("lease/alive/uav")
print("up", flush=True)
time.sleep(60)
"""


def frozen_for(router: str, lease_s: float, frozen_s: float) -> list[str]:
    """Start a UAV session with ``lease_s``, freeze its process for ``frozen_s``; the liveliness
    events the swarm saw meanwhile ("put": joined, "delete": declared gone)."""
    events: list[str] = []
    with zenoh.open(to_zenoh(Rendezvous((router,), mode="client").zenoh_config())) as obs:
        sub = obs.liveliness().declare_subscriber(
            "lease/alive/**", lambda s: events.append("put" if s.kind == zenoh.SampleKind.PUT else "delete"), history=True)
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        proc = subprocess.Popen([sys.executable, "-c", UAV, router, str(lease_s)], stdout=subprocess.PIPE, env=env)
        try:
            assert proc.stdout is not None and proc.stdout.readline().strip() == b"up"
            assert wait_for(lambda: events == ["put"], 10.0)
            os.kill(proc.pid, signal.SIGSTOP)
            time.sleep(frozen_s)
            os.kill(proc.pid, signal.SIGCONT)
            time.sleep(0.5)
            return list(events)
        finally:
            proc.kill()
            proc.wait(10)
            sub.undeclare()


def test_a_frozen_uav_is_dropped_after_its_lease_and_kept_within_it(router: str) -> None:
    assert frozen_for(router, lease_s=1.0, frozen_s=2.5)[:2] == ["put", "delete"]  # gone: its lease ran out
    assert frozen_for(router, lease_s=6.0, frozen_s=2.5) == ["put"]  # kept: it came back within its lease


def test_the_lease_is_validated_and_named() -> None:
    with pytest.raises(ConfigError, match="lease_s"):
        convert({"lease_s": 0.1}, NetworkConfig)
    scenario = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"
    assert load_scenario(scenario, ["network.lease_s=10"]).network.lease_s == 10.0
    with pytest.raises(ScenarioError, match="network.lease_s"):
        load_scenario(scenario, ["network.lease_s=600"])
