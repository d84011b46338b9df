"""Companion failsafes on a real virtual-UAV process (uav_stack/failsafe.py, docs/reliability.md).

One UAV flies its mission as a client of a real edge router. Its FCU link is cut through the
fault key (the virtual UAV process cuts the UDP link between its FCU and its agent); then the
edge router is killed with SIGKILL, which takes the UAV's whole swarm link away. The test checks
the sequence and the timing: FCU link lost after the 3 s heartbeat timeout, no pose published
meanwhile, control taken back once the link returns; swarm link lost -> hold at T1 -> land at T2.
A physical UAV's agent refuses injected faults.
"""

from __future__ import annotations

import csv
import json
import math
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from discovery.netutil import free_port, wait_tcp
from mrswarm.gcs.watch import rows_from
from swarmnet.connectivity import Rendezvous
from swarmnet.observer import SwarmObserver
from tests.conftest import wait_for
from tests.gcs_helpers import HOME, ROOT, stop_process
from uav_stack.config import AgentConfig, MissionConfig, NetworkConfig, VirtualUavConfig
from uav_stack.failsafe import FailsafeConfig

pytestmark = pytest.mark.e2e

T1, T2 = 2.0, 6.0  # s: hold, then land (short, for the test)


def start_router(port: int) -> subprocess.Popen[bytes]:
    proc = subprocess.Popen([sys.executable, "-m", "discovery.rendezvous", "--listen", f"tcp/127.0.0.1:{port}", "--insecure"],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_tcp("127.0.0.1", port, 20.0, alive=lambda: proc.poll() is None)
    return proc


def start_uav(tmp: Path, endpoint: str) -> subprocess.Popen[bytes]:
    agent = AgentConfig(swarm="fs", uav=1, origin=HOME, fcu="", altitude=8.0, autostart=True, record_dir=str(tmp),
                        mission=MissionConfig(area=(-40.0, 40.0, -40.0, 40.0)),
                        network=NetworkConfig(endpoints=(endpoint,), mode="client"),
                        failsafe=FailsafeConfig(swarm_link_hold_s=T1, swarm_link_action_s=T2))
    path = tmp / "uav1.config.json"
    path.write_text(VirtualUavConfig(agent=agent, home=HOME).to_json())
    with open(tmp / "uav1.log", "ab") as log:
        return subprocess.Popen([sys.executable, "-m", "uav_stack.virtual_uav", "--config", str(path)], cwd=ROOT, stdout=log,
                                stderr=subprocess.STDOUT, start_new_session=True)


def events(tmp: Path) -> list[dict]:
    try:
        return json.loads((tmp / "uav1.json").read_text())["failsafes"]["events"]
    except (OSError, ValueError, KeyError):
        return []


def first(evs: list[dict], failsafe: str, event: str) -> float | None:
    return next((e["t"] for e in evs if e["failsafe"] == failsafe and e["event"] == event), None)


def test_a_uav_flies_through_fcu_link_loss_then_swarm_link_loss(tmp_path: Path) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = start_router(port)
    uav = start_uav(tmp_path, endpoint)
    obs = SwarmObserver("fs", Rendezvous((endpoint,), mode="client")).open()
    try:
        def phase() -> str | None:
            obs.poll()
            v = obs.uavs.get(1)
            return v.state.phase if v is not None and v.state is not None else None

        assert wait_for(lambda: phase() == "mission", 60.0, 0.1), f"never reached its mission: {phase()}"
        time.sleep(2.0)

        # ---- FCU link loss: 5 s without a byte between the FCU and the agent
        cut = 5.0
        t_cut = time.time()
        pending = obs.inject(1, "fcu_link_loss", {"duration_s": cut})
        assert wait_for(lambda: (obs.poll(), pending.complete)[1], 5.0, 0.05), "no acknowledgement of the fault"
        assert pending.acks[1].ok, pending.acks[1].message
        # a copy (the chaos controller sends again until it hears the ack) is acked alike, never applied twice
        first_ack = pending.acks.pop(1)
        obs.send_again(pending)
        assert wait_for(lambda: (obs.poll(), pending.complete)[1], 3.0, 0.05), "no acknowledgement of the copy"
        assert (pending.acks[1].ok, pending.acks[1].message) == (first_ack.ok, first_ack.message)
        poses: list[float] = []  # arrival times of fresh poses
        seen_override_at = None
        watch_row = None
        deadline = t_cut + cut + 8.0
        while time.time() < deadline:
            for p in obs.poll():
                if p.uav == 1:
                    poses.append(time.time())
            v = obs.uavs[1]
            if seen_override_at is None and v.state is not None and v.state.override == "failsafe:fcu_link":
                seen_override_at = time.time()
                watch_row = next(r for r in rows_from(obs, time.time()) if r.id == 1)  # what `mrswarm gcs watch` shows
            if seen_override_at is not None and v.state is not None and v.state.phase == "mission" and not v.state.override:
                break
            time.sleep(0.05)
        t_back = time.time()
        assert seen_override_at is not None, "the failsafe never showed in the UAV's state"
        # 3 s after the last heartbeat (1 Hz), the state at 1 Hz
        assert 1.9 <= seen_override_at - t_cut <= 5.0, seen_override_at - t_cut
        assert watch_row is not None and "failsafe:fcu_link" in watch_row.get("phase")
        # the neighbours see the pose go stale: nothing newer while the link is cut
        during = [t for t in poses if t_cut + 0.5 < t < t_cut + cut]
        assert not during, f"{len(during)} poses published while the FCU link was cut"
        assert cut < t_back - t_cut < cut + 6.0, t_back - t_cut  # control taken back, mission resumed
        evs = events(tmp_path)
        t_trig, t_clear, t_resumed = (first(evs, "fcu_link", e) for e in ("triggered", "cleared", "resumed"))
        assert t_trig is not None and t_clear is not None and t_resumed is not None, evs
        assert 1.9 <= t_trig - t_cut <= 4.0 and cut - 0.5 <= t_clear - t_cut <= cut + 1.5 and t_resumed >= t_clear
        assert [e["event"] for e in evs if e["failsafe"] == "fcu_link"].count("triggered") == 1  # one cut, not two
        assert json.loads((tmp_path / "uav1.json").read_text())["agent"]["faults"] == 1

        # ---- swarm link loss: the edge router dies; in client mode it carried everything
        time.sleep(2.0)
        t_kill = time.time()
        router.kill()
        router.wait(5)
        assert wait_for(lambda: first(events(tmp_path), "swarm_link", "land") is not None, T2 + 8.0, 0.2), events(tmp_path)
        evs = events(tmp_path)
        t_hold, t_land = first(evs, "swarm_link", "triggered"), first(evs, "swarm_link", "land")
        assert t_hold is not None and t_land is not None
        assert T1 - 0.2 <= t_hold - t_kill <= T1 + 1.2, t_hold - t_kill
        assert T2 - 0.2 <= t_land - t_kill <= T2 + 1.2, t_land - t_kill
        # it held its position between the two, then landed
        with open(tmp_path / "uav1.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        held = [(float(r["x"]), float(r["y"])) for r in rows if t_hold + 1.0 <= float(r["t_wall"]) <= t_land - 0.2]
        assert held and all(r["phase"] == "hold" for r in rows if t_hold + 0.3 <= float(r["t_wall"]) <= t_land - 0.3)
        assert max(math.dist(held[0], p) for p in held) < 2.0  # held, braking included
        assert wait_for(lambda: json.loads((tmp_path / "uav1.json").read_text())["phase"] == "landed", 30.0, 0.5)
    finally:
        obs.close()
        stop_process(uav)
        if router.poll() is None:
            router.kill()
            router.wait(5)


def test_a_physical_uav_refuses_injected_faults(tmp_path: Path) -> None:
    port, fcu_port = free_port(), free_port(kind=socket.SOCK_DGRAM)
    endpoint = f"tcp/127.0.0.1:{port}"
    router = start_router(port)
    fcu = subprocess.Popen([sys.executable, "-m", "uav_stack.fcu", "--sysid", "9", "--listen", f"127.0.0.1:{fcu_port}"],
                           cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    agent = subprocess.Popen([sys.executable, "-m", "mrswarm", "agent", "--fcu", f"udpout:127.0.0.1:{fcu_port}", "--swarm", "fs",
                              "--uav", "9", "--origin", f"{HOME.lat},{HOME.lon},{HOME.alt}", "--connect", endpoint,
                              "--mode", "client", "--realm", "physical", "--sysid", "9", "--insecure"],
                             cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    obs = SwarmObserver("fs", Rendezvous((endpoint,), mode="client")).open()
    try:
        assert wait_for(lambda: (obs.poll(), 9 in obs.uavs and obs.uavs[9].state is not None)[1], 30.0, 0.1)
        pending = obs.inject(9, "battery_drop", {"level": 0.05})
        assert wait_for(lambda: (obs.poll(), pending.complete)[1], 5.0, 0.05)
        ack = pending.acks[9]
        assert not ack.ok and "physical" in ack.message
    finally:
        obs.close()
        stop_process(agent)
        stop_process(fcu)
        router.kill()
        router.wait(5)
