"""MAVLink protocol surface over real UDP: discovery, streams, commands, params, missions,
robustness against bad input. The FCU runs its own run() loop in a background thread."""

from __future__ import annotations

import math
import struct
import time

import pytest

from tests.fcu_helpers import FcuThread, MavClient
from uav_stack.fcu import FcuConfig, VehicleConfig
from uav_stack.fcu import px4 as px4fw
from uav_stack.fcu.modes import px4_custom_mode
from uav_stack.mav import mavlink as M
from uav_stack.mav import mavutil

NAN = math.nan
HOME = (47.397742, 8.545594, 488.0)


def cfg(flavour: str = "px4", **params: float) -> FcuConfig:
    from uav_stack.geo import GeoPoint

    return FcuConfig([VehicleConfig(sysid=1, home=GeoPoint(*HOME), flavour=flavour, params=dict(params))])


@pytest.fixture
def px4():
    with FcuThread(cfg()) as ft, MavClient(ft.addrs[0]) as c:
        c.heartbeat()
        assert c.recv_match("HEARTBEAT", 3.0) is not None
        yield ft, c


def test_heartbeat_streams_and_px4_mode_encoding(px4) -> None:
    ft, c = px4
    hb = c.latest["HEARTBEAT"]
    assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
    assert hb.type == M.MAV_TYPE_QUADROTOR and hb.autopilot == M.MAV_AUTOPILOT_PX4
    assert hb.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED and not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.custom_mode == px4_custom_mode(4, 3) == 50593792  # AUTO.LOITER (Hold)
    assert mavutil.interpret_px4_mode(hb.base_mode, hb.custom_mode) == "LOITER"
    assert hb.system_status == M.MAV_STATE_STANDBY
    c.counts.clear()
    c.drain(2.0)
    n = c.counts
    # PX4's onboard-link streams at its rates (never faster than the 50 Hz physics), nothing else periodic
    for name, (hz, _) in px4fw.STREAMS.items():
        want = 2.0 * min(hz, ft.fcu.config.physics_hz)
        assert 0.8 * want - 1.5 <= n.get(name, 0) <= 1.2 * want + 1.5, (name, n)
    assert 1 <= n["HEARTBEAT"] <= 3 and "NAMED_VALUE_FLOAT" not in n and "STATUSTEXT" not in n
    ss = c.latest["SYS_STATUS"]
    for bit in (M.MAV_SYS_STATUS_SENSOR_GPS, M.MAV_SYS_STATUS_PREARM_CHECK, M.MAV_SYS_STATUS_GEOFENCE):
        assert ss.onboard_control_sensors_health & bit and ss.onboard_control_sensors_present & bit
    assert ss.battery_remaining == 100
    gp = c.latest["GLOBAL_POSITION_INT"]
    assert gp.lat == round(HOME[0] * 1e7) and gp.lon == round(HOME[1] * 1e7)
    assert abs(gp.alt - HOME[2] * 1000) <= 1 and abs(gp.relative_alt) <= 1
    assert c.latest["EXTENDED_SYS_STATE"].landed_state == M.MAV_LANDED_STATE_ON_GROUND
    assert c.latest["GPS_RAW_INT"].fix_type == M.GPS_FIX_TYPE_3D_FIX


def test_request_message_autopilot_version_home_and_unknown(px4) -> None:
    _, c = px4
    # PX4 sends the message just before its ACK
    assert c.command_long(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == M.MAV_RESULT_ACCEPTED
    av = c.latest.get("AUTOPILOT_VERSION")
    assert av is not None and av.flight_sw_version == px4fw.FLIGHT_SW_VERSION
    for cap in (M.MAV_PROTOCOL_CAPABILITY_MAVLINK2, M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT,
                M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED,
                M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE):
        assert av.capabilities & cap
    n = c.counts["AUTOPILOT_VERSION"]
    assert c.command_long(M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1) == M.MAV_RESULT_ACCEPTED
    assert c.counts["AUTOPILOT_VERSION"] == n + 1
    assert c.command_long(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION) == M.MAV_RESULT_ACCEPTED
    home = c.latest.get("HOME_POSITION")
    assert home is not None and home.latitude == round(HOME[0] * 1e7)
    assert c.command_long(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE) == M.MAV_RESULT_ACCEPTED
    assert c.command_long(M.MAV_CMD_REQUEST_MESSAGE, 9999) == M.MAV_RESULT_DENIED


def test_unknown_command_unsupported_and_ack_addressing(px4) -> None:
    _, c = px4
    c.send(c.mav.command_long_encode(1, 1, 31337, 0, 0, 0, 0, 0, 0, 0, 0))
    ack = c.recv_match("COMMAND_ACK", 2.0)
    assert ack is not None and ack.command == 31337 and ack.result == M.MAV_RESULT_UNSUPPORTED
    assert (ack.target_system, ack.target_component) == (245, 190)
    assert c.command_int(M.MAV_CMD_DO_FLIGHTTERMINATION, M.MAV_FRAME_GLOBAL_INT, 1) == M.MAV_RESULT_UNSUPPORTED
    # addressed to another system: ignored, no ACK
    c.send(c.mav.command_long_encode(7, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
    assert c.recv_match("COMMAND_ACK", 0.5) is None


def test_nan_and_int32_max_params_are_unset(px4) -> None:
    ft, c = px4
    # MAVSDK style: every unused param NaN
    unset = (NAN,) * 6
    assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, *unset) == M.MAV_RESULT_ACCEPTED
    assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 0, *unset) == M.MAV_RESULT_ACCEPTED
    assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, NAN, *unset) == M.MAV_RESULT_DENIED  # p1 NaN: nothing to do
    assert c.command_long(M.MAV_CMD_DO_SET_MODE, NAN, *unset) == M.MAV_RESULT_DENIED
    assert c.command_long(M.MAV_CMD_REQUEST_MESSAGE, NAN, *unset) == M.MAV_RESULT_DENIED
    assert c.command_long(M.MAV_CMD_SET_MESSAGE_INTERVAL, NAN, *unset) == M.MAV_RESULT_DENIED
    assert c.command_long(M.MAV_CMD_DO_CHANGE_SPEED, NAN, *unset) == M.MAV_RESULT_ACCEPTED
    # COMMAND_INT with INT32_MAX x/y and NaN z: reposition keeps the position (but needs arming)
    i32 = 2**31 - 1
    assert c.command_int(M.MAV_CMD_DO_REPOSITION, M.MAV_FRAME_GLOBAL_INT, x=i32, y=i32) == M.MAV_RESULT_DENIED
    assert ft.fcu.stats.handler_errors == 0
    assert ft.alive


def test_malformed_datagrams_are_counted_and_dropped(px4) -> None:
    ft, c = px4
    good = c.mav.command_long_encode(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, 242, 0, 0, 0, 0, 0, 0).pack(c.mav)
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    before = ft.fcu.stats.bad_datagrams
    for junk in (b"", b"\x00" * 3, b"hello world", bytes(bad_crc), good[:-4], b"\xfd" + b"\xff" * 300,
                 bytes(range(256)) * 4):  # fmt: skip
        c.send_raw(junk)
    # a valid message still works afterwards, also glued behind garbage
    c.send_raw(b"garbage" + good)
    assert c.recv_match("COMMAND_ACK", 2.0, lambda m: m.command == M.MAV_CMD_REQUEST_MESSAGE) is not None
    assert c.command_long(M.MAV_CMD_REQUEST_MESSAGE, 242) == M.MAV_RESULT_ACCEPTED
    assert ft.fcu.stats.bad_datagrams - before >= 6
    assert ft.fcu.stats.handler_errors == 0
    assert ft.alive


def test_hostile_values_do_not_break_handlers(px4) -> None:
    ft, c = px4
    # structurally valid messages with values no handler expects: huge counts, NaN everywhere
    c.send(c.mav.mission_count_encode(1, 1, 65535, 0))
    c.send(c.mav.set_position_target_local_ned_encode(0, 1, 1, 1, 0, *([NAN] * 11)))
    c.send(c.mav.set_position_target_global_int_encode(0, 1, 1, 6, 0, 2**31 - 1, -(2**31), NAN, *([NAN] * 8)))
    c.send(c.mav.param_set_encode(1, 1, b"MPC_XY_CRUISE", NAN, M.MAV_PARAM_TYPE_REAL32))
    c.send(c.mav.param_set_encode(1, 1, bytes([0xFF] * 16), 1.0, M.MAV_PARAM_TYPE_REAL32))
    c.send(c.mav.set_mode_encode(1, 0xFF, 0xFFFFFFFF))
    c.send(c.mav.command_int_encode(1, 1, 99, M.MAV_CMD_DO_REPOSITION, 0, 0, *([NAN] * 4), 0, 0, NAN))
    assert c.command_long(M.MAV_CMD_REQUEST_MESSAGE, 242) == M.MAV_RESULT_ACCEPTED
    assert c.param_read("MPC_XY_CRUISE").param_value == pytest.approx(5.0)
    assert ft.fcu.stats.handler_errors == 0
    assert ft.fcu.truth().mode == "HOLD" and ft.alive


def test_handler_exception_is_logged_counted_and_vehicle_keeps_flying(px4, caplog) -> None:
    ft, c = px4

    def broken(v, m):  # a host-registered handler with a bug
        raise RuntimeError("boom")

    ft.fcu.handlers["DEBUG"] = broken
    c.send(c.mav.debug_encode(0, 1, 2.0))
    assert c.command_long(M.MAV_CMD_REQUEST_MESSAGE, 242) == M.MAV_RESULT_ACCEPTED
    assert c.wait(lambda: ft.fcu.stats.handler_errors >= 1, 2.0)
    assert ft.fcu.stats.handler_errors_by_type["DEBUG"] == 1
    assert any("boom" in r.getMessage() or (r.exc_info and "boom" in str(r.exc_info[1])) for r in caplog.records)
    assert c.recv_match("HEARTBEAT", 2.0) is not None and ft.alive


def test_set_message_interval_changes_rates(px4) -> None:
    _, c = px4
    us = 1e6 / 25
    assert c.command_long(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, us) == M.MAV_RESULT_ACCEPTED
    assert c.command_long(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, -1) == M.MAV_RESULT_ACCEPTED
    assert c.command_long(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, 2e5) == M.MAV_RESULT_ACCEPTED
    c.drain(0.3)
    c.counts.clear()
    c.drain(2.0)
    assert 40 <= c.counts.get("ATTITUDE", 0) <= 60
    assert c.counts.get("GLOBAL_POSITION_INT", 0) == 0
    assert 8 <= c.counts.get("ATTITUDE_QUATERNION", 0) <= 12
    assert c.command_long(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 0) == M.MAV_RESULT_ACCEPTED
    assert c.recv_match("GLOBAL_POSITION_INT", 1.0) is not None  # back to the default
    assert c.command_long(M.MAV_CMD_GET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE) == M.MAV_RESULT_ACCEPTED
    mi = c.latest.get("MESSAGE_INTERVAL")  # (just before the ACK)
    assert mi is not None and mi.interval_us == 40000
    assert c.command_long(M.MAV_CMD_SET_MESSAGE_INTERVAL, 12345, 1000) == M.MAV_RESULT_DENIED


def test_params_list_read_set_bytewise(px4) -> None:
    ft, c = px4
    c.send(c.mav.param_request_list_encode(1, 1))
    got = {}
    deadline = time.monotonic() + 3
    while time.monotonic() < deadline:
        m = c.recv_match("PARAM_VALUE", 0.5)
        if m is None:
            break
        got[m.param_id] = m
        if len(got) == m.param_count + 1:  # (and _HASH_CHECK)
            break
    hash_check = got.pop("_HASH_CHECK")  # PX4 starts the list with it (index 65535)
    assert hash_check.param_index == 65535 and hash_check.param_type == M.MAV_PARAM_TYPE_UINT32
    count = next(iter(got.values())).param_count
    assert len(got) == count == 901  # PX4 1.16's parameters, every one
    assert sorted(m.param_index for m in got.values()) == list(range(count))
    for name in ("MIS_TAKEOFF_ALT", "MPC_XY_CRUISE", "COM_OF_LOSS_T", "NAV_DLL_ACT", "GF_ACTION", "MAV_SYS_ID"):
        assert name in got
    assert got["MIS_TAKEOFF_ALT"].param_value == pytest.approx(2.5)
    assert "SIM_OFB_STREAM_T" not in got  # the emulator's own settings are not on the list
    # INT32 parameters travel bytewise (PX4)
    sysid = got["MAV_SYS_ID"]
    assert sysid.param_type == M.MAV_PARAM_TYPE_INT32
    assert struct.unpack("<i", struct.pack("<f", sysid.param_value))[0] == 1
    # read by index and by name
    idx = got["MPC_XY_CRUISE"].param_index
    assert c.param_read(index=idx).param_id == "MPC_XY_CRUISE"
    # set a float and a bytewise int; bad values are refused and the old value echoed
    assert c.param_set("MIS_TAKEOFF_ALT", 1.2).param_value == pytest.approx(1.2)
    gf = struct.unpack("<f", struct.pack("<i", 3))[0]
    v = c.param_set("GF_ACTION", gf, M.MAV_PARAM_TYPE_INT32)
    assert struct.unpack("<i", struct.pack("<f", v.param_value))[0] == 3
    assert c.param_set("MPC_XY_CRUISE", -4.0).param_value == pytest.approx(5.0)
    assert not c.statustexts  # (PX4 sends none on this link)
    # an unknown name: no answer at all
    assert c.param_set("NO_SUCH_PARAM", 1.0, timeout=0.5) is None and c.param_read("NO_SUCH_PARAM", timeout=0.5) is None
    assert ft.fcu.vehicles[0].settings.takeoff_alt == pytest.approx(1.2)


def test_mission_protocol_empty_upload_download_clear(px4) -> None:
    _, c = px4
    for mtype in (0, 1, 2):
        c.send(c.mav.mission_request_list_encode(1, 1, mtype))
        mc = c.recv_match("MISSION_COUNT", 2.0)
        assert mc is not None and mc.count == 0 and mc.mission_type == mtype
        assert (mc.target_system, mc.target_component) == (245, 190)
    # upload two items
    c.send(c.mav.mission_count_encode(1, 1, 2, 0))
    for seq in (0, 1):
        req = c.recv_match(("MISSION_REQUEST_INT", "MISSION_REQUEST"), 2.0)
        assert req is not None and req.seq == seq
        c.send(c.mav.mission_item_int_encode(1, 1, seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_WAYPOINT,
                                             0, 1, 0, 0, 0, NAN, 473977000 + seq, 85456000, 10.0))  # fmt: skip
    ack = c.recv_match("MISSION_ACK", 2.0)
    assert ack is not None and ack.type == M.MAV_MISSION_ACCEPTED
    c.send(c.mav.mission_request_list_encode(1, 1, 0))
    assert c.recv_match("MISSION_COUNT", 2.0).count == 2
    c.send(c.mav.mission_request_int_encode(1, 1, 1, 0))
    item = c.recv_match("MISSION_ITEM_INT", 2.0)
    assert item is not None and item.x == 473977001 and item.z == pytest.approx(10.0)
    c.send(c.mav.mission_clear_all_encode(1, 1, 0))
    assert c.recv_match("MISSION_ACK", 2.0).type == M.MAV_MISSION_ACCEPTED
    c.send(c.mav.mission_request_list_encode(1, 1, 0))
    assert c.recv_match("MISSION_COUNT", 2.0).count == 0


def test_timesync_ping_and_ftp_nak(px4) -> None:
    ft, c = px4
    c.send(c.mav.timesync_encode(0, 123456789))
    ts = c.recv_match("TIMESYNC", 2.0)
    assert ts is not None and ts.ts1 == 123456789 and ts.tc1 > 0
    assert abs(ts.tc1 / 1e9 - ft.fcu.sim_time) < 1.0  # sim clock
    c.send(c.mav.ping_encode(42, 7, 0, 0))
    p = c.recv_match("PING", 2.0)
    assert p is not None and (p.time_usec, p.seq, p.target_system, p.target_component) == (42, 7, 245, 190)
    payload = bytearray(251)
    payload[0:2] = (5).to_bytes(2, "little")
    payload[3] = 4  # OpenFileRO
    payload[4] = 16
    payload[12:28] = b"@PARAM/param.pck"
    c.send(c.mav.file_transfer_protocol_encode(0, 1, 1, payload))
    f = c.recv_match("FILE_TRANSFER_PROTOCOL", 2.0)
    assert f is not None
    r = bytes(f.payload)
    assert r[3] == 129 and r[5] == 4 and r[12] == 10  # NAK, for OpenFileRO, FileNotFound
    assert int.from_bytes(r[0:2], "little") == 6


def test_mavutil_udpout_client_and_second_peer() -> None:
    """A stock pymavlink connection (as MAVProxy/scripts use) sees the vehicle; peers are learned."""
    with FcuThread(cfg()) as ft:
        port = ft.addrs[0][1]
        m1 = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=245, source_component=190)
        m2 = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=200, source_component=190)
        try:
            for m in (m1, m2):
                m.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            hb = m1.recv_match(type="HEARTBEAT", blocking=True, timeout=3)
            assert hb is not None and hb.get_srcSystem() == 1
            assert m2.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=3) is not None
            m2.mav.command_long_send(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0)
            got = {}
            for _ in range(2):  # (PX4: the message, then the ACK)
                m = m2.recv_match(type=["AUTOPILOT_VERSION", "COMMAND_ACK"], blocking=True, timeout=3)
                assert m is not None
                got[m.get_type()] = m
            assert got["COMMAND_ACK"].target_system == 200 and "AUTOPILOT_VERSION" in got
            assert len(ft.fcu.vehicles[0].link.peers) == 2
        finally:
            m1.close()
            m2.close()


def test_static_remote_receives_stream_without_sending() -> None:
    import socket

    from uav_stack.geo import GeoPoint

    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    sink.settimeout(3.0)
    try:
        c = FcuConfig([VehicleConfig(sysid=3, home=GeoPoint(*HOME), remotes=(sink.getsockname(),))])
        with FcuThread(c):
            data, _ = sink.recvfrom(65535)
            msgs = M.MAVLink(None).parse_buffer(data)
            assert msgs and all(m.get_srcSystem() == 3 for m in msgs)
    finally:
        sink.close()


def _random_value(rng, ftype: str, n: int):
    def one():
        if ftype in ("float", "double"):
            return rng.choice([0.0, 1.0, -1.0, NAN, math.inf, -math.inf, 1e30, rng.uniform(-1e4, 1e4)])
        lo, hi = {"uint8_t": (0, 255), "int8_t": (-128, 127), "uint16_t": (0, 65535), "int16_t": (-32768, 32767),
                  "uint32_t": (0, 2**32 - 1), "int32_t": (-(2**31), 2**31 - 1), "uint64_t": (0, 2**64 - 1),
                  "int64_t": (-(2**63), 2**63 - 1)}[ftype]  # fmt: skip
        return rng.choice([lo, hi, 0, 1, rng.randint(lo, hi)])

    if ftype == "char":
        return bytes(rng.randrange(256) for _ in range(max(n, 1)))
    return [one() for _ in range(n)] if n else one()


def test_fuzzed_messages_never_break_the_vehicle() -> None:
    """Random field values (NaN, inf, extremes) in every message the FCU handles, both flavours."""
    import random

    rng = random.Random(20240611)
    focus = [M.MAVLINK_MSG_ID_COMMAND_LONG, M.MAVLINK_MSG_ID_COMMAND_INT, M.MAVLINK_MSG_ID_SET_MODE,
             M.MAVLINK_MSG_ID_PARAM_SET, M.MAVLINK_MSG_ID_PARAM_REQUEST_READ, M.MAVLINK_MSG_ID_MISSION_COUNT,
             M.MAVLINK_MSG_ID_MISSION_ITEM_INT, M.MAVLINK_MSG_ID_MISSION_ITEM, M.MAVLINK_MSG_ID_MISSION_REQUEST_INT,
             M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED, M.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT,
             M.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL, M.MAVLINK_MSG_ID_TIMESYNC, M.MAVLINK_MSG_ID_PING,
             M.MAVLINK_MSG_ID_MISSION_CLEAR_ALL, M.MAVLINK_MSG_ID_MISSION_REQUEST_LIST, M.MAVLINK_MSG_ID_HEARTBEAT]  # fmt: skip
    commands = [400, 22, 21, 20, 17, 176, 192, 178, 179, 410, 510, 511, 512, 520, 31337]
    from uav_stack.geo import GeoPoint

    c2 = FcuConfig([VehicleConfig(sysid=1, home=GeoPoint(*HOME)),
                    VehicleConfig(sysid=2, home=GeoPoint(*HOME), flavour="ardupilot")])  # fmt: skip
    with FcuThread(c2) as ft:
        clients = [MavClient(a, target_sysid=i + 1) for i, a in enumerate(ft.addrs)]
        try:
            sent = 0
            for k in range(2500):
                c = rng.choice(clients)
                mid = rng.choice(focus) if rng.random() < 0.85 else rng.choice(list(M.mavlink_map))
                cls = M.mavlink_map[mid]
                lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))  # wire order
                kw = {f: _random_value(rng, t, lengths[f]) for f, t in zip(cls.fieldnames, cls.fieldtypes, strict=True)}
                if "target_system" in kw and rng.random() < 0.8:
                    kw["target_system"] = c.target_sysid
                if "target_component" in kw and rng.random() < 0.8:
                    kw["target_component"] = 1
                if "command" in kw and mid in (M.MAVLINK_MSG_ID_COMMAND_LONG, M.MAVLINK_MSG_ID_COMMAND_INT):
                    kw["command"] = rng.choice(commands)
                try:
                    buf = cls(**kw).pack(c.mav)
                except Exception:  # noqa: BLE001 - the generator made a value pymavlink cannot pack
                    continue
                c.send_raw(buf)
                sent += 1
                if k % 100 == 0:
                    c.drain(0.02)
            assert sent > 2000
            time.sleep(0.5)
            assert ft.fcu.stats.handler_errors == 0, dict(ft.fcu.stats.handler_errors_by_type)
            assert ft.alive
        finally:
            for c in clients:
                c.close()
        for i, addr in enumerate(ft.addrs):
            with MavClient(addr, target_sysid=i + 1) as fresh:
                assert fresh.command_long(M.MAV_CMD_REQUEST_MESSAGE, 242) == M.MAV_RESULT_ACCEPTED


def test_a_turned_down_link_carries_only_what_is_wanted() -> None:
    """streams.turned_down: the FCU configured as a companion turns a PX4 down (every unasked stream off)."""
    from uav_stack.fcu.streams import turned_down

    wanted = {"GLOBAL_POSITION_INT": 10.0, "SYS_STATUS": 1.0, "AHRS2": 4.0}  # (AHRS2: not a PX4 message)
    rates = turned_down("px4", wanted)
    assert rates["GLOBAL_POSITION_INT"] == 10.0 and rates["ATTITUDE"] == 0.0 and "AHRS2" not in rates
    assert turned_down("ardupilot", wanted) == wanted
    with FcuThread(FcuConfig([VehicleConfig(sysid=1)], stream_rates=rates)) as ft, MavClient(ft.addrs[0]) as c:
        c.heartbeat()
        c.drain(2.0)
        assert {n for n, k in c.counts.items() if k > 1} == {"GLOBAL_POSITION_INT", "SYS_STATUS", "HEARTBEAT"}, c.counts
        assert 16 <= c.counts["GLOBAL_POSITION_INT"] <= 24


def test_ardupilot_takes_no_nan_where_it_makes_integers() -> None:
    """A real ArduCopter 4.7 SITL stops (floating-point trap) on a COMMAND_LONG with NaN in param 5 or 6,
    which it turns into COMMAND_INT's integers: the virtual one leaves such a command unanswered and counts it,
    and takes the same command with 0 there."""
    nan = float("nan")
    with FcuThread(cfg(flavour="ardupilot")) as ft, MavClient(ft.addrs[0]) as c:
        assert c.command_long(M.MAV_CMD_SET_MESSAGE_INTERVAL, 33, 100000, 0, 0, nan, nan, 0, timeout=1.0) is None
        assert ft.fcu.stats.nan_integer_params == 1
        assert c.command_long(M.MAV_CMD_SET_MESSAGE_INTERVAL, 33, 100000) == M.MAV_RESULT_ACCEPTED
