"""``mrswarm netem``: the CLI changes a live node's impairments over real Zenoh and waits for its ack."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from swarmnet.connectivity import Rendezvous
from swarmnet.node import NodeIdentity, SwarmNode
from tests.conftest import wait_for

ROOT = Path(__file__).resolve().parents[1]


def cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "mrswarm", "netem", *args]


def test_set_reaches_every_live_uav_and_reports_their_acks(router: str, tmp_path: Path) -> None:
    rdv = Rendezvous((router,))
    nodes = [SwarmNode(NodeIdentity("clitest", i), rdv, netem={"preset": "lan"}).open() for i in (1, 2)]
    try:
        assert wait_for(lambda: all((n.poll(), n.alive_uavs() >= {1, 2})[1] for n in nodes), 10.0)
        (tmp_path / "network.json").write_text(f'{{"swarm": "clitest", "endpoints": ["{router}"]}}')
        t0 = time.time()
        proc = subprocess.Popen(cli("set", "--run", str(tmp_path), "--preset", "degraded", "--class", "v2v", "--delay", "150ms"),
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            while proc.poll() is None and time.time() - t0 < 60:  # the UAV loop: poll at 10 Hz
                for n in nodes:
                    n.poll()
                time.sleep(0.04)
            out = proc.communicate(timeout=10)[0]
        finally:
            if proc.poll() is None:
                proc.kill()
        assert proc.returncode == 0, out
        assert "2/2 UAVs applied it" in out
        for n in nodes:
            assert n.netem is not None and n.netem.config.preset == "degraded"
            v2v = n.netem.config.class_profile("v2v")
            assert v2v is not None and v2v.delay is not None
            assert (v2v.delay.ms, v2v.delay.jitter_ms) == (150.0, 30.0)  # the flag changed the preset's mean only
            change = n.netem_changes[-1]
            assert change["source"] == "cli" and change["t"] - change["t_sent"] < 1.0
    finally:
        for n in nodes:
            n.close()


def test_bad_values_fail_before_sending_and_name_the_field() -> None:
    res = subprocess.run(cli("set", "--connect", "tcp/127.0.0.1:9", "--loss", "150%"), cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 2 and "v2v.loss.p: must be a probability" in res.stderr
    res = subprocess.run(cli("set", "--connect", "tcp/127.0.0.1:9", "--delay", "fast"), cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 2 and "--delay: 'fast' is not a time" in res.stderr
    # the message itself, as every UAV would refuse it (before its codec, sent and waited for in vain)
    res = subprocess.run(cli("set", "--connect", "tcp/127.0.0.1:9", "--preset", "lan", "--targets", "1,0"), cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "netem_set.targets.1: must be an integer in [1, 65535], got 0" in res.stderr


def test_presets_lists_every_preset_per_class() -> None:
    res = subprocess.run(cli("presets"), cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0
    for name in ("none", "lan", "5g-campus", "lte", "degraded", "wifi-mesh"):
        assert f"\n{name}\n" in f"\n{res.stdout}"
    assert "delay 9.81ms" in res.stdout and "loss gilbert_elliott 10%" in res.stdout
