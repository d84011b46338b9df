"""Codec: round trips, the 48-byte pose budget, and rejection of bad input."""

from __future__ import annotations

import math
import random
import time

import msgpack
import pytest

from swarmnet import messages as M
from swarmnet.messages import (
    MAX_POSE_BYTES,
    AgentState,
    Command,
    CommandAck,
    DecodeError,
    Kind,
    Pose,
    Realm,
    Rejected,
    SwarmMessage,
    Telemetry,
    decode_ack,
    decode_command,
    decode_pose,
    decode_state,
    decode_swarm_message,
    decode_telemetry,
    encode_ack,
    encode_command,
    encode_pose,
    encode_state,
    encode_swarm_message,
    encode_telemetry,
    tag,
)


def pose(**kw: object) -> Pose:
    base = dict(uav=7, realm=Realm.VIRTUAL, seq=12, t_sim=35.2, t_wall=time.time(), x=12.34, y=-45.6, z=20.0,
                vx=4.9, vy=-0.1, vz=0.0, yaw=1.2)
    base.update(kw)
    return Pose(**base)  # type: ignore[arg-type]


def test_pose_round_trip_within_resolution() -> None:
    p = pose()
    q = decode_pose(encode_pose(p))
    assert (q.uav, q.realm, q.seq) == (p.uav, p.realm, p.seq)
    for f in ("x", "y", "z", "vx", "vy", "vz"):
        assert getattr(q, f) == pytest.approx(getattr(p, f), abs=0.005)
    assert q.yaw == pytest.approx(p.yaw, abs=1e-4)
    assert q.t_sim == pytest.approx(p.t_sim, abs=1e-3)
    assert q.t_wall == pytest.approx(p.t_wall, abs=1e-6)


def test_pose_never_exceeds_48_bytes_anywhere_in_range() -> None:
    extremes = pose(uav=65535, realm=Realm.PHYSICAL, seq=65535, t_sim=4294967.295, t_wall=4.0e9,
                    x=-21474836.47, y=21474836.47, z=-327.67, vx=-327.67, vy=327.67, vz=-327.67, yaw=-math.pi)
    assert len(encode_pose(extremes)) <= MAX_POSE_BYTES
    rng = random.Random(1)
    for _ in range(2000):
        p = pose(uav=rng.randint(1, 65535), seq=rng.randint(0, 65535), t_sim=rng.uniform(0, 4e6), t_wall=rng.uniform(0, 4e9),
                 x=rng.uniform(-2e7, 2e7), y=rng.uniform(-2e7, 2e7), z=rng.uniform(-327, 327),
                 vx=rng.uniform(-300, 300), vy=rng.uniform(-300, 300), vz=rng.uniform(-300, 300), yaw=rng.uniform(-10, 10))
        assert len(encode_pose(p)) <= MAX_POSE_BYTES
    # a typical in-flight pose is far smaller than the paper's 399 B
    assert len(encode_pose(pose())) <= 36


def test_pose_yaw_is_wrapped_and_seq_wraps() -> None:
    q = decode_pose(encode_pose(pose(yaw=3 * math.pi / 2, seq=65537)))
    assert q.yaw == pytest.approx(-math.pi / 2, abs=1e-4)
    assert q.seq == 1


@pytest.mark.parametrize("bad", [dict(z=400.0), dict(vx=math.nan), dict(x=math.inf), dict(uav=0), dict(t_sim=-1.0)])
def test_pose_encoder_refuses_values_the_format_cannot_hold(bad: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        encode_pose(pose(**bad))


def _fields() -> list[object]:
    return msgpack.unpackb(encode_pose(pose()))


@pytest.mark.parametrize(
    "mutate, reason",
    [
        (lambda f: f.__setitem__(0, tag(Kind.POSE, 2)), "wrong_version"),
        (lambda f: f.__setitem__(0, tag(Kind.TELEMETRY)), "wrong_type"),
        (lambda f: f.__setitem__(0, "pose"), "malformed"),
        (lambda f: f.pop(), "malformed"),
        (lambda f: f.append(1), "malformed"),
        (lambda f: f.__setitem__(1, 0), "bad_field"),
        (lambda f: f.__setitem__(1, 70000), "bad_field"),
        (lambda f: f.__setitem__(1, "7"), "bad_field"),
        (lambda f: f.__setitem__(2, 2), "bad_field"),
        (lambda f: f.__setitem__(6, 1.5), "bad_field"),
        (lambda f: f.__setitem__(8, 40000), "bad_field"),
        (lambda f: f.__setitem__(12, 40000), "bad_field"),
        (lambda f: f.__setitem__(3, -1), "bad_field"),
        (lambda f: f.__setitem__(5, True), "bad_field"),
    ],
)
def test_pose_decoder_rejects_bad_fields_with_a_reason(mutate, reason: str) -> None:  # type: ignore[no-untyped-def]
    f = _fields()
    mutate(f)
    with pytest.raises(DecodeError) as ei:
        decode_pose(msgpack.packb(f))
    assert ei.value.reason == reason


@pytest.mark.parametrize(
    "data, reason",
    [
        (b"", "malformed"),
        (b"\xc1", "malformed"),  # never-used msgpack byte
        (b"\x93\x01\x02", "malformed"),  # truncated array
        (msgpack.packb({"uav": 1}), "malformed"),
        (msgpack.packb([]), "malformed"),
        (bytes(49), "oversized"),
        (msgpack.packb([tag(Kind.POSE)] + [1] * 12) + b"\x00", "malformed"),  # trailing garbage
    ],
)
def test_pose_decoder_rejects_garbage(data: bytes, reason: str) -> None:
    with pytest.raises(DecodeError) as ei:
        decode_pose(data)
    assert ei.value.reason == reason


def test_decoders_never_raise_anything_but_decode_error_on_random_bytes() -> None:
    rng = random.Random(7)
    decoders = [decode_pose, decode_telemetry, decode_state, decode_swarm_message, decode_command, decode_ack]
    samples = [encode_pose(pose())]
    for _ in range(3000):
        base = bytearray(rng.choice(samples)) if rng.random() < 0.5 else bytearray(rng.randbytes(rng.randint(0, 60)))
        for _ in range(rng.randint(1, 4)):
            if base:
                base[rng.randrange(len(base))] = rng.randrange(256)
        for dec in decoders:
            try:
                dec(bytes(base))
            except DecodeError:
                pass


def test_telemetry_state_command_ack_round_trip() -> None:
    now = time.time()
    t = Telemetry(uav=3, realm=Realm.PHYSICAL, seq=9, t_wall=now, mode="OFFBOARD", armed=True, battery=0.8, voltage=15.9,
                  lat=46.6, lon=14.26, alt=470.5, rtf=0.97)
    t2 = decode_telemetry(encode_telemetry(t))
    assert (t2.uav, t2.realm, t2.mode, t2.armed, t2.battery, t2.rtf) == (3, Realm.PHYSICAL, "OFFBOARD", True, 0.8, 0.97)
    s = AgentState(uav=3, realm=Realm.VIRTUAL, seq=1, t_wall=now, phase="mission", behaviour="lawnmower", override="",
                   detail="strip 2/10")
    assert decode_state(encode_state(s)).detail == "strip 2/10"
    c = Command(sender="gcs", cmd_id=42, target=0, verb="goto", args={"x": 1.0, "y": 2.0, "z": 10.0}, t_wall=now)
    c2 = decode_command(encode_command(c))
    assert (c2.verb, c2.args, c2.target, c2.cmd_id) == ("goto", {"x": 1.0, "y": 2.0, "z": 10.0}, 0, 42)
    a = CommandAck(uav=3, cmd_id=42, ok=False, message="outside geofence", t_wall=now)
    assert decode_ack(encode_ack(a)).message == "outside geofence"


def test_swarm_message_limits() -> None:
    m = SwarmMessage(src=1, dst=0, topic="task/claim", seq=1, t_wall=time.time(), body={"cell": [3, 4]})
    assert decode_swarm_message(encode_swarm_message(m)).body == {"cell": [3, 4]}
    with pytest.raises(ValueError, match="limit"):
        encode_swarm_message(SwarmMessage(1, 0, "big", 1, time.time(), b"x" * 2000), max_bytes=1024)
    with pytest.raises(ValueError, match="topic"):
        encode_swarm_message(SwarmMessage(1, 0, "bad topic!", 1, time.time(), None))
    big = encode_swarm_message(SwarmMessage(1, 0, "big", 1, time.time(), b"x" * 2000))
    with pytest.raises(DecodeError) as ei:
        decode_swarm_message(big, max_bytes=1024)
    assert ei.value.reason == "oversized"
    bad_topic = msgpack.packb([tag(Kind.SWARM_MESSAGE), 1, 0, "../etc", 1, 1, None])
    with pytest.raises(DecodeError):
        decode_swarm_message(bad_topic)


def test_acceptance_rules_reject_a_valid_payload_in_the_wrong_place_with_a_reason() -> None:
    """Each rule names its counter; a decode failure is one kind of rejection."""
    def reason(accept, *args) -> str:  # type: ignore[no-untyped-def]
        with pytest.raises(Rejected) as exc:
            accept(*args)
        return exc.value.reason

    p7 = encode_pose(pose(uav=7))
    assert M.accept_pose("mrs/a/7/pose", p7).uav == 7
    assert reason(M.accept_pose, "mrs/a/8/pose", p7) == "key_mismatch"  # UAV 8's key, UAV 7's payload
    assert reason(M.accept_pose, "mrs/a/7/pose", b"\xc1") == "malformed"
    assert issubclass(DecodeError, Rejected)
    assert M.accept_neighbour_pose("mrs/a/7/pose", p7, me=3).uav == 7
    assert reason(M.accept_neighbour_pose, "mrs/a/7/pose", p7, 7) == "own_id"
    # a batched pose must name the sender the batch lists for it, as a direct pose names its key's UAV
    assert M.accept_batched_pose(7, p7).uav == 7
    assert reason(M.accept_batched_pose, 8, p7) == "key_mismatch"

    t = Telemetry(4, Realm.VIRTUAL, 1, time.time(), "GUIDED", True, 0.5, 12.0, 1.0, 2.0, 3.0, 1.0)
    assert M.accept_telemetry("mrs/a/4/telemetry", encode_telemetry(t)) == decode_telemetry(encode_telemetry(t))
    assert reason(M.accept_telemetry, "mrs/a/5/telemetry", encode_telemetry(t)) == "key_mismatch"
    st = AgentState(4, Realm.VIRTUAL, 1, time.time(), "mission", "coverage")
    assert reason(M.accept_state, "mrs/a/5/state", encode_state(st)) == "key_mismatch"
    ack = CommandAck(4, 9, True, "", time.time())
    assert reason(M.accept_ack, "mrs/a/5/ack", encode_ack(ack)) == "key_mismatch"

    bcast = encode_swarm_message(SwarmMessage(2, 0, "chat", 1, time.time(), "hi"))
    direct = encode_swarm_message(SwarmMessage(2, 3, "chat", 1, time.time(), "hi"))
    # swarm messages sit under their sender's id: mrs/<swarm>/<src>/msg/<topic>, mrs/<swarm>/<src>/to/<dst>/<topic>
    assert M.accept_swarm_message("mrs/a/2/msg/chat", bcast, 3).dst == 0
    assert M.accept_swarm_message("mrs/a/2/to/3/chat", direct, 3).dst == 3
    assert reason(M.accept_swarm_message, "mrs/a/2/msg/chat", direct, 3) == "wrong_destination"  # unicast on a broadcast key
    assert reason(M.accept_swarm_message, "mrs/a/2/to/3/chat", bcast, 3) == "wrong_destination"  # broadcast on a unicast key
    assert reason(M.accept_swarm_message, "mrs/a/2/to/3/chat", direct, 4) == "wrong_destination"  # for someone else
    assert reason(M.accept_swarm_message, "mrs/a/5/msg/chat", bcast, 3) == "key_mismatch"  # UAV 2 speaking on UAV 5's key
    assert reason(M.accept_swarm_message, "mrs/a/5/to/3/chat", direct, 3) == "key_mismatch"
    assert reason(M.accept_swarm_message, "mrs/a/msg/chat", bcast, 3) == "wrong_destination"  # no sender in the key
    assert reason(M.accept_swarm_message, "mrs/a/2/msg/chat", bcast, 3, 16) == "oversized"

    for_all = encode_command(Command("gcs", 1, 0, "land", {}, time.time()))
    for_5 = encode_command(Command("gcs", 2, 5, "hold", {}, time.time()))
    assert M.accept_command("mrs/a/cmd", for_all, 3).verb == "land"
    assert M.accept_command("mrs/a/5/cmd", for_5, 5).verb == "hold"
    assert reason(M.accept_command, "mrs/a/3/cmd", for_5, 3) == "wrong_destination"
