"""The agent's FCU link over the connection strings a real UAV uses, and the standalone agent.

A serial-port FCU is the one piece of hardware we cannot have: a pty stands in for the
serial port, bridged to a virtual FCU's UDP socket, so the agent's pymavlink ``serial:``
path (pyserial, stream framing) is exercised for real.
"""

from __future__ import annotations

import json
import math
import os
import select
import socket
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path

import pytest

from tests.conftest import free_port, wait_for
from tests.fcu_helpers import FcuThread
from uav_stack.autopilot import PX4_PROFILE
from uav_stack.fcu import FcuConfig, VehicleConfig
from uav_stack.fcu_link import VELOCITY_ONLY_MASK, FcuLink
from uav_stack.geo import GeoPoint
from uav_stack.mav import mavlink

HOME = GeoPoint(46.6167, 14.2650, 446.0)
ROOT = Path(__file__).resolve().parents[1]


class PtyBridge:
    """Bytes written to the pty go to the FCU's UDP socket and back: a serial cable."""

    def __init__(self, fcu_addr: tuple[str, int]):
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.port = os.ttyname(slave)
        self._slave = slave
        self.fcu_addr = fcu_addr
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            r, _, _ = select.select([self.master, self.sock], [], [], 0.1)
            if self.master in r:
                data = os.read(self.master, 4096)
                if data:
                    self.sock.sendto(data, self.fcu_addr)
            if self.sock in r:
                data, _ = self.sock.recvfrom(65535)
                os.write(self.master, data)

    def __enter__(self) -> PtyBridge:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()
        os.close(self.master)
        os.close(self._slave)


def fly_takeoff(link: FcuLink, alt: float = 3.0, timeout: float = 20.0) -> None:
    deadline = time.time() + timeout

    def pump(until) -> bool:  # type: ignore[no-untyped-def]
        while time.time() < deadline:
            link.poll()
            link.service()
            if until():
                return True
            time.sleep(0.02)
        return False

    assert pump(lambda: link.connected and link.state.has_position), "no heartbeat/position from the FCU"
    assert link.state.profile is PX4_PROFILE and link.state.mode == "HOLD"  # PX4 AUTO.LOITER, named as PX4 names it
    h = link.arm()
    assert pump(lambda: h.done) and h.accepted, h.status
    assert pump(lambda: link.state.armed)
    t = link.takeoff(HOME.alt + alt, alt)
    assert pump(lambda: t.done) and t.accepted, t.status
    assert pump(lambda: link.state.relative_alt > alt - 0.3), link.state.relative_alt
    assert link.rtf.value == pytest.approx(1.0, abs=0.15)


def test_agent_link_over_a_serial_port() -> None:
    with FcuThread(FcuConfig([VehicleConfig(sysid=1, home=HOME)])) as ft, PtyBridge(ft.addrs[0]) as pty:
        link = FcuLink(f"serial:{pty.port}:921600").open()
        try:
            fly_takeoff(link)
            assert link.counts["bad"] == 0
        finally:
            link.close()


def test_agent_link_px4_sitl_style_udpin() -> None:
    """PX4 SITL streams to a fixed port and the companion binds it (udpin)."""
    port = free_port(socket.SOCK_DGRAM)
    with FcuThread(FcuConfig([VehicleConfig(sysid=1, home=HOME, remotes=(("127.0.0.1", port),))])):
        link = FcuLink(f"udpin:127.0.0.1:{port}").open()
        try:
            fly_takeoff(link)
        finally:
            link.close()


def test_standalone_agent_flies_a_standalone_fcu(tmp_path: Path, router: str) -> None:
    """`mrswarm fcu` + `mrswarm agent --autostart`: how a real UAV's companion runs the stack."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    fcu = subprocess.Popen([sys.executable, "-m", "mrswarm", "fcu", "--listen", "127.0.0.1:0",
                            "--home", f"{HOME.lat},{HOME.lon},{HOME.alt}", "--duration", "60"],
                           cwd=ROOT, stdout=subprocess.PIPE, text=True, env=env)
    agent = None
    try:
        line = fcu.stdout.readline()  # type: ignore[union-attr]
        assert line.startswith("LISTEN"), line
        addr = line.split()[2]
        rec = tmp_path / "rec"
        agent = subprocess.Popen(
            [sys.executable, "-m", "mrswarm", "agent", "--fcu", f"udpout:{addr}", "--swarm", "solo", "--uav", "3",
             "--origin", f"{HOME.lat},{HOME.lon},{HOME.alt}", "--connect", router, "--listen", "tcp/127.0.0.1:0",
             "--autostart", "--record-dir", str(rec), "--duration", "40", "--insecure"],  # a plain router: not about security
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        # autostart: arm, take off to the default 20 m mission altitude, go offboard and fly the mission
        assert wait_for(lambda: (rec / "uav3.json").exists()
                        and json.loads((rec / "uav3.json").read_text())["phase"] in ("hover", "mission", "done"), 45.0)
        stats = json.loads((rec / "uav3.json").read_text())
        assert stats["realm"] == "physical" and stats["fcu_link"]["bad"] == 0
        rows = (rec / "uav3.csv").read_text().splitlines()
        assert rows[0].startswith("t_wall,") and len(rows) > 20
        z = [float(r.split(",")[4]) for r in rows[1:]]
        assert max(z) > 18.0  # climbed to the mission altitude above the origin
    finally:
        for p in (agent, fcu):
            if p is not None and p.poll() is None:
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()


def test_the_velocity_setpoint_leaves_as_pymavlink_frames_it_tick_after_tick() -> None:
    """What the agent sends its FCU ten times a second, through the link's framing: exactly the
    frames pymavlink's own ``set_position_target_local_ned_send`` writes, tick after tick."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(2.0)
    link = FcuLink(f"udpout:127.0.0.1:{rx.getsockname()[1]}", source_system=42, source_component=191, target_system=7).open()
    try:
        ref = mavlink.MAVLink(None, 42, 191)
        for k, (vn, ve, vd) in enumerate([(1.5, -2.0, 0.0), (0.0, 0.25, -1.0), (math.nan, 3.0, 0.5)] * 100):
            link.state.position_boot_s = 0.1 * k
            ref.seq = link.conn.mav.seq
            link.send_velocity_ned(vn, ve, vd)
            want = ref.set_position_target_local_ned_encode(
                int(link.state.position_boot_s * 1000) & 0xFFFFFFFF, 7, mavlink.MAV_COMP_ID_AUTOPILOT1,
                mavlink.MAV_FRAME_LOCAL_NED, VELOCITY_ONLY_MASK, 0, 0, 0, vn, ve, vd, 0, 0, 0, 0, 0).pack(ref)
            got = rx.recv(2048)
            assert got == want, k
        assert link.counts["tx_setpoints"] == 300
    finally:
        link.close()
        rx.close()
