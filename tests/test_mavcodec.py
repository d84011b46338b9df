"""The FCU link's datagram parser (uav_stack.mavcodec.MAVLink): one datagram at a time, pymavlink's rules."""

from __future__ import annotations

from uav_stack.mav import mavlink as M
from uav_stack.mavcodec import MAVLink


def _attitude(seq: int = 0) -> bytes:
    sender = M.MAVLink(None, 7, 11)
    sender.seq = seq
    return bytes(M.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6).pack(sender))


def test_a_datagram_never_carries_over_into_the_next() -> None:
    """A truncated datagram leaves nothing behind: the next whole one parses alone."""
    p = MAVLink(None)
    p.robust_parsing = True
    good = _attitude()
    assert p.parse_datagram(good[:15]) == []
    assert [m.get_type() for m in p.parse_datagram(good)] == ["ATTITUDE"] and p.buf_len() == 0


def test_a_datagram_parses_as_pymavlinks_parse_buffer_does_bad_frames_named() -> None:
    """Whole frames end to end come out as pymavlink's messages, counted as pymavlink counts them;
    a frame with a bad CRC is pymavlink's ``MAVLink_bad_data``, and the frames around it still parse."""
    data = _attitude(1) + _attitude(2)
    bad = bytearray(_attitude(3))
    bad[-1] ^= 0xFF
    ours, theirs = MAVLink(None), M.MAVLink(None)
    ours.robust_parsing = theirs.robust_parsing = True
    got = ours.parse_datagram(data + bytes(bad) + _attitude(4))
    want = theirs.parse_buffer(bytearray(data + bytes(bad) + _attitude(4))) or []
    assert [type(m) for m in got] == [type(m) for m in want]
    assert [m.get_type() for m in got if not isinstance(m, M.MAVLink_bad_data)] == ["ATTITUDE"] * 3
    assert any(isinstance(m, M.MAVLink_bad_data) for m in got)
    assert [m.get_seq() for m in got if not isinstance(m, M.MAVLink_bad_data)] == [1, 2, 4]
    assert ours.total_packets_received == theirs.total_packets_received
