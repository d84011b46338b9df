"""Cellular realism: on the docker runtime's network multicast is impossible, unicast works.

Each case builds a real network with the runtime, puts probe containers on it and looks
at what arrives. The positive control (``multicast: allow``, a plain bridge) shows that the
probes do see each other's multicast and that Zenoh peers with multicast scouting switched
**on** find each other there; with ``multicast: drop`` (the default) neither happens, while
unicast still flows. The end-to-end run (test_docker_run.py) flies on the dropped network,
so its discovery went through the rendezvous router only.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from deploy.docker_runtime import ContainerSettings, DockerRuntime
from deploy.plan import NetworkPlan, SwarmPlan
from tests.docker_support import docker_image, no_leftovers  # noqa: F401

pytestmark = pytest.mark.docker

PROBE = ["python3", "-m", "deploy.mcast_probe"]


def last_json(box: Any, timeout: float = 60.0) -> dict[str, Any]:
    code = box.container.wait(timeout=timeout)["StatusCode"]
    out = box.container.logs(stdout=True, stderr=True).decode()
    assert code == 0, out[-2000:]
    return json.loads(out.strip().splitlines()[-1])


@pytest.mark.parametrize("multicast", ["allow", "drop"])
def test_multicast_and_zenoh_scouting_only_on_an_open_network(multicast: str, docker_image: str, tmp_path: Path,
                                                            no_leftovers: None) -> None:
    rt = DockerRuntime(tmp_path / "run", settings=ContainerSettings(image=docker_image, multicast=multicast), swarm="probe")
    try:
        rt.start_network(NetworkPlan((SwarmPlan("probe"),)))
        listener = rt.start_container("listen", [*PROBE, "listen", "--seconds", "12"])
        za = rt.start_container("za", [*PROBE, "zenoh", "--name", "za", "--seconds", "14"])
        zb = rt.start_container("zb", [*PROBE, "zenoh", "--name", "zb", "--seconds", "14"])
        sender = rt.start_container("send", [*PROBE, "send", "--to", listener.ip, "--seconds", "8"])
        got, sent = last_json(listener), last_json(sender)
        a, b = last_json(za), last_json(zb)
    finally:
        rt.stop()
    assert sent["unicast"] > 20 and got["unicast"] > 20  # the network itself works either way
    if multicast == "allow":
        assert got["multicast"] > 20 and got["broadcast"] > 20, (sent, got)
        assert a["heard"] == ["zb"] and b["heard"] == ["za"], (a, b)  # found each other by scouting alone
    else:
        assert got["multicast"] == 0 and got["broadcast"] == 0, (sent, got)
        assert a["heard"] == [] and b["heard"] == [] and a["peers"] == 0 and b["peers"] == 0, (a, b)
    assert rt.sealed is False  # rules removed with the network
