"""MAVProxy, a real ground station, takes one UAV of a running swarm mission to RTL through its agent's router."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path

import pytest

from mrswarm.gcs.session import open_observer, resolve_target
from tests.conftest import free_port, wait_for
from tests.gcs_helpers import ROOT, gcs, run_dir, start_run, stop_run

pytestmark = pytest.mark.e2e
SCENARIO = ROOT / "tests" / "scenarios" / "gcs_mavproxy.yaml"
MAVPROXY = shutil.which("mavproxy.py")


def _free_udp_block(n: int) -> int:
    """A base port with base+1..base+n free for UDP (the routers' listen ports)."""
    for _ in range(50):
        base = free_port(socket.SOCK_DGRAM)
        if base + n > 65535:
            continue
        socks = []
        try:
            for i in range(1, n + 1):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind(("127.0.0.1", base + i))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise RuntimeError("no free UDP port block")


def test_mavproxy_switches_one_uav_to_rtl_it_yields_and_the_swarm_carries_on(tmp_path: Path) -> None:
    assert MAVPROXY is not None, "mavproxy.py not found: MAVProxy is in the test extra (pip install -e '.[test]')"
    base = _free_udp_block(3)
    run = start_run(SCENARIO, tmp_path, [f"gcs.listen_base={base}"])
    mp: subprocess.Popen[str] | None = None
    obs = None
    try:
        rdir = run_dir(tmp_path)
        obs = open_observer(resolve_target(str(rdir), [], None))

        def phases() -> dict[int, str]:
            obs.poll()
            return obs.phases()

        assert wait_for(lambda: [phases().get(u) for u in (1, 2, 3)] == ["mission"] * 3, 120, 0.2), \
            f"swarm never reached the mission: {phases()}"
        # MAVProxy connects to UAV 2's router (udpout to the agent's listening endpoint) and is fed
        # commands on stdin once it has detected the vehicle (its --cmd runs before any heartbeat).
        mp = subprocess.Popen([MAVPROXY, f"--master=udpout:127.0.0.1:{base + 2}", "--no-state", "--cmd=set requireexit 0"],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              cwd=tmp_path, start_new_session=True)
        out: list[str] = []
        threading.Thread(target=lambda: out.extend(iter(mp.stdout.readline, "")), daemon=True).start()  # type: ignore[union-attr]
        assert wait_for(lambda: any("Detected vehicle 2:1" in line for line in out), 60, 0.2), "".join(out)[-2000:]
        assert wait_for(lambda: any("Received" in line and "parameters" in line for line in out), 30, 0.2), "".join(out)[-2000:]
        assert mp.stdin is not None
        mp.stdin.write("mode RTL\n")
        mp.stdin.flush()
        assert wait_for(lambda: any("DO_SET_MODE: ACCEPTED" in line for line in out), 20, 0.2), "".join(out)[-2000:]

        def yielded() -> bool:
            obs.poll()
            v = obs.uavs.get(2)
            return v is not None and v.state is not None and v.state.phase == "yielded"

        assert wait_for(yielded, 15, 0.1), phases()
        st = obs.uavs[2].state
        assert st is not None and st.override in ("fcu:RTL", "gcs:DO_SET_MODE") and "setpoints stopped" in st.detail
        # the others carry on with the mission: still in it and still moving
        before = {u: (obs.uavs[u].pose.x, obs.uavs[u].pose.y) for u in (1, 3)}  # type: ignore[union-attr]
        time.sleep(3.0)
        obs.poll()
        assert phases()[1] == phases()[3] == "mission"
        for u in (1, 3):
            p = obs.uavs[u].pose
            assert p is not None and ((p.x - before[u][0]) ** 2 + (p.y - before[u][1]) ** 2) ** 0.5 > 3.0
        # UAV 2 is really in RTL (ArduPilot climbs to RTL_ALT 15 m first) and the CLI reports it
        res = gcs(["telemetry", "--run", str(rdir), "--uav", "2", "--json"])
        assert res.returncode == 0, res.stderr
        assert '"mode": "RTL"' in res.stdout and '"phase": "yielded"' in res.stdout
        res = gcs(["nodes", "--run", str(rdir), "--json"])
        assert res.returncode == 0, res.stderr
        nodes = [__import__("json").loads(line) for line in res.stdout.splitlines()]
        assert sorted(n["id"] for n in nodes if n["role"] == "uav") == [1, 2, 3]
        assert all(n["realm"] == "virtual" and n["alive"] and n["last_seen"] for n in nodes if n["role"] == "uav")
        # a discovery run: the server's registry adds each node's software version and Zenoh locators
        assert all(n["version"].startswith("mrswarm") and "tls/127.0.0.1:" in n["address"]  # secured run: TLS locators
                   for n in nodes if n["role"] == "uav"), nodes
        res = gcs(["watch", "--run", str(rdir), "--once", "--filter", "override"])
        assert res.returncode == 0, res.stderr
        table = [line.split() for line in res.stdout.splitlines() if line.split() and line.split()[0].isdigit()]
        assert [row[:3] for row in table] == [["2", "V", "yielded"]], res.stdout
        stats_file = rdir / "uav2.json"
        tx = __import__("json").loads(stats_file.read_text())["fcu_link"]["tx_setpoints"]
        time.sleep(2.5)
        assert __import__("json").loads(stats_file.read_text())["fcu_link"]["tx_setpoints"] == tx  # no more setpoints
    finally:
        if obs is not None:
            obs.close()
        if mp is not None and mp.poll() is None:
            try:
                os.killpg(mp.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            mp.wait(10)
        stop_run(run)
