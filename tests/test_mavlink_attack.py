"""MAVLink locked to its owner, attacked as a rogue local process would, on a real virtual UAV.

One virtual UAV process (virtual FCU + agent, ArduPilot flavour so MAVProxy can change its
modes) flies its mission; its MAVLink router listens for ground stations with signing
required. The attacker knows nothing but the UDP ports the process has open (what ``ss -uapn``
shows) and the UAV's system id:

1. from 16 other local ports it sends forged FCU heartbeats (mode LAND), a forged position
   54 m away, LAND and disarm commands and unsigned mode changes to every one of them. The
   UAV must keep flying its mission, its swarm pose must not jump, and every forged datagram
   must be counted where it was refused;
2. MAVProxy without the key cannot reach the UAV (its frames are refused and counted);
3. MAVProxy with the key (``signing key <passphrase>``) takes the UAV over (RTL): the agent
   yields, as with any ground station.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sysconfig
import threading
import time
from pathlib import Path

import psutil
import pytest

from swarmnet.connectivity import Rendezvous
from swarmnet.observer import SwarmObserver
from tests.conftest import free_port, wait_for
from tests.gcs_helpers import start_virtual_uav, stop_process
from uav_stack.config import MavlinkSigning
from uav_stack.geo import GeoPoint, LocalFrame
from uav_stack.mav import mavlink as M
from uav_stack.mavlink_signing import write_key_file

pytestmark = pytest.mark.e2e
# beside the interpreter (the checkout's .venv/bin, also when that venv is not activated), else on PATH
MAVPROXY = shutil.which("mavproxy.py", path=os.pathsep.join([sysconfig.get_path("scripts"), os.environ.get("PATH", "")]))
UAV = 3  # MAVLink sysid 3 (uav_stack.sysid.allocate_sysid)
ARDUPILOT_LAND, ARDUPILOT_RTL = 9, 6


def forged_frames(lat: float, lon: float, alt: float) -> bytes:
    """What the attacker sends to every port: the FCU's ids, its claims, and commands to it."""
    fcu = M.MAVLink(None, UAV, 1)  # posing as the FCU
    gcs = M.MAVLink(None, 255, 190)  # posing as a ground station
    armed = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | M.MAV_MODE_FLAG_SAFETY_ARMED
    flat, flon, _ = LocalFrame(GeoPoint(lat, lon, alt)).to_geodetic(0.0, 53.8, 0.0)  # 53.8 m north of the UAV
    frames = [
        M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, armed, ARDUPILOT_LAND,
                                    M.MAV_STATE_ACTIVE, 3).pack(fcu),
        M.MAVLink_global_position_int_message(int(time.time() * 1000) & 0xFFFFFFFF, int(flat * 1e7), int(flon * 1e7),
                                              int(alt * 1000), 8000, 0, 0, 0, 0).pack(fcu),
        M.MAVLink_command_long_message(UAV, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, ARDUPILOT_LAND, 0, 0, 0, 0, 0).pack(gcs),
        M.MAVLink_command_long_message(UAV, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196, 0, 0, 0, 0, 0).pack(gcs),
        M.MAVLink_set_mode_message(UAV, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ARDUPILOT_LAND).pack(gcs),
    ]
    return b"".join(frames)


def _stats(tmp: Path) -> dict:
    return json.loads((tmp / f"uav{UAV}.json").read_text())


class MavProxy:
    """MAVProxy as a ground station on the UAV's router endpoint, fed commands on stdin."""

    def __init__(self, port: int, cwd: Path, passphrase: str | None = None):
        assert MAVPROXY is not None, "mavproxy.py not found: MAVProxy is in the test extra (pip install -e '.[test]')"
        args = [MAVPROXY, f"--master=udpout:127.0.0.1:{port}", "--no-state", "--cmd=set requireexit 0"]
        if passphrase is not None:  # the key before the first frame: MAVProxy's link signs from the start
            args[-1] += f"; signing key {passphrase}"
        self.proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     cwd=cwd, start_new_session=True, env={**os.environ, "MAVLINK20": "1"})
        self.out: list[str] = []
        threading.Thread(target=lambda: self.out.extend(iter(self.proc.stdout.readline, "")), daemon=True).start()  # type: ignore[union-attr]

    def saw(self, text: str) -> bool:
        return any(text in line for line in self.out)

    def send(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def tail(self) -> str:
        return "".join(self.out)[-2000:]

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.proc.wait(10)


def test_forged_mavlink_is_ignored_and_counted_the_mission_goes_on_and_only_a_signed_gcs_takes_over(
        tmp_path: Path, router: str) -> None:
    passphrase = write_key_file(tmp_path / "mavlink.key").read_text().strip()
    gcs_port = free_port(socket.SOCK_DGRAM)
    proc = start_virtual_uav(tmp_path, router, uav=UAV, endpoints=(f"udpin:127.0.0.1:{gcs_port}",), autostart=True,
                             flavour="ardupilot", signing=MavlinkSigning(key_file=str(tmp_path / "mavlink.key")))
    obs = SwarmObserver("gcs", Rendezvous((router,), mode="client"), role="gcs", name="test").open()
    attackers = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(16)]
    proxies: list[MavProxy] = []

    def state():  # noqa: ANN202
        obs.poll()
        v = obs.uavs.get(UAV)
        return v.state if v is not None else None

    try:
        assert wait_for(lambda: (s := state()) is not None and s.phase == "mission", 90, 0.1), state()
        for a in attackers:
            a.bind(("127.0.0.1", 0))
        targets = [("127.0.0.1", c.laddr.port) for c in psutil.Process(proc.pid).net_connections(kind="udp")
                   if c.laddr and (c.laddr.ip.startswith("127.") or c.laddr.ip == "0.0.0.0")]
        assert len(targets) >= 3, targets  # the FCU, the agent's FCU link, the router's endpoint
        tel = obs.uavs[UAV].telemetry
        assert tel is not None and tel.mode == "GUIDED" and tel.armed

        # ---- 1. the forgeries, 3 s at 10 Hz from 16 ports to every port ----------------------------
        poses: list[tuple[float, float, float]] = []
        phases: set[str] = set()
        rounds = 0
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            t = obs.uavs[UAV].telemetry
            data = forged_frames(t.lat, t.lon, t.alt) if t is not None else b""
            for a in attackers:
                for addr in targets:
                    a.sendto(data, addr)
            rounds += 1
            deadline = time.monotonic() + 0.1
            while time.monotonic() < deadline:
                s = state()
                phases.add(s.phase if s is not None else "?")
                p = obs.uavs[UAV].pose
                if p is not None and (not poses or poses[-1] != (p.t_wall, p.x, p.y)):
                    poses.append((p.t_wall, p.x, p.y))
                time.sleep(0.02)
        per_port = rounds * len(attackers)  # datagrams each port received from the attacker
        time.sleep(1.5)  # the UAV keeps going after the attack, too
        s = state()
        phases.add(s.phase if s is not None else "?")
        assert phases == {"mission"}, phases  # no yield, no landing: the forged mode and commands did nothing
        t = obs.uavs[UAV].telemetry
        assert t is not None and t.mode == "GUIDED" and t.armed, t
        jumps = [math.dist(a[1:], b[1:]) for a, b in zip(poses, poses[1:], strict=False)]
        assert len(poses) >= 10 and max(jumps) < 10.0, (max(jumps), poses[:5])  # the forged 54 m never showed
        assert math.dist(poses[0][1:], poses[-1][1:]) > 3.0  # still flying its lanes
        st = _stats(tmp_path)
        fcu_link, fcu, rt = st["fcu_link"], st["virtual_fcu"], st["mavlink_router"]
        assert fcu_link["foreign_source"] >= per_port, fcu_link  # forged "FCU" frames to the agent's link
        assert fcu["foreign_datagrams"] >= per_port and fcu["commands"].get("ACCEPTED", 0) >= 1, fcu  # to the FCU
        assert rt["unsigned_refused"] >= 5 * per_port and rt["to_fcu"] == 0, rt  # to the router: every frame refused

        # ---- 2. MAVProxy without the key: refused, never answered ---------------------------------------
        proxies.append(MavProxy(gcs_port, tmp_path))
        refused = rt["unsigned_refused"]
        assert wait_for(lambda: _stats(tmp_path)["mavlink_router"]["unsigned_refused"] > refused + 20, 20, 0.5)
        assert not proxies[-1].saw(f"Detected vehicle {UAV}:1"), proxies[-1].tail()  # nothing comes back to it
        proxies[-1].send("mode RTL")
        time.sleep(2.0)
        assert state().phase == "mission" and _stats(tmp_path)["mavlink_router"]["to_fcu"] == 0
        proxies[-1].close()

        # ---- 3. MAVProxy with the key: a ground station like any other --------------------------------
        proxies.append(MavProxy(gcs_port, tmp_path, passphrase))
        mp = proxies[-1]
        assert wait_for(lambda: mp.saw(f"Detected vehicle {UAV}:1"), 60, 0.2), mp.tail()
        assert wait_for(lambda: mp.saw("Received") and mp.saw("parameters"), 40, 0.2), mp.tail()
        mp.send("mode RTL")
        assert wait_for(lambda: mp.saw("DO_SET_MODE: ACCEPTED"), 20, 0.2), mp.tail()
        assert wait_for(lambda: state().phase == "yielded", 15, 0.1), state()
        rt = _stats(tmp_path)["mavlink_router"]
        assert rt["signed"] > 0 and rt["to_fcu"] > 0 and rt["bad_signature"] == 0, rt
    finally:
        for mp in proxies:
            mp.close()
        for a in attackers:
            a.close()
        obs.close()
        stop_process(proc)
