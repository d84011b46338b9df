"""The FCU link's compiled MAVLink framing against pymavlink itself: same frames, same objects, same refusals.

``uav_stack._mavcodec`` must be a narrower fast path of pymavlink, never a different codec: every
frame it packs is the frame pymavlink packs, every message it parses has pymavlink's attributes,
and every datagram it cannot take whole it declines untouched, so pymavlink parses (and names)
it as before.
"""

from __future__ import annotations

import math
import random
import struct
from typing import Any

import pytest

from uav_stack import mavcodec
from uav_stack.mav import mavlink as M
from uav_stack.mavcodec import MAVCODEC, MAVLink, pack

PLAIN = [cls for _, cls in sorted(M.mavlink_map.items()) if mavcodec._plain(cls)]
RANGES = {"uint8_t": (0, 255), "int8_t": (-128, 127), "uint16_t": (0, 65535), "int16_t": (-32768, 32767),
          "uint32_t": (0, 2**32 - 1), "int32_t": (-(2**31), 2**31 - 1), "uint64_t": (0, 2**64 - 1),
          "int64_t": (-(2**63), 2**63 - 1)}


def _value(rng: random.Random, ftype: str) -> Any:
    if rng.random() < 0.3:
        return 0  # zeros at the end of a payload are trimmed in MAVLink 2
    if ftype in ("float", "double"):
        v = rng.choice([rng.uniform(-1e6, 1e6), rng.uniform(-1, 1), math.nan, math.inf, -0.0])
        return struct.unpack("<f", struct.pack("<f", v))[0] if ftype == "float" else v
    lo, hi = RANGES[ftype]
    return rng.choice([lo, hi, rng.randint(lo, hi)])


def _message(rng: random.Random, cls: Any) -> Any:
    return cls(*[_value(rng, t) for t in cls.fieldtypes])


def _same(a: Any, b: Any) -> bool:
    """Equal values, NaN equal to NaN (and -0.0 told from 0.0)."""
    if isinstance(a, float) and isinstance(b, float):
        return struct.pack("<d", a) == struct.pack("<d", b)
    return type(a) is type(b) and a == b


def _attributes_equal(x: Any, y: Any) -> None:
    vx, vy = vars(x), vars(y)
    assert set(vx) == set(vy), set(vx) ^ set(vy)
    for k in vx:
        if k == "_header":
            assert vars(vx[k]) == vars(vy[k]), k
        else:
            assert _same(vx[k], vy[k]), (type(x).__name__, k, vx[k], vy[k])


def _sender(rng: random.Random, cls: type = M.MAVLink) -> Any:
    mav = cls(None, rng.randint(0, 255), rng.randint(0, 255))
    mav.seq = rng.randint(0, 255)
    return mav


def test_the_compiled_pass_is_built_and_covers_the_fcu_links_hot_messages() -> None:
    assert MAVCODEC == "compiled"  # the test command installs the compiler that builds it
    for name in ("HEARTBEAT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE", "SYS_STATUS", "VFR_HUD",
                 "SET_POSITION_TARGET_LOCAL_NED", "COMMAND_LONG", "COMMAND_ACK", "EXTENDED_SYS_STATE"):
        assert mavcodec.frames_plainly(getattr(M, f"MAVLink_{name.lower()}_message")), name
    # arrays and strings stay pymavlink's
    for name in ("BATTERY_STATUS", "STATUSTEXT", "NAMED_VALUE_FLOAT", "HOME_POSITION"):
        assert not mavcodec.frames_plainly(getattr(M, f"MAVLink_{name.lower()}_message")), name
    assert len(PLAIN) > 100


def test_every_plain_message_packs_to_pymavlinks_frame_with_its_attributes() -> None:
    rng = random.Random(11)
    for cls in PLAIN:
        for _ in range(12):
            mav = _sender(rng)
            ours = _message(rng, cls)
            theirs = cls(*[getattr(ours, n) for n in cls.fieldnames])
            frame = pack(ours, mav)
            assert type(frame) is bytes
            assert frame == theirs.pack(mav), cls.__name__
            _attributes_equal(ours, theirs)


def test_datagrams_parse_to_pymavlinks_messages() -> None:
    rng = random.Random(12)
    parser, reference = MAVLink(None), M.MAVLink(None)
    for _ in range(1500):
        frames = []
        for _ in range(rng.randint(1, 8)):
            frames.append(_message(rng, rng.choice(PLAIN)).pack(_sender(rng)))
        data = b"".join(frames)
        assert mavcodec._CODEC.decode(data) is not None  # the compiled pass took it
        ours = parser.parse_datagram(data)
        theirs = reference.parse_buffer(bytearray(data))
        assert len(ours) == len(theirs) == len(frames)
        for x, y in zip(ours, theirs, strict=True):
            assert type(x) is type(y)
            _attributes_equal(x, y)
            assert x.get_msgbuf() == y.get_msgbuf() and x.get_srcSystem() == y.get_srcSystem()
    assert parser.total_packets_received == reference.total_packets_received
    assert parser.total_bytes_received == reference.total_bytes_received


def _recrc(frame: bytes | bytearray, cls: Any) -> bytes:
    """``frame`` (unsigned MAVLink 2) with its CRC made good again after an edit of its header or payload."""
    body = bytes(frame[:10 + frame[1]])
    crc = M.x25crc(body[1:])
    crc.accumulate(bytes((cls.crc_extra,)))
    return body + struct.pack("<H", crc.crc)


def _corruptions(rng: random.Random) -> list[tuple[str, bytes]]:
    """Datagrams the compiled pass must not take: each with a reason."""
    good = M.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6).pack(_sender(rng))
    sender = _sender(rng)
    sender.signing.secret_key = bytes(range(32))
    sender.signing.sign_outgoing = True
    sender.signing.link_id = 1
    signed = M.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6).pack(sender)
    v1 = M.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6).pack(_sender(rng), force_mavlink1=True)
    statustext = M.MAVLink_statustext_message(6, b"hello").pack(_sender(rng))
    battery = M.MAVLink_battery_status_message(0, 0, 0, 250, [3700] * 10, 10, 100, 100, 50).pack(_sender(rng))
    flipped = bytearray(good)
    flipped[rng.randint(1, len(good) - 1)] ^= 1 << rng.randint(0, 7)
    unknown = bytearray(good)
    unknown[7:10] = (0xABCDEF).to_bytes(3, "little")
    longer = bytearray(good)
    longer[1] += 4
    longer[10 + good[1]:10 + good[1]] = bytes(4)
    incompat = bytearray(good)
    incompat[2] = 0x02  # a flag this version does not know: the spec says drop the frame
    return [
        ("signed", signed), ("MAVLink 1", v1), ("a string field", statustext), ("an array field", battery),
        ("a flipped bit", bytes(flipped)), ("an unknown id", bytes(unknown)), ("truncated", good[:-1]),
        ("trailing junk", good + b"\x00\x01"), ("junk first", b"\x55" + good), ("empty", b""),
        ("a payload longer than the message", _recrc(longer, M.MAVLink_attitude_message)),
        ("an unknown incompatibility flag", _recrc(incompat, M.MAVLink_attitude_message)),
        ("a good frame then a signed one", good + signed),
    ]


def test_what_it_cannot_take_whole_goes_to_pymavlink_untouched() -> None:
    rng = random.Random(13)
    for _ in range(60):
        for why, data in _corruptions(rng):
            assert mavcodec._CODEC.decode(data) is None, why
            ours, theirs = MAVLink(None), M.MAVLink(None)
            ours.robust_parsing = theirs.robust_parsing = True
            got = ours.parse_datagram(data)
            want = theirs.parse_buffer(bytearray(data)) or []
            assert [type(m) for m in got] == [type(m) for m in want], why
            for x, y in zip(got, want, strict=True):
                if not isinstance(x, M.MAVLink_bad_data):
                    _attributes_equal(x, y)


def test_compatibility_flags_are_kept_as_pymavlink_keeps_them() -> None:
    """A frame may carry compatibility flags a receiver does not know; they are kept, not refused."""
    rng = random.Random(16)
    for cls in PLAIN[:40]:
        frame = bytearray(_message(rng, cls).pack(_sender(rng)))
        frame[3] = rng.randint(1, 255)
        data = _recrc(frame, cls)
        ours, theirs = MAVLink(None).parse_datagram(data), M.MAVLink(None).parse_buffer(bytearray(data))
        assert len(ours) == len(theirs) == 1 and ours[0]._header.compat_flags == frame[3]
        _attributes_equal(ours[0], theirs[0])


def test_a_datagram_never_carries_over_into_the_next() -> None:
    """A truncated datagram leaves nothing behind: the next whole one parses alone (both paths)."""
    rng = random.Random(14)
    p = MAVLink(None)
    p.robust_parsing = True
    good = M.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6).pack(_sender(rng))
    assert p.parse_datagram(good[:15]) == []
    assert [m.get_type() for m in p.parse_datagram(good)] == ["ATTITUDE"] and p.buf_len() == 0


def test_a_signing_link_and_bad_values_are_left_to_pymavlink() -> None:
    rng = random.Random(15)
    mav = _sender(rng)
    mav.signing.secret_key = bytes(range(32))
    mav.signing.sign_outgoing = True
    mav.signing.link_id = 2
    msg = M.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
    frame = pack(msg, mav)
    assert frame[2] & M.MAVLINK_IFLAG_SIGNED and len(frame) == 10 + frame[1] + 2 + 13
    checker = M.MAVLink(None)
    checker.signing.secret_key = bytes(range(32))
    assert checker.parse_buffer(bytearray(frame))[0].get_type() == "ATTITUDE" and checker.signing.goodsig_count == 1
    # a value out of its field's range: struct.error, as from pymavlink
    bad = M.MAVLink_command_ack_message(70000, 0)
    with pytest.raises(struct.error):
        pack(bad, _sender(rng))
    with pytest.raises(struct.error):
        bad.pack(_sender(rng))
    # a system id out of range: pymavlink's own error
    wide = M.MAVLink(None, 300, 1)
    with pytest.raises(struct.error):
        pack(M.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6), wide)


class _Sink:
    def __init__(self) -> None:
        self.out: list[bytes] = []

    def write(self, buf: bytes) -> None:
        self.out.append(bytes(buf))


def test_send_methods_write_pymavlinks_bytes_and_count_alike() -> None:
    ours, theirs = MAVLink(_Sink(), 7, 191), M.MAVLink(_Sink(), 7, 191)
    for mav in (ours, theirs):
        for k in range(300):  # the sequence number wraps
            mav.set_position_target_local_ned_send(k * 100, 1, 1, M.MAV_FRAME_LOCAL_NED, 0b110111000111,
                                                   0, 0, 0, 1.5, -2.0, 0.0, 0, 0, 0, 0, 0)
            if k % 50 == 0:
                mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
                mav.statustext_send(M.MAV_SEVERITY_INFO, b"still flying")  # a string: pymavlink's
    assert ours.file.out == theirs.file.out
    assert (ours.seq, ours.total_packets_sent, ours.total_bytes_sent) == \
           (theirs.seq, theirs.total_packets_sent, theirs.total_bytes_sent)


def test_a_pymavlink_that_frames_or_builds_differently_switches_the_pass_off_for_that_message(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The import-time check (``mavcodec._agrees``) refuses a message the pass would get wrong:
    a layout or CRC extra unlike pymavlink's, or a decode that sets an attribute per message."""
    from groundfloor.compiled import compiled_module

    compiled = compiled_module("uav_stack._mavcodec")
    assert compiled is not None
    att = M.MAVLink_attitude_message

    def codec(crc_extra: int) -> Any:
        template, header = mavcodec._templates(att)
        return compiled.Codec(M.MAVLink_header, header, [(att, att.id, crc_extra, att.unpacker.unpack, att.unpacker.pack,
                                                          att.unpacker.size, tuple(att.ordered_fieldnames), template)])

    assert mavcodec._agrees(codec(att.crc_extra), att)
    assert not mavcodec._agrees(codec((att.crc_extra + 1) & 0xFF), att)  # another CRC extra

    decode = M.MAVLink.decode

    def newer_decode(self: Any, msgbuf: bytearray) -> Any:  # a pymavlink that notes each frame's length
        m = decode(self, msgbuf)
        m._frame_len = len(msgbuf)
        return m

    monkeypatch.setattr(M.MAVLink, "decode", newer_decode)
    assert not mavcodec._agrees(codec(att.crc_extra), att)


class CountingMAVLink(MAVLink):
    """Counts the frames pymavlink itself decodes (the compiled pass never calls ``decode``)."""

    decoded = 0

    def decode(self, msgbuf: bytearray) -> Any:
        self.decoded += 1
        return super().decode(msgbuf)


def test_a_datagram_of_plain_frames_and_a_few_others_sends_only_the_others_to_pymavlink() -> None:
    """A virtual FCU's datagram once a second: its plain telemetry beside BATTERY_STATUS (arrays)
    and NAMED_VALUE_FLOAT (a string), bad frames too. Parsed as pymavlink parses the whole
    datagram, with pymavlink decoding only the frames the compiled pass does not take."""
    rng = random.Random(17)
    others = [
        lambda s: M.MAVLink_battery_status_message(0, 0, 0, 250, [3700] * 10, 10, 100, 100, 50).pack(s),
        lambda s: M.MAVLink_named_value_float_message(12, b"rtf", 0.97).pack(s),
        lambda s: M.MAVLink_statustext_message(6, b"hello").pack(s),
    ]
    for _ in range(400):
        frames, expect_pymavlink = [], 0
        for _ in range(rng.randint(2, 9)):
            if rng.random() < 0.3:
                frame = bytearray(rng.choice(others)(_sender(rng)))
                expect_pymavlink += 1
            else:
                frame = bytearray(_message(rng, rng.choice(PLAIN)).pack(_sender(rng)))
            if rng.random() < 0.1:  # a flipped bit past the length byte: a bad CRC, or a field's value
                frame[rng.randint(2, len(frame) - 1)] ^= 1 << rng.randint(0, 7)
            frames.append(bytes(frame))
        data = b"".join(frames)
        ours, theirs = CountingMAVLink(None), M.MAVLink(None)
        ours.robust_parsing = theirs.robust_parsing = True
        got = ours.parse_datagram(data)
        want = theirs.parse_buffer(bytearray(data)) or []
        assert [type(m) for m in got] == [type(m) for m in want]
        for x, y in zip(got, want, strict=True):
            if isinstance(x, M.MAVLink_bad_data):
                assert bytes(x.data) == bytes(y.data) and x.reason == y.reason
            else:
                _attributes_equal(x, y)
        assert ours.total_packets_received == theirs.total_packets_received
        assert ours.total_bytes_received == theirs.total_bytes_received
        # pymavlink decoded only the frames the compiled pass declines alone: the others, and
        # plain frames it leaves to pymavlink (bad values, a flipped bit); never a good plain one
        parts = mavcodec.split_frames(data)
        if parts is None:  # a flipped signed flag: the frames no longer tile the datagram, all of it to pymavlink
            continue
        declined = sum(mavcodec._CODEC.decode(f) is None for f in parts)
        assert declined >= expect_pymavlink
        refused_unread = sum(1 for m in got if isinstance(m, M.MAVLink_bad_data) and "incompat" in m.reason)
        assert ours.decoded == declined - refused_unread and ours.buf_len() == 0
