"""The ArduPilot flavour against recordings of a real ArduCopter 4.7 SITL (tests/captures.py): from factory
defaults it answers as the firmware does, over real UDP MAVLink, on the firmware's own boot timeline.

Each test replays what the recorder sent in one capture (at the times it sent them, or, where the
recorder waited for the vehicle, when the same condition holds) and holds the emulator to what the real
firmware answered: message types and rates after boot and after each request, acknowledgements, mode
numbers and transitions, texts, parameter names and encodings. The sim runs faster than real time.
"""

from __future__ import annotations

import math

import pytest

from tests import captures
from tests.fcu_conformance import (
    Replay,
    assert_heartbeat_rate,
    assert_rates_like,
    capture_acks,
    capture_heartbeats,
    extra_heartbeats,
    rate_windows,
    resend,
    sent_by_recorder,
    transitions_like,
)
from uav_stack.fcu import ardupilot
from uav_stack.fcu.firmware import firmware
from uav_stack.mav import mavlink as M

AP = captures.ARDUPILOT
NAN = math.nan


def _summary(capture: str) -> dict:
    return captures.summary(AP, capture)


def test_factory_defaults_are_silent_but_for_heartbeat_boot_texts_timesync_and_home() -> None:
    s = _summary("boot_passive")
    with Replay(AP, rtf=8) as r:
        r.until(s["duration_s"])
    assert {m.get_type() for _, m in r.rx} == set(s["rx_message_types"])  # no periodic stream unasked
    assert [x[2] for x in r.texts()] == [x["text"] for x in s["statustext"]]
    assert [x[1] for x in r.texts()] == [x["severity"] for x in s["statustext"]]
    for (t, _, _), x in zip(r.texts(), s["statustext"], strict=True):
        assert abs(t - x["t"]) < 0.2, (x["text"], t)
    # HEARTBEAT: BOOT (89) then STANDBY (81), STABILIZE, at 1 Hz
    transitions_like(capture_heartbeats(AP, "boot_passive"), r.heartbeat_states())
    hb = r.of("HEARTBEAT")[0][1]
    assert (hb.type, hb.autopilot, hb.mavlink_version) == (M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 3)
    assert abs(r.of("HEARTBEAT")[0][0] - s["first_of_each_rx_type"]["HEARTBEAT"]["t"]) < 0.2
    assert_heartbeat_rate(r, 10.0, s["duration_s"])
    # TIMESYNC requests every 10 s; GPS_GLOBAL_ORIGIN and HOME_POSITION once, when the EKF origin is set
    ts = [t for t, m in r.of("TIMESYNC") if m.tc1 == 0]
    assert abs(len(ts) - s["rx_message_types"]["TIMESYNC"]["count"]) <= 1
    assert all(abs(b - a - 10.0) < 0.1 for a, b in zip(ts, ts[1:], strict=False))
    for name in ("GPS_GLOBAL_ORIGIN", "HOME_POSITION"):
        got = r.of(name)
        assert len(got) == 1 and abs(got[0][0] - s["first_of_each_rx_type"][name]["t"]) < 0.2, (name, got)
    home = r.of("HOME_POSITION")[0][1]
    want = s["first_of_each_rx_type"]["HOME_POSITION"]
    assert abs(home.latitude - want["latitude"]) <= 2 and abs(home.longitude - want["longitude"]) <= 2  # (1e-7 deg)
    # the boot's unsolicited PARAM_VALUEs, all with index 65535
    pv = r.of("PARAM_VALUE")
    assert len(pv) == s["rx_message_types"]["PARAM_VALUE"]["count"] and {m.param_index for _, m in pv} == {65535}
    for label, t0, t1, rates in rate_windows(AP, "boot_passive"):
        assert_rates_like(rates, r.rates(t0, t1), t1 - t0, label)


def test_streams_start_when_asked_and_follow_request_data_stream_and_message_intervals() -> None:
    s = _summary("stream_requests")
    with Replay(AP, rtf=4) as r:
        r.replay(sent_by_recorder(AP, "stream_requests"), until=s["duration_s"])
    for label, t0, t1, rates in rate_windows(AP, "stream_requests"):
        assert_rates_like(rates, r.rates(t0, t1), t1 - t0, label)
    # REQUEST_DATA_STREAM is never ACKed; every command's ACK is the firmware's
    assert r.acks() == capture_acks(AP, "stream_requests")
    # the MAV1_* parameter holds what REQUEST_DATA_STREAM set last (ALL, stop)
    assert r.vehicle.params.get("MAV1_POSITION") == 0.0 and r.vehicle.params.get("MAV1_PARAMS") == 0.0
    # GET_MESSAGE_INTERVAL: MESSAGE_INTERVAL (just before its ACK)
    want = [(e["fields"]["message_id"], e["fields"]["interval_us"]) for e in s["rx_events"] if e["type"] == "MESSAGE_INTERVAL"]
    assert [(m.message_id, m.interval_us) for _, m in r.of("MESSAGE_INTERVAL")] == want
    order = [m.get_type() for _, m in r.rx if m.get_type() in ("MESSAGE_INTERVAL", "COMMAND_ACK")]
    k = order.index("MESSAGE_INTERVAL")
    assert order[k:k + 2] == ["MESSAGE_INTERVAL", "COMMAND_ACK"]
    # AUTOPILOT_VERSION (REQUEST_MESSAGE and REQUEST_AUTOPILOT_CAPABILITIES): 4.7.0-dev's
    av = [m for _, m in r.of("AUTOPILOT_VERSION")]
    want_av = next(e["fields"] for e in s["rx_events"] if e["type"] == "AUTOPILOT_VERSION")
    assert len(av) == 2
    assert (av[0].flight_sw_version, av[0].capabilities) == (want_av["flight_sw_version"], want_av["capabilities"])
    assert list(av[0].flight_custom_version) == want_av["flight_custom_version"]
    # REQUEST_MESSAGE GLOBAL_POSITION_INT before the GPS: all zeros but the heading
    first = s["global_position_int_first"]
    t, gp = r.of("GLOBAL_POSITION_INT")[0]
    assert abs(t - first["t"]) < 0.1
    assert (gp.lat, gp.lon, gp.alt, gp.relative_alt) == (0, 0, 0, 0) and gp.hdg != 65535
    # REQUEST_MESSAGE HOME_POSITION before home exists: ACCEPTED, no message (home comes once set, at 20 s)
    assert r.of("HOME_POSITION")[0][0] > 19.5
    # EKF flags and the GPS fix once streamed
    assert [v for _, v in r.field_changes("EKF_STATUS_REPORT", "flags")] == [
        x["value"] for x in s["field_transitions"]["EKF_STATUS_REPORT.flags"]]  # fmt: skip
    assert [v for _, v in r.field_changes("GPS_RAW_INT", "fix_type")] == [6]


def test_arming_too_early_is_refused_with_the_firmware_texts_then_arms_and_disarms_itself() -> None:
    s = _summary("arm_too_early")
    sent = sent_by_recorder(AP, "arm_too_early")
    with Replay(AP, rtf=4) as r:
        r.replay(sent, until=s["duration_s"])
    assert r.acks() == capture_acks(AP, "arm_too_early")
    assert not r.of("COMMAND_ACK", 5.0, 5.2)[1:]  # SET_MODE gets no ACK (only DO_SET_MODE's)
    # each refused arm: ACK FAILED then the firmware's "Arm: ..." texts, CRITICAL, in its order
    arms = [x.t for x in sent if x.msg.get_type() == "COMMAND_LONG" and x.msg.command == M.MAV_CMD_COMPONENT_ARM_DISARM]
    arms.append(math.inf)
    for k, want in enumerate(s["arm_attempts"]):
        texts = [(sev, text) for t, sev, text in r.texts() if arms[k] <= t < arms[k + 1] and not text.startswith("EKF")
                 and not text.startswith("GPS") and "origin" not in text and "Field" not in text and "PreArm" not in text
                 and text != "Disarming motors"]  # fmt: skip
        assert [t for _, t in texts] == want["statustext_during_attempt"], (arms[k], texts)
        if want["arm_ack"] == "MAV_RESULT_FAILED":
            assert {sev for sev, _ in texts} == {M.MAV_SEVERITY_CRITICAL}
    # unprompted, once an arm was refused: the pre-arm failures every 30 s
    prearm = [(round(t, 1), text) for t, _, text in r.texts() if text.startswith("PreArm")]
    want_pre = [(round(x["t"], 1), x["text"]) for x in s["statustext"] if x["text"].startswith("PreArm")]
    assert [x[1] for x in prearm] == [x[1] for x in want_pre] and abs(prearm[0][0] - want_pre[0][0]) < 0.3
    # armed without a takeoff: "Disarming motors" DISARM_DELAY (10 s) later
    t_arm = next(t for t, _, text in r.texts() if text == "Arming motors")
    t_dis = next(t for t, _, text in r.texts() if text == "Disarming motors")
    want_dis = next(x["t"] for x in s["statustext"] if x["text"] == "Disarming motors")
    want_arm = next(x["t"] for x in s["statustext"] if x["text"] == "Arming motors")
    assert abs((t_dis - t_arm) - (want_dis - want_arm)) < 0.3
    transitions_like(capture_heartbeats(AP, "arm_too_early"), r.heartbeat_states())
    # a mode change sends an extra HEARTBEAT at once; arming and disarming do not
    ack_t = {(m.command, m.result): t for t, m in r.of("COMMAND_ACK")}
    t_mode = ack_t[(M.MAV_CMD_DO_SET_MODE, M.MAV_RESULT_ACCEPTED)]
    t_armed = ack_t[(M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_RESULT_ACCEPTED)]
    extra = extra_heartbeats(r)
    assert [t for t in extra if t > 4.0] == pytest.approx([t_mode], abs=0.03)
    # arming sets home where the vehicle is: GPS_GLOBAL_ORIGIN and HOME_POSITION again
    assert r.of("HOME_POSITION", t_armed, t_armed + 0.03) and r.of("GPS_GLOBAL_ORIGIN", t_armed, t_armed + 0.03)
    # the EKF's flags, the GPS fix, the position before and after the fix
    for field in ("EKF_STATUS_REPORT.flags", "GPS_RAW_INT.fix_type"):
        name, attr = field.split(".")
        want_ch = s["field_transitions"][field]
        got = r.field_changes(name, attr)
        assert [v for _, v in got] == [x["value"] for x in want_ch], field
        for (t, _), x in zip(got, want_ch, strict=True):
            assert abs(t - x["t"]) < 0.35, (field, t, x)
    zeros = [m for t, m in r.of("GLOBAL_POSITION_INT") if t < s["global_position_int_first_nonzero_latlon"]["t"] - 0.3]
    assert zeros and all((m.lat, m.lon, m.alt, m.relative_alt) == (0, 0, 0, 0) and m.hdg != 65535 for m in zeros)
    t_fix, fix = next((t, m) for t, m in r.of("GLOBAL_POSITION_INT") if m.lat != 0)
    assert abs(t_fix - s["global_position_int_first_nonzero_latlon"]["t"]) < 0.35 and fix.relative_alt == 0
    # LOCAL_POSITION_NED and WIND only once the EKF has a horizontal position; AHRS2 once it is initialised
    for name in ("LOCAL_POSITION_NED", "WIND", "AHRS2", "EKF_STATUS_REPORT"):
        assert abs(r.of(name)[0][0] - s["rx_message_types"][name]["first_t"]) < 0.35, name


def _arm_and_take_off(r: Replay, sent: list, alt_m: float) -> None:
    """GUIDED, arm and NAV_TAKEOFF as the recorder sent them, once the EKF uses GPS; climbs to ``alt_m``."""
    assert r.wait_for(lambda: any(m.flags == ardupilot.EKF_USING_GPS for _, m in r.of("EKF_STATUS_REPORT", r.now - 1)), 60)
    for cmd in (M.MAV_CMD_DO_SET_MODE, M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_CMD_NAV_TAKEOFF):
        msg = next(x.msg for x in sent if x.msg.get_type() == "COMMAND_LONG" and x.msg.command == cmd)
        r.send(resend(r.client, msg))
        assert r.wait_for(lambda c=cmd: any(m.command == c for _, m in r.of("COMMAND_ACK")), 2.0)
        r.until(r.now + 0.5)
    assert r.wait_for(lambda: r.of("GLOBAL_POSITION_INT") and r.of("GLOBAL_POSITION_INT")[-1][1].relative_alt > alt_m * 1000,
                      40.0)  # fmt: skip


def _velocity(r: Replay, vn: float, ve: float, seconds: float) -> float:
    """Velocity setpoints (LOCAL_NED, velocity only) at 10 Hz, as the recorder sent them; the time of the last."""
    end = r.now + seconds
    last = r.now
    while r.now < end:
        r.send(r.client.mav.set_position_target_local_ned_encode(0, 1, 1, M.MAV_FRAME_LOCAL_NED, 3527, 0, 0, 0, vn, ve, 0,
                                                                 0, 0, 0, 0, 0))  # fmt: skip
        last = r.now
        r.until(r.now + 0.1)
    return last


def test_guided_flight_takes_off_flies_velocities_times_out_and_lands_as_the_firmware() -> None:
    s = _summary("guided_flight")
    sent = sent_by_recorder(AP, "guided_flight")
    with Replay(AP, rtf=5) as r:
        r.replay([x for x in sent if x.t < 3.0])  # REQUEST_DATA_STREAM(ALL, 4 Hz) and the message intervals
        t_takeoff = r.now
        _arm_and_take_off(r, sent, 14.5)
        acks = {m.command: t for t, m in r.of("COMMAND_ACK")}
        t_takeoff = acks[M.MAV_CMD_NAV_TAKEOFF]
        lift = next(t for t, m in r.of("GLOBAL_POSITION_INT") if m.relative_alt > 300)
        r.until(r.now + 3.0)
        last_north = _velocity(r, 3.0, 0.0, 10.0)
        r.until(r.now + 5.0)  # no setpoints: the GUIDED timeout
        stopped = r.now
        _velocity(r, 0.0, 3.0, 10.0)
        r.send(r.client.mav.set_position_target_local_ned_encode(0, 1, 1, M.MAV_FRAME_LOCAL_NED, 3576, 0, 0, -15, 0, 0, 0,
                                                                 0, 0, 0, 0, 0))  # fmt: skip
        t_pos = r.now
        home_n = r.vehicle.ctx.dyn.pos[0]
        assert r.wait_for(lambda: math.hypot(*home_n[:2]) < 1.0 and math.hypot(*r.vehicle.ctx.dyn.vel[0, :2]) < 0.3, 40)
        t_arrived = r.now
        land = next(x.msg for x in sent if x.msg.get_type() == "COMMAND_LONG" and x.msg.command == M.MAV_CMD_NAV_LAND)
        r.send(resend(r.client, land))
        assert r.wait_for(lambda: not r.vehicle.armed, 60)
        r.until(r.now + 2.0)
    # the firmware's modes, armed bits and system_status, in its order (STANDBY armed, ACTIVE once flying)
    transitions_like(capture_heartbeats(AP, "guided_flight"), r.heartbeat_states())
    assert r.acks() == capture_acks(AP, "guided_flight")
    want = [x["value"] for x in s["field_transitions"]["EXTENDED_SYS_STATE.landed_state"]]
    assert [v for _, v in r.field_changes("EXTENDED_SYS_STATE", "landed_state")] == want
    # NAV_TAKEOFF: ACKed at once, off the ground a few seconds later (the throttle ramp), climbing at WPNAV_SPEED_UP
    assert 2.5 < lift - t_takeoff < 5.0, lift - t_takeoff
    climb = max(-m.vz for _, m in r.of("GLOBAL_POSITION_INT")) / 100.0
    assert climb <= r.vehicle.params.get("WPNAV_SPEED_UP") / 100.0 + 0.1
    # the GUIDED timeout (GUID_TIMEOUT 3 s): full speed until then, then it brakes and holds, still GUIDED
    # (it brakes more gently than ArduCopter: docs/fcu.md, known differences)
    vn = [(t, m.vx / 100.0) for t, m in r.of("GLOBAL_POSITION_INT", last_north, stopped)]
    assert all(v > 2.5 for t, v in vn if t < last_north + 2.9)
    braking = [v for t, v in vn if t > last_north + 3.4]
    assert braking == sorted(braking, reverse=True) and braking[-1] < 1.2
    assert all(m.custom_mode == 4 for _, m in r.of("HEARTBEAT", last_north, stopped))
    # POSITION_TARGET_GLOBAL_INT only while the position target is flown
    pt = [t for t, _ in r.of("POSITION_TARGET_GLOBAL_INT")]
    assert pt and min(pt) >= t_pos - 0.1 and max(pt) <= t_arrived + 10.0
    # LAND: 1.5 m/s down to LAND_ALT_LOW, then LAND_SPEED; "Disarming motors" about 2 s after touching down
    texts = [x[2] for x in r.texts()]
    assert "Arming motors" in texts and texts.count("Disarming motors") == 1
    assert not [m for _, m in r.of("COMMAND_ACK") if m.command not in {c for c, _ in capture_acks(AP, "guided_flight")}]


def test_parameters_carry_the_47_names_types_and_echo_as_the_firmware() -> None:
    s = _summary("params")
    fw = {p["name"]: p for p in captures.json_file(AP, "params", "params.json")["params"]}
    with Replay(AP, rtf=2) as r:
        r.replay(sent_by_recorder(AP, "params"), until=s["duration_s"])
    t_req = s["param_list_stats"]["t_request"]
    listed = [(t, m) for t, m in r.of("PARAM_VALUE", t_req, t_req + 3.0) if m.param_index != 65535]
    got = {m.param_id: m for _, m in listed}
    t_list = [t for t, _ in listed]
    assert len(got) == len(fw) == s["param_list_stats"]["param_count"]
    for name, p in fw.items():
        m = got[name]
        assert (m.param_index, m.param_type, m.param_count) == (p["index"], p["type"], len(fw)), name
        assert m.param_value == pytest.approx(p["value"], rel=1e-6, abs=1e-9), name
    want_s = s["param_list_stats"]["t_last_value"] - s["param_list_stats"]["t_request"]
    assert 0.5 * want_s < t_list[-1] - t_list[0] < 2.0 * want_s + 0.2
    # the banner comes with PARAM_REQUEST_LIST
    banner = [x["text"] for x in s["statustext"] if abs(x["t"] - s["param_list_stats"]["t_request"]) < 0.1]
    texts = [x[2] for x in r.texts()]
    assert banner[0] in texts and banner[2] in texts
    # reads: by name (answered with index 65535), old names not at all, by index with the index
    reads = [m for t, m in r.of("PARAM_VALUE") if t > s["param_list_stats"]["t_last_value"] + 1.0]
    for name, want in s["param_request_read_results"].items():
        mine = [m for m in reads if m.param_id == (want or {}).get("param_id", name)] if want else \
            [m for m in reads if m.param_id == name]  # fmt: skip
        if want is None:
            assert not mine, f"{name}: the firmware does not answer, the emulator did"
        else:
            assert mine and (mine[0].param_index, mine[0].param_type) == (want["param_index"], want["param_type"]), name
    # PARAM_SET: echoed with index 65535 and the parameter's own type; an unknown one: nothing
    for name, res in s["param_set_results"].items():
        echo = [m for m in reads if m.param_id == name]
        if not res["echo"]:
            assert not echo, name
            continue
        e = res["echo"][0]
        assert (echo[0].param_index, echo[0].param_type, echo[0].param_value) == (e["param_index"], e["param_type"],
                                                                                  e["param_value"]), name  # fmt: skip


def test_mission_upload_is_asked_with_mission_request_and_flown_in_auto() -> None:
    s = _summary("mission_upload")
    sent = sent_by_recorder(AP, "mission_upload")
    items = [x.msg for x in sent if x.msg.get_type() == "MISSION_ITEM_INT"]
    with Replay(AP, rtf=5) as r:
        r.replay([x for x in sent if x.t < 3.0])
        assert r.wait_for(lambda: any(m.flags == ardupilot.EKF_USING_GPS for _, m in r.of("EKF_STATUS_REPORT")), 60)
        t_up = r.now
        requests = r.upload(items)
        r.until(r.now + 0.5)
        t_down = r.now
        down = r.download(len(items))
        for cmd, p2 in ((M.MAV_CMD_DO_SET_MODE, 3), (M.MAV_CMD_COMPONENT_ARM_DISARM, NAN), (M.MAV_CMD_DO_SET_MODE, 4),
                        (M.MAV_CMD_COMPONENT_ARM_DISARM, NAN), (M.MAV_CMD_MISSION_START, NAN)):  # fmt: skip
            p = (1, p2) if cmd == M.MAV_CMD_DO_SET_MODE else (1, 0) if cmd == M.MAV_CMD_COMPONENT_ARM_DISARM else (0, 0)
            n = len(r.of("COMMAND_ACK"))
            r.send(r.client.mav.command_long_encode(1, 1, cmd, 0, *p, 0, 0, 0, 0, 0))
            assert r.wait_for(lambda k=n: len(r.of("COMMAND_ACK")) > k, 2)
            r.until(r.now + 1.5)  # (a heartbeat shows each state)
        assert r.wait_for(lambda: any(m.seq == 2 for _, m in r.of("MISSION_ITEM_REACHED")), 90)
        r.until(r.now + 2.0)
    # MISSION_REQUEST (id 40, not _INT) for every item, then ACCEPTED and "Flight plan received"
    assert requests == [("MISSION_REQUEST", seq) for seq in s["mission_requested_seqs"]]
    assert [m.type for _, m in r.of("MISSION_ACK", t_up) if m.get_srcSystem() == 1] == [M.MAV_MISSION_ACCEPTED]
    # the download: item 0 is home (frame 0, AMSL), RTL in frame 0, the rest as uploaded
    for want in s["mission_download"]["items"]:
        m = down[want["seq"]]
        assert (m.frame, m.command, m.current) == (want["frame"], want["command"], want["current"]), want
        assert abs(m.x - want["x"]) <= 2 and abs(m.y - want["y"]) <= 2, want  # (1e-7 deg)
        assert m.z == pytest.approx(want["z"], abs=0.2)
    assert r.acks() == capture_acks(AP, "mission_upload")
    texts = [x[2] for x in r.texts()]
    want_texts = [x["text"] for x in s["statustext"] if x["t"] > 44.0 and "yaw alignment" not in x["text"]]
    got_texts = [t for t in texts if t in set(want_texts)]
    assert got_texts[:len(want_texts) - 2] == want_texts[:-2]  # up to "Reached command #2", "Mission: 3 WP"
    states = [v for _, v in r.field_changes("MISSION_CURRENT", "mission_state")]
    assert states == [x["value"] for x in s["field_transitions"]["MISSION_CURRENT.mission_state"]]
    assert {m.total for _, m in r.of("MISSION_CURRENT", t_down)} == {s["mission_download"]["count"] - 1}
    transitions_like(capture_heartbeats(AP, "mission_upload")[:5], r.heartbeat_states()[:5])


def test_link_loss_failsafes_follow_the_firmware_defaults() -> None:
    s = _summary("failsafes")
    sent = sent_by_recorder(AP, "failsafes")
    with Replay(AP, rtf=5) as r:
        r.replay([x for x in sent if x.t < 5.0], until=5.0)  # streams and the failsafe parameters read
        reads = {m.param_id: m.param_value for _, m in r.of("PARAM_VALUE") if m.param_index == 65535}
        for name, value in s["failsafe_param_defaults"].items():
            assert reads.get(name) == pytest.approx(value), name
        _arm_and_take_off(r, sent, 9.5)
        hold = r.client.mav.set_position_target_local_ned_encode(0, 1, 1, M.MAV_FRAME_LOCAL_NED, 3576, 30, 0, -10, 0, 0, 0,
                                                                 0, 0, 0, 0, 0)  # fmt: skip
        for _ in range(60):  # the position target at 2 Hz until it is there
            if abs(r.vehicle.ctx.dyn.pos[0, 0] - 30) < 1.0:
                break
            r.send(hold)
            r.until(r.now + 0.5)
        assert abs(r.vehicle.ctx.dyn.pos[0, 0] - 30) < 1.0
        # (A) FS_GCS_ENABLE=0: 15 s without any GCS traffic changes nothing
        r.gcs_heartbeat = False
        t_a = r.now
        r.until(t_a + 15.0)
        assert {m.custom_mode for _, m in r.of("HEARTBEAT", t_a)} == {4} and not r.texts()[-1][2].startswith("GCS")
        # (B) FS_GCS_ENABLE=1, heartbeats stopped, position setpoints still sent at 2 Hz
        r.gcs_heartbeat = True
        r.until(r.now + 3.0)
        r.send(r.client.mav.param_set_encode(1, 1, b"FS_GCS_ENABLE", 1, M.MAV_PARAM_TYPE_REAL32))
        r.until(r.now + 0.5)
        r.gcs_heartbeat = False
        t_last_hb = r._next_gcs_hb - 1.0
        while r.vehicle.mode.name == "GUIDED" and r.now < t_last_hb + 20:
            r.send(hold)
            r.until(r.now + 0.5)
        t_fs = next(t for t, _, text in r.texts() if text == "GCS Failsafe")
        r.until(r.now + 3.0)
        r.gcs_heartbeat = True
        r._next_gcs_hb = 0.0
        assert r.wait_for(lambda: any(text == "GCS Failsafe Cleared" for _, _, text in r.texts()), 5)
        r.until(r.now + 3.0)
        assert r.vehicle.mode.name == "RTL"  # the failsafe is over, the mode stays
        # (C) back in GUIDED, the SITL RC receiver lost: "Radio Failsafe" 1 s later, RTL
        r.send(r.client.mav.command_long_encode(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0))
        r.until(r.now + 1.0)
        r.send(hold)
        r.until(r.now + 5.0)
        t_rc = r.now
        r.send(r.client.mav.param_set_encode(1, 1, b"SIM_RC_FAIL", 1, M.MAV_PARAM_TYPE_REAL32))
        assert r.wait_for(lambda: any(text == "Radio Failsafe" for _, _, text in r.texts()), 5)
        t_radio = next(t for t, _, text in r.texts() if text == "Radio Failsafe")
        r.until(t_rc + 12.0)
        r.send(r.client.mav.param_set_encode(1, 1, b"SIM_RC_FAIL", 0, M.MAV_PARAM_TYPE_REAL32))
        assert r.wait_for(lambda: not r.vehicle.armed, 90)
        r.until(r.now + 1.0)
    timeout = s["failsafe_param_defaults"]["FS_GCS_TIMEOUT"]  # "GCS Failsafe" that long after the last heartbeat
    assert timeout <= t_fs - t_last_hb < timeout + 0.4
    for text in ("GCS Failsafe", "GCS Failsafe Cleared", "Radio Failsafe", "Radio Failsafe Cleared"):
        want = next(x for x in s["statustext"] if x["text"] == text)
        got = [(sev, t) for t, sev, t2 in r.texts() if t2 == text]
        assert got and got[0][0] == want["severity"], text
    assert abs(t_radio - t_rc - 1.0) < 0.3
    transitions_like(capture_heartbeats(AP, "failsafes"), r.heartbeat_states())


def test_short_boot_is_the_firmware_boot_in_the_same_order_ready_in_a_second() -> None:
    with Replay(AP, rtf=1, boot="short") as r:
        r.send(r.client.mav.request_data_stream_encode(1, 1, 0, 10, 1))
        r.until(2.0)
        assert r.vehicle.gps_ok and r.vehicle.boot.ready_at <= 1.0 + 1e-9
    assert [x[2] for x in r.texts()] == [x["text"] for x in _summary("boot_passive")["statustext"]]
    assert [v for _, v in r.field_changes("EKF_STATUS_REPORT", "flags")][-1] == ardupilot.EKF_USING_GPS
    transitions_like(capture_heartbeats(AP, "boot_passive"), r.heartbeat_states())


def test_the_parameter_table_is_the_firmwares() -> None:
    """The table the emulator ships is the one the real firmware listed (names, order, types, defaults)."""
    fw = firmware("ardupilot")
    want = captures.json_file(AP, "params", "params.json")["params"]
    assert [(p.name, p.ptype) for p in fw.params] == [(p["name"], p["type"]) for p in sorted(want, key=lambda p: p["index"])]
    assert not any(p.name.startswith("SR0_") or p.name in ("SYSID_THISMAV", "SYSID_MYGCS") for p in fw.params)
