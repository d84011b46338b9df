"""MAVLink 2 frames of the FCU link, packed and parsed by compiled code where pymavlink's rules allow.

Every tick a virtual UAV's FCU packs its telemetry and the agent parses it, and the agent packs
its setpoint and the FCU parses that: about 40 messages a second each way, over the real UDP
link. pymavlink does this in Python (its ``decode``, ``_pack`` and CRC object were 13-15 % of a
UAV's main thread, docs/benchmarks.md). ``uav_stack._mavcodec`` (uav_stack/_mavcodec.c, built
by ``setup.py``, optional) does the same work in one pass for the dialect's *plain* messages:
no array and no string fields, unsigned MAVLink 2 frames. It is not a second codec: it takes
each message's layout, CRC extra and class from pymavlink, and builds the same objects
pymavlink builds (every attribute equal, ``tests/test_mavcodec.py``).

* :func:`pack` gives the frame ``msg.pack(mav)`` gives and leaves the same attributes on the
  message; a message with arrays or strings, or a link that signs, goes to pymavlink.
* :meth:`MAVLink.parse_datagram` takes the messages of a datagram in one pass when every frame
  in it is a plain, unsigned MAVLink 2 frame with a good CRC. In a datagram of MAVLink 2
  frames end to end it takes the plain ones and hands each other frame to pymavlink alone;
  any other datagram goes wholly to pymavlink's parser, which names and counts whatever is
  wrong, as before.
* :class:`MAVLink` is pymavlink's ``MAVLink`` with both: its ``*_send`` methods pack with
  :func:`pack`. The FCU's vehicles and the agent's FCU link use it.

:data:`MAVCODEC` says which this process runs (a UAV's status file: ``virtual_fcu.mavlink``);
``MRSWARM_PURE_PYTHON=1`` chooses pymavlink for all of it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from groundfloor.compiled import compiled_module
from uav_stack.mav import mavlink

log = logging.getLogger(__name__)


def _plain(cls: Any) -> bool:
    """No arrays and no strings: the payload is the class's fields, in wire order, one value each."""
    return (all(n == 1 for n in cls.lengths) and "char" not in cls.fieldtypes
            and len(cls.ordered_fieldnames) == len(cls.unpacker.unpack(bytes(cls.unpacker.size))))


def _templates(cls: Any) -> tuple[dict[str, Any], dict[str, Any]]:
    """A message of ``cls`` and its header as pymavlink's own decode leaves them (every value is
    overwritten per message; the rest, ``_type``, ``_fieldnames``..., is what pymavlink sets)."""
    sender = mavlink.MAVLink(None, 1, 1)
    frame = cls(*([0] * len(cls.fieldnames))).pack(sender)
    msg = mavlink.MAVLink(None).decode(bytearray(frame))
    return dict(vars(msg)), dict(vars(msg._header))


def _state(msg: Any) -> dict[str, Any]:
    """A message's attributes, its header's by value."""
    return {k: vars(v) if k == "_header" else v for k, v in vars(msg).items()}


def _agrees(codec: Any, cls: Any) -> bool:
    """Does the compiled pass frame and parse a message of ``cls`` exactly as this pymavlink does?

    Checked once per message at import, on a message whose every field is set, so that a
    pymavlink release that frames or builds its objects differently switches the pass off for
    that message instead of handing the agent objects unlike pymavlink's."""
    sender = mavlink.MAVLink(None, 7, 11)
    sender.seq = 201
    values = [(k % 7) + 1.5 if t in ("float", "double") else (k % 7) + 1 for k, t in enumerate(cls.fieldtypes)]
    ours, theirs = cls(*values), cls(*values)
    frame = theirs.pack(sender)
    if codec.pack(ours, sender) != frame or _state(ours) != _state(theirs):
        return False
    parsed = codec.decode(frame)
    return parsed is not None and len(parsed) == 1 and _state(parsed[0]) == _state(mavlink.MAVLink(None).decode(bytearray(frame)))


def _build() -> Any:
    compiled = compiled_module("uav_stack._mavcodec")
    if compiled is None or float(mavlink.WIRE_PROTOCOL_VERSION) != 2.0:
        return None
    specs = []
    header: dict[str, Any] = {}
    for msgid, cls in sorted(mavlink.mavlink_map.items()):
        if not _plain(cls):
            continue
        template, header = _templates(cls)
        specs.append((cls, msgid, cls.crc_extra, cls.unpacker.unpack, cls.unpacker.pack, cls.unpacker.size,
                      tuple(cls.ordered_fieldnames), template))
    codec = compiled.Codec(mavlink.MAVLink_header, header, specs)
    agreed = [spec for spec in specs if _agrees(codec, spec[0])]
    if len(agreed) < len(specs):
        log.warning("MAVLink framing: %d of %d plain messages are framed by pymavlink alone (this pymavlink builds them "
                    "unlike the compiled pass)", len(specs) - len(agreed), len(specs))
        codec = compiled.Codec(mavlink.MAVLink_header, header, agreed) if agreed else None
    return codec


_CODEC = _build()
MAVCODEC = "compiled" if _CODEC is not None else "pymavlink"
"""Which framing this process runs on its FCU link: ``"compiled"`` or ``"pymavlink"``."""


def _pymavlink_pack(msg: Any, mav: Any) -> bytes:
    frame: bytes = msg.pack(mav)
    return frame


pack: Callable[[Any, Any], bytes] = _CODEC.pack if _CODEC is not None else _pymavlink_pack
"""``pack(msg, mav)`` is ``msg.pack(mav)``: the frame, and ``msg``'s ``_header``, ``_payload``, ``_msgbuf``
and ``_crc`` as pymavlink sets them; like pymavlink it leaves ``mav.seq`` to the caller. The compiled
pass itself when present (it hands what it does not frame to ``msg.pack``): no Python call in between."""


class MAVLink(mavlink.MAVLink):
    """pymavlink's ``MAVLink`` for a link of whole datagrams, framing plain messages with the compiled pass.

    :meth:`send` and every ``*_send`` method pack with :func:`pack`; :meth:`parse_datagram` parses
    one datagram. Counters (``total_packets_sent``, ``total_packets_received``...) and callbacks
    behave as pymavlink's own.
    """

    def send(self, mavmsg: Any, force_mavlink1: bool = False) -> None:
        buf = mavmsg.pack(self, force_mavlink1=True) if force_mavlink1 else pack(mavmsg, self)
        self.file.write(buf)
        self.seq = (self.seq + 1) % 256  # type: ignore[has-type]  # pymavlink leaves it unannotated
        self.total_packets_sent += 1
        self.total_bytes_sent += len(buf)
        if self.send_callback is not None and self.send_callback_args is not None and self.send_callback_kwargs is not None:
            self.send_callback(mavmsg, *self.send_callback_args, **self.send_callback_kwargs)

    def parse_datagram(self, data: bytes) -> list[Any]:
        """The messages of one datagram (it holds whole frames, so nothing carries over from the last).

        Plain, unsigned MAVLink 2 frames with good CRCs are parsed by the compiled pass: a whole
        datagram of them at once; in a datagram of MAVLink 2 frames end to end
        (:func:`split_frames`), each frame the pass does not take goes to pymavlink alone; any
        other datagram wholly to pymavlink's ``parse_buffer``. pymavlink returns bad data as
        ``MAVLink_bad_data`` and may raise on some corrupt frames, as it always did.
        """
        self._reset()
        if _CODEC is None:
            return self.parse_buffer(data) or []
        msgs: list[Any] | None = _CODEC.decode(data)
        if msgs is not None:
            self._took(data, msgs)
            return msgs
        frames = split_frames(data)
        if frames is None:  # not whole MAVLink 2 frames end to end: pymavlink resyncs and names the junk
            return self.parse_buffer(data) or []
        out: list[Any] = []
        for frame in frames:  # a datagram of plain frames and a few others: only the others to pymavlink
            got = _CODEC.decode(frame)
            if got is not None:
                self._took(frame, got)
            else:
                got = self.parse_buffer(frame) or []
                self._reset()  # (a whole frame leaves nothing behind; a bad one neither)
            out.extend(got)
        return out

    def _reset(self) -> None:
        """pymavlink's parser as new: no partial frame carries over into the next datagram (or frame)."""
        self.buf = bytearray()
        self.buf_index = 0
        self.expected_length = mavlink.HEADER_LEN_V1 + 2
        self.have_prefix_error = False

    def _took(self, data: bytes, msgs: list[Any]) -> None:
        """Count (and call back for) what the compiled pass parsed, as pymavlink's parser does."""
        self.total_bytes_received += len(data)
        self.total_packets_received += len(msgs)
        if self.callback is not None and self.callback_args is not None and self.callback_kwargs is not None:
            for m in msgs:
                self.callback(m, *self.callback_args, **self.callback_kwargs)


def split_frames(data: bytes) -> list[bytes] | None:
    """``data`` cut into its MAVLink 2 frames, or None unless it is nothing but MAVLink 2 frames end to end.

    Why: a virtual FCU's datagram of a tick holds its 10 Hz plain messages and, once a second,
    a few with arrays or strings (BATTERY_STATUS, HOME_POSITION, NAMED_VALUE_FLOAT) that the
    compiled pass does not take. Cut apart, only those few go to pymavlink, rather than the
    whole datagram (pymavlink's decodes in a lone UAV's 46 s: 506 before, 92 after). Frames are cut by pymavlink's own
    length rule (header, payload, CRC, a signature when the signed flag is set), so pymavlink
    parses each piece exactly as it would have parsed it within the datagram, bad frames included.
    """
    n, at = len(data), 0
    frames = []
    while at < n:
        if n - at < mavlink.HEADER_LEN_V2 + 2 or data[at] != mavlink.PROTOCOL_MARKER_V2:
            return None
        end = at + mavlink.HEADER_LEN_V2 + 2 + data[at + 1]
        if data[at + 2] & mavlink.MAVLINK_IFLAG_SIGNED:
            end += mavlink.MAVLINK_SIGNATURE_BLOCK_LEN
        if end > n:
            return None
        frames.append(data[at:end])
        at = end
    return frames


def frames_plainly(cls: Any) -> bool:
    """Does the compiled pass frame messages of ``cls`` (False when it is absent)?"""
    return _CODEC is not None and bool(_CODEC.knows(cls))
