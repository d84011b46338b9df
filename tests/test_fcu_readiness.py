"""The agent's FCU link on the frames of real ArduCopter 4.7 and PX4 1.16 firmware, over real UDP.

Each test sends a capture's vehicle frames (tests/captures.py) from a UDP socket to an
:class:`~uav_stack.fcu_link.FcuLink` listening with ``udpin``, as the firmware sent them, and
reads the link's clock from the frame being replayed (its time in the capture). What the link
makes of them is held to what the capture's summary says the firmware did: when it had a position,
when its pre-arm checks passed, why it refused to arm, what it is; and what the start-up contract
asks of each (factory-default ArduCopter streams nothing; PX4 streams unasked).
"""

from __future__ import annotations

import socket
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import pytest

from tests import captures
from tests.conftest import free_port, wait_for
from uav_stack.fcu_link import FcuLink
from uav_stack.mav import mavlink as M


@dataclass
class Replay:
    """A capture's vehicle frames sent to a link; ``t`` is the capture's time (s since the firmware started)."""

    link: FcuLink
    sent: list[Any] = field(default_factory=list)  # what the link sent back (to the "firmware")
    t: float = 0.0


@contextmanager
def replayed(autopilot: str, capture: str, summary_t0: Callable[[dict[str, Any]], float]) -> Iterator[
        Callable[[float], Replay]]:
    """``run(until)`` replays the capture's vehicle frames up to capture time ``until`` (s) and returns the Replay."""
    summary = captures.summary(autopilot, capture)
    frames = [f for f in captures.frames(autopilot, capture) if f.msg.get_srcSystem() == 1]
    first_hb = next(f.t for f in frames if f.msg.get_type() == "HEARTBEAT")
    origin = first_hb - summary_t0(summary)  # wall time of the capture's t = 0
    port = free_port(socket.SOCK_DGRAM)
    fw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    fw.bind(("127.0.0.1", 0))
    fw.setblocking(False)
    rep = Replay(FcuLink(f"udpin:127.0.0.1:{port}", source_system=1, clock=lambda: rep.t))
    rep.link.open()
    parser = M.MAVLink(None)
    it = iter(frames)

    def run(until: float) -> Replay:
        for f in it:
            rep.t = f.t - origin
            fw.sendto(f.raw, ("127.0.0.1", port))
            rep.link.poll()
            rep.link.service()
            while True:
                try:
                    data = fw.recv(65535)
                except BlockingIOError:
                    break
                rep.sent += parser.parse_buffer(data) or []
            if rep.t >= until:
                break
        return rep

    try:
        yield run
    finally:
        rep.link.close()
        fw.close()


def _ardupilot_t0(s: dict[str, Any]) -> float:
    return float(s["first_of_each_rx_type"]["HEARTBEAT"]["t"])


def _px4_t0(s: dict[str, Any]) -> float:
    return float(s["first_heartbeat_t"])


def test_arducopter_has_no_position_until_its_ekf_uses_gps() -> None:
    """GLOBAL_POSITION_INT is all zeros before the GPS (t < 10 s), then real while the EKF is in
    constant-position mode (flags 167), and a position only once it uses GPS (flags 831, t = 41.8)."""
    s = captures.summary(captures.ARDUPILOT, "arm_too_early")
    ekf = {e["value"]: e["t"] for e in s["field_transitions"]["EKF_STATUS_REPORT.flags"]}
    first_nonzero = s["global_position_int_first_nonzero_latlon"]["t"]
    with replayed(captures.ARDUPILOT, "arm_too_early", _ardupilot_t0) as run:
        st = run(first_nonzero - 0.3).link.state
        assert not st.has_position and "latitude and longitude 0" in st.no_position
        st = run(ekf[831] - 0.5).link.state
        assert not st.has_position and "does not use GPS" in st.no_position and "0xa7" in st.no_position
        assert "constant-position mode" in st.no_position
        assert st.gps_fix == 6  # the GPS had its fix long before: the EKF decides
        rep = run(ekf[831] + 1.0)
        assert rep.link.state.has_position and rep.link.state.no_position == ""
        assert abs(rep.link.state.lat - s["global_position_int_last"]["lat"] * 1e-7) < 1e-3
        c = rep.link.counts
        assert c["no_position"] > 50 and c["foreign_id"] == 0 and c["unknown_id"] == 0 and c["bad"] == 0


def test_arducopter_pre_arm_bit_and_refusal_texts() -> None:
    s = captures.summary(captures.ARDUPILOT, "arm_too_early")
    health = s["field_transitions"]["SYS_STATUS.onboard_control_sensors_health"]
    ready_at = next(h["t"] for h in health if h["value"] & M.MAV_SYS_STATUS_PREARM_CHECK)
    with replayed(captures.ARDUPILOT, "arm_too_early", _ardupilot_t0) as run:
        st = run(ready_at - 1.0).link.state
        assert st.prearm_ok is False
        reasons = st.reasons_since(0.0)
        for text in ("Arm: Need Alt Estimate", "Arm: AHRS: waiting for home", "Arm: Need Position Estimate",
                     "PreArm: Need Position Estimate"):
            assert text in reasons
        assert not any("EKF3 IMU0 is using GPS" in r for r in reasons)  # INFO texts are not reasons
        assert run(ready_at + 0.5).link.state.prearm_ok is True


def test_px4_after_landing_sits_in_offboard_not_armable_and_says_why() -> None:
    """PX4 returns to OFFBOARD after disarming, its pre-arm bit cleared; the re-arm is refused with
    an EVENT only; HOLD makes it armable again (t = 62.5)."""
    s = captures.summary(captures.PX4, "takeoff_offboard_land")
    rearm = s["immediate_rearm_ack"]["t"]
    with replayed(captures.PX4, "takeoff_offboard_land", _px4_t0) as run:
        st = run(30.0).link.state
        assert st.has_position and st.prearm_ok is True and st.armed
        st = run(rearm + 0.5).link.state
        assert st.mode == "OFFBOARD" and not st.armed and st.prearm_ok is False
        reasons = st.reasons_since(rearm - 0.1)
        assert reasons == ["commander_arm_denied_resolve_failures (Arming denied: Resolve system health failures first)"]
        assert "check_modes_offboard_signal (No offboard signal)" in st.px4_checks
        st = run(s["arm_after_hold_ack"]["t"] - 0.1).link.state
        assert st.mode == "HOLD" and st.prearm_ok is True
        c = run(1e9).link.counts
        assert c["foreign_id"] == 0 and c["unknown_id"] == 0 and c["bad"] == 0


def test_px4_position_only_once_its_estimator_has_one() -> None:
    s = captures.summary(captures.PX4, "boot_passive")
    flags = s["field_change_timelines"]["ESTIMATOR_STATUS"]
    good = next(f["t"] for f in flags if f["flags"] & M.ESTIMATOR_POS_HORIZ_ABS)
    with replayed(captures.PX4, "boot_passive", _px4_t0) as run:
        st = run(good - 0.05).link.state
        assert not st.has_position
        st = run(good + 1.0).link.state
        assert st.has_position  # PX4 also sets CONST_POS_MODE while disarmed: that is not "no GPS" on PX4
        assert st.estimator_flags & M.ESTIMATOR_CONST_POS_MODE


@pytest.mark.parametrize(("autopilot", "capture", "version"), [
    (captures.ARDUPILOT, "stream_requests", "4.7.0-dev (2598e9d4)"),
    (captures.PX4, "stream_requests", "1.16.0"),
])
def test_the_autopilots_version(autopilot: str, capture: str, version: str) -> None:
    with replayed(autopilot, capture, _ardupilot_t0 if autopilot == captures.ARDUPILOT else _px4_t0) as run:
        assert run(1e9).link.state.version.startswith(version)


def _asked(sent: list[Any]) -> dict[str, float]:
    """SET_MESSAGE_INTERVAL requests among what the link sent: message name -> Hz."""
    out = {}
    for m in sent:
        if m.get_type() == "COMMAND_LONG" and m.command == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            out[M.mavlink_map[int(m.param1)].msgname] = 1e6 / m.param2
    return out


def test_factory_default_arducopter_is_asked_for_everything_the_agent_needs() -> None:
    """boot_passive: ArduCopter streams only HEARTBEAT. The link asks for each message, a few times
    (the recording does not answer), falls back to REQUEST_DATA_STREAM and says what it waits for."""
    with replayed(captures.ARDUPILOT, "boot_passive", _ardupilot_t0) as run:
        rep = run(12.0)
        assert rep.link.contract.waiting_for() == "no GLOBAL_POSITION_INT from the autopilot: requested at 10 Hz, 3 tries"
        rep = run(1e9)  # 90 s: after giving up, asked again every 30 s
        assert rep.link.contract.waiting_for() == "no GLOBAL_POSITION_INT from the autopilot: requested at 10 Hz, 5 tries"
    asked = _asked(rep.sent)
    assert asked["GLOBAL_POSITION_INT"] == pytest.approx(10.0)
    assert {"SYS_STATUS", "EXTENDED_SYS_STATE", "HOME_POSITION", "GPS_RAW_INT", "EKF_STATUS_REPORT"} <= set(asked)
    streams = {m.req_stream_id for m in rep.sent if m.get_type() == "REQUEST_DATA_STREAM"}
    assert M.MAV_DATA_STREAM_POSITION in streams and M.MAV_DATA_STREAM_EXTENDED_STATUS in streams
    assert any(m.get_type() == "COMMAND_LONG" and m.command == M.MAV_CMD_REQUEST_MESSAGE
               and int(m.param1) == M.MAVLINK_MSG_ID_AUTOPILOT_VERSION for m in rep.sent)


def test_px4_streaming_unasked_is_left_alone() -> None:
    """PX4's onboard link streams GLOBAL_POSITION_INT at 50 Hz, SYS_STATUS, GPS_RAW_INT, ESTIMATOR_STATUS...
    unasked: the link asks for none of them, and never sends REQUEST_DATA_STREAM (PX4 ignores it)."""
    with replayed(captures.PX4, "boot_passive", _px4_t0) as run:
        rep = run(1e9)
    asked = _asked(rep.sent)
    for name in ("GLOBAL_POSITION_INT", "SYS_STATUS", "GPS_RAW_INT", "ESTIMATOR_STATUS", "EXTENDED_SYS_STATE"):
        assert name not in asked, name
        assert rep.link.contract.streams[name].status == "ok", name
    assert not any(m.get_type() == "REQUEST_DATA_STREAM" for m in rep.sent)
    assert rep.link.contract.waiting_for() == ""


def test_only_other_systems_and_components_are_foreign_not_the_fcus_own_unknown_ids() -> None:
    """A frame of the pinned FCU whose id mrswarm's dialect lacks is the FCU's (``unknown_id``); a frame
    of another system or component, known id or not, is foreign (``foreign_id``)."""
    port = free_port(socket.SOCK_DGRAM)
    link = FcuLink(f"udpin:127.0.0.1:{port}", source_system=1).open()
    fw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    fw.bind(("127.0.0.1", 0))

    def unknown_frame(sysid: int, compid: int, msgid: int = 0xABCDE) -> bytes:
        payload = b"\x01\x02\x03"
        return bytes([0xFD, len(payload), 0, 0, 0, sysid, compid]) + msgid.to_bytes(3, "little") + payload + b"\x00\x00"

    try:
        fcu = M.MAVLink(None, 1, 1)
        other = M.MAVLink(None, 1, 154)  # a gimbal of the same system
        for frame in (fcu.heartbeat_encode(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 3).pack(fcu),
                      unknown_frame(1, 1), unknown_frame(1, 1), unknown_frame(7, 1), unknown_frame(1, 154),
                      other.heartbeat_encode(M.MAV_TYPE_GIMBAL, M.MAV_AUTOPILOT_INVALID, 0, 0, 3).pack(other),
                      fcu.ahrs2_encode(0, 0, 0, 0, 0, 0).pack(fcu)):
            fw.sendto(frame, ("127.0.0.1", port))
        assert wait_for(lambda: (link.poll(), link.counts["rx"] >= 7)[1], 5.0), link.counts
        c = link.counts
        assert c["unknown_id"] == 2 and c["foreign_id"] == 3 and c["bad"] == 0
        assert link.rx_types["AHRS2"] == 1  # ArduPilot's own message, of the FCU: neither
    finally:
        link.close()
        fw.close()


def test_a_virtual_fcu_slower_than_real_time_is_not_asked_again_for_its_own_rates() -> None:
    """At RTF 0.5 the virtual FCU's 10 Hz GLOBAL_POSITION_INT arrives 5 times a wall second: the rate is
    the FCU's time's, so the contract asks for nothing. (The PX4 flavour streams it at PX4's 50 Hz from
    boot: set to 10 Hz here, as a configured link.)"""
    import time

    from tests.fcu_helpers import FcuThread
    from uav_stack.fcu import FcuConfig, VehicleConfig
    from uav_stack.geo import GeoPoint

    with FcuThread(FcuConfig([VehicleConfig(sysid=1, home=GeoPoint(46.6, 14.2, 446.0))], target_rtf=0.5,
                             stream_rates={"GLOBAL_POSITION_INT": 10.0})) as ft:  # fmt: skip
        link = FcuLink(f"udpout:{ft.addrs[0][0]}:{ft.addrs[0][1]}").open()
        try:
            end = time.monotonic() + 9.0
            while time.monotonic() < end:
                link.poll()
                link.service()
                time.sleep(0.05)
            gpi = link.contract.streams["GLOBAL_POSITION_INT"]
            assert gpi.status == "ok" and gpi.ack == "" and 4.0 < gpi.hz < 6.0, gpi
            assert link.rtf.value == pytest.approx(0.5, abs=0.1)
        finally:
            link.close()
