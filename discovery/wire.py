"""Zenoh's UDP scouting messages (Scout and Hello), encoded and decoded by hand.

The discovery proxy (``discovery/proxy.py``) speaks this to the Zenoh session of its own
process, over loopback only:

* it sends a **Scout** to the session's scouting responder and gets back the session's
  **Hello** (its ZID, whatami and locators), sent from the session's scouting socket;
* it sends the **Hellos of remote nodes** to that scouting socket, and Zenoh dials their
  locators as if it had scouted them itself.

Wire format of Zenoh protocol version 0x09 (zenoh 1.x; upstream source:
``commons/zenoh-codec/src/scouting/{scout,hello}.rs``). Pinned by ``tests/test_discovery_wire.py`` against a live
session, so an upgrade that changes it fails loudly::

    Scout:  0x01 | version | flags = what (3 bits: router 1, peer 2, client 4) [| I 0x08 + (zid_len-1) << 4] [zid]
    Hello:  0x02 [| L 0x20 locators present] [| Z 0x80 extensions] | version
            | flags = whatami (router 0, peer 1, client 2) | (zid_len-1) << 4
            | zid (zid_len bytes, little-endian) | [VLE count, then VLE length + UTF-8 per locator]

A ZID is a 128-bit integer; its text form (``str(session.info.zid())``) is lower-case hex
without leading zeros, its wire form the little-endian bytes without trailing zero bytes.
"""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass

from groundfloor.errors import Rejected

PROTOCOL_VERSION = 0x09
SCOUT_ID = 0x01
HELLO_ID = 0x02
FLAG_L = 0x20  # Hello: locators present
FLAG_Z = 0x80  # extensions follow
SCOUT_FLAG_I = 0x08  # Scout: zid present

WHATAMI_ROUTER, WHATAMI_PEER, WHATAMI_CLIENT = 0, 1, 2
WHAT_ROUTER, WHAT_PEER, WHAT_CLIENT = 1, 2, 4

MAX_LOCATORS = 16
MAX_LOCATOR_LEN = 256


class WireError(Rejected):
    """A datagram that is not a Scout/Hello we understand; ``reason`` is a counter name."""


@dataclass(frozen=True)
class Hello:
    zid: bytes  # little-endian wire bytes, 1..16, no trailing zero byte (except ZID 0)
    whatami: int = WHATAMI_PEER
    locators: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not 1 <= len(self.zid) <= 16:
            raise ValueError(f"a ZID has 1..16 bytes, got {len(self.zid)}")
        if self.whatami not in (WHATAMI_ROUTER, WHATAMI_PEER, WHATAMI_CLIENT):
            raise ValueError(f"whatami must be 0, 1 or 2, got {self.whatami}")

    @property
    def zid_hex(self) -> str:
        return zid_to_hex(self.zid)


def zid_to_hex(zid: bytes) -> str:
    """Wire bytes -> the text form Zenoh prints (``str(session.info.zid())``)."""
    return format(int.from_bytes(zid, "little"), "x")


def zid_from_hex(text: str) -> bytes:
    """Text form -> wire bytes (little-endian, trailing zero bytes dropped)."""
    value = int(text, 16)
    if not 0 <= value < 1 << 128:
        raise ValueError(f"ZID {text!r} does not fit 128 bits")
    n = max(1, (value.bit_length() + 7) // 8)
    return value.to_bytes(n, "little")


# ---- VLE (LEB128) ---------------------------------------------------------------------------
def _vle(value: int) -> bytes:
    out = bytearray()
    while True:
        b = value & 0x7F
        value >>= 7
        if value:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _read_vle(data: bytes, pos: int, limit: int) -> tuple[int, int]:
    value = shift = 0
    for _ in range(10):
        if pos >= len(data):
            raise WireError("truncated", "in a length")
        b = data[pos]
        pos += 1
        value |= (b & 0x7F) << shift
        if not b & 0x80:
            if value > limit:
                raise WireError("too_large", f"length {value} > {limit}")
            return value, pos
        shift += 7
    raise WireError("malformed", "length longer than 10 bytes")


# ---- Scout -----------------------------------------------------------------------------------
def encode_scout(what: int = WHAT_ROUTER | WHAT_PEER | WHAT_CLIENT) -> bytes:
    return bytes((SCOUT_ID, PROTOCOL_VERSION, what & 0x07))


# ---- Hello -----------------------------------------------------------------------------------
def encode_hello(h: Hello) -> bytes:
    header = HELLO_ID | (FLAG_L if h.locators else 0)
    out = bytearray((header, PROTOCOL_VERSION, (h.whatami & 0x03) | ((len(h.zid) - 1) << 4)))
    out += h.zid
    if h.locators:
        out += _vle(len(h.locators))
        for loc in h.locators:
            b = loc.encode()
            out += _vle(len(b)) + b
    return bytes(out)


def decode_hello(data: bytes) -> Hello:
    """Parse a Hello; raises :class:`WireError` for anything else (never another exception)."""
    if len(data) < 4:
        raise WireError("truncated", f"{len(data)} bytes")
    header = data[0]
    if header & 0x1F != HELLO_ID:
        raise WireError("not_hello", f"message id {header & 0x1F}")
    if data[1] != PROTOCOL_VERSION:
        raise WireError("bad_version", f"zenoh scouting version {data[1]:#x}, expected {PROTOCOL_VERSION:#x}")
    flags = data[2]
    whatami = flags & 0x03
    if whatami == 3:
        raise WireError("malformed", "whatami 3")
    zlen = 1 + (flags >> 4)
    pos = 3 + zlen
    if len(data) < pos:
        raise WireError("truncated", "in the ZID")
    zid = bytes(data[3:pos])
    locators: list[str] = []
    if header & FLAG_L:
        count, pos = _read_vle(data, pos, MAX_LOCATORS)
        for _ in range(count):
            n, pos = _read_vle(data, pos, MAX_LOCATOR_LEN)
            if pos + n > len(data):
                raise WireError("truncated", "in a locator")
            try:
                locators.append(data[pos:pos + n].decode())
            except UnicodeDecodeError:
                raise WireError("malformed", "locator is not UTF-8") from None
            pos += n
    # extensions (Z flag) are ignored: a Hello we relay is re-encoded from its fields
    return Hello(zid, whatami, tuple(locators))


# ---- locators --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Locator:
    """``proto/host:port[?metadata][#config]``, split; ``host`` without IPv6 brackets."""

    proto: str
    host: str
    port: str
    tail: str = ""  # "?..." / "#..." kept verbatim

    @classmethod
    def parse(cls, text: str) -> Locator:
        if "/" not in text:
            raise ValueError(f"locator {text!r} has no protocol")
        proto, rest = text.split("/", 1)
        tail = ""
        for sep in ("?", "#"):
            if sep in rest:
                i = rest.index(sep)
                rest, tail = rest[:i], rest[i:] + tail
        if rest.startswith("["):
            end = rest.find("]")
            if end < 0 or not rest[end + 1:].startswith(":"):
                raise ValueError(f"locator {text!r}: bad IPv6 address")
            host, port = rest[1:end], rest[end + 2:]
        else:
            if ":" not in rest:
                raise ValueError(f"locator {text!r} has no port")
            host, port = rest.rsplit(":", 1)
        return cls(proto, host, port, tail)

    def __str__(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.proto}/{host}:{self.port}{self.tail}"

    def with_host(self, host: str) -> Locator:
        return Locator(self.proto, host, self.port, self.tail)

    @property
    def is_loopback(self) -> bool:
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:
            return self.host == "localhost"


def advertised_locators(locators: tuple[str, ...] | list[str], advertise: tuple[str, ...] = (),
                        keep_loopback: bool = False) -> tuple[str, ...]:
    """The locators a node should announce to remote nodes.

    ``advertise`` entries are either whole locators (``tcp/203.0.113.5:7447``, used
    verbatim) or bare hosts (``203.0.113.5``), which replace the host of every locator the
    session listens on (same protocol and port), e.g. a public address in front of a NAT
    that forwards the port. Without ``advertise``, loopback locators are dropped unless
    ``keep_loopback`` (everything runs on one machine).
    """
    parsed = []
    for text in locators:
        try:
            parsed.append(Locator.parse(text))
        except ValueError:
            continue
    if advertise:
        out: list[str] = []
        for a in advertise:
            if "/" in a:
                out.append(a)
            else:
                out.extend(str(p.with_host(a)) for p in parsed if p.proto in ("tcp", "udp", "tls", "quic"))
        return tuple(dict.fromkeys(out))
    return tuple(dict.fromkeys(str(p) for p in parsed if keep_loopback or not p.is_loopback))
