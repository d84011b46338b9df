"""MAVLink 2 message signing for the router's ground-station links.

A signed frame carries, after its CRC, a link id, a 48-bit timestamp (10 µs units since
2015-01-01) and the first 6 bytes of SHA-256(key + frame up to the timestamp); receivers drop
frames whose signature does not match or whose timestamp does not grow per stream
(link id, system id, component id) (mavlink.io, "Message signing").

The key is a passphrase in a file, hashed with SHA-256 into the 32-byte secret, as MAVProxy
(``signing key <passphrase>``) and QGroundControl (its MAVLink 2 signing key setting) derive
it, so the same file configures the router and both ground stations. ``mrswarm keys`` keeps
one per swarm (``mavlink.key``) and prints it.

* :class:`Signer` signs frames going out to one endpoint. Frames keep their sender's ids and
  sequence number; only the signing flag, the CRC and the signature block change, so the
  FCU's stream stays the FCU's stream to the ground station.
* :class:`VerifyingParser` is a pymavlink decoder that checks the signature *before* it
  records a stream's timestamp. (pymavlink's own check records the timestamp first, so one
  forged frame with a far-future timestamp would make every later genuine frame of that
  stream look like a replay.) Unsigned frames are refused unless the policy allows them; a
  frame with a wrong signature or a replayed timestamp is always refused, and so is, unless
  unsigned frames are allowed, a frame whose id the dialect does not know (pymavlink returns
  those before it checks any signature). Every outcome is counted.

SHA-256 is the interpreter's built-in one: ``hashlib`` would load OpenSSL into every UAV
process (see ``uav_stack.mav``).
"""

from __future__ import annotations

import copy
import os
import struct
import time
from pathlib import Path
from typing import Any

from groundfloor.errors import MrswarmError
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


class SigningKeyError(ValueError, MrswarmError):
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
    """A new random passphrase (256 bits, as ``mrswarm keys`` makes them) in ``path``, which must
    not exist yet, readable by its owner only (0600)."""
    import secrets

    passphrase = secrets.token_urlsafe(32)
    while passphrase.startswith("-"):  # a command line would read it as an option
        passphrase = secrets.token_urlsafe(32)
    p = Path(path)
    fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(passphrase + "\n")
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


REFUSED_SIGNATURE = "Invalid signature"  # pymavlink's reason for a frame its signature check refused
REFUSED_UNKNOWN_ID = "unknown message id refused"  # ours: an id outside the dialect, on a link that needs signatures
REFUSED_REASONS = frozenset({REFUSED_SIGNATURE, REFUSED_UNKNOWN_ID})  # BAD_DATA that is a refusal, not garbage
# what an unsigned ground station would command with: counted apart among the unsigned frames refused
COMMAND_IDS = frozenset({mavlink.MAVLINK_MSG_ID_COMMAND_LONG, mavlink.MAVLINK_MSG_ID_COMMAND_INT,
                         mavlink.MAVLINK_MSG_ID_SET_MODE})


class VerifyingParser(mavlink.MAVLink):
    """A MAVLink decoder that verifies signatures with ``key`` (see the module docstring).

    ``allow_unsigned``: accept unsigned frames (counted), else refuse them. ``key`` None: no
    signature can be checked, so every signed frame is refused as badly signed (a router
    without a key takes no frame from a ground station unless unsigned ones are allowed).
    Unless unsigned frames are allowed, a frame whose id the dialect does not know is refused
    before anything else: pymavlink would return it as ``MAVLink_unknown`` without checking
    its signature (it cannot check its CRC either).

    Counters: ``signed`` (good signature), ``bad_signature`` (wrong signature), ``replayed``
    (a good signature with a timestamp already seen on its stream, or a new stream older than
    :data:`NEW_STREAM_SLACK`), ``unsigned_accepted``, ``unsigned_refused`` (of which
    ``unsigned_commands_refused`` were COMMAND_LONG, COMMAND_INT or SET_MODE) and
    ``unknown_id_refused``. ``heard_refused`` is set when a well-formed frame (its CRC good) was
    refused for its signature or for having none; the router clears it per datagram.
    """

    def __init__(self, key: bytes | None, allow_unsigned: bool = False):
        super().__init__(None)
        self.robust_parsing = True
        self.allow_unsigned = allow_unsigned
        # no key: a random one nobody has, so every signature fails and pymavlink still asks about unsigned frames
        self.signing.secret_key = key if key is not None else os.urandom(32)
        self.signing.timestamp = signing_timestamp()
        self.signing.allow_unsigned_callback = self._allow_unsigned
        self.signed = self.bad_signature = self.replayed = self.unsigned_accepted = self.unsigned_refused = 0
        self.unsigned_commands_refused = self.unknown_id_refused = 0
        self.heard_refused = False
        self._last_bad = False

    def decode(self, msgbuf: bytearray) -> Any:
        """pymavlink's decode, after refusing (unless unsigned frames are allowed) an id outside the dialect."""
        if not self.allow_unsigned:
            if msgbuf[0] == _V2:
                msg_id = msgbuf[7] | msgbuf[8] << 8 | msgbuf[9] << 16 if len(msgbuf) >= mavlink.HEADER_LEN_V2 else -1
            else:
                msg_id = msgbuf[5] if len(msgbuf) > 5 else -1
            if msg_id not in mavlink.mavlink_map:
                self.unknown_id_refused += 1
                raise mavlink.MAVError(REFUSED_UNKNOWN_ID)
        return super().decode(msgbuf)

    def check_signature(self, msgbuf: bytearray, srcSystem: int, srcComponent: int) -> bool:  # noqa: N803 - pymavlink's names
        """Signature first, then the timestamp; a stream's timestamp moves only on a good frame."""
        sig = self.signing
        expected = _sha256(sig.secret_key + bytes(msgbuf[:-6])).digest()[:6]
        self._last_bad = True
        if expected != bytes(msgbuf[-6:]):
            self.bad_signature += 1
            return False
        stamp = bytes(msgbuf[-12:-6]) + b"\0\0"
        timestamp = struct.unpack("<Q", stamp)[0]
        stream = (msgbuf[-13], srcSystem, srcComponent)
        last = sig.stream_timestamps.get(stream)
        if not (timestamp > last if last is not None else timestamp + NEW_STREAM_SLACK >= sig.timestamp):
            self.replayed += 1
            return False
        self._last_bad = False
        streams = sig.stream_timestamps
        streams.pop(stream, None)
        streams[stream] = timestamp
        if len(streams) > MAX_STREAMS:
            del streams[next(iter(streams))]
        sig.timestamp = max(sig.timestamp, timestamp)
        self.signed += 1
        return True

    def _allow_unsigned(self, mav: Any, msg_id: int) -> bool:
        """pymavlink asks this for unsigned frames and for frames whose signature failed (in
        both cases after their CRC was found good: a well-formed frame)."""
        if self._last_bad:  # a wrong signature is never let through as "unsigned"
            self._last_bad = False
            self.heard_refused = True
            return False
        if self.allow_unsigned:
            self.unsigned_accepted += 1
            return True
        self.unsigned_refused += 1
        if msg_id in COMMAND_IDS:
            self.unsigned_commands_refused += 1
        self.heard_refused = True
        return False

    def counters(self) -> dict[str, int]:
        return {"signed": self.signed, "bad_signature": self.bad_signature, "replayed": self.replayed,
                "unsigned_accepted": self.unsigned_accepted, "unsigned_refused": self.unsigned_refused,
                "unsigned_commands_refused": self.unsigned_commands_refused, "unknown_id_refused": self.unknown_id_refused}
