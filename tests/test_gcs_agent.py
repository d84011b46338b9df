"""The agent's side of ground-station control, on real virtual-UAV processes:

* override verbs, their acks and their errors (bad args, geofence, impossible in this phase);
* a human taking over through the MAVLink router makes the agent yield and stop its setpoints,
  both when the FCU's mode leaves OFFBOARD (PX4) and when the mode stays GUIDED (ArduPilot);
* ``resume`` takes control back.

The ground stations sign their frames with the UAVs' MAVLink key, as the routers require.
"""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

import pytest

from swarmnet.connectivity import Rendezvous
from swarmnet.observer import SwarmObserver
from tests.conftest import free_port, wait_for
from tests.gcs_helpers import HOME, start_virtual_uav, stop_process
from uav_stack.config import MavlinkSigning
from uav_stack.geo import LocalFrame
from uav_stack.mav import mavlink
from uav_stack.mavlink_signing import read_key_file, signing_timestamp, write_key_file

pytestmark = pytest.mark.e2e


def _cmd(obs: SwarmObserver, uav: int, verb: str, args: dict | None = None, timeout: float = 8.0) -> tuple[bool, str]:
    p = obs.command(verb, [uav], args)
    assert wait_for(lambda: (obs.poll(), p.complete)[1], timeout, 0.05), f"no ack for {verb}"
    a = p.acks[uav]
    return a.ok, a.message


def _state(obs: SwarmObserver, uav: int):  # noqa: ANN202
    obs.poll()
    v = obs.uavs.get(uav)
    return v.state if v is not None else None


def _phase_is(obs: SwarmObserver, uav: int, phase: str) -> bool:
    st = _state(obs, uav)
    return st is not None and st.phase == phase


def _tx_setpoints(tmp: Path, uav: int) -> int:
    return json.loads((tmp / f"uav{uav}.json").read_text())["fcu_link"]["tx_setpoints"]


def signing(key: bytes, sysid: int = 255) -> mavlink.MAVLink:
    """A ground station's packer that signs every frame with ``key``."""
    mav = mavlink.MAVLink(None, sysid, 190)
    mav.signing.secret_key, mav.signing.sign_outgoing, mav.signing.timestamp = key, True, signing_timestamp()
    return mav


class RawGcs:
    """A ground station on a raw UDP socket talking to an agent's udpin router endpoint."""

    def __init__(self, port: int, key: bytes, sysid: int = 255):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.addr = ("127.0.0.1", port)
        self.mav = signing(key, sysid)
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True

    def send(self, msg: mavlink.MAVLink_message) -> None:
        self.sock.sendto(msg.pack(self.mav), self.addr)

    def heartbeat(self) -> None:
        self.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3))

    def wait_for(self, mtype: str, pred=lambda m: True, timeout: float = 10.0):  # noqa: ANN001, ANN201
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.heartbeat()
            try:
                data = self.sock.recv(65535)
            except TimeoutError:
                continue
            for m in self.parser.parse_buffer(data) or []:
                if m.get_type() == mtype and pred(m):
                    return m
        raise AssertionError(f"no {mtype} from the router within {timeout} s")

    def close(self) -> None:
        self.sock.close()


class QgcLike:
    """A ground station on one shared port that, like QGroundControl's UDP link, sends every
    message to every address it has heard from (so each router sees traffic for other vehicles)."""

    def __init__(self, key: bytes) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.mav = signing(key)
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.vehicles: dict[int, tuple[str, int]] = {}

    def wait_vehicles(self, sysids: set[int], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not sysids <= set(self.vehicles):
            try:
                data, addr = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            for m in self.parser.parse_buffer(data) or []:
                if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1:
                    self.vehicles[m.get_srcSystem()] = addr
        return sysids <= set(self.vehicles)

    def set_mode_everywhere(self, target: int, custom_mode: int) -> None:
        hb = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3).pack(self.mav)
        msg = mavlink.MAVLink_set_mode_message(target, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode).pack(self.mav)
        for addr in set(self.vehicles.values()):
            self.sock.sendto(hb + msg, addr)

    def close(self) -> None:
        self.sock.close()


def test_override_verbs_takeover_and_resume(tmp_path: Path, router: str) -> None:
    p2 = free_port(socket.SOCK_DGRAM)
    key_file = write_key_file(tmp_path / "mavlink.key")
    key, signed = read_key_file(key_file), MavlinkSigning(key_file=str(key_file))
    qgc = QgcLike(key)  # one shared ground-station port, like QGroundControl's 14550 (with the key set)
    shared = f"udpout:127.0.0.1:{qgc.port}"
    procs = [
        start_virtual_uav(tmp_path, router, uav=1, endpoints=(shared,), autostart=True, signing=signed),
        start_virtual_uav(tmp_path, router, uav=2, endpoints=(shared, f"udpin:127.0.0.1:{p2}"), autostart=True,
                          flavour="ardupilot", signing=signed),
    ]
    obs = SwarmObserver("gcs", Rendezvous((router,), mode="client"), role="gcs", name="test").open()
    gcs2 = RawGcs(p2, key)
    try:
        for u in (1, 2):  # both flavours take off and fly the mission on their own (ArduPilot: GUIDED first)
            assert wait_for(lambda u=u: _phase_is(obs, u, "mission"), 90, 0.1), _state(obs, u)

        # ---- errors come back to the sender, nothing changes ----------------------------------
        assert _cmd(obs, 1, "goto", {"x": 500.0, "y": 0.0, "z": 10.0}) == \
            (False, "goto: (500, 0) is outside the geofence x -40..40, y -40..40")
        ok, msg = _cmd(obs, 1, "goto", {"x": "ten", "y": 0})
        assert not ok and "x='ten' is not a finite number" in msg
        ok, msg = _cmd(obs, 1, "goto", {"x": 1.0})
        assert not ok and "missing argument 'y'" in msg
        ok, msg = _cmd(obs, 1, "goto", {"x": 1.0, "y": 1.0, "z": 500.0})
        assert not ok and "altitude 500 m outside" in msg
        ok, msg = _cmd(obs, 1, "arm")
        assert not ok and "only on the ground" in msg
        ok, msg = _cmd(obs, 1, "disarm")
        assert not ok and "in the air" in msg
        assert _cmd(obs, 1, "fly_to_the_moon") == (False, "unknown command 'fly_to_the_moon'")
        assert _phase_is(obs, 1, "mission")

        # ---- goto, then resume ---------------------------------------------------------------
        ok, msg = _cmd(obs, 1, "goto", {"x": 12.0, "y": -6.0, "z": 12.0})
        assert ok and msg == "going to (12, -6, 12)"
        frame = LocalFrame(HOME)

        def at_goal() -> bool:
            obs.poll()
            v = obs.uavs[1]
            return v.pose is not None and abs(v.pose.x - 12.0) < 1.0 and abs(v.pose.y + 6.0) < 1.0 and abs(v.pose.z - 12.0) < 1.0

        assert wait_for(at_goal, 30, 0.1), obs.uavs[1].pose
        assert wait_for(lambda: _state(obs, 1).detail.startswith("arrived at (12, -6, 12)"), 3, 0.05), _state(obs, 1)
        assert _cmd(obs, 1, "resume") == (True, "behaviour resumed")
        assert wait_for(lambda: _phase_is(obs, 1, "mission"), 5, 0.1)
        del frame

        # ---- PX4: a human switches UAV 1 to HOLD, QGroundControl's way: the SET_MODE message, sent to
        # every vehicle address on the shared port. UAV 1's agent yields; UAV 2's router drops it.
        assert qgc.wait_vehicles({1, 2}, 10), qgc.vehicles
        qgc.set_mode_everywhere(1, 4 << 16 | 3 << 24)  # PX4 AUTO.LOITER
        assert wait_for(lambda: _phase_is(obs, 1, "yielded"), 10, 0.1), _state(obs, 1)
        assert _phase_is(obs, 2, "mission")
        assert wait_for(lambda: json.loads((tmp_path / "uav2.json").read_text())["mavlink_router"]["dropped_unknown_target"] >= 1,
                        3, 0.2)
        st = _state(obs, 1)
        # whichever the agent noticed first: the command passing its router, or the FCU's new mode
        assert st.override in ("gcs:SET_MODE", "fcu:HOLD") and "setpoints stopped" in st.detail
        time.sleep(1.5)
        tx = _tx_setpoints(tmp_path, 1)
        time.sleep(2.2)
        assert _tx_setpoints(tmp_path, 1) == tx  # no setpoint since: the human has the vehicle
        ok, msg = _cmd(obs, 1, "hold")
        assert not ok and "send resume to take control back" in msg
        # resume takes control back: OFFBOARD again, then the mission
        ok, msg = _cmd(obs, 1, "resume")
        assert ok and "taking control back from HOLD" in msg
        assert wait_for(lambda: _phase_is(obs, 1, "mission"), 15, 0.1), _state(obs, 1)
        assert obs.uavs[1].telemetry is not None
        assert wait_for(lambda: (obs.poll(), obs.uavs[1].telemetry.mode == "OFFBOARD")[1], 5, 0.1)

        # ---- ArduPilot: a GCS reposition keeps the mode GUIDED, the router still tells the agent ---------
        gcs2.wait_for("HEARTBEAT", lambda m: m.get_srcSystem() == 2)
        gcs2.send(mavlink.MAVLink_command_int_message(2, 1, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                     mavlink.MAV_CMD_DO_REPOSITION,
                                                     0, 0, -1, 0, 0, 0, int(HOME.lat * 1e7), int(HOME.lon * 1e7), 15.0))
        ack = gcs2.wait_for("COMMAND_ACK", lambda m: m.command == mavlink.MAV_CMD_DO_REPOSITION and m.target_system == 255)
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED
        assert wait_for(lambda: _phase_is(obs, 2, "yielded"), 10, 0.1), _state(obs, 2)
        assert _state(obs, 2).override == "gcs:DO_REPOSITION"
        assert obs.uavs[2].telemetry.mode == "GUIDED"

        # ---- rtl and land through the agent, acknowledged with the FCU's answer ------------------------
        assert _cmd(obs, 1, "rtl") == (True, "returning to launch")
        assert wait_for(lambda: (obs.poll(), obs.uavs[1].telemetry.mode == "RTL")[1], 5, 0.1)
        assert _state(obs, 1).override == "rtl"
        assert _cmd(obs, 2, "land") == (True, "landing")
        assert wait_for(lambda: _phase_is(obs, 2, "landed"), 60, 0.2), _state(obs, 2)
        ok, msg = _cmd(obs, 2, "resume")
        assert not ok and "cannot resume" in msg
        for u in (1, 2):  # every command above went through the flight's transition table, none against it
            assert wait_for(lambda u=u: json.loads((tmp_path / f"uav{u}.json").read_text())["agent"]["commands"] >= 2, 3, 0.2)
            assert json.loads((tmp_path / f"uav{u}.json").read_text())["agent"]["illegal_transitions"] == 0
    finally:
        qgc.close()
        gcs2.close()
        obs.close()
        for p in procs:
            stop_process(p)
