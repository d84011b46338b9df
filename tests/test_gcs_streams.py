"""The FCU's ground-station streams flow only while a ground station listens (uav_stack/gcs_streams.py):
a real virtual-UAV process, its router sending to a ground station's UDP port as to QGroundControl's 14550."""

from __future__ import annotations

import json
import socket
import time
from collections import Counter
from pathlib import Path

import pytest

from tests.conftest import wait_for
from tests.gcs_helpers import start_virtual_uav, stop_process
from uav_stack.gcs_streams import GCS_QUIET_S, GCS_STREAMS
from uav_stack.mav import mavlink

pytestmark = pytest.mark.e2e


class Listener:
    """A ground station's UDP port: counts the message types the router sends it, and speaks
    (a GCS heartbeat a second, as QGroundControl does) only when told to."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.mav = mavlink.MAVLink(None, 255, 190)
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.router: tuple[str, int] | None = None

    def listen(self, seconds: float, speak: bool = False) -> Counter[str]:
        """Message types received over ``seconds``; with ``speak``, a heartbeat back every second."""
        seen: Counter[str] = Counter()
        end = time.monotonic() + seconds
        next_hb = 0.0
        while time.monotonic() < end:
            if speak and self.router is not None and time.monotonic() >= next_hb:
                hb = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3)
                self.sock.sendto(hb.pack(self.mav), self.router)
                next_hb = time.monotonic() + 1.0
            try:
                data, addr = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            self.router = addr
            for m in self.parser.parse_buffer(data) or []:
                seen[m.get_type()] += 1
        return seen


def _streams(tmp: Path) -> dict:
    return json.loads((tmp / "uav1.json").read_text())["gcs_streams"]


def test_ground_station_streams_flow_only_while_a_ground_station_listens(tmp_path: Path, router: str) -> None:
    gcs = Listener()
    proc = start_virtual_uav(tmp_path, router, endpoints=(f"udpout:127.0.0.1:{gcs.port}",))
    try:
        # nobody has spoken: heartbeats and positions reach the port (a ground station finds the vehicle), the rest not
        assert wait_for(lambda: (tmp_path / "uav1.json").exists() and _streams(tmp_path)["switches"] >= 1, 30, 0.2)
        gcs.listen(1.0)  # what the FCU had sent before it was asked, waiting in the socket
        quiet = gcs.listen(3.0)
        assert quiet["HEARTBEAT"] >= 2 and quiet["GLOBAL_POSITION_INT"] >= 25, quiet
        assert not set(GCS_STREAMS) & set(quiet), quiet

        # a ground station speaks: everything flows from its first heartbeat on
        gcs.listen(1.0, speak=True)
        heard = gcs.listen(3.0, speak=True)
        assert set(GCS_STREAMS) - {"MISSION_CURRENT"} <= set(heard), heard  # (no mission: MISSION_CURRENT may be quiet)
        assert heard["ATTITUDE"] >= 10 and heard["GLOBAL_POSITION_INT"] >= 25, heard
        assert _streams(tmp_path)["on"] is True

        # it goes quiet: after GCS_QUIET_S its streams stop again, the vehicle's heartbeat and position do not
        gcs.listen(GCS_QUIET_S + 1.5)
        after = gcs.listen(3.0)
        assert after["HEARTBEAT"] >= 2 and after["GLOBAL_POSITION_INT"] >= 25, after
        assert not set(GCS_STREAMS) & set(after), after
        st = _streams(tmp_path)
        assert st["on"] is False and st["switches"] == 3, st
    finally:
        stop_process(proc)
        gcs.sock.close()
