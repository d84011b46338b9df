"""MAVLink 2 message signing for the router's ground-station links.

A signed frame carries, after its CRC, a link id, a 48-bit timestamp (10 µs units since
2015-01-01) and the first 6 bytes of SHA-256(key + frame up to the timestamp); receivers drop
frames whose signature does not match or whose timestamp does not grow per stream
(link id, system id, component id) (mavlink.io, "Message signing").

The key is a passphrase in a file, hashed with SHA-256 into the 32-byte secret, as MAVProxy
derives it (``signing key <passphrase>``), so the same file configures the router and MAVProxy.

* :class:`Signer` signs frames going out to one endpoint. Frames keep their sender's ids and
  sequence number; only the signing flag, the CRC and the signature block change, so the
  FCU's stream stays the FCU's stream to the ground station.
* :class:`VerifyingParser` is a pymavlink decoder that checks the signature *before* it
  records a stream's timestamp. (pymavlink's own check records the timestamp first, so one
  forged frame with a far-future timestamp would make every later genuine frame of that
  stream look like a replay.) Unsigned frames are accepted or refused by policy; a frame with
  a wrong signature is always refused. Every outcome is counted.

SHA-256 is the interpreter's built-in one: ``hashlib`` would load OpenSSL into every UAV
process (see ``uav_stack.mav``).
"""

from __future__ import annotations

import copy
import struct
import time
from pathlib import Path
from typing import Any

from uav_stack.mav import mavlink

try:  # the interpreter's own SHA-256: hashlib would load OpenSSL (~4 MB RSS per UAV process)
    from _sha256 import sha256 as _sha256  # type: ignore[import-not-found]  # CPython 3.11
except ImportError:  # pragma: no cover - CPython 3.12+
    from _sha2 import sha256 as _sha256  # type: ignore[import-not-found]

EPOCH_2015 = 1420070400  # s: the signing timestamp's epoch (2015-01-01 00:00 UTC)
MAX_STREAMS = 256  # (link id, sysid, compid) streams whose last timestamp a verifier remembers
NEW_STREAM_SLACK = 6_000_000  # 60 s in 10 µs units: how far behind our clock a new stream may start
MIN_PASSPHRASE = 8  # characters
_V2 = mavlink.PROTOCOL_MARKER_V2
_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED
_SIG_LEN = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN  # 13: link id, timestamp, signature


class SigningKeyError(ValueError):
    """A key file that cannot be used; the message names the file."""


def signing_timestamp(now: float | None = None) -> int:
    """Now, in the signing timestamp's units (10 µs since 2015-01-01)."""
    t = time.time() if now is None else now
    return int((max(t, EPOCH_2015) - EPOCH_2015) * 100_000)


def key_from_passphrase(passphrase: str) -> bytes:
    """The 32-byte secret of a passphrase: SHA-256 of its ASCII bytes (as MAVProxy's signing module does)."""
    return _sha256(passphrase.encode("ascii")).digest()


def read_key_file(path: str | Path) -> bytes:
    """The secret from a passphrase file (one line of printable ASCII without spaces: what
    ``signing key <passphrase>`` takes in MAVProxy)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="ascii").strip()
    except OSError as exc:
        raise SigningKeyError(f"{p}: cannot read the MAVLink signing key: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise SigningKeyError(f"{p}: the MAVLink signing key must be a passphrase in ASCII") from None
    if len(text) < MIN_PASSPHRASE or not text.isprintable() or any(c.isspace() for c in text):
        raise SigningKeyError(f"{p}: the MAVLink signing key must be one passphrase of at least {MIN_PASSPHRASE} "
                              "printable characters without spaces")
    return key_from_passphrase(text)


def write_key_file(path: str | Path) -> Path:
    """A new random passphrase (256 bits) in ``path``, readable by its owner only (0600)."""
    import os
    import secrets

    p = Path(path)
    fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(secrets.token_urlsafe(32) + "\n")
    return p


def is_signed(frame: bytes | bytearray) -> bool:
    return len(frame) > 2 and frame[0] == _V2 and bool(frame[2] & _SIGNED)


class Signer:
    """Signs the frames sent to one endpoint (one link id, one monotonic timestamp)."""

    def __init__(self, key: bytes, link_id: int = 0):
        self.key = key
        self.link_id = link_id & 0xFF
        self.timestamp = signing_timestamp()
        self._repack = mavlink.MAVLink(None)  # MAVLink 1 frames are re-encoded as MAVLink 2 first

    def sign(self, msg: Any) -> bytes | None:
        """``msg``'s frame, signed; None if it cannot be (a message outside our dialect)."""
        known = mavlink.mavlink_map.get(msg.get_msgId())  # the CRC needs the message's crc_extra
        if known is None or isinstance(msg, mavlink.MAVLink_unknown):
            return None
        crc_extra = known.crc_extra
        frame = msg.get_msgbuf()
        if frame[0] != _V2:
            frame = self._as_v2(msg)
        body = bytearray(frame[:mavlink.HEADER_LEN_V2 + frame[1]])  # magic, header, payload
        body[2] = (body[2] | _SIGNED) & 0xFF
        crc = mavlink.x25crc(body[1:])
        crc.accumulate(bytes((crc_extra,)))
        body += struct.pack("<H", crc.crc)
        # our clock, and strictly increasing per frame: the receiver refuses a timestamp it has seen
        self.timestamp = max(self.timestamp + 1, signing_timestamp())
        body += struct.pack("<BQ", self.link_id, self.timestamp)[:7]
        body += _sha256(self.key + bytes(body)).digest()[:6]
        return bytes(body)

    def _as_v2(self, msg: Any) -> bytes:
        p = self._repack
        p.seq, p.srcSystem, p.srcComponent = msg.get_seq(), msg.get_srcSystem(), msg.get_srcComponent()
        return copy.copy(msg).pack(p)  # a copy: pack() rewrites the message's own buffer


class VerifyingParser(mavlink.MAVLink):
    """A MAVLink decoder that verifies signatures with ``key`` (see the module docstring).

    ``require``: refuse unsigned frames (else accept them, counted). Counters: ``signed``
    (good signature), ``bad_signature`` (wrong signature, or a replayed/old timestamp),
    ``unsigned_accepted``, ``unsigned_refused``.
    """

    def __init__(self, key: bytes, require: bool):
        super().__init__(None)
        self.robust_parsing = True
        self.require = require
        self.signing.secret_key = key
        self.signing.timestamp = signing_timestamp()
        self.signing.allow_unsigned_callback = self._allow_unsigned
        self.signed = self.bad_signature = self.unsigned_accepted = self.unsigned_refused = 0
        self._last_bad = False

    def check_signature(self, msgbuf: bytearray, srcSystem: int, srcComponent: int) -> bool:  # noqa: N803 - pymavlink's names
        """Signature first, then the timestamp; a stream's timestamp moves only on a good frame."""
        sig = self.signing
        expected = _sha256(sig.secret_key + bytes(msgbuf[:-6])).digest()[:6]
        stamp = bytes(msgbuf[-12:-6]) + b"\0\0"
        timestamp = struct.unpack("<Q", stamp)[0]
        stream = (msgbuf[-13], srcSystem, srcComponent)
        ok = expected == bytes(msgbuf[-6:])
        if ok:
            last = sig.stream_timestamps.get(stream)
            ok = timestamp > last if last is not None else timestamp + NEW_STREAM_SLACK >= sig.timestamp
        if not ok:
            self.bad_signature += 1
            self._last_bad = True
            return False
        streams = sig.stream_timestamps
        streams.pop(stream, None)
        streams[stream] = timestamp
        if len(streams) > MAX_STREAMS:
            del streams[next(iter(streams))]
        sig.timestamp = max(sig.timestamp, timestamp)
        self.signed += 1
        return True

    def _allow_unsigned(self, mav: Any, msg_id: int) -> bool:
        """pymavlink asks this for unsigned frames and for frames whose signature failed."""
        if self._last_bad:  # a wrong signature is never let through as "unsigned"
            self._last_bad = False
            return False
        if self.require:
            self.unsigned_refused += 1
            return False
        self.unsigned_accepted += 1
        return True

    def counters(self) -> dict[str, int]:
        return {"signed": self.signed, "bad_signature": self.bad_signature,
                "unsigned_accepted": self.unsigned_accepted, "unsigned_refused": self.unsigned_refused}
