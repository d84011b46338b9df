"""Swarm messages: dataclasses and their versioned msgpack wire format.

Every message is a msgpack array whose first element is a one-byte *tag*:
``tag = kind << 4 | version``. Decoding checks the tag, the array length, every field's
type and range, and the payload size, and raises :class:`DecodeError` (with a short
``reason`` used as a counter name) for anything else. Nothing here raises any other
exception on bad input.

Next to the codec live the *acceptance rules*: what a receiver takes from the network beyond
a payload that decodes (the key names the payload's UAV, a message goes where its key says,
a command targets this UAV, nobody else speaks with our id). Each rule is a small function
raising :class:`Rejected` with a counter name (``DecodeError`` is one kind of rejection), and
each ``accept_*`` function composes the rules of one stream. :mod:`swarmnet.receive` runs them
on every sample and counts each rejection, so bad input never reaches the agent.

The pose is the hot message (10 Hz from every UAV to every other UAV), so it is quantised
to fixed-point integers, which msgpack stores in 1-5 bytes: at most **48 bytes** per pose
for any value in range (the paper's ROS/swarmio pose was 399 B). Resolution: 1 cm, 1 cm/s,
1e-4 rad, 1 ms of sim time, 1 us of wall time. The full layout is in docs/keyspace.md.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Annotated, Any

import msgpack
import msgspec

from groundfloor.errors import Rejected  # a sample a receiver does not take, counted in NodeStats.rejected
from swarmnet.keyspace import message_route, uav_from_key


class DecodeError(Rejected):
    """A payload that is not a valid message (``malformed``, ``oversized``, ``wrong_type``, ...)."""


class Kind(IntEnum):
    POSE = 1
    TELEMETRY = 2
    STATE = 3
    SWARM_MESSAGE = 4
    COMMAND = 5
    COMMAND_ACK = 6
    POSE_BATCH = 7
    FAULT = 8
    READING = 9
    ACTUATION = 10
    TRAFFIC = 11
    BEHAVIOUR_REPORT = 12


class Realm(IntEnum):
    VIRTUAL = 0
    PHYSICAL = 1

    @classmethod
    def parse(cls, value: str | int | Realm) -> Realm:
        if isinstance(value, str):
            try:
                return cls[value.upper()]
            except KeyError:
                raise ValueError(f"realm must be 'virtual' or 'physical', not {value!r}") from None
        return cls(value)

    @property
    def label(self) -> str:
        return self.name.lower()


VERSION = 1
BATCH_VERSION = 2  # v2 carries the key (sender) of every pose; v1 carried the payloads only


def tag(kind: Kind, version: int = VERSION) -> int:
    return (int(kind) << 4) | version


# --- limits ----------------------------------------------------------------------------
UAV_ID_MIN, UAV_ID_MAX = 1, 65535
MAX_POSE_BYTES = 48
MAX_TELEMETRY_BYTES = 256
MAX_STATE_BYTES = 512
MAX_COMMAND_BYTES = 1024
DEFAULT_MAX_MESSAGE_BYTES = 64 * 1024
MAX_BATCH_POSES = 4096
MAX_BATCH_BYTES = 16 + MAX_BATCH_POSES * (MAX_POSE_BYTES + 2) + 16
MAX_READING_POINTS = 64  # detections in one reading (burning cells, targets)
MAX_READING_BYTES = 1536  # header (~80 B) + at most 64 points of <= 20 B
MAX_ACTUATION_BYTES = 128
MAX_TRAFFIC_REPORTS = 1024
MAX_TRAFFIC_BYTES = 32 + MAX_TRAFFIC_REPORTS * 48
READING_LIMIT = 1e12  # |value| and |point value| of a reading, in the sensor's unit
AMOUNT_LIMIT = 1e6  # an actuation's amount, in the actuator's unit (litres for a spray)
_INT16 = 32767
_INT32 = 2**31 - 1
_UINT32 = 2**32 - 1
_UINT64 = 2**64 - 1
XY_LIMIT_M = _INT32 / 100.0  # ~21,474 km, effectively unbounded; stored as int32 cm
Z_LIMIT_M = _INT16 / 100.0  # +-327.67 m around the swarm origin's altitude, stored as int16 cm
SPEED_LIMIT_MS = _INT16 / 100.0  # +-327.67 m/s per axis
TOPIC_RE = re.compile(r"^[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*$")
NAME_RE = re.compile(r"^[A-Za-z0-9_\-]{1,32}$")
MAX_TOPIC_LEN = 64
MAX_TEXT_LEN = 200
MAX_FAULT_BYTES = 256
MAX_FAULT_ARGS = 8
VALUE_NAME_RE = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")  # a name a behaviour records a value under (ctx.record)
MAX_REPORT_SAMPLES = 256  # recorded values in one behaviour report
MAX_REPORT_TOPICS = 64  # message topics in one behaviour report
MAX_REPORT_BYTES = 32 * 1024  # every report within the bounds above fits (about 30 KiB at most)


def check_uav_id(uav: Any, field_name: str = "uav") -> int:
    if type(uav) is not int or not (UAV_ID_MIN <= uav <= UAV_ID_MAX):
        raise DecodeError("bad_field", f"{field_name} must be an integer in {UAV_ID_MIN}..{UAV_ID_MAX}, got {uav!r}")
    return uav


# --- dataclasses -------------------------------------------------------------------------
@dataclass(slots=True)
class Pose:
    """Where a UAV is, in the swarm's shared ENU frame (metres from the swarm origin).

    Treat as immutable. It is not ``frozen`` only because a frozen dataclass's ``__init__``
    costs 6x more (1.6 vs 0.3 us), and a UAV decodes ~500 poses a second at N = 50.
    """

    uav: int
    realm: Realm
    seq: int  # 16-bit, wraps; receivers count gaps as losses
    t_sim: float  # flight-controller (simulation) time, s since its boot
    t_wall: float  # wall-clock time the pose was sampled, s since the Unix epoch
    x: float
    y: float
    z: float
    vx: float
    vy: float
    vz: float
    yaw: float  # rad, ENU convention (0 = east, counter-clockwise)


@dataclass(frozen=True, slots=True)
class Telemetry:
    """Flight-controller status a ground station wants, at a low rate (1-2 Hz)."""

    uav: int
    realm: Realm
    seq: int
    t_wall: float
    mode: str
    armed: bool
    battery: float  # remaining fraction 0..1, or -1 if unknown
    voltage: float  # V, or -1 if unknown
    lat: float
    lon: float
    alt: float  # AMSL, m
    rtf: float  # real-time factor of the FCU (1.0 for a physical UAV)
    # the UAV's pose ages over its last full second, p50 in ms (-1: unknown, or from a sender
    # that predates them): transport (sender's stamp -> arrival) and at use (arrival -> controller)
    transport_ms: float = -1.0
    use_ms: float = -1.0


@dataclass(frozen=True, slots=True)
class AgentState:
    """The agent's own state machine: phase, behaviour, override and a short detail."""

    uav: int
    realm: Realm
    seq: int
    t_wall: float
    phase: str  # e.g. idle, ready, takeoff, mission, hold, landing, landed, done, error
    behaviour: str
    override: str = ""  # non-empty while a human/GCS override suspends the behaviour
    detail: str = ""


@dataclass(frozen=True, slots=True)
class SwarmMessage:
    """Application message between UAVs: broadcast (``dst`` 0) or unicast."""

    src: int
    dst: int  # 0 = broadcast to the swarm
    topic: str
    seq: int
    t_wall: float
    body: Any  # any msgpack-able value


@dataclass(frozen=True, slots=True)
class Command:
    """A command to one UAV or (``target`` 0) to the whole swarm."""

    sender: str  # who sent it (e.g. "gcs", "runner")
    cmd_id: int
    target: int  # 0 = all UAVs of the swarm
    verb: str
    args: dict[str, Any] = field(default_factory=dict)
    t_wall: float = 0.0


@dataclass(frozen=True, slots=True)
class CommandAck:
    uav: int
    cmd_id: int
    ok: bool
    message: str
    t_wall: float


@dataclass(frozen=True, slots=True)
class PoseBatch:
    """Poses of many UAVs in one message (the edge pose feed), each still a pose payload.

    ``senders[i]`` is the UAV whose key ``poses[i]`` arrived on at the edge (the edge's access
    control bound that key to the UAV's certificate), so a receiver checks it again exactly as
    for a direct pose (:func:`accept_batched_pose`).
    """

    seq: int
    t_wall: float
    senders: list[int]  # the UAV id of each pose's key, in order
    poses: list[bytes]  # encoded Pose payloads, validated again by every receiver


@dataclass(frozen=True, slots=True)
class FaultInjection:
    """A fault the experiment controller injects into one virtual UAV (docs/reliability.md).

    The virtual UAV process applies it to its virtual FCU or to the link between the FCU and
    the agent, and acknowledges it on its ack key (``cmd_id = fault_id``); a physical UAV's
    agent refuses it. ``args`` holds finite numbers only, named with their unit
    (``duration_s``, ``dx_m``, ``dy_m``, ``sigma_m``, ``level``).
    """

    sender: str
    fault_id: int
    target: int  # the UAV; never 0 (a fault is injected into one UAV at a time)
    kind: str  # fcu_link_loss, gps_jump, gps_noise, battery_drop
    args: dict[str, float] = field(default_factory=dict)
    t_wall: float = 0.0


@dataclass(frozen=True, slots=True)
class Reading:
    """One virtual sensor reading for one UAV, computed at the edge from its shared pose (docs/world.md).

    ``value`` is the scalar (a concentration, a tank level, a count; 0/1 for a binary sensor);
    ``points`` are detections ``(x, y, v)`` in the swarm's ENU frame, metres (burning cells
    with their heat, targets with their id). ``t_meas`` is the instant the reading describes
    and ``t_sent`` when the edge released it: the difference is the sensor's latency.
    """

    uav: int
    sensor: str
    seq: int
    t_meas: float  # wall, s
    t_sent: float  # wall, s
    value: float
    points: tuple[tuple[float, float, float], ...] = ()


@dataclass(frozen=True, slots=True)
class Actuation:
    """A UAV's request to its virtual actuator (``amount`` in the actuator's unit: litres for a spray).

    It carries no position: the world applies it where it tracks the UAV (its last shared pose),
    so a UAV cannot act where it is not.
    """

    uav: int
    actuator: str
    seq: int
    t_wall: float
    amount: float


@dataclass(frozen=True, slots=True)
class TrafficReport:
    """Another swarm's UAV as traffic, like Remote ID: an opaque track id, where, how fast; nothing else."""

    track: int  # stable for the run, says nothing about the swarm or the UAV id
    t_wall: float  # when the position was sampled, s
    lat: float  # degrees
    lon: float  # degrees
    alt: float  # metres AMSL
    ve: float  # m/s east
    vn: float  # m/s north
    vu: float  # m/s up


@dataclass(frozen=True, slots=True)
class Traffic:
    """The airspace feed for one swarm: every UAV of the other swarms, in one message."""

    seq: int
    t_wall: float
    reports: tuple[TrafficReport, ...]


@dataclass(frozen=True, slots=True)
class TopicCounts:
    """A behaviour's counters of one message topic since its start (uav_stack/sdk/adapter.py)."""

    sent: int
    send_errors: int
    received: int
    rejected: int
    dropped: int  # received, but over the inbox's bound between two steps
    age_mean_ms: float | None  # of what arrived; None: nothing yet
    age_max_ms: float | None


@dataclass(frozen=True, slots=True)
class BehaviourReport:
    """What a UAV's behaviour recorded since the previous report, and its message counters (docs/sdk.md).

    ``samples`` are ``(t_wall, name, value)`` in the order recorded (``ctx.record``), at most
    :data:`MAX_REPORT_SAMPLES`; a value may be any float (NaN and infinities too). ``dropped``
    counts the samples no report carried (over that bound) and ``refused`` the ``ctx.record``
    calls refused (a bad name or value, too many names), both since the start.
    """

    uav: int
    seq: int
    t_wall: float
    samples: tuple[tuple[float, str, float], ...] = ()
    topics: dict[str, TopicCounts] = field(default_factory=dict)
    dropped: int = 0
    refused: int = 0


Message = (Pose | Telemetry | AgentState | SwarmMessage | Command | CommandAck | PoseBatch | FaultInjection | Reading | Actuation
           | Traffic | BehaviourReport)


# --- helpers -------------------------------------------------------------------------------
def _unpack(data: bytes | bytearray | memoryview, limit: int) -> list[Any]:
    if len(data) > limit:
        raise DecodeError("oversized", f"{len(data)} bytes > {limit}")
    if not data:
        raise DecodeError("malformed", "empty payload")
    try:
        obj = msgpack.unpackb(data, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several types (ExtraData, FormatError, StackError, TypeError...)
        raise DecodeError("malformed", f"not msgpack: {type(exc).__name__}") from None
    if type(obj) is not list or not obj:
        raise DecodeError("malformed", "expected a non-empty msgpack array")
    return obj


def _expect(obj: list[Any], kind: Kind, n: int, version: int = VERSION) -> None:
    t = obj[0]
    if type(t) is not int:
        raise DecodeError("malformed", "tag is not an integer")
    if t >> 4 != kind:
        raise DecodeError("wrong_type", f"expected {kind.name.lower()}, got kind {t >> 4}")
    if t & 0xF != version:
        raise DecodeError("wrong_version", f"{kind.name.lower()} version {t & 0xF}, this node speaks {version}")
    if len(obj) != n:
        raise DecodeError("malformed", f"{kind.name.lower()} has {len(obj)} fields, expected {n}")


def _int(v: Any, lo: int, hi: int, name: str) -> int:
    if type(v) is not int or not (lo <= v <= hi):
        raise DecodeError("bad_field", f"{name}={v!r} outside {lo}..{hi}")
    return v


def _num(v: Any, lo: float, hi: float, name: str) -> float:
    if type(v) not in (int, float) or not (lo <= v <= hi):  # NaN fails the comparison too
        raise DecodeError("bad_field", f"{name}={v!r} outside {lo}..{hi}")
    return float(v)


def _str(v: Any, max_len: int, name: str, pattern: re.Pattern[str] | None = None) -> str:
    if type(v) is not str or len(v) > max_len or (pattern is not None and not pattern.match(v)):
        raise DecodeError("bad_field", f"{name}={v!r:.60} is not a valid string")
    return v


def _realm(v: Any) -> Realm:
    if v == 0 and type(v) is int:
        return Realm.VIRTUAL
    if v == 1 and type(v) is int:
        return Realm.PHYSICAL
    raise DecodeError("bad_field", f"realm={v!r}")


def _us(t: float) -> int:
    return int(round(t * 1e6))


def _q(value: float, scale: float, limit: int, name: str) -> int:
    """Quantise to a fixed-point integer, refusing values the wire format cannot hold."""
    q = round(value * scale)  # raises on NaN/inf
    if not -limit <= q <= limit:
        raise ValueError(f"{name}={value} out of range +-{limit / scale}")
    return q


# --- pose ----------------------------------------------------------------------------------
_POSE_TAG = tag(Kind.POSE)


def encode_pose(p: Pose) -> bytes:
    """The pose on the wire (msgpack, fixed-point integers: cm, cm/s, 1e-4 rad, ms, us).

    Every UAV encodes its pose at the pose rate: a valid pose is quantised with no call but
    ``round`` per field and checked in one expression; anything else goes the slow way, which
    names the field (:func:`_checked_pose_fields`)."""
    try:
        fields = [
            _POSE_TAG, p.uav, int(p.realm), p.seq & 0xFFFF, round(p.t_sim * 1000.0), round(p.t_wall * 1e6),
            round(p.x * 100.0), round(p.y * 100.0), round(p.z * 100.0),
            round(p.vx * 100.0), round(p.vy * 100.0), round(p.vz * 100.0),
            round(math.remainder(p.yaw, math.tau) * 1e4),
        ]
    except (ValueError, OverflowError):  # NaN or infinite
        fields = _checked_pose_fields(p)
    if not (UAV_ID_MIN <= fields[1] <= UAV_ID_MAX and 0 <= fields[4] <= _UINT32 and 0 <= fields[5] <= _UINT64
            and -_INT32 <= fields[6] <= _INT32 and -_INT32 <= fields[7] <= _INT32 and -_INT16 <= fields[8] <= _INT16
            and -_INT16 <= fields[9] <= _INT16 and -_INT16 <= fields[10] <= _INT16 and -_INT16 <= fields[11] <= _INT16
            and -_INT16 <= fields[12] <= _INT16):
        fields = _checked_pose_fields(p)
    return msgpack.packb(fields)


def _checked_pose_fields(p: Pose) -> list[int]:
    """The pose's wire fields, or a ValueError naming the first that the wire cannot hold."""
    try:
        fields = [
            _POSE_TAG,
            p.uav,
            int(p.realm),
            p.seq & 0xFFFF,
            round(p.t_sim * 1000.0),
            _us(p.t_wall),
            _q(p.x, 100.0, _INT32, "x"),
            _q(p.y, 100.0, _INT32, "y"),
            _q(p.z, 100.0, _INT16, "z"),
            _q(p.vx, 100.0, _INT16, "vx"),
            _q(p.vy, 100.0, _INT16, "vy"),
            _q(p.vz, 100.0, _INT16, "vz"),
            _q(math.remainder(p.yaw, math.tau), 1e4, _INT16, "yaw"),
        ]
    except (ValueError, OverflowError) as exc:
        raise ValueError(f"cannot encode pose of UAV {p.uav}: {exc}") from None
    if not (UAV_ID_MIN <= p.uav <= UAV_ID_MAX) or not (0 <= fields[4] <= _UINT32) or not (0 <= fields[5] <= _UINT64):
        raise ValueError(f"cannot encode pose of UAV {p.uav}: id or timestamps out of range")
    return fields


_POSE_FIELDS = (  # name, lo, hi of the integer fields 1..12, in wire order
    ("uav", UAV_ID_MIN, UAV_ID_MAX), ("realm", 0, 1), ("seq", 0, 0xFFFF), ("t_sim", 0, _UINT32), ("t_wall", 0, _UINT64),
    ("x", -_INT32, _INT32), ("y", -_INT32, _INT32), ("z", -_INT16, _INT16),
    ("vx", -_INT16, _INT16), ("vy", -_INT16, _INT16), ("vz", -_INT16, _INT16), ("yaw", -31416, 31416),
)
_REALMS = (Realm.VIRTUAL, Realm.PHYSICAL)


class _PoseWire(msgspec.Struct, array_like=True, forbid_unknown_fields=True, gc=False):
    """The pose's wire layout with every range, so that msgspec checks a valid pose in C (the fast path)."""

    tag: Annotated[int, msgspec.Meta(ge=_POSE_TAG, le=_POSE_TAG)]
    uav: Annotated[int, msgspec.Meta(ge=UAV_ID_MIN, le=UAV_ID_MAX)]
    realm: Annotated[int, msgspec.Meta(ge=0, le=1)]
    seq: Annotated[int, msgspec.Meta(ge=0, le=0xFFFF)]
    t_sim: Annotated[int, msgspec.Meta(ge=0, le=_UINT32)]
    t_wall: Annotated[int, msgspec.Meta(ge=0, le=2**63 - 1)]  # us; msgspec bounds stop at int64 (year 292 277)
    x: Annotated[int, msgspec.Meta(ge=-_INT32, le=_INT32)]
    y: Annotated[int, msgspec.Meta(ge=-_INT32, le=_INT32)]
    z: Annotated[int, msgspec.Meta(ge=-_INT16, le=_INT16)]
    vx: Annotated[int, msgspec.Meta(ge=-_INT16, le=_INT16)]
    vy: Annotated[int, msgspec.Meta(ge=-_INT16, le=_INT16)]
    vz: Annotated[int, msgspec.Meta(ge=-_INT16, le=_INT16)]
    yaw: Annotated[int, msgspec.Meta(ge=-31416, le=31416)]


_decode_pose_wire = msgspec.msgpack.Decoder(_PoseWire).decode


def decode_pose(data: bytes) -> Pose:
    """The hot path (every neighbour pose, ~500 a second per UAV at N = 50): msgspec decodes and
    range-checks a valid pose in C (3x faster than msgpack + Python checks); anything it refuses
    goes through :func:`_decode_pose_checked`, which names the reason."""
    if len(data) <= MAX_POSE_BYTES:
        try:
            o = _decode_pose_wire(data)
        except (msgspec.DecodeError, msgspec.ValidationError):
            pass
        else:
            return Pose(o.uav, _REALMS[o.realm], o.seq, o.t_sim / 1000.0, o.t_wall / 1e6, o.x / 100.0, o.y / 100.0,
                        o.z / 100.0, o.vx / 100.0, o.vy / 100.0, o.vz / 100.0, o.yaw / 1e4)
    return _decode_pose_checked(data)


def _decode_pose_checked(data: bytes) -> Pose:
    """One loop of integer range checks, then scaling; raises :class:`DecodeError` with the reason."""
    o = _unpack(data, MAX_POSE_BYTES)
    _expect(o, Kind.POSE, 13)
    for i, (name, lo, hi) in enumerate(_POSE_FIELDS, 1):
        v = o[i]
        if type(v) is not int or not lo <= v <= hi:  # bool is not an int here
            raise DecodeError("bad_field", f"{name}={v!r} outside {lo}..{hi}")
    return Pose(o[1], _REALMS[o[2]], o[3], o[4] / 1000.0, o[5] / 1e6, o[6] / 100.0, o[7] / 100.0, o[8] / 100.0,
                o[9] / 100.0, o[10] / 100.0, o[11] / 100.0, o[12] / 1e4)


# --- telemetry -----------------------------------------------------------------------------
_TELEMETRY_TAG = tag(Kind.TELEMETRY)


def _ms_or_unknown(v: float) -> float:
    return round(float(v), 2) if 0.0 <= v < 1e6 else -1.0  # NaN fails the comparison


def encode_telemetry(t: Telemetry) -> bytes:
    return msgpack.packb(
        [
            _TELEMETRY_TAG,
            t.uav,
            int(t.realm),
            t.seq & 0xFFFFFFFF,
            _us(t.t_wall),
            t.mode[:32],
            bool(t.armed),
            float(t.battery),
            float(t.voltage),
            float(t.lat),
            float(t.lon),
            float(t.alt),
            float(t.rtf),
            _ms_or_unknown(t.transport_ms),
            _ms_or_unknown(t.use_ms),
        ]
    )


def decode_telemetry(data: bytes) -> Telemetry:
    """13 fields, or 15 with the pose ages (a sender of either kind is understood)."""
    o = _unpack(data, MAX_TELEMETRY_BYTES)
    _expect(o, Kind.TELEMETRY, 15 if len(o) == 15 else 13)
    ages = (_num(o[13], -1.0, 1e6, "transport_ms"), _num(o[14], -1.0, 1e6, "use_ms")) if len(o) == 15 else (-1.0, -1.0)
    if type(o[6]) is not bool:
        raise DecodeError("bad_field", f"armed={o[6]!r}")
    return Telemetry(
        uav=check_uav_id(o[1]),
        realm=_realm(o[2]),
        seq=_int(o[3], 0, _UINT32, "seq"),
        t_wall=_int(o[4], 0, _UINT64, "t_wall") / 1e6,
        mode=_str(o[5], 32, "mode"),
        armed=o[6],
        battery=_num(o[7], -1.0, 1.0, "battery"),
        voltage=_num(o[8], -1.0, 1000.0, "voltage"),
        lat=_num(o[9], -90.0, 90.0, "lat"),
        lon=_num(o[10], -180.0, 180.0, "lon"),
        alt=_num(o[11], -1000.0, 100000.0, "alt"),
        rtf=_num(o[12], 0.0, 1000.0, "rtf"),
        transport_ms=ages[0],
        use_ms=ages[1],
    )


# --- agent state -------------------------------------------------------------------------------
_STATE_TAG = tag(Kind.STATE)


def encode_state(s: AgentState) -> bytes:
    return msgpack.packb(
        [_STATE_TAG, s.uav, int(s.realm), s.seq & 0xFFFFFFFF, _us(s.t_wall), s.phase, s.behaviour, s.override,
         s.detail[:MAX_TEXT_LEN]]
    )


def decode_state(data: bytes) -> AgentState:
    o = _unpack(data, MAX_STATE_BYTES)
    _expect(o, Kind.STATE, 9)
    return AgentState(
        uav=check_uav_id(o[1]),
        realm=_realm(o[2]),
        seq=_int(o[3], 0, _UINT32, "seq"),
        t_wall=_int(o[4], 0, _UINT64, "t_wall") / 1e6,
        phase=_str(o[5], 32, "phase", NAME_RE),
        behaviour=_str(o[6], 32, "behaviour"),
        override=_str(o[7], 32, "override"),
        detail=_str(o[8], MAX_TEXT_LEN, "detail"),
    )


# --- swarm messages ---------------------------------------------------------------------------
_SWARM_MESSAGE_TAG = tag(Kind.SWARM_MESSAGE)


def encode_swarm_message(m: SwarmMessage, max_bytes: int = DEFAULT_MAX_MESSAGE_BYTES) -> bytes:
    if not TOPIC_RE.match(m.topic) or len(m.topic) > MAX_TOPIC_LEN:
        raise ValueError(f"invalid topic {m.topic!r}: use up to {MAX_TOPIC_LEN} chars of [A-Za-z0-9_-] separated by '/'")
    data = msgpack.packb([_SWARM_MESSAGE_TAG, m.src, m.dst, m.topic, m.seq & 0xFFFFFFFF, _us(m.t_wall), m.body])
    if len(data) > max_bytes:
        raise ValueError(f"message on {m.topic!r} is {len(data)} bytes, over the {max_bytes}-byte limit")
    return data


def decode_swarm_message(data: bytes, max_bytes: int = DEFAULT_MAX_MESSAGE_BYTES) -> SwarmMessage:
    o = _unpack(data, max_bytes)
    _expect(o, Kind.SWARM_MESSAGE, 7)
    dst = o[2]
    if dst != 0:
        check_uav_id(dst, "dst")
    return SwarmMessage(
        src=check_uav_id(o[1], "src"),
        dst=dst,
        topic=_str(o[3], MAX_TOPIC_LEN, "topic", TOPIC_RE),
        seq=_int(o[4], 0, _UINT32, "seq"),
        t_wall=_int(o[5], 0, _UINT64, "t_wall") / 1e6,
        body=o[6],
    )


# --- commands ---------------------------------------------------------------------------------
_COMMAND_TAG = tag(Kind.COMMAND)
_ACK_TAG = tag(Kind.COMMAND_ACK)


def encode_command(c: Command) -> bytes:
    data = msgpack.packb([_COMMAND_TAG, c.sender, c.cmd_id & 0xFFFFFFFF, c.target, c.verb, c.args, _us(c.t_wall)])
    if len(data) > MAX_COMMAND_BYTES:
        raise ValueError(f"command {c.verb!r} is {len(data)} bytes, over {MAX_COMMAND_BYTES}")
    return data


def decode_command(data: bytes) -> Command:
    o = _unpack(data, MAX_COMMAND_BYTES)
    _expect(o, Kind.COMMAND, 7)
    target = o[3]
    if target != 0:
        check_uav_id(target, "target")
    if type(o[5]) is not dict:
        raise DecodeError("bad_field", "args must be a map")
    return Command(
        sender=_str(o[1], 32, "sender", NAME_RE),
        cmd_id=_int(o[2], 0, _UINT32, "cmd_id"),
        target=target,
        verb=_str(o[4], 32, "verb", NAME_RE),
        args=o[5],
        t_wall=_int(o[6], 0, _UINT64, "t_wall") / 1e6,
    )


def encode_ack(a: CommandAck) -> bytes:
    return msgpack.packb([_ACK_TAG, a.uav, a.cmd_id & 0xFFFFFFFF, bool(a.ok), a.message[:MAX_TEXT_LEN], _us(a.t_wall)])


def decode_ack(data: bytes) -> CommandAck:
    o = _unpack(data, MAX_COMMAND_BYTES)
    _expect(o, Kind.COMMAND_ACK, 6)
    if type(o[3]) is not bool:
        raise DecodeError("bad_field", f"ok={o[3]!r}")
    return CommandAck(
        uav=check_uav_id(o[1]),
        cmd_id=_int(o[2], 0, _UINT32, "cmd_id"),
        ok=o[3],
        message=_str(o[4], MAX_TEXT_LEN, "message"),
        t_wall=_int(o[5], 0, _UINT64, "t_wall") / 1e6,
    )


# --- fault injection -------------------------------------------------------------------------
_FAULT_TAG = tag(Kind.FAULT)


def encode_fault(f: FaultInjection) -> bytes:
    if not NAME_RE.match(f.sender) or not NAME_RE.match(f.kind):
        raise ValueError(f"fault sender {f.sender!r} and kind {f.kind!r} must be 1-32 characters of [A-Za-z0-9_-]")
    check_uav_id(f.target, "target")
    if len(f.args) > MAX_FAULT_ARGS:
        raise ValueError(f"a fault takes at most {MAX_FAULT_ARGS} arguments, got {len(f.args)}")
    for k, v in f.args.items():
        if not NAME_RE.match(k) or isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"fault argument {k}={v!r}: names of [A-Za-z0-9_-], finite numbers")
    data = msgpack.packb([_FAULT_TAG, f.sender, f.fault_id & 0xFFFFFFFF, f.target, f.kind, dict(f.args), _us(f.t_wall)])
    if len(data) > MAX_FAULT_BYTES:
        raise ValueError(f"fault {f.kind!r} is {len(data)} bytes, over {MAX_FAULT_BYTES}")
    return data


def decode_fault(data: bytes) -> FaultInjection:
    o = _unpack(data, MAX_FAULT_BYTES)
    _expect(o, Kind.FAULT, 7)
    args = o[5]
    if type(args) is not dict or len(args) > MAX_FAULT_ARGS:
        raise DecodeError("bad_field", f"args must be a map of at most {MAX_FAULT_ARGS} numbers")
    for k, v in args.items():
        _str(k, 32, "argument name", NAME_RE)
        if type(v) not in (int, float) or not math.isfinite(v):
            raise DecodeError("bad_field", f"argument {k}={v!r} is not a finite number")
    return FaultInjection(
        sender=_str(o[1], 32, "sender", NAME_RE),
        fault_id=_int(o[2], 0, _UINT32, "fault_id"),
        target=check_uav_id(o[3], "target"),
        kind=_str(o[4], 32, "kind", NAME_RE),
        args={k: float(v) for k, v in args.items()},
        t_wall=_int(o[6], 0, _UINT64, "t_wall") / 1e6,
    )


# --- pose batches (edge feed) ---------------------------------------------------------------
_BATCH_TAG = tag(Kind.POSE_BATCH, BATCH_VERSION)


def encode_pose_batch(b: PoseBatch) -> bytes:
    if len(b.poses) > MAX_BATCH_POSES:
        raise ValueError(f"{len(b.poses)} poses in one batch, over {MAX_BATCH_POSES}")
    if len(b.senders) != len(b.poses):
        raise ValueError(f"{len(b.senders)} senders for {len(b.poses)} poses")
    return msgpack.packb([_BATCH_TAG, b.seq & 0xFFFFFFFF, _us(b.t_wall), b.senders, b.poses], use_bin_type=True)


def decode_pose_batch(data: bytes) -> PoseBatch:
    """Checks the envelope; every pose inside is decoded (and validated) by the caller."""
    o = _unpack(data, MAX_BATCH_BYTES)
    _expect(o, Kind.POSE_BATCH, 5, BATCH_VERSION)
    senders, poses = o[3], o[4]
    if type(poses) is not list or len(poses) > MAX_BATCH_POSES:
        raise DecodeError("bad_field", f"poses must be a list of at most {MAX_BATCH_POSES} payloads")
    if type(senders) is not list or len(senders) != len(poses):
        raise DecodeError("bad_field", "senders must list one UAV id per pose")
    for p in poses:
        if type(p) is not bytes or len(p) > MAX_POSE_BYTES:
            raise DecodeError("bad_field", "a batched pose is not a <= 48-byte payload")
    for u in senders:
        check_uav_id(u, "sender")
    return PoseBatch(seq=_int(o[1], 0, _UINT32, "seq"), t_wall=_int(o[2], 0, _UINT64, "t_wall") / 1e6, senders=senders,
                     poses=poses)


def batched_pose_count(data: bytes, exclude: int = 0) -> int:
    """How many poses an edge-feed batch carries from UAVs other than ``exclude``; 0 for a
    payload that is not one.

    Why: a UAV on the edge feed with aligned ticks counts the poses of an instant as they arrive,
    on its pose inlet's thread (:meth:`swarmnet.receive.Inlet.expect`), to act as soon as they
    are in; the batch's own pose of the UAV (the feed sends the swarm's poses to all) is not a
    neighbour's. About a microsecond for a batch of ten; the full checks run when the owner
    takes the batch in (:func:`accept_pose_batch`)."""
    try:
        o = _unpack(data, MAX_BATCH_BYTES)
    except DecodeError:
        return 0
    senders = o[3] if len(o) == 5 and o[0] == _BATCH_TAG else None
    if type(senders) is not list:
        return 0
    return len(senders) - senders.count(exclude)


# --- virtual sensors and actuators (world service) -----------------------------------------
_READING_TAG = tag(Kind.READING)
_ACTUATION_TAG = tag(Kind.ACTUATION)
_TRAFFIC_TAG = tag(Kind.TRAFFIC)


def _finite(v: Any, limit: float, name: str) -> float:
    if type(v) not in (int, float) or not -limit <= v <= limit:  # NaN fails the comparison too
        raise DecodeError("bad_field", f"{name}={v!r:.40} is not a finite number within +-{limit:g}")
    return float(v)


def encode_reading(r: Reading) -> bytes:
    if not NAME_RE.match(r.sensor):
        raise ValueError(f"invalid sensor name {r.sensor!r}: 1-32 characters of [A-Za-z0-9_-]")
    if len(r.points) > MAX_READING_POINTS:
        raise ValueError(f"{len(r.points)} points in one reading, over {MAX_READING_POINTS}")
    if not -READING_LIMIT <= r.value <= READING_LIMIT:
        raise ValueError(f"reading value {r.value} is not finite within +-{READING_LIMIT:g}")
    try:
        points = [[_q(x, 100.0, _INT32, "x"), _q(y, 100.0, _INT32, "y"), float(v)] for x, y, v in r.points]
    except (ValueError, OverflowError) as exc:
        raise ValueError(f"cannot encode a reading of {r.sensor}: {exc}") from None
    if any(not -READING_LIMIT <= p[2] <= READING_LIMIT for p in points):
        raise ValueError("a point value is not finite")
    return msgpack.packb([_READING_TAG, r.uav, r.sensor, r.seq & 0xFFFFFFFF, _us(r.t_meas), _us(r.t_sent), float(r.value),
                          points])


def decode_reading(data: bytes) -> Reading:
    o = _unpack(data, MAX_READING_BYTES)
    _expect(o, Kind.READING, 8)
    pts = o[7]
    if type(pts) is not list or len(pts) > MAX_READING_POINTS:
        raise DecodeError("bad_field", f"points must be a list of at most {MAX_READING_POINTS}")
    points = []
    for p in pts:
        if type(p) is not list or len(p) != 3:
            raise DecodeError("bad_field", "a point is [x_cm, y_cm, value]")
        points.append((_int(p[0], -_INT32, _INT32, "point x") / 100.0, _int(p[1], -_INT32, _INT32, "point y") / 100.0,
                       _finite(p[2], READING_LIMIT, "point value")))
    return Reading(
        uav=check_uav_id(o[1]),
        sensor=_str(o[2], 32, "sensor", NAME_RE),
        seq=_int(o[3], 0, _UINT32, "seq"),
        t_meas=_int(o[4], 0, _UINT64, "t_meas") / 1e6,
        t_sent=_int(o[5], 0, _UINT64, "t_sent") / 1e6,
        value=_finite(o[6], READING_LIMIT, "value"),
        points=tuple(points),
    )


def encode_actuation(a: Actuation) -> bytes:
    if not NAME_RE.match(a.actuator):
        raise ValueError(f"invalid actuator name {a.actuator!r}: 1-32 characters of [A-Za-z0-9_-]")
    if not 0.0 <= a.amount <= AMOUNT_LIMIT:
        raise ValueError(f"actuation amount {a.amount} outside 0..{AMOUNT_LIMIT:g}")
    return msgpack.packb([_ACTUATION_TAG, a.uav, a.actuator, a.seq & 0xFFFFFFFF, _us(a.t_wall), float(a.amount)])


def decode_actuation(data: bytes) -> Actuation:
    o = _unpack(data, MAX_ACTUATION_BYTES)
    _expect(o, Kind.ACTUATION, 6)
    return Actuation(
        uav=check_uav_id(o[1]),
        actuator=_str(o[2], 32, "actuator", NAME_RE),
        seq=_int(o[3], 0, _UINT32, "seq"),
        t_wall=_int(o[4], 0, _UINT64, "t_wall") / 1e6,
        amount=_num(o[5], 0.0, AMOUNT_LIMIT, "amount"),
    )


def encode_traffic(t: Traffic) -> bytes:
    """Positions as 1e-7 degrees and cm (about 1 cm), velocities in cm/s, like the pose."""
    if len(t.reports) > MAX_TRAFFIC_REPORTS:
        raise ValueError(f"{len(t.reports)} traffic reports in one message, over {MAX_TRAFFIC_REPORTS}")
    try:
        reports = [[r.track & 0xFFFFFFFF, _us(r.t_wall), _q(r.lat, 1e7, 900_000_000, "lat"), _q(r.lon, 1e7, 1_800_000_000, "lon"),
                    _q(r.alt, 100.0, _INT32, "alt"), _q(r.ve, 100.0, _INT16, "ve"), _q(r.vn, 100.0, _INT16, "vn"),
                    _q(r.vu, 100.0, _INT16, "vu")] for r in t.reports]
    except (ValueError, OverflowError) as exc:
        raise ValueError(f"cannot encode traffic: {exc}") from None
    return msgpack.packb([_TRAFFIC_TAG, t.seq & 0xFFFFFFFF, _us(t.t_wall), reports])


_TRAFFIC_FIELDS = (("track", 0, _UINT32), ("t_wall", 0, _UINT64), ("lat", -900_000_000, 900_000_000),
                   ("lon", -1_800_000_000, 1_800_000_000), ("alt", -_INT32, _INT32), ("ve", -_INT16, _INT16),
                   ("vn", -_INT16, _INT16), ("vu", -_INT16, _INT16))


def decode_traffic(data: bytes) -> Traffic:
    o = _unpack(data, MAX_TRAFFIC_BYTES)
    _expect(o, Kind.TRAFFIC, 4)
    raw = o[3]
    if type(raw) is not list or len(raw) > MAX_TRAFFIC_REPORTS:
        raise DecodeError("bad_field", f"reports must be a list of at most {MAX_TRAFFIC_REPORTS}")
    reports = []
    for r in raw:
        if type(r) is not list or len(r) != 8:
            raise DecodeError("bad_field", "a traffic report has 8 fields")
        for (name, lo, hi), v in zip(_TRAFFIC_FIELDS, r, strict=True):
            if type(v) is not int or not lo <= v <= hi:
                raise DecodeError("bad_field", f"traffic {name}={v!r} outside {lo}..{hi}")
        reports.append(TrafficReport(r[0], r[1] / 1e6, r[2] / 1e7, r[3] / 1e7, r[4] / 100.0, r[5] / 100.0, r[6] / 100.0,
                                     r[7] / 100.0))
    return Traffic(seq=_int(o[1], 0, _UINT32, "seq"), t_wall=_int(o[2], 0, _UINT64, "t_wall") / 1e6, reports=tuple(reports))


# --- behaviour reports (uav_stack/sdk) -------------------------------------------------------
_BEHAVIOUR_REPORT_TAG = tag(Kind.BEHAVIOUR_REPORT)


AGE_LIMIT_MS = 1e12  # a topic's message age in a behaviour report, ms (beyond: unknown)


def _age_ms(v: float | None) -> float | None:
    return float(v) if v is not None and 0.0 <= v <= AGE_LIMIT_MS else None  # NaN fails the comparison too


def encode_behaviour_report(r: BehaviourReport) -> bytes:
    """``[tag, uav, seq, t_wall_us, samples, topics, dropped, refused]``: samples ``[t_wall_us, name, value]``,
    topics ``{topic: [sent, send_errors, received, rejected, dropped, age_mean_ms, age_max_ms]}``."""
    if len(r.samples) > MAX_REPORT_SAMPLES:
        raise ValueError(f"{len(r.samples)} samples in one behaviour report, over {MAX_REPORT_SAMPLES}")
    if len(r.topics) > MAX_REPORT_TOPICS:
        raise ValueError(f"{len(r.topics)} topics in one behaviour report, over {MAX_REPORT_TOPICS}")
    samples = []
    for t, name, value in r.samples:
        if not VALUE_NAME_RE.match(name):
            raise ValueError(f"invalid value name {name!r}: 1-64 characters of [A-Za-z0-9_.-]")
        samples.append([_us(t), name, float(value)])
    topics = {}
    for topic, c in r.topics.items():
        if len(topic) > MAX_TOPIC_LEN or not TOPIC_RE.match(topic):
            raise ValueError(f"invalid topic {topic!r}")
        topics[topic] = [c.sent, c.send_errors, c.received, c.rejected, c.dropped, _age_ms(c.age_mean_ms), _age_ms(c.age_max_ms)]
    return msgpack.packb([_BEHAVIOUR_REPORT_TAG, r.uav, r.seq & 0xFFFFFFFF, _us(r.t_wall), samples, topics,
                          min(r.dropped, _UINT32), min(r.refused, _UINT32)])


def _ms_or_none(v: Any, name: str) -> float | None:
    if v is None:
        return None
    return _num(v, 0.0, AGE_LIMIT_MS, name)


def decode_behaviour_report(data: bytes) -> BehaviourReport:
    o = _unpack(data, MAX_REPORT_BYTES)
    _expect(o, Kind.BEHAVIOUR_REPORT, 8)
    raw, rawt = o[4], o[5]
    if type(raw) is not list or len(raw) > MAX_REPORT_SAMPLES:
        raise DecodeError("bad_field", f"samples must be a list of at most {MAX_REPORT_SAMPLES}")
    samples = []
    for s in raw:
        if type(s) is not list or len(s) != 3 or type(s[2]) not in (int, float):
            raise DecodeError("bad_field", "a sample is [t_wall_us, name, value]")
        samples.append((_int(s[0], 0, _UINT64, "sample t_wall") / 1e6, _str(s[1], 64, "value name", VALUE_NAME_RE), float(s[2])))
    if type(rawt) is not dict or len(rawt) > MAX_REPORT_TOPICS:
        raise DecodeError("bad_field", f"topics must be a map of at most {MAX_REPORT_TOPICS}")
    topics = {}
    for topic, c in rawt.items():
        _str(topic, MAX_TOPIC_LEN, "topic", TOPIC_RE)
        if type(c) is not list or len(c) != 7:
            raise DecodeError("bad_field", f"the counters of topic {topic} are 7 numbers")
        sent, send_errors, received, rejected, dropped = (_int(v, 0, _UINT64, f"{topic} counter") for v in c[:5])
        topics[topic] = TopicCounts(sent, send_errors, received, rejected, dropped, _ms_or_none(c[5], f"{topic} age_mean_ms"),
                                    _ms_or_none(c[6], f"{topic} age_max_ms"))
    return BehaviourReport(uav=check_uav_id(o[1]), seq=_int(o[2], 0, _UINT32, "seq"),
                           t_wall=_int(o[3], 0, _UINT64, "t_wall") / 1e6, samples=tuple(samples), topics=topics,
                           dropped=_int(o[6], 0, _UINT32, "dropped"),
                           refused=_int(o[7], 0, _UINT32, "refused"))


# --- acceptance rules -------------------------------------------------------------------------
# A rule raises Rejected(reason) for a sample that decodes but is out of place. An accept_*
# function is decode + the rules of one stream; bound to its node's id, each has the shape
# (key, payload) -> message that swarmnet.receive.receive takes.
def check_key_names_uav(key: str, uav: int) -> None:
    """A per-UAV key (``mrs/<swarm>/<uav>/pose``, ``telemetry``, ``state``, ``ack``) carries only
    that UAV's messages: a node cannot speak for another (``key_mismatch``)."""
    if uav_from_key(key) != uav:
        raise Rejected("key_mismatch", f"payload says UAV {uav}")


def check_not_own_id(uav: int, me: int) -> None:
    """A UAV never hears its own poses from the network (its subscription takes remote samples
    only), so one with its id comes from a misconfigured or spoofing node (``own_id``)."""
    if uav == me:
        raise Rejected("own_id", "another node publishes poses with our UAV id")


def check_route(key: str, src: int, dst: int, me: int) -> None:
    """A swarm message sits where it says: its key names its sender (``key_mismatch``: access
    control bound that key to the sender's certificate), and it goes where its key says
    (``wrong_destination``): ``dst`` 0 on a broadcast key (``mrs/<swarm>/<src>/msg/...``), this
    node's id on a unicast key to it (``mrs/<swarm>/<src>/to/<me>/...``)."""
    route = message_route(key)
    if route is None:
        raise Rejected("wrong_destination", "not a swarm-message key")
    sender, addressee = route
    if sender != src:
        raise Rejected("key_mismatch", f"payload says sender {src}")
    if addressee == 0:
        if dst != 0:
            raise Rejected("wrong_destination", "unicast payload on a broadcast key")
    elif dst != me or addressee != me:
        raise Rejected("wrong_destination", f"dst {dst}")


def check_command_target(target: int, me: int) -> None:
    """A command is for this UAV or (``target`` 0) the whole swarm (``wrong_destination``)."""
    if target != 0 and target != me:
        raise Rejected("wrong_destination", f"command for UAV {target}")


def check_key_names(key: str, name: str) -> None:
    """A sensor or actuator key (``mrs/<swarm>/<uav>/sense/<sensor>``, ``.../act/<actuator>``) ends
    with the name its payload carries (``key_mismatch``)."""
    if key.rsplit("/", 1)[-1] != name:
        raise Rejected("key_mismatch", f"payload names {name!r}")


def accept_pose(key: str, data: bytes) -> Pose:
    """A pose on ``mrs/<swarm>/<uav>/pose``: it decodes and names the UAV its key names."""
    pose = decode_pose(data)
    check_key_names_uav(key, pose.uav)
    return pose


def accept_neighbour_pose(key: str, data: bytes, me: int) -> Pose:
    """A pose a UAV ``me`` takes from its neighbours: :func:`accept_pose`, and not our own id."""
    pose = accept_pose(key, data)
    check_not_own_id(pose.uav, me)
    return pose


def accept_pose_batch(key: str, data: bytes) -> PoseBatch:
    """An edge-feed batch on ``mrs/<swarm>/feed/poses``: the envelope decodes (its poses are
    accepted one by one with :func:`accept_batched_pose`)."""
    return decode_pose_batch(data)


def accept_batched_pose(sender: int, data: bytes) -> Pose:
    """The batch rule: a pose inside an edge-feed batch decodes and names ``sender``, the UAV the
    batch lists for it (:attr:`PoseBatch.senders`), as a direct pose must name the UAV of its key
    (:func:`accept_pose`, ``key_mismatch``). The edge accepted it on that UAV's pose key, which
    access control binds to the UAV's certificate; a receiver checks again rather than trust
    the batch.

    Why an id and not the sender's key: formatting a key per pose, then parsing it back, was a
    quarter of a batched pose's receive path (about 500 poses a second per UAV at N = 50)."""
    pose = decode_pose(data)
    if pose.uav != sender:
        raise Rejected("key_mismatch", f"payload says UAV {pose.uav}, the batch says UAV {sender}")
    return pose


def accept_telemetry(key: str, data: bytes) -> Telemetry:
    """Telemetry on ``mrs/<swarm>/<uav>/telemetry``: it decodes and names the key's UAV."""
    t = decode_telemetry(data)
    check_key_names_uav(key, t.uav)
    return t


def accept_state(key: str, data: bytes) -> AgentState:
    """An agent state on ``mrs/<swarm>/<uav>/state``: it decodes and names the key's UAV."""
    st = decode_state(data)
    check_key_names_uav(key, st.uav)
    return st


def accept_ack(key: str, data: bytes) -> CommandAck:
    """A command ack on ``mrs/<swarm>/<uav>/ack``: it decodes and names the key's UAV."""
    a = decode_ack(data)
    check_key_names_uav(key, a.uav)
    return a


def accept_swarm_message(key: str, data: bytes, me: int, max_bytes: int = DEFAULT_MAX_MESSAGE_BYTES) -> SwarmMessage:
    """A broadcast or unicast swarm message for node ``me``: it decodes within ``max_bytes``
    (bytes), its key names its sender and it goes where its key says (:func:`check_route`)."""
    msg = decode_swarm_message(data, max_bytes)
    check_route(key, msg.src, msg.dst, me)
    return msg


def accept_fault(key: str, data: bytes, me: int) -> FaultInjection:
    """A fault on ``mrs/<swarm>/<me>/fault``: it decodes, names the key's UAV and targets ``me``
    (never the whole swarm). Whether this UAV may take it (a virtual one) the agent decides."""
    f = decode_fault(data)
    check_key_names_uav(key, f.target)
    check_command_target(f.target, me)
    return f


def accept_command(key: str, data: bytes, me: int) -> Command:
    """A command on ``mrs/<swarm>/<me>/cmd`` or ``mrs/<swarm>/cmd``: it decodes and targets ``me`` or all."""
    cmd = decode_command(data)
    check_command_target(cmd.target, me)
    return cmd


def accept_reading(key: str, data: bytes, me: int) -> Reading:
    """A reading on ``mrs/<swarm>/<me>/sense/<sensor>``: it decodes, names the key's UAV and
    sensor, and that UAV is ``me`` (a reading for another UAV is never taken, ``wrong_destination``)."""
    r = decode_reading(data)
    check_key_names_uav(key, r.uav)
    check_key_names(key, r.sensor)
    if r.uav != me:
        raise Rejected("wrong_destination", f"reading for UAV {r.uav}")
    return r


def accept_actuation(key: str, data: bytes) -> Actuation:
    """An actuator request on ``mrs/<swarm>/<uav>/act/<actuator>``: it decodes and names the key's
    UAV and actuator (a UAV cannot act for another)."""
    a = decode_actuation(data)
    check_key_names_uav(key, a.uav)
    check_key_names(key, a.actuator)
    return a


def accept_traffic(key: str, data: bytes) -> Traffic:
    """The airspace feed on ``mrs/airspace/<swarm>/traffic``: it decodes (every report in range)."""
    return decode_traffic(data)


def accept_behaviour_report(key: str, data: bytes) -> BehaviourReport:
    """A behaviour report on ``mrs/<swarm>/<uav>/behaviour``: it decodes and names the key's UAV."""
    r = decode_behaviour_report(data)
    check_key_names_uav(key, r.uav)
    return r
