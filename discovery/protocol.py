"""The beacon protocol between discovery proxies and the discovery server (docs/discovery.md).

Every datagram is one authenticated message::

    offset  size  field
    0       4     magic  b"MRSD"
    4       1     protocol version (1)
    5       1     message type (MsgType); bit 7 set: a node tag follows the body (TAGGED)
    6       1     n = length of the swarm name (1..32)
    7       n     swarm name, ASCII [A-Za-z0-9_-]
    7+n     8     timestamp, microseconds since the Unix epoch (big-endian)
    15+n    8     nonce (random)
    23+n    ...   body: one msgpack value (layout per type below)
    [end-64 32    node tag (TAGGED only): HMAC-SHA256 over everything before it, keyed with the
                  sender's own beacon token (swarmnet/security/beacon.py)]
    end-32  32    HMAC-SHA256 over everything before it, keyed with the swarm's key

The swarm's key lets its holders in; the node tag binds a BEACON or BYE to the identity it
speaks for: a server that knows the swarm's roster and beacon key (``--identities``) derives
the token of the certificate that identity holds and refuses any other (discovery/identities.py),
so one node's credentials speak only for that node.

The receiver checks, in this order and without ever raising anything but
:class:`ProtocolError`: size (<= MAX_DATAGRAM), magic, version, type, swarm name, that it
knows the swarm's key, the MAC (constant-time), and only then decodes the body. A
:class:`ReplayGuard` then rejects timestamps outside the window and nonces seen before.

Bodies (msgpack arrays)::

    BEACON    [entry, view, period]          proxy -> server, every period
    BYE       [role, node]                   proxy -> server, on clean exit
    PEERS     [snap, part, parts, [entry..]] server -> proxy; snap 0 = push of new/changed
                                             entries, else part of a full snapshot
    GONE      [[role, node]..]               server -> proxy: members that left or expired
    ACK       [view]                         server -> proxy: your view is current
    QUERY     [qid]                          client -> server: list the swarm's registry
    REGISTRY  [qid, part, parts, [[entry, first_seen, last_seen, "ip:port"]..], stats|nil]

    entry = [role, node, realm, software, zid (bin, little-endian), whatami, [locator..]]
    view  = 8-byte digest of the entries the proxy holds for the swarm (see view_digest)
"""

from __future__ import annotations

import os
import re
import struct
import time
from _operator import _compare_digest as compare_digest  # what hmac.compare_digest is
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import msgpack

from groundfloor.errors import Rejected
from swarmnet.keyspace import SWARM_RE, check_swarm

# The interpreter's own SHA-256: hashlib/hmac would load OpenSSL (~4 MB RSS per UAV process).
# Both are private CPython modules that typeshed has no stubs for, hence the ignores.
try:
    from _sha256 import sha256 as _sha256  # type: ignore[import-not-found]  # CPython 3.11
except ImportError:  # pragma: no cover - CPython 3.12+
    from _sha2 import sha256 as _sha256  # type: ignore[import-not-found]

_IPAD = bytes(x ^ 0x36 for x in range(256))
_OPAD = bytes(x ^ 0x5C for x in range(256))


def hmac_sha256(key: bytes, msg: bytes) -> bytes:
    """HMAC-SHA256 (RFC 2104) on the built-in SHA-256, checked against ``hmac`` in the tests."""
    if len(key) > 64:
        key = _sha256(key).digest()
    key = key.ljust(64, b"\0")
    inner = _sha256(key.translate(_IPAD) + msg).digest()
    return _sha256(key.translate(_OPAD) + inner).digest()


MAGIC = b"MRSD"
VERSION = 1
DEFAULT_PORT = 7450  # UDP
MAX_DATAGRAM = 1400  # below the IPv4 MTU of LTE/5G bearers (~1428-1500) minus tunnels
MAC_LEN = 32
NONCE_LEN = 8
MIN_KEY_LEN = 16
DEFAULT_PERIOD = 1.0  # s between beacons
DEFAULT_TTL = 3.0  # s without a beacon before the server forgets a node
DEFAULT_WINDOW = 10.0  # s of clock difference accepted (and how long nonces are remembered)

ROLES = ("uav", "gcs", "edge", "observer")
REALMS = ("virtual", "physical")
MAX_LOCATORS = 8
MAX_LOCATOR_LEN = 100
MAX_SOFTWARE_LEN = 48
LOCATOR_RE = re.compile(r"^[a-z0-9]{2,8}/[\x21-\x7e]{3,}$")

_TS = struct.Struct(">Q")
_MASK64 = (1 << 64) - 1
MAX_ITEMS = 256  # items per array a receiver unpacks (unseal's max_array_len)


TAGGED = 0x80  # type-byte flag: a node tag precedes the MAC


class MsgType(IntEnum):
    BEACON = 1
    BYE = 2
    PEERS = 3
    GONE = 4
    ACK = 5
    QUERY = 6
    REGISTRY = 7


class ProtocolError(Rejected):
    """A datagram we drop; ``reason`` is the counter it is counted under."""


def check_key(key: str | bytes, what: str = "discovery key") -> bytes:
    """Keys are text (e.g. from ``mrswarm discovery keygen``); their UTF-8 bytes key the HMAC."""
    b = key.encode() if isinstance(key, str) else bytes(key)
    if len(b) < MIN_KEY_LEN:
        raise ValueError(f"{what} must be at least {MIN_KEY_LEN} characters (got {len(b)}); "
                         "generate one with `mrswarm discovery keygen`")
    return b


def new_key() -> str:
    return os.urandom(32).hex()


# ---- node entries --------------------------------------------------------------------------------
@dataclass(frozen=True)
class NodeEntry:
    """What a node announces: who it is and where its Zenoh session can be reached."""

    role: str
    node: int
    realm: str
    software: str
    zid: bytes  # wire form (little-endian)
    whatami: int  # 0 router, 1 peer
    locators: tuple[str, ...]

    @property
    def key(self) -> tuple[str, int]:
        return (self.role, self.node)

    @property
    def zid_hex(self) -> str:
        return format(int.from_bytes(self.zid, "little"), "x")

    def to_wire(self) -> list[Any]:
        return [self.role, self.node, self.realm, self.software, self.zid, self.whatami, list(self.locators)]

    @classmethod
    def from_wire(cls, obj: Any) -> NodeEntry:
        if not isinstance(obj, list) or len(obj) != 7:
            raise ProtocolError("invalid_entry", "entry must be a 7-item array")
        role, node, realm, software, zid, whatami, locators = obj
        if role not in ROLES:
            raise ProtocolError("invalid_entry", f"role {role!r}")
        if type(node) is not int or not 1 <= node <= 65535:
            raise ProtocolError("invalid_entry", f"node id {node!r}")
        if realm not in REALMS:
            raise ProtocolError("invalid_entry", f"realm {realm!r}")
        if not isinstance(software, str) or len(software) > MAX_SOFTWARE_LEN:
            raise ProtocolError("invalid_entry", "software version")
        if not isinstance(zid, bytes) or not 1 <= len(zid) <= 16:
            raise ProtocolError("invalid_entry", "zid")
        if whatami not in (0, 1):
            raise ProtocolError("invalid_entry", f"whatami {whatami!r} (only routers and peers can be dialled)")
        if not isinstance(locators, list) or not 1 <= len(locators) <= MAX_LOCATORS:
            raise ProtocolError("invalid_entry", "needs 1..8 locators")
        for loc in locators:
            if not isinstance(loc, str) or len(loc) > MAX_LOCATOR_LEN or not LOCATOR_RE.match(loc):
                raise ProtocolError("invalid_entry", f"locator {loc!r}")
        return cls(role, node, realm, software, zid, whatami, tuple(locators))


def entry_hash(e: NodeEntry) -> int:
    """One entry's 64-bit share of a :func:`view_digest`."""
    return int.from_bytes(_sha256(msgpack.packb(e.to_wire(), use_bin_type=True)).digest()[:8], "big")


def digest_of(total: int) -> bytes:
    """The 8-byte view digest of a sum of :func:`entry_hash` values."""
    return (total & _MASK64).to_bytes(8, "big")


def view_digest(entries: Any) -> bytes:
    """8-byte digest of a set of entries (order-independent): lets the server answer a
    beacon with a tiny ACK when the proxy already holds exactly the current member list.

    It is the sum of the entries' hashes modulo 2**64, so the server keeps one running sum
    per swarm and gets any member's view of the others (sum minus the member's own hash) in
    constant time, whatever the swarm's size. It only decides between an ACK and a full
    snapshot inside an authenticated message; it protects nothing by itself."""
    return digest_of(sum(entry_hash(e) for e in entries))


# ---- envelope --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Envelope:
    type: MsgType
    swarm: str
    ts: float
    nonce: bytes
    body: Any
    tag: bytes = b""  # the node tag of a TAGGED datagram ...
    tagged: bytes = b""  # ... and the bytes it covers

    def tag_matches(self, token: bytes) -> bool:
        """The node tag was made with ``token`` (constant time); False for an untagged datagram."""
        return bool(self.tag) and compare_digest(hmac_sha256(token, self.tagged), self.tag)


def seal(mtype: MsgType, swarm: str, key: bytes, body: Any, ts: float | None = None, nonce: bytes | None = None,
         token: bytes | None = None) -> bytes:
    """One datagram; with ``token`` (the sender's beacon token) it carries the node tag too."""
    sw = swarm.encode()
    check_swarm(swarm)
    head = MAGIC + bytes((VERSION, int(mtype) | (TAGGED if token else 0), len(sw))) + sw
    head += _TS.pack(int((time.time() if ts is None else ts) * 1e6)) + (nonce or os.urandom(NONCE_LEN))
    data = head + msgpack.packb(body, use_bin_type=True)
    if token:
        data += hmac_sha256(token, data)
    data += hmac_sha256(key, data)
    if len(data) > MAX_DATAGRAM:
        raise ValueError(f"message of {len(data)} bytes exceeds {MAX_DATAGRAM}")
    return data


def peek(data: bytes) -> tuple[MsgType, str]:
    """Type and swarm of a datagram, checking only the header (no key needed)."""
    n = len(data)
    if n > MAX_DATAGRAM:
        raise ProtocolError("oversized", f"{n} bytes")
    if n < 7 + 1 + 8 + NONCE_LEN + 1 + MAC_LEN:
        raise ProtocolError("malformed", f"{n} bytes is too short")
    if data[:4] != MAGIC:
        raise ProtocolError("malformed", "bad magic")
    if data[4] != VERSION:
        raise ProtocolError("bad_version", f"protocol version {data[4]}, expected {VERSION}")
    try:
        mtype = MsgType(data[5] & (0xFF ^ TAGGED))
    except ValueError:
        raise ProtocolError("malformed", f"message type {data[5]}") from None
    sl = data[6]
    try:
        swarm = data[7:7 + sl].decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError("malformed", "swarm name") from None
    tail = MAC_LEN * (2 if data[5] & TAGGED else 1)
    if not SWARM_RE.match(swarm) or len(swarm) != sl or n < 7 + sl + 8 + NONCE_LEN + 1 + tail:
        raise ProtocolError("malformed", "swarm name")
    return mtype, swarm


def unseal(data: bytes, key_for: Callable[[str], bytes | None]) -> Envelope:
    """Verify and decode one datagram. Raises only :class:`ProtocolError`."""
    mtype, swarm = peek(data)
    key = key_for(swarm)
    if key is None:
        raise ProtocolError("unknown_swarm", swarm)
    mac = hmac_sha256(key, data[:-MAC_LEN])
    if not compare_digest(mac, data[-MAC_LEN:]):
        raise ProtocolError("bad_mac", f"swarm {swarm}")
    p = 7 + len(swarm)
    ts = _TS.unpack_from(data, p)[0] / 1e6
    nonce = bytes(data[p + 8:p + 8 + NONCE_LEN])
    end = len(data) - MAC_LEN
    tag = tagged = b""
    if data[5] & TAGGED:
        end -= MAC_LEN
        tag, tagged = bytes(data[end:end + MAC_LEN]), bytes(data[:end])
    try:
        body = msgpack.unpackb(data[p + 8 + NONCE_LEN:end], raw=False, use_list=True, strict_map_key=True,
                               max_str_len=MAX_DATAGRAM, max_bin_len=64, max_array_len=MAX_ITEMS, max_map_len=64)
    except Exception as exc:  # msgpack raises many types on bad input; all mean "malformed"
        raise ProtocolError("malformed", f"body: {type(exc).__name__}") from None
    return Envelope(mtype, swarm, ts, nonce, body, tag, tagged)


class ReplayGuard:
    """Rejects messages whose timestamp is outside ``window`` of our clock, or whose nonce was
    already seen (nonces are remembered for twice the window, so a replay cannot outlive them)."""

    def __init__(self, window: float = DEFAULT_WINDOW, max_nonces: int = 200_000):
        self.window = window
        self.max_nonces = max_nonces
        self._seen: set[bytes] = set()
        self._order: deque[tuple[float, bytes]] = deque()

    def check(self, env: Envelope, now: float | None = None) -> None:
        now = time.time() if now is None else now
        if abs(now - env.ts) > self.window:
            raise ProtocolError("stale", f"timestamp {now - env.ts:+.1f} s off (window {self.window:.0f} s)")
        order, seen = self._order, self._seen
        while order and (order[0][0] < now - 2 * self.window or len(order) > self.max_nonces):
            seen.discard(order.popleft()[1])
        k = env.swarm.encode() + env.nonce
        if k in seen:
            raise ProtocolError("replayed", "nonce seen before")
        seen.add(k)
        order.append((now, k))


# ---- bodies ------------------------------------------------------------------------------------------
def _array(body: Any, n: int, what: str) -> list[Any]:
    if not isinstance(body, list) or len(body) != n:
        raise ProtocolError("malformed", f"{what} body must be a {n}-item array")
    return body


def _digest(v: Any) -> bytes:
    if not isinstance(v, bytes) or len(v) != 8:
        raise ProtocolError("malformed", "view digest")
    return v


def _node_key(v: Any) -> tuple[str, int]:
    if not isinstance(v, list) or len(v) != 2 or v[0] not in ROLES or type(v[1]) is not int or not 1 <= v[1] <= 65535:
        raise ProtocolError("malformed", "node key")
    return (v[0], v[1])


def _count(v: Any, lo: int, hi: int, what: str) -> int:
    if type(v) is not int or not lo <= v <= hi:
        raise ProtocolError("malformed", what)
    return v


@dataclass(frozen=True)
class Beacon:
    entry: NodeEntry
    view: bytes
    period: float


def beacon_body(b: Beacon) -> list[Any]:
    return [b.entry.to_wire(), b.view, b.period]


def parse_beacon(body: Any) -> Beacon:
    entry, view, period = _array(body, 3, "BEACON")
    if not isinstance(period, (int, float)) or not 0.05 <= period <= 60:
        raise ProtocolError("malformed", "period")
    return Beacon(NodeEntry.from_wire(entry), _digest(view), float(period))


def parse_bye(body: Any) -> tuple[str, int]:
    return _node_key(body)


@dataclass(frozen=True)
class Peers:
    snap: int  # 0: a push of new/changed entries; else the id of a full snapshot
    part: int
    parts: int
    entries: tuple[NodeEntry, ...]


def peers_body(p: Peers) -> list[Any]:
    return [p.snap, p.part, p.parts, [e.to_wire() for e in p.entries]]


def parse_peers(body: Any) -> Peers:
    snap, part, parts, entries = _array(body, 4, "PEERS")
    _count(snap, 0, 0xFFFFFFFF, "snapshot id")
    _count(parts, 1, 1024, "parts")
    _count(part, 0, parts - 1, "part")
    if not isinstance(entries, list):
        raise ProtocolError("malformed", "entries")
    return Peers(snap, part, parts, tuple(NodeEntry.from_wire(e) for e in entries))


def parse_gone(body: Any) -> list[tuple[str, int]]:
    if not isinstance(body, list):
        raise ProtocolError("malformed", "GONE body")
    return [_node_key(k) for k in body]


def parse_ack(body: Any) -> bytes:
    return _digest(_array(body, 1, "ACK")[0])


def parse_query(body: Any) -> int:
    return _count(_array(body, 1, "QUERY")[0], 0, 0xFFFFFFFF, "query id")


@dataclass(frozen=True)
class RegisteredNode:
    """A registry row as the server reports it (times are the server's clock)."""

    swarm: str
    entry: NodeEntry
    first_seen: float
    last_seen: float
    address: str

    def to_dict(self) -> dict[str, Any]:
        e = self.entry
        return {"swarm": self.swarm, "role": e.role, "node": e.node, "realm": e.realm, "software": e.software,
                "zid": e.zid_hex, "locators": list(e.locators), "first_seen": self.first_seen,
                "last_seen": self.last_seen, "address": self.address}


def parse_registry(body: Any, swarm: str) -> tuple[int, int, int, list[RegisteredNode], dict[str, Any] | None]:
    qid, part, parts, rows, stats = _array(body, 5, "REGISTRY")
    _count(qid, 0, 0xFFFFFFFF, "query id")
    _count(parts, 1, 1024, "parts")
    _count(part, 0, parts - 1, "part")
    if not isinstance(rows, list) or (stats is not None and not isinstance(stats, dict)):
        raise ProtocolError("malformed", "registry rows")
    out = []
    for r in rows:
        if (not isinstance(r, list) or len(r) != 4 or not all(isinstance(x, (int, float)) for x in r[1:3])
                or not isinstance(r[3], str)):
            raise ProtocolError("malformed", "registry row")
        out.append(RegisteredNode(swarm, NodeEntry.from_wire(r[0]), float(r[1]), float(r[2]), r[3]))
    return qid, part, parts, out, stats


BODY_BUDGET = MAX_DATAGRAM - 120  # bytes of items per datagram: the envelope and array headers take the rest


def packed_size(obj: Any) -> int:
    return len(msgpack.packb(obj, use_bin_type=True))


def chunk_entries(items: list[Any], budget: int = BODY_BUDGET, max_items: int = MAX_ITEMS) -> list[list[Any]]:
    """Split wire-form items into groups whose msgpack encoding fits one datagram (and that a
    receiver unpacks: at most ``max_items`` per group). Always at least one group."""
    groups: list[list[Any]] = [[]]
    size = 0
    for it in items:
        n = packed_size(it)
        if groups[-1] and (size + n > budget or len(groups[-1]) >= max_items):
            groups.append([])
            size = 0
        groups[-1].append(it)
        size += n
    return groups


class PartAssembler:
    """Collects the parts of multi-datagram answers (snapshots, registry answers) by message id.

    A part that disagrees with the ones already held about how many parts there are starts
    the message over (counted in ``inconsistent``); it never raises. Only the newest message
    id is held, so memory is bounded by one message (at most 1024 parts).
    """

    def __init__(self) -> None:
        self.msg_id: int | None = None
        self.parts = 0
        self.got: dict[int, list[Any]] = {}
        self.inconsistent = 0

    def add(self, msg_id: int, part: int, parts: int, items: list[Any] | tuple[Any, ...]) -> list[Any] | None:
        """Store one part; the whole message's items, in part order, once every part is in."""
        if not 0 <= part < parts:
            self.inconsistent += 1
            return None
        if msg_id != self.msg_id or parts != self.parts:
            if msg_id == self.msg_id:
                self.inconsistent += 1
            self.msg_id, self.parts, self.got = msg_id, parts, {}
        self.got[part] = list(items)
        if len(self.got) < parts:
            return None
        out = [it for i in range(parts) for it in self.got[i]]
        self.msg_id, self.parts, self.got = None, 0, {}
        return out
