"""The PX4 flavour against recordings of a real PX4 1.16 SIH SITL (tests/captures.py): from factory defaults
it answers on its onboard link as the firmware does, over real UDP MAVLink, on the firmware's own boot
timeline.

Each test sends what the recorder sent in one capture (its summary's marks say what and when; where the
recorder waited for the vehicle, the test waits for the same condition) and holds the emulator to what the
real firmware answered: message types and rates from boot and after each request, acknowledgements, mode
numbers and transitions, events instead of texts, parameter names and encodings. The sim runs faster
than real time, with 100 Hz physics so that ATTITUDE can stream at PX4's 100 Hz.
"""

from __future__ import annotations

import math
import struct

import pytest

from tests import captures
from tests.fcu_conformance import (
    Replay,
    assert_heartbeat_rate,
    assert_rates_like,
    capture_acks,
    capture_heartbeats,
    rate_windows,
    transitions_like,
)
from uav_stack.fcu import px4
from uav_stack.fcu.firmware import firmware
from uav_stack.fcu.modes import px4_custom_mode
from uav_stack.mav import mavlink as M

P = captures.PX4
NAN = math.nan
PHYSICS_HZ = 100.0
HOLD, TAKEOFF, OFFBOARD, POSCTL, LAND = (px4_custom_mode(4, 3), px4_custom_mode(4, 2), px4_custom_mode(6),
                                         px4_custom_mode(3), px4_custom_mode(4, 6))  # fmt: skip


def _summary(capture: str) -> dict:
    return captures.summary(P, capture)


def _mark(capture: str, starts: str) -> float:
    return next(float(m["t"]) for m in _summary(capture)["marks"] if m["label"].startswith(starts))


def _events(capture: str) -> list[tuple[float, int]]:
    return [(e["t"], e["id"]) for e in _summary(capture)["events"]]


def _health(ids: list[int]) -> set[int]:
    return {e.id for report in px4.HEALTH_REPORTS.values() for e in report} & set(ids)


def _command(r: Replay, command: int, *params: float) -> int:
    """Send a COMMAND_LONG and wait for its (first) ACK; the result."""
    n = len(r.of("COMMAND_ACK"))
    p = [float(x) for x in params] + [0.0] * (7 - len(params))
    r.send(r.client.mav.command_long_encode(1, 1, command, 0, *p))
    assert r.wait_for(lambda: len(r.of("COMMAND_ACK")) > n, 2.0), f"no ACK for command {command}"
    return int(r.of("COMMAND_ACK")[n][1].result)


def test_it_streams_its_onboard_set_from_boot_some_before_the_first_heartbeat() -> None:
    s = _summary("boot_passive")
    with Replay(P, rtf=2, physics_hz=PHYSICS_HZ) as r:
        r.until(s["duration_s"])
    for label, t0, t1, rates in rate_windows(P, "boot_passive"):
        assert_rates_like(rates, r.rates(t0, t1), t1 - t0, label)
    assert_heartbeat_rate(r, 10.0, s["duration_s"])
    assert {m.get_type() for _, m in r.rx} == set(s["rx_message_types"])
    # each message starts when the firmware starts it: GPS_RAW_INT, IMU and local position before the heartbeat
    for name, x in s["rx_message_types"].items():
        assert abs(r.of(name)[0][0] - x["first_t"]) < 0.2, (name, r.of(name)[0][0], x["first_t"])
    assert r.of("GPS_RAW_INT")[0][0] < r.of("HEARTBEAT")[0][0]
    # no STATUSTEXT ever; GLOBAL_POSITION_INT never without a position (no zeros: it starts when valid)
    assert not r.of("STATUSTEXT")
    assert all(m.lat != 0 and m.lon != 0 for _, m in r.of("GLOBAL_POSITION_INT"))
    assert {m.fix_type for _, m in r.of("GPS_RAW_INT")} == {s["field_change_timelines"]["GPS_RAW_INT"][0]["fix_type"]}
    # HOLD from boot: UNINIT until the checks pass, then STANDBY
    transitions_like(capture_heartbeats(P, "boot_passive"), r.heartbeat_states(), t_tol=1.1)
    hb = r.of("HEARTBEAT")[0][1]
    assert (hb.type, hb.autopilot, hb.mavlink_version) == (M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 3)
    # the estimator's flags, the boot's events and its parameter changes
    want_flags = [x["flags"] for x in s["field_change_timelines"]["ESTIMATOR_STATUS"]]
    assert [v for _, v in r.field_changes("ESTIMATOR_STATUS", "flags")] == want_flags
    assert [m.id for _, m in r.of("EVENT")] == [i for _, i in _events("boot_passive")]
    assert [m.param_id for _, m in r.of("PARAM_VALUE")] == [row[1] for row in firmware("px4").boot_param_values]


def test_message_intervals_are_honoured_and_request_data_stream_ignored() -> None:
    s = _summary("stream_requests")
    with Replay(P, rtf=2, physics_hz=PHYSICS_HZ) as r:
        r.until(_mark("stream_requests", "SET_MESSAGE_INTERVAL batch"))
        for mid, us in ((33, 20000), (30, 40000), (242, 1000000), (245, 200000), (1, 500000)):
            assert _command(r, M.MAV_CMD_SET_MESSAGE_INTERVAL, mid, us) == M.MAV_RESULT_ACCEPTED
        for mid in (148, 242):
            assert _command(r, M.MAV_CMD_REQUEST_MESSAGE, mid) == M.MAV_RESULT_ACCEPTED
        assert _command(r, M.MAV_CMD_GET_MESSAGE_INTERVAL, 33) == M.MAV_RESULT_ACCEPTED
        r.until(_mark("stream_requests", "REQUEST_DATA_STREAM"))
        n_acks = len(r.of("COMMAND_ACK"))
        r.send(r.client.mav.request_data_stream_encode(1, 1, M.MAV_DATA_STREAM_ALL, 10, 1))
        r.send(r.client.mav.request_data_stream_encode(1, 1, M.MAV_DATA_STREAM_POSITION, 2, 1))
        r.until(_mark("stream_requests", "SET_MESSAGE_INTERVAL ATTITUDE -1"))
        assert len(r.of("COMMAND_ACK")) == n_acks  # REQUEST_DATA_STREAM: no ACK
        assert _command(r, M.MAV_CMD_SET_MESSAGE_INTERVAL, 30, -1) == M.MAV_RESULT_ACCEPTED
        assert _command(r, M.MAV_CMD_SET_MESSAGE_INTERVAL, 33, 0) == M.MAV_RESULT_ACCEPTED
        r.until(s["duration_s"])
    for label, t0, t1, rates in rate_windows(P, "stream_requests"):
        assert_rates_like(rates, r.rates(t0 + 0.1, t1), t1 - t0 - 0.1, label)
    assert r.acks() == capture_acks(P, "stream_requests")
    assert [(m.message_id, m.interval_us) for _, m in r.of("MESSAGE_INTERVAL")] == [(33, 20000)]
    av = r.of("AUTOPILOT_VERSION")[0][1]
    want = s["first_message_of_each_type"]["AUTOPILOT_VERSION"]["fields"]
    assert (av.flight_sw_version, av.capabilities) == (want["flight_sw_version"], want["capabilities"])
    assert list(av.flight_custom_version) == want["flight_custom_version"]
    assert not r.of("STATUSTEXT")


def test_arming_too_early_is_refused_with_an_event_only_then_it_arms_and_disarms_itself() -> None:
    s = _summary("arm_too_early")
    with Replay(P, rtf=2, physics_hz=PHYSICS_HZ) as r:
        for attempt in s["arm_attempts"]:
            r.until(attempt["t"])
            _command(r, M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        r.until(s["duration_s"])
    assert r.acks() == capture_acks(P, "arm_too_early")  # TEMPORARILY_REJECTED, then ACCEPTED
    assert not r.of("STATUSTEXT")
    notable = [(t, m.id) for t, m in r.of("EVENT") if m.id not in _health([m.id])]
    want = [(t, i) for t, i in _events("arm_too_early") if i not in _health([i])]
    assert [i for _, i in notable] == [i for _, i in want]  # logger, arm denied, armed by, disarmed by (no takeoff)
    t_armed = next(t for t, i in notable if i == px4.ARMED_BY.id)
    t_dis = next(t for t, i in notable if i == px4.DISARMED_PREFLIGHT.id)
    want_armed = next(t for t, i in want if i == px4.ARMED_BY.id)
    want_dis = next(t for t, i in want if i == px4.DISARMED_PREFLIGHT.id)
    assert abs((t_dis - t_armed) - (want_dis - want_armed)) < 0.5
    disarmed = next(m for _, m in r.of("EVENT") if m.id == px4.DISARMED_PREFLIGHT.id)
    assert bytes(disarmed.arguments[:1]) == px4.DISARMED_PREFLIGHT.args
    transitions_like(capture_heartbeats(P, "arm_too_early"), r.heartbeat_states())


def _setpoints(r: Replay, vn: float, ve: float, seconds: float) -> None:
    """Velocity setpoints (LOCAL_NED, type_mask 0x0DC7) at 10 Hz, as the recorder sent them."""
    end = r.now + seconds
    while r.now < end:
        r.send(r.client.mav.set_position_target_local_ned_encode(0, 1, 1, M.MAV_FRAME_LOCAL_NED, 0x0DC7, 0, 0, 0, vn, ve, 0,
                                                                 0, 0, 0, 0, 0))  # fmt: skip
        r.until(r.now + 0.1)


def test_takeoff_offboard_loss_land_then_back_in_offboard_refusing_to_arm_until_the_mode_changes() -> None:
    s = _summary("takeoff_offboard_land")
    with Replay(P, rtf=2, physics_hz=PHYSICS_HZ) as r:
        assert r.wait_for(lambda: bool(r.of("GLOBAL_POSITION_INT")), 10)  # "global position valid"
        while _command(r, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) != M.MAV_RESULT_ACCEPTED:
            r.until(r.now + 0.5)
        home_amsl = s["home_amsl_m_from_gpi"]
        assert _command(r, M.MAV_CMD_NAV_TAKEOFF, NAN, 0, 0, NAN, NAN, NAN, home_amsl + 10) == M.MAV_RESULT_ACCEPTED
        assert r.wait_for(lambda: r.of("GLOBAL_POSITION_INT")[-1][1].relative_alt > 9500, 30)
        r.until(r.now + 2.0)
        _setpoints(r, 0, 0, 1.5)
        r.send(r.client.mav.command_long_encode(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 129, 6, 0, 0, 0, 0, 0))
        _setpoints(r, 3, 0, 7.5)
        _setpoints(r, 0, 3, 7.5)
        t_stop = r.now
        r.until(t_stop + 3.0)  # setpoints stopped: the offboard failsafe
        intended = [m.intended_custom_mode for _, m in r.of("CURRENT_MODE", t_stop) if m.custom_mode == POSCTL]
        assert _command(r, M.MAV_CMD_NAV_LAND) == M.MAV_RESULT_ACCEPTED
        assert r.wait_for(lambda: not r.vehicle.armed, 60)
        r.until(r.now + 1.1)  # "DISARMED detected via heartbeat"
        rearm = _command(r, M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        r.until(r.now + 3.0)
        assert _command(r, M.MAV_CMD_DO_SET_MODE, 1, 4, 3) == M.MAV_RESULT_ACCEPTED
        r.until(r.now + 1.5)
        assert _command(r, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        r.until(r.now + 1.0)
        assert _command(r, M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == M.MAV_RESULT_ACCEPTED
        r.until(r.now + 3.0)
    # the firmware's modes, base_mode and system_status in its order: TAKEOFF, HOLD by itself at the altitude,
    # OFFBOARD, POSCTL (CRITICAL) when the setpoints stop, LAND, then OFFBOARD again, UNINIT, until HOLD
    transitions_like(capture_heartbeats(P, "takeoff_offboard_land"), r.heartbeat_states())
    assert rearm == s["immediate_rearm_ack"]["result"] == M.MAV_RESULT_TEMPORARILY_REJECTED
    # two identical ACKs for every DO_SET_MODE; the refused arm retries at boot aside, the firmware's ACKs
    def squash(acks: list[tuple[int, int]]) -> list[tuple[int, int]]:
        out: list[tuple[int, int]] = []
        for a in acks:
            if not (out and a == out[-1] == (M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_RESULT_TEMPORARILY_REJECTED)):
                out.append(a)
        return out
    assert squash(r.acks()) == squash(capture_acks(P, "takeoff_offboard_land"))
    assert r.acks().count((M.MAV_CMD_DO_SET_MODE, M.MAV_RESULT_ACCEPTED)) == 4
    # CURRENT_MODE keeps OFFBOARD as the intended mode through the failsafe
    assert intended and set(intended) == {OFFBOARD}
    # the events, in the firmware's order (its health reports aside); no STATUSTEXT
    def notable(ids: list[int]) -> list[int]:
        out: list[int] = []
        for i in ids:
            if i not in _health([i]) and not (out and i == out[-1] == px4.ARM_DENIED.id):
                out.append(i)
        return out
    assert notable([m.id for _, m in r.of("EVENT")]) == notable([i for _, i in _events("takeoff_offboard_land")])
    assert not r.of("STATUSTEXT")
    # landed_state: ON_GROUND, TAKEOFF, IN_AIR (when HOLD comes), LANDING, ON_GROUND
    want = [x["landed_state"] for x in s["field_change_timelines"]["EXTENDED_SYS_STATE"]]
    assert [v for _, v in r.field_changes("EXTENDED_SYS_STATE", "landed_state")] == want


def test_parameters_list_hash_first_int32_bytewise_and_echo_twice() -> None:
    s = _summary("params")
    fw = captures.json_file(P, "params", "params.json")["params"]
    with Replay(P, rtf=2, physics_hz=PHYSICS_HZ) as r:
        r.until(_mark("params", "PARAM_REQUEST_LIST"))
        t_list = r.now
        r.send(r.client.mav.param_request_list_encode(1, 1))
        r.until(_mark("params", "PARAM_SET MIS_TAKEOFF_ALT"))
        listed = r.of("PARAM_VALUE", t_list)
        r.send(r.client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 5.0, M.MAV_PARAM_TYPE_REAL32))
        r.until(_mark("params", "PARAM_SET NAV_DLL_ACT"))
        r.send(r.client.mav.param_set_encode(1, 1, b"NAV_DLL_ACT", struct.unpack("<f", struct.pack("<i", 2))[0],
                                             M.MAV_PARAM_TYPE_INT32))  # fmt: skip
        r.until(_mark("params", "PARAM_SET unknown"))
        t_unknown = r.now
        r.send(r.client.mav.param_set_encode(1, 1, b"NO_SUCH_PARAM", 1.0, M.MAV_PARAM_TYPE_REAL32))
        r.until(_mark("params", "PARAM_REQUEST_READ MIS_TAKEOFF_ALT"))
        quiet = r.of("PARAM_VALUE", t_unknown)
        r.send(r.client.mav.param_request_read_encode(1, 1, b"MIS_TAKEOFF_ALT", -1))
        r.until(_mark("params", "PARAM_REQUEST_READ NO_SUCH_PARAM"))
        t_read_unknown = r.now
        r.send(r.client.mav.param_request_read_encode(1, 1, b"NO_SUCH_PARAM", -1))
        r.until(s["duration_s"])
    # _HASH_CHECK first (index 65535, UINT32), then every parameter, INT32 bytewise
    first = listed[0][1]
    hc = s["hash_check"]
    assert (first.param_id, first.param_index, first.param_type) == ("_HASH_CHECK", hc["index"], hc["type"])
    assert struct.pack("<f", first.param_value).hex() == hc["raw_bytes_le_hex"]
    got = {m.param_id: m for _, m in listed[1:] if m.param_index != 65535}
    assert len(got) == s["param_count_reported"] and {m.param_count for m in got.values()} == {s["param_count_reported"]}
    for p in fw:
        if p["name"] == "_HASH_CHECK":
            continue
        m = got[p["name"]]
        assert (m.param_index, m.param_type) == (p["index"], p["type"]), p["name"]
        assert struct.pack("<f", m.param_value).hex() == p["raw_bytes_le_hex"], p["name"]
    dur = listed[-1][0] - listed[0][0]
    want_dur = s["list_last_t"] - _mark("params", "PARAM_REQUEST_LIST")
    assert 0.5 * want_dur < dur < 2.0 * want_dur, dur
    # PARAM_SET echoed twice; the unknown one gets nothing (neither set nor read)
    after = [(m.param_id, m.param_index, struct.pack("<f", m.param_value).hex()) for _, m in r.of("PARAM_VALUE", t_list + 3)]
    want_after = [(x["name"], x["index"], x["raw_bytes_le_hex"]) for x in s["param_value_after_list_phase"]]
    assert after == want_after
    assert not quiet and not r.of("PARAM_VALUE", t_read_unknown)
    assert r.vehicle.settings.takeoff_alt == pytest.approx(5.0) and r.vehicle.params.get("NAV_DLL_ACT") == 2


def test_mission_upload_asks_seq0_with_mission_request_then_request_int_and_repeats_item_reached() -> None:
    s = _summary("mission_upload")
    items = s["uploaded_items"]
    with Replay(P, rtf=2, physics_hz=PHYSICS_HZ) as r:
        r.until(_mark("mission_upload", "MISSION_COUNT"))
        t_up = r.now
        requests = r.upload([_item(r, it) for it in items])
        down = r.download(len(items))
        r.until(_mark("mission_upload", "armed") - 0.3)
        assert _command(r, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        assert _command(r, M.MAV_CMD_MISSION_START, 0, 3) == s["mission_start_ack"]["result"]
        assert r.wait_for(lambda: any(m.seq == 1 for _, m in r.of("MISSION_ITEM_REACHED")), 90)
        r.until(r.now + 5.0)
    assert requests == [("MISSION_REQUEST", 0)] + [("MISSION_REQUEST_INT", k) for k in range(1, len(items))]
    assert [m.type for _, m in r.of("MISSION_ACK", t_up) if m.get_srcSystem() == 1] == [s["upload_ack"]["type"]]
    for k, want in s["downloaded_items"].items():
        m = down[int(k)]
        assert (m.frame, m.command, m.current, m.x, m.y) == (want["frame"], want["command"], want["current"], want["x"],
                                                             want["y"]), k  # fmt: skip
    # MISSION_CURRENT: the total 65535 until there is a mission, then 4; mission_state always 0
    totals = [v for _, v in r.field_changes("MISSION_CURRENT", "total")]
    assert totals == [s["field_change_timelines"]["MISSION_CURRENT"][0]["total"], len(items)] == [65535, len(items)]
    assert {m.mission_state for _, m in r.of("MISSION_CURRENT")} == {0}
    # AUTO.MISSION with the events mission_execute and mission_climb_before_start
    assert any(m.custom_mode == px4_custom_mode(4, 4) for _, m in r.of("HEARTBEAT"))
    ids = [m.id for _, m in r.of("EVENT")]
    assert ids.index(px4.MISSION_EXECUTE.id) < ids.index(px4.MISSION_CLIMB.id)
    # MISSION_ITEM_REACHED repeated about once a second for the last item reached
    reached0 = [t for t, m in r.of("MISSION_ITEM_REACHED") if m.seq == 0]
    want0 = [x["t"] for x in s["mission_item_reached"] if x["seq"] == 0]
    gaps = [b - a for a, b in zip(reached0, reached0[1:], strict=False)]
    assert len(reached0) >= 3 and all(0.8 < g < 1.3 for g in gaps), gaps
    assert len(want0) >= 3


def _item(r: Replay, it: dict) -> object:
    """An uploaded item of the summary as the recorder's MISSION_ITEM_INT."""
    p1, p2, p3, p4 = (NAN if v == "NaN" else float(v) for v in it["params1_4"])
    return r.client.mav.mission_item_int_encode(1, 1, it["seq"], it["frame"], getattr(M, it["command"]), 0, 1, p1, p2, p3,
                                                p4, it["x"], it["y"], it["z"], 0)  # fmt: skip


def test_gcs_heartbeat_loss_does_nothing_with_the_default_nav_dll_act() -> None:
    s = _summary("gcs_loss")
    assert s["params"]["NAV_DLL_ACT"]["int"] == 0
    with Replay(P, rtf=2, physics_hz=PHYSICS_HZ) as r:
        assert r.wait_for(lambda: bool(r.of("GLOBAL_POSITION_INT")), 10)
        while _command(r, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) != M.MAV_RESULT_ACCEPTED:
            r.until(r.now + 0.5)
        assert _command(r, M.MAV_CMD_NAV_TAKEOFF, NAN, 0, 0, NAN, NAN, NAN, r.vehicle.home.alt + 8) == M.MAV_RESULT_ACCEPTED
        assert r.wait_for(lambda: r.vehicle.mode.custom_mode == HOLD and not r.vehicle.landed, 30)
        t0 = r.now
        r.gcs_heartbeat = False
        r.until(t0 + s["gap_s"])
        r.gcs_heartbeat = True
        r.until(r.now + 3.0)
    assert {(m.custom_mode, m.system_status) for _, m in r.of("HEARTBEAT", t0)} == {(HOLD, M.MAV_STATE_ACTIVE)}
    assert not r.of("EVENT", t0) and not r.of("STATUSTEXT")


def test_short_boot_is_the_firmware_boot_in_the_same_order_ready_in_a_second() -> None:
    with Replay(P, rtf=1, boot="short") as r:
        r.until(2.0)
        assert r.vehicle.gps_ok and r.vehicle.boot.ready_at <= 1.0 + 1e-9
        assert _command(r, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    transitions_like(capture_heartbeats(P, "boot_passive"), r.heartbeat_states()[:2])
    assert [m.id for _, m in r.of("EVENT")][:15] == [i for _, i in _events("boot_passive")][:15]


def test_the_parameter_table_is_the_firmwares() -> None:
    fw = firmware("px4")
    want = sorted((p for p in captures.json_file(P, "params", "params.json")["params"] if p["name"] != "_HASH_CHECK"),
                  key=lambda p: p["index"])  # fmt: skip
    assert [(p.name, p.ptype) for p in fw.params] == [(p["name"], p["type"]) for p in want]
    hc = next(p for p in captures.json_file(P, "params", "params.json")["params"] if p["name"] == "_HASH_CHECK")
    assert fw.hash_check == hc["value"]
