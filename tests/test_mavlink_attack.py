"""Red team: MAVLink locked by default, attacked as a rogue local process would, on a real virtual UAV.

One virtual UAV process (virtual FCU + agent, ArduPilot flavour so MAVProxy can change its
modes) flies its mission with the swarm's MAVLink key (``mrswarm keys init`` makes it). Its
router sends to a ground-station port, as to QGroundControl's 14550 in a default run, and listens
on another. The attacker knows the UDP ports the process has open (what ``ss -uapn`` shows) and
the UAV's system id, and holds the ground-station port itself:

1. on the ground-station port it gets the UAV's telemetry, but its unsigned force-disarm, LAND
   and mode changes are refused and counted, and the UAV flies on;
2. from 16 other local ports it sends forged FCU heartbeats (mode LAND), a forged position
   54 m away, LAND and disarm commands and unsigned mode changes to every port: the UAV keeps
   flying its mission, its swarm pose does not jump, every forged datagram is counted where it
   was refused;
3. 20 000 random datagrams to every MAVLink socket of the process (fuzzed frames of every id,
   thousands of them commands to the UAV that an open parser would take; from the
   ground-station port to the router's socket that sends there): not one command is accepted;
4. frames whose id no dialect defines, unsigned and signed with the swarm's key: dropped and
   counted, never forwarded to the FCU;
5. MAVProxy without the key sees the UAV but cannot command it; MAVProxy with the key as
   ``mrswarm keys mavlink`` prints it (``signing key <passphrase>``) takes the UAV over (RTL):
   the agent yields, as with any ground station.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import sysconfig
import threading
import time
from pathlib import Path

import psutil
import pytest

from swarmnet.connectivity import Rendezvous
from swarmnet.observer import SwarmObserver
from tests.conftest import free_port, wait_for
from tests.fcu_helpers import DatagramParser
from tests.gcs_helpers import ROOT, mavlink_passphrase, mavproxy_args, start_virtual_uav, stop_process
from tests.mavlink_fuzz import UNKNOWN_IDS, Fuzzer, would_command
from tests.test_mavlink_security import signing_gcs, unknown_frame
from uav_stack.config import MavlinkSigning
from uav_stack.fcu_link import ACK_RETRIES
from uav_stack.geo import GeoPoint, LocalFrame
from uav_stack.mav import mavlink as M
from uav_stack.mavlink_signing import is_signed, key_from_passphrase

pytestmark = pytest.mark.e2e
# beside the interpreter (the checkout's .venv/bin, also when that venv is not activated), else on PATH
MAVPROXY = shutil.which("mavproxy.py", path=os.pathsep.join([sysconfig.get_path("scripts"), os.environ.get("PATH", "")]))
UAV = 3  # MAVLink sysid 3 (uav_stack.sysid.allocate_sysid)
ARDUPILOT_LAND, ARDUPILOT_RTL = 9, 6
FLOOD = 20_000  # random datagrams to each socket


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


def _fresh_stats(tmp: Path) -> dict:
    """The agent's counters as of now (its stats file is rewritten every second)."""
    time.sleep(2.2)
    return _stats(tmp)


def udp_drops(ports: list[int]) -> int:
    """Datagrams the kernel dropped on these local UDP ports (full receive buffers), from /proc/net/udp."""
    total = 0
    with open("/proc/net/udp") as f:
        for line in f.readlines()[1:]:
            fields = line.split()
            if int(fields[1].rsplit(":", 1)[1], 16) in ports:
                total += int(fields[12])
    return total


class MavProxy:
    """MAVProxy as a ground station on the UAV's router endpoint, fed commands on stdin."""

    def __init__(self, port: int, cwd: Path, passphrase: str | None = None):
        assert MAVPROXY is not None, "mavproxy.py not found: MAVProxy is in the test extra (pip install -e '.[test]')"
        args, env = mavproxy_args(MAVPROXY, port, passphrase)  # the key before the first frame: its link signs from the start
        self.proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     cwd=cwd, start_new_session=True, env=env)
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


def test_mavlink_is_locked_telemetry_to_anyone_commands_only_from_a_ground_station_with_the_swarms_key(
        tmp_path: Path, router: str) -> None:
    keys = tmp_path / "keys"
    res = subprocess.run([sys.executable, "-m", "mrswarm", "keys", "init", "--swarm", "gcs", "--dir", str(keys)], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    passphrase = mavlink_passphrase("--dir", str(keys))
    key = key_from_passphrase(passphrase)
    qgc_port, listen_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)
    qgc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the attacker holds the ground-station port
    qgc.bind(("127.0.0.1", qgc_port))
    qgc.settimeout(0.05)
    proc = start_virtual_uav(tmp_path, router, uav=UAV, autostart=True, flavour="ardupilot",
                             endpoints=(f"udpout:127.0.0.1:{qgc_port}", f"udpin:127.0.0.1:{listen_port}"),
                             signing=MavlinkSigning(key_file=str(keys / "mavlink.key")))
    obs = SwarmObserver("gcs", Rendezvous((router,), mode="client"), role="gcs", name="test").open()
    attackers = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(16)]
    proxies: list[MavProxy] = []
    phases: set[str] = set()

    def state():  # noqa: ANN202
        obs.poll()
        v = obs.uavs.get(UAV)
        return v.state if v is not None else None

    def watch(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            s = state()
            phases.add(s.phase if s is not None else "?")
            time.sleep(0.05)

    def from_qgc_port(seconds: float) -> list:  # noqa: ANN202 - what the router sends the ground-station port
        out, parser = [], DatagramParser()
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                data, addr = qgc.recvfrom(65535)
            except OSError:
                continue
            out += [(m, addr) for m in parser.parse(data)[0]]
        return out

    try:
        assert wait_for(lambda: (s := state()) is not None and s.phase == "mission", 90, 0.1), state()
        phases.add("mission")
        for a in attackers:
            a.bind(("127.0.0.1", 0))
        ports = sorted({c.laddr.port for c in psutil.Process(proc.pid).net_connections(kind="udp")
                        if c.laddr and (c.laddr.ip.startswith("127.") or c.laddr.ip == "0.0.0.0")})
        assert len(ports) == 4, ports  # the FCU, the agent's FCU link, the router's two endpoints
        tel = obs.uavs[UAV].telemetry
        assert tel is not None and tel.mode == "GUIDED" and tel.armed

        # ---- 1. the ground-station port: telemetry, signed; no command -----------------------------------
        heard = from_qgc_port(1.5)
        assert {"HEARTBEAT", "GLOBAL_POSITION_INT"} <= {m.get_type() for m, _ in heard if m.get_srcSystem() == UAV}
        assert all(is_signed(m.get_msgbuf()) for m, _ in heard)  # signed, and read by a parser without the key (QGC's)
        router_out = heard[0][1]  # the router's socket that sends here: the only one that reads what comes from here
        gcs = M.MAVLink(None, 255, 190)
        disarm = M.MAVLink_command_long_message(UAV, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196, 0, 0, 0, 0, 0)
        land = M.MAVLink_set_mode_message(UAV, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ARDUPILOT_LAND)
        for _ in range(5):
            qgc.sendto(disarm.pack(gcs) + land.pack(gcs), router_out)
            time.sleep(0.1)
        watch(1.0)
        rt = _fresh_stats(tmp_path)["mavlink_router"]
        assert rt["unsigned_commands_refused"] == 10 and rt["to_fcu"] == 0 and rt["signing"] == "signed", rt
        assert phases == {"mission"} and (t := obs.uavs[UAV].telemetry) is not None and t.armed, (phases, t)

        # ---- 2. forgeries, 3 s at 10 Hz from 16 ports to every port --------------------------------------
        targets = [("127.0.0.1", p) for p in ports]
        poses: list[tuple[float, float, float]] = []
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
        watch(1.5)  # the UAV keeps going after the attack, too
        assert phases == {"mission"}, phases  # no yield, no landing: the forged mode and commands did nothing
        t = obs.uavs[UAV].telemetry
        assert t is not None and t.mode == "GUIDED" and t.armed, t
        jumps = [math.dist(a[1:], b[1:]) for a, b in zip(poses, poses[1:], strict=False)]
        assert len(poses) >= 10 and max(jumps) < 10.0, (max(jumps), poses[:5])  # the forged 54 m never showed
        assert math.dist(poses[0][1:], poses[-1][1:]) > 3.0  # still flying its lanes
        st = _fresh_stats(tmp_path)
        fcu_link, fcu, rt = st["fcu_link"], st["virtual_fcu"], st["mavlink_router"]
        assert fcu_link["foreign_source"] >= per_port, fcu_link  # forged "FCU" frames to the agent's link
        assert fcu["foreign_datagrams"] >= per_port, fcu  # to the FCU: dropped before they are parsed
        assert rt["unsigned_refused"] >= 5 * per_port and rt["foreign_source"] >= per_port and rt["to_fcu"] == 0, rt

        # ---- 3. 20 000 random datagrams to every socket --------------------------------------------------
        flood = Fuzzer(UAV, seed=48).datagrams(FLOOD)
        assert would_command(flood, UAV) > 5000  # an open parser takes thousands of commands to the UAV from it
        before, drops0 = st, udp_drops(ports)
        sources = {addr: ([qgc] if addr == router_out else attackers) for addr in targets}
        for i in range(0, FLOOD, 200):  # ~2000 datagrams a second to each socket
            for addr, senders in sources.items():
                for k, d in enumerate(flood[i:i + 200]):
                    senders[k % len(senders)].sendto(d, addr)
            watch(0.1)
        watch(2.0)
        after = _fresh_stats(tmp_path)
        assert phases == {"mission"}, phases
        t = obs.uavs[UAV].telemetry
        assert t is not None and t.mode == "GUIDED" and t.armed, t
        fcu0, fcu1 = before["virtual_fcu"], after["virtual_fcu"]
        # not one command: the FCU acknowledged only the agent's own (none, flying its lanes)
        own = after["fcu_link"]["commands"] - before["fcu_link"]["commands"]
        assert sum(fcu1["commands"].values()) - sum(fcu0["commands"].values()) <= own * (1 + ACK_RETRIES), (fcu0, fcu1)
        rt0, rt1 = before["mavlink_router"], after["mavlink_router"]
        assert rt1["to_fcu"] == 0 and rt1["gcs_to_gcs"] == 0 and rt1["signed"] == 0, rt1
        # every datagram to the FCU and to the agent's link was read and refused, or dropped by a full buffer
        refused = (fcu1["foreign_datagrams"] - fcu0["foreign_datagrams"]
                   + after["fcu_link"]["foreign_source"] - before["fcu_link"]["foreign_source"])
        router_read = sum(rt1[k] - rt0[k] for k in ("bad_datagrams", "unsigned_refused", "bad_signature", "unknown_id_refused",
                                                    "foreign_source"))
        assert refused + router_read + udp_drops(ports) - drops0 >= 4 * FLOOD, (refused, router_read, udp_drops(ports))
        assert refused >= FLOOD // 2 and router_read >= 1000, (refused, router_read)

        # ---- 4. ids no dialect defines: dropped, counted, never forwarded --------------------------------
        keyed = signing_gcs(key)
        for i in range(40):
            frames = [unknown_frame(UNKNOWN_IDS[i % 4], signing_gcs(None)), unknown_frame(UNKNOWN_IDS[(i + 1) % 4], keyed)]
            qgc.sendto(b"".join(frames), router_out)
            attackers[0].sendto(b"".join(frames), ("127.0.0.1", listen_port))
            time.sleep(0.02)
        rt2 = _fresh_stats(tmp_path)["mavlink_router"]
        assert rt2["unknown_id_refused"] - rt1["unknown_id_refused"] == 160 and rt2["to_fcu"] == 0, rt2

        # ---- 5. MAVProxy without the key: it watches, it cannot command ------------------------------------
        proxies.append(MavProxy(listen_port, tmp_path))
        mp = proxies[-1]
        assert wait_for(lambda: mp.saw(f"Detected vehicle {UAV}:1"), 60, 0.2), mp.tail()  # telemetry to anyone
        refused = rt2["unsigned_refused"]
        assert wait_for(lambda: _stats(tmp_path)["mavlink_router"]["unsigned_refused"] > refused + 20, 20, 0.5)
        mp.send("mode RTL")
        watch(3.0)
        assert phases == {"mission"} and _stats(tmp_path)["mavlink_router"]["to_fcu"] == 0, phases
        mp.close()

        # ---- 6. MAVProxy with the key `mrswarm keys mavlink` printed: a ground station like any other --------
        proxies.append(MavProxy(listen_port, tmp_path, passphrase))
        mp = proxies[-1]
        assert wait_for(lambda: mp.saw(f"Detected vehicle {UAV}:1"), 60, 0.2), mp.tail()
        assert wait_for(lambda: mp.saw("Received") and mp.saw("parameters"), 40, 0.2), mp.tail()
        mp.send("mode RTL")
        assert wait_for(lambda: mp.saw("DO_SET_MODE: ACCEPTED"), 20, 0.2), mp.tail()
        assert wait_for(lambda: state().phase == "yielded", 15, 0.1), state()
        rt = _stats(tmp_path)["mavlink_router"]
        assert rt["signed"] > 0 and rt["to_fcu"] > 0, rt
    finally:
        for mp in proxies:
            mp.close()
        for a in attackers:
            a.close()
        qgc.close()
        obs.close()
        stop_process(proc)
