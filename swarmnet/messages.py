"""Swarm messages: dataclasses and their versioned msgpack wire format, one codec per kind.

Every message is a msgpack array whose first element is a one-byte *tag*:
``tag = kind << 4 | version``. Each kind's wire form is an array-like msgspec struct
(:class:`PoseWire`, :class:`TelemetryWire`...; msgspec writes the tag first) whose field types
carry the bounds (``msgspec.Meta``: ranges, lengths, patterns), and each kind has one
:class:`Codec` (:data:`CODECS`): the struct, the payload's size limit, and a small check for what
the bounds cannot say (a list as long as another, an application's value), which also scales
fixed point back to floats. Decoding is one msgspec call that checks the tag, the array length and
every field, then the check; a payload refused is read once more to name the reason
(:meth:`Codec.refusal`), and :class:`DecodeError` carries it (a short ``reason`` used as a counter
name, a detail naming the field, e.g. ``pose.z: expected `int` <= 32767, got 40000``). Nothing here
raises any other exception on bad input. The bytes are those the hand-written codec before it
wrote, kind by kind (tests/test_messages_wire.py).

Next to the codec live the *acceptance rules*: what a receiver takes from the network beyond
a payload that decodes (the key names the payload's UAV, a message goes where its key says,
a command targets this UAV, nobody else speaks with our id). Each rule is a small function
raising :class:`Rejected` with a counter name (``DecodeError`` is one kind of rejection), and
each ``accept_*`` function composes a kind's decode with the rules of one stream.
:mod:`swarmnet.receive` runs them on every sample and counts each rejection, so bad input never
reaches the agent.

The pose is the hot message (10 Hz from every UAV to every other UAV), so it is quantised
to fixed-point integers, which msgpack stores in 1-5 bytes: at most **48 bytes** per pose
for any value in range (the paper's ROS/swarmio pose was 399 B). Resolution: 1 cm, 1 cm/s,
1e-4 rad, 1 ms of sim time, 1 us of wall time. The full layout is in docs/keyspace.md.

The message types stay dataclasses, not the wire structs: their fields are floats in SI units
where the wire holds fixed-point integers.
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Annotated, Any, Generic, Protocol, TypeVar

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


# --- the wire: one msgspec struct per kind -----------------------------------------------------
# Each kind's wire form is an array-like msgspec struct: msgspec writes it as a msgpack array, its
# tag first, and reads it back checking the tag, the length and every field's type and bound in
# one call (in C). Field names are the message's; values are as on the wire (fixed point, us).
Uav = Annotated[int, msgspec.Meta(ge=UAV_ID_MIN, le=UAV_ID_MAX)]
UavOrAll = Annotated[int, msgspec.Meta(ge=0, le=UAV_ID_MAX)]  # 0: every UAV (a broadcast, a command to all)
RealmValue = Annotated[int, msgspec.Meta(ge=0, le=1)]
Seq = Annotated[int, msgspec.Meta(ge=0, le=_UINT32)]
Micros = Annotated[int, msgspec.Meta(ge=0)]  # us since the Unix epoch (a uint64: msgpack has no larger integer)
Count = Annotated[int, msgspec.Meta(ge=0)]  # a uint64 counter
I16 = Annotated[int, msgspec.Meta(ge=-_INT16, le=_INT16)]
I32 = Annotated[int, msgspec.Meta(ge=-_INT32, le=_INT32)]
Name = Annotated[str, msgspec.Meta(max_length=32, pattern=NAME_RE.pattern)]
Label = Annotated[str, msgspec.Meta(max_length=32)]
Text = Annotated[str, msgspec.Meta(max_length=MAX_TEXT_LEN)]
Topic = Annotated[str, msgspec.Meta(max_length=MAX_TOPIC_LEN, pattern=TOPIC_RE.pattern)]
ValueName = Annotated[str, msgspec.Meta(max_length=64, pattern=VALUE_NAME_RE.pattern)]
Finite = Annotated[float, msgspec.Meta(ge=-sys.float_info.max, le=sys.float_info.max)]  # NaN fails both bounds
ReadingValue = Annotated[float, msgspec.Meta(ge=-READING_LIMIT, le=READING_LIMIT)]
AGE_LIMIT_MS = 1e12  # a topic's message age in a behaviour report, ms (beyond: unknown)
AgeMs = Annotated[float, msgspec.Meta(ge=0.0, le=AGE_LIMIT_MS)]
PoseAge = Annotated[float, msgspec.Meta(ge=-1.0, le=1e6)]  # ms; -1: unknown


class Wire(msgspec.Struct, array_like=True, forbid_unknown_fields=True):
    """A message kind's wire form: a msgpack array, ``[tag, field, ...]``, no more fields than declared."""


_POSE_TAG = tag(Kind.POSE)
_TELEMETRY_TAG = tag(Kind.TELEMETRY)
_STATE_TAG = tag(Kind.STATE)
_SWARM_MESSAGE_TAG = tag(Kind.SWARM_MESSAGE)
_COMMAND_TAG = tag(Kind.COMMAND)
_ACK_TAG = tag(Kind.COMMAND_ACK)
_BATCH_TAG = tag(Kind.POSE_BATCH, BATCH_VERSION)
_FAULT_TAG = tag(Kind.FAULT)
_READING_TAG = tag(Kind.READING)
_ACTUATION_TAG = tag(Kind.ACTUATION)
_TRAFFIC_TAG = tag(Kind.TRAFFIC)
_BEHAVIOUR_REPORT_TAG = tag(Kind.BEHAVIOUR_REPORT)


class PoseWire(Wire, tag=_POSE_TAG, gc=False):
    """``[tag, uav, realm, seq, t_sim_ms, t_wall_us, x_cm, y_cm, z_cm, vx_cms, vy_cms, vz_cms, yaw_1e-4rad]``."""

    uav: Uav
    realm: RealmValue
    seq: Annotated[int, msgspec.Meta(ge=0, le=0xFFFF)]
    t_sim: Annotated[int, msgspec.Meta(ge=0, le=_UINT32)]
    t_wall: Micros
    x: I32
    y: I32
    z: I16
    vx: I16
    vy: I16
    vz: I16
    yaw: Annotated[int, msgspec.Meta(ge=-31416, le=31416)]


class TelemetryWire(Wire, tag=_TELEMETRY_TAG):
    """13 fields, or 15 with the pose ages (a sender of either kind is understood; this one writes 15)."""

    uav: Uav
    realm: RealmValue
    seq: Seq
    t_wall: Micros
    mode: Label
    armed: bool
    battery: Annotated[float, msgspec.Meta(ge=-1.0, le=1.0)]
    voltage: Annotated[float, msgspec.Meta(ge=-1.0, le=1000.0)]
    lat: Annotated[float, msgspec.Meta(ge=-90.0, le=90.0)]
    lon: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)]
    alt: Annotated[float, msgspec.Meta(ge=-1000.0, le=100000.0)]
    rtf: Annotated[float, msgspec.Meta(ge=0.0, le=1000.0)]
    transport_ms: PoseAge | msgspec.UnsetType = msgspec.UNSET
    use_ms: PoseAge | msgspec.UnsetType = msgspec.UNSET


class StateWire(Wire, tag=_STATE_TAG):
    uav: Uav
    realm: RealmValue
    seq: Seq
    t_wall: Micros
    phase: Name
    behaviour: Label
    override: Label
    detail: Text


class SwarmMessageWire(Wire, tag=_SWARM_MESSAGE_TAG):
    """The body is the application's msgpack value, packed and read by msgpack itself (:func:`_app_value`)."""

    src: Uav
    dst: UavOrAll
    topic: Topic
    seq: Seq
    t_wall: Micros
    body: msgspec.Raw


class CommandWire(Wire, tag=_COMMAND_TAG):
    sender: Name
    cmd_id: Seq
    target: UavOrAll
    verb: Name
    args: msgspec.Raw  # a map, read by msgpack as a swarm message's body is
    t_wall: Micros


class CommandAckWire(Wire, tag=_ACK_TAG):
    uav: Uav
    cmd_id: Seq
    ok: bool
    message: Text
    t_wall: Micros


class PoseBatchWire(Wire, tag=_BATCH_TAG):
    """Version 2: ``[tag, seq, t_wall_us, senders, poses]``, a sender (UAV id) per pose payload."""

    seq: Seq
    t_wall: Micros
    senders: Annotated[list[Uav], msgspec.Meta(max_length=MAX_BATCH_POSES)]
    poses: Annotated[list[Annotated[bytes, msgspec.Meta(max_length=MAX_POSE_BYTES)]], msgspec.Meta(max_length=MAX_BATCH_POSES)]


class FaultWire(Wire, tag=_FAULT_TAG):
    sender: Name
    fault_id: Seq
    target: Uav
    kind: Name
    args: Annotated[dict[Name, Finite], msgspec.Meta(max_length=MAX_FAULT_ARGS)]
    t_wall: Micros


class ReadingWire(Wire, tag=_READING_TAG):
    """Points ``[x_cm, y_cm, value]``."""

    uav: Uav
    sensor: Name
    seq: Seq
    t_meas: Micros
    t_sent: Micros
    value: ReadingValue
    points: Annotated[list[tuple[I32, I32, ReadingValue]], msgspec.Meta(max_length=MAX_READING_POINTS)]


class ActuationWire(Wire, tag=_ACTUATION_TAG):
    uav: Uav
    actuator: Name
    seq: Seq
    t_wall: Micros
    amount: Annotated[float, msgspec.Meta(ge=0.0, le=AMOUNT_LIMIT)]


TrafficReportWire = tuple[  # track, t_wall_us, lat and lon in 1e-7 degrees, alt cm, ve vn vu cm/s
    Seq, Micros, Annotated[int, msgspec.Meta(ge=-900_000_000, le=900_000_000)],
    Annotated[int, msgspec.Meta(ge=-1_800_000_000, le=1_800_000_000)], I32, I16, I16, I16]


class TrafficWire(Wire, tag=_TRAFFIC_TAG):
    """Positions as 1e-7 degrees and cm (about 1 cm), velocities in cm/s, like the pose."""

    seq: Seq
    t_wall: Micros
    reports: Annotated[list[TrafficReportWire], msgspec.Meta(max_length=MAX_TRAFFIC_REPORTS)]


TopicCountsWire = tuple[Count, Count, Count, Count, Count, AgeMs | None, AgeMs | None]  # as TopicCounts' fields


class BehaviourReportWire(Wire, tag=_BEHAVIOUR_REPORT_TAG):
    """Samples ``[t_wall_us, name, value]`` (any float, NaN too); topics ``{topic: [sent, send_errors,
    received, rejected, dropped, age_mean_ms, age_max_ms]}``."""

    uav: Uav
    seq: Seq
    t_wall: Micros
    samples: Annotated[list[tuple[Micros, ValueName, float]], msgspec.Meta(max_length=MAX_REPORT_SAMPLES)]
    topics: Annotated[dict[Topic, TopicCountsWire], msgspec.Meta(max_length=MAX_REPORT_TOPICS)]
    dropped: Seq
    refused: Seq


# --- the codec: a kind's struct, its size limit and its check -------------------------------------
W = TypeVar("W", bound=Wire)
T = TypeVar("T")
T_co = TypeVar("T_co", covariant=True)
_encode = msgspec.msgpack.Encoder().encode
_AT = re.compile(r"(?s)(.*) - at (`key` in )?`\$\[(\d+)\](.*)`")


class Decode(Protocol[T_co]):
    """A kind's decode-and-check: ``data`` (at most ``max_bytes`` bytes, by default the kind's
    limit) as the message, or :class:`DecodeError` with the reason."""

    def __call__(self, data: bytes, max_bytes: int = ...) -> T_co: ...


@dataclass(frozen=True, slots=True)
class Codec(Generic[W, T]):
    """One message kind on the wire, and its one way in: :attr:`decode`.

    ``wire`` is the struct msgspec decodes and checks; ``check`` takes the decoded struct to the
    message, raising :class:`DecodeError` for what msgspec's bounds cannot say (a list as long as
    another, an application's value) and scaling fixed point back to floats.
    """

    kind: Kind
    wire: type[W]
    max_bytes: int
    check: Callable[[W], T]
    lengths: tuple[int, ...] = ()  # array lengths (the tag counted) of a valid payload; () = every field
    decode: Decode[T] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.lengths:
            object.__setattr__(self, "lengths", (len(self.wire.__struct_fields__) + 1,))
        object.__setattr__(self, "decode", self._decode_function())

    @property
    def name(self) -> str:
        return self.kind.name.lower()

    @property
    def version(self) -> int:
        t = self.wire.__struct_config__.tag
        if not isinstance(t, int):
            raise TypeError(f"{self.wire.__name__}: a wire struct's tag is tag(kind, version), not {t!r}")
        return t & 0xF

    def _decode_function(self) -> Decode[T]:
        """:attr:`decode`, a closure: a neighbour pose (~500 a second per UAV at N = 50) pays no
        attribute lookups and no bound-method call, as fast as the pose decoder written by hand."""
        decoder, check, refusal, limit = msgspec.msgpack.Decoder(self.wire).decode, self.check, self.refusal, self.max_bytes

        def decode(data: bytes, max_bytes: int = limit) -> T:
            if len(data) > max_bytes:
                raise DecodeError("oversized", f"{len(data)} bytes > {max_bytes}")
            try:
                w = decoder(data)
            except msgspec.DecodeError as exc:  # (a msgspec.ValidationError is one)
                raise refusal(data, exc) from None
            return check(w)

        decode.__qualname__ = decode.__name__ = f"decode_{self.name}"
        return decode

    def refusal(self, data: bytes, exc: Exception) -> DecodeError:
        """Why msgspec refused ``data``, as a counter name: the array is read once more (msgpack)
        to tell a payload that is not this kind's (``malformed``: not msgpack, not an array, a tag
        that is not an integer, a length not this kind's; ``wrong_type``; ``wrong_version``) from
        one with a field out of its bounds (``bad_field``, naming the field)."""
        if not data:
            return DecodeError("malformed", "empty payload")
        try:
            o = msgpack.unpackb(data, raw=False, strict_map_key=True)
        except Exception as err:  # msgpack raises several types (ExtraData, FormatError, StackError, TypeError...)
            return DecodeError("malformed", f"not msgpack: {type(err).__name__}")
        if type(o) is not list or not o:
            return DecodeError("malformed", "expected a non-empty msgpack array")
        t, name, version = o[0], self.name, self.version
        if type(t) is not int:
            return DecodeError("malformed", "tag is not an integer")
        if t >> 4 != self.kind:
            return DecodeError("wrong_type", f"expected {name}, got kind {t >> 4}")
        if t & 0xF != version:
            return DecodeError("wrong_version", f"{name} version {t & 0xF}, this node speaks {version}")
        if len(o) not in self.lengths:
            return DecodeError("malformed", f"{name} has {len(o)} fields, expected {' or '.join(map(str, self.lengths))}")
        if not isinstance(exc, msgspec.ValidationError):  # (a msgspec.DecodeError that msgpack read)
            return DecodeError("malformed", f"{name}: {exc}")
        return DecodeError("bad_field", self._field_error(o, str(exc)))

    def _field_error(self, o: list[Any], error: str) -> str:
        """msgspec's ``Expected `int` <= 32767 - at `$[8]``` as ``pose.z: expected `int` <= 32767, got 40000``."""
        m = _AT.fullmatch(error)
        if m is None:
            return f"{self.name}: {error}"
        what, key, index, inner = m.group(1), m.group(2), int(m.group(3)), m.group(4)
        fields = self.wire.__struct_fields__
        where = f"{self.name}.{fields[index - 1] if 0 < index <= len(fields) else f'[{index}]'}{inner}"
        what = what[:1].lower() + what[1:]
        if key:
            return f"{where} key: {what}"
        got = f", got {o[index]!r:.60}" if not inner and index < len(o) else ""
        return f"{where}: {what}{got}"


def _app_value(kind: Kind, field_name: str, raw: msgspec.Raw) -> Any:
    """An application's value (a swarm message's body, a command's arguments) as msgpack reads it: maps
    keyed by strings (or bytes) only, extension types as :class:`msgpack.ExtType` (``malformed``
    otherwise, as for a payload that is not msgpack)."""
    try:
        return msgpack.unpackb(raw, raw=False, strict_map_key=True)
    except Exception as exc:  # noqa: BLE001 - msgpack raises several types
        raise DecodeError("malformed", f"{kind.name.lower()}.{field_name}: not msgpack ({type(exc).__name__})") from None


def _us(t: float) -> int:
    return int(round(t * 1e6))


def wire_time(t: float) -> float:
    """``t`` (s since the epoch) as a message's time reads once decoded: whole microseconds, as the wire holds it."""
    return _us(t) / 1e6


def _q(value: float, scale: float, limit: int, name: str) -> int:
    """Quantise to a fixed-point integer, refusing values the wire format cannot hold."""
    q = round(value * scale)  # raises on NaN/inf
    if not -limit <= q <= limit:
        raise ValueError(f"{name}={value} out of range +-{limit / scale}")
    return q


_REALMS = (Realm.VIRTUAL, Realm.PHYSICAL)


# --- pose ----------------------------------------------------------------------------------
def _pose(w: PoseWire) -> Pose:
    return Pose(w.uav, _REALMS[w.realm], w.seq, w.t_sim / 1000.0, w.t_wall / 1e6, w.x / 100.0, w.y / 100.0, w.z / 100.0,
                w.vx / 100.0, w.vy / 100.0, w.vz / 100.0, w.yaw / 1e4)


POSE = Codec(Kind.POSE, PoseWire, MAX_POSE_BYTES, _pose)


def encode_pose(p: Pose) -> bytes:
    """The pose on the wire (msgpack, fixed-point integers: cm, cm/s, 1e-4 rad, ms, us).

    Every UAV encodes its pose at the pose rate: a valid pose is quantised with no call but
    ``round`` per field and checked in one expression; anything else goes the slow way, which
    names the field (:func:`_checked_pose`)."""
    try:
        w = PoseWire(p.uav, int(p.realm), p.seq & 0xFFFF, round(p.t_sim * 1000.0), round(p.t_wall * 1e6), round(p.x * 100.0),
                     round(p.y * 100.0), round(p.z * 100.0), round(p.vx * 100.0), round(p.vy * 100.0), round(p.vz * 100.0),
                     round(math.remainder(p.yaw, math.tau) * 1e4))
    except (ValueError, OverflowError):  # NaN or infinite
        w = _checked_pose(p)
    if not (UAV_ID_MIN <= w.uav <= UAV_ID_MAX and 0 <= w.t_sim <= _UINT32 and 0 <= w.t_wall <= _UINT64
            and -_INT32 <= w.x <= _INT32 and -_INT32 <= w.y <= _INT32 and -_INT16 <= w.z <= _INT16
            and -_INT16 <= w.vx <= _INT16 and -_INT16 <= w.vy <= _INT16 and -_INT16 <= w.vz <= _INT16
            and -_INT16 <= w.yaw <= _INT16):
        w = _checked_pose(p)
    return _encode(w)


def _checked_pose(p: Pose) -> PoseWire:
    """The pose's wire form, or a ValueError naming the first field that the wire cannot hold."""
    try:
        w = PoseWire(p.uav, int(p.realm), p.seq & 0xFFFF, round(p.t_sim * 1000.0), _us(p.t_wall), _q(p.x, 100.0, _INT32, "x"),
                     _q(p.y, 100.0, _INT32, "y"), _q(p.z, 100.0, _INT16, "z"), _q(p.vx, 100.0, _INT16, "vx"),
                     _q(p.vy, 100.0, _INT16, "vy"), _q(p.vz, 100.0, _INT16, "vz"),
                     _q(math.remainder(p.yaw, math.tau), 1e4, _INT16, "yaw"))
    except (ValueError, OverflowError) as exc:
        raise ValueError(f"cannot encode pose of UAV {p.uav}: {exc}") from None
    if not (UAV_ID_MIN <= p.uav <= UAV_ID_MAX) or not (0 <= w.t_sim <= _UINT32) or not (0 <= w.t_wall <= _UINT64):
        raise ValueError(f"cannot encode pose of UAV {p.uav}: id or timestamps out of range")
    return w


# The hot path (every neighbour pose, ~500 a second per UAV at N = 50): msgspec decodes and
# range-checks the pose in C, then one call scales it (_pose).
decode_pose = POSE.decode

# --- telemetry -----------------------------------------------------------------------------
def _telemetry(w: TelemetryWire) -> Telemetry:
    transport, use = w.transport_ms, w.use_ms
    if transport is msgspec.UNSET or use is msgspec.UNSET:
        if transport is not use:
            raise DecodeError("malformed", "telemetry has 14 fields, expected 13 or 15")
        transport = use = -1.0
    return Telemetry(w.uav, _REALMS[w.realm], w.seq, w.t_wall / 1e6, w.mode, w.armed, w.battery, w.voltage, w.lat, w.lon,
                     w.alt, w.rtf, transport, use)


TELEMETRY = Codec(Kind.TELEMETRY, TelemetryWire, MAX_TELEMETRY_BYTES, _telemetry, lengths=(13, 15))


def _ms_or_unknown(v: float) -> float:
    return round(float(v), 2) if 0.0 <= v < 1e6 else -1.0  # NaN fails the comparison


def encode_telemetry(t: Telemetry) -> bytes:
    return _encode(TelemetryWire(t.uav, int(t.realm), t.seq & 0xFFFFFFFF, _us(t.t_wall), t.mode[:32], bool(t.armed),
                                 float(t.battery), float(t.voltage), float(t.lat), float(t.lon), float(t.alt), float(t.rtf),
                                 _ms_or_unknown(t.transport_ms), _ms_or_unknown(t.use_ms)))


decode_telemetry = TELEMETRY.decode

# --- agent state -------------------------------------------------------------------------------
def _state(w: StateWire) -> AgentState:
    return AgentState(w.uav, _REALMS[w.realm], w.seq, w.t_wall / 1e6, w.phase, w.behaviour, w.override, w.detail)


STATE = Codec(Kind.STATE, StateWire, MAX_STATE_BYTES, _state)


def encode_state(s: AgentState) -> bytes:
    return _encode(StateWire(s.uav, int(s.realm), s.seq & 0xFFFFFFFF, _us(s.t_wall), s.phase, s.behaviour, s.override,
                             s.detail[:MAX_TEXT_LEN]))


decode_state = STATE.decode

# --- swarm messages ---------------------------------------------------------------------------
def _swarm_message(w: SwarmMessageWire) -> SwarmMessage:
    return SwarmMessage(w.src, w.dst, w.topic, w.seq, w.t_wall / 1e6, _app_value(Kind.SWARM_MESSAGE, "body", w.body))


SWARM_MESSAGE = Codec(Kind.SWARM_MESSAGE, SwarmMessageWire, DEFAULT_MAX_MESSAGE_BYTES, _swarm_message)


def encode_swarm_message(m: SwarmMessage, max_bytes: int = DEFAULT_MAX_MESSAGE_BYTES) -> bytes:
    if not TOPIC_RE.match(m.topic) or len(m.topic) > MAX_TOPIC_LEN:
        raise ValueError(f"invalid topic {m.topic!r}: use up to {MAX_TOPIC_LEN} chars of [A-Za-z0-9_-] separated by '/'")
    data = _encode(SwarmMessageWire(m.src, m.dst, m.topic, m.seq & 0xFFFFFFFF, _us(m.t_wall), msgspec.Raw(msgpack.packb(m.body))))
    if len(data) > max_bytes:
        raise ValueError(f"message on {m.topic!r} is {len(data)} bytes, over the {max_bytes}-byte limit")
    return data


decode_swarm_message = SWARM_MESSAGE.decode

# --- commands ---------------------------------------------------------------------------------
def _command(w: CommandWire) -> Command:
    args = _app_value(Kind.COMMAND, "args", w.args)
    if type(args) is not dict:
        raise DecodeError("bad_field", f"command.args: must be a map, got {type(args).__name__}")
    return Command(w.sender, w.cmd_id, w.target, w.verb, args, w.t_wall / 1e6)


def _ack(w: CommandAckWire) -> CommandAck:
    return CommandAck(w.uav, w.cmd_id, w.ok, w.message, w.t_wall / 1e6)


COMMAND = Codec(Kind.COMMAND, CommandWire, MAX_COMMAND_BYTES, _command)
COMMAND_ACK = Codec(Kind.COMMAND_ACK, CommandAckWire, MAX_COMMAND_BYTES, _ack)


def encode_command(c: Command) -> bytes:
    data = _encode(CommandWire(c.sender, c.cmd_id & 0xFFFFFFFF, c.target, c.verb, msgspec.Raw(msgpack.packb(c.args)),
                               _us(c.t_wall)))
    if len(data) > MAX_COMMAND_BYTES:
        raise ValueError(f"command {c.verb!r} is {len(data)} bytes, over {MAX_COMMAND_BYTES}")
    return data


decode_command = COMMAND.decode

def encode_ack(a: CommandAck) -> bytes:
    return _encode(CommandAckWire(a.uav, a.cmd_id & 0xFFFFFFFF, bool(a.ok), a.message[:MAX_TEXT_LEN], _us(a.t_wall)))


decode_ack = COMMAND_ACK.decode

# --- fault injection -------------------------------------------------------------------------
def _fault(w: FaultWire) -> FaultInjection:
    return FaultInjection(w.sender, w.fault_id, w.target, w.kind, w.args, w.t_wall / 1e6)


FAULT = Codec(Kind.FAULT, FaultWire, MAX_FAULT_BYTES, _fault)


def encode_fault(f: FaultInjection) -> bytes:
    if not NAME_RE.match(f.sender) or not NAME_RE.match(f.kind):
        raise ValueError(f"fault sender {f.sender!r} and kind {f.kind!r} must be 1-32 characters of [A-Za-z0-9_-]")
    check_uav_id(f.target, "target")
    if len(f.args) > MAX_FAULT_ARGS:
        raise ValueError(f"a fault takes at most {MAX_FAULT_ARGS} arguments, got {len(f.args)}")
    for k, v in f.args.items():
        if not NAME_RE.match(k) or isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"fault argument {k}={v!r}: names of [A-Za-z0-9_-], finite numbers")
    args = {k: float(v) if isinstance(v, float) else v for k, v in f.args.items()}  # (a float subclass: numpy's)
    data = _encode(FaultWire(f.sender, f.fault_id & 0xFFFFFFFF, f.target, f.kind, args, _us(f.t_wall)))
    if len(data) > MAX_FAULT_BYTES:
        raise ValueError(f"fault {f.kind!r} is {len(data)} bytes, over {MAX_FAULT_BYTES}")
    return data


decode_fault = FAULT.decode

# --- pose batches (edge feed) ---------------------------------------------------------------
def _pose_batch(w: PoseBatchWire) -> PoseBatch:
    if len(w.senders) != len(w.poses):
        raise DecodeError("bad_field", f"pose_batch.senders: one UAV id per pose, got {len(w.senders)} for {len(w.poses)}")
    return PoseBatch(w.seq, w.t_wall / 1e6, w.senders, w.poses)


POSE_BATCH = Codec(Kind.POSE_BATCH, PoseBatchWire, MAX_BATCH_BYTES, _pose_batch)


def encode_pose_batch(b: PoseBatch) -> bytes:
    if len(b.poses) > MAX_BATCH_POSES:
        raise ValueError(f"{len(b.poses)} poses in one batch, over {MAX_BATCH_POSES}")
    if len(b.senders) != len(b.poses):
        raise ValueError(f"{len(b.senders)} senders for {len(b.poses)} poses")
    return _encode(PoseBatchWire(b.seq & 0xFFFFFFFF, _us(b.t_wall), b.senders, b.poses))


decode_pose_batch = POSE_BATCH.decode  # the envelope; each pose in it is accepted on its own (accept_batched_pose)

class _BatchSenders(Wire, tag=_BATCH_TAG):
    """A batch's senders, nothing else looked at (:func:`batched_pose_count`)."""

    seq: msgspec.Raw
    t_wall: msgspec.Raw
    senders: list[Any]
    poses: msgspec.Raw


_decode_batch_senders = msgspec.msgpack.Decoder(_BatchSenders).decode


def batched_pose_count(data: bytes, exclude: int = 0) -> int:
    """How many poses an edge-feed batch carries from UAVs other than ``exclude``; 0 for a
    payload that is not one.

    Why: a UAV on the edge feed with aligned ticks counts the poses of an instant as they arrive,
    on its pose inlet's thread (:meth:`swarmnet.receive.Inlet.expect`), to act as soon as they
    are in; the batch's own pose of the UAV (the feed sends the swarm's poses to all) is not a
    neighbour's. About a microsecond for a batch of ten; the full checks run when the owner
    takes the batch in (:func:`accept_pose_batch`)."""
    if len(data) > MAX_BATCH_BYTES:
        return 0
    try:
        senders = _decode_batch_senders(data).senders
    except msgspec.DecodeError:  # (ValidationError is one)
        return 0
    return len(senders) - senders.count(exclude)


# --- virtual sensors and actuators (world service) -----------------------------------------
def _reading(w: ReadingWire) -> Reading:
    return Reading(w.uav, w.sensor, w.seq, w.t_meas / 1e6, w.t_sent / 1e6, w.value,
                   tuple((x / 100.0, y / 100.0, v) for x, y, v in w.points))


def _actuation(w: ActuationWire) -> Actuation:
    return Actuation(w.uav, w.actuator, w.seq, w.t_wall / 1e6, w.amount)


def _traffic(w: TrafficWire) -> Traffic:
    return Traffic(w.seq, w.t_wall / 1e6, tuple(TrafficReport(r[0], r[1] / 1e6, r[2] / 1e7, r[3] / 1e7, r[4] / 100.0,
                                                              r[5] / 100.0, r[6] / 100.0, r[7] / 100.0) for r in w.reports))


READING = Codec(Kind.READING, ReadingWire, MAX_READING_BYTES, _reading)
ACTUATION = Codec(Kind.ACTUATION, ActuationWire, MAX_ACTUATION_BYTES, _actuation)
TRAFFIC = Codec(Kind.TRAFFIC, TrafficWire, MAX_TRAFFIC_BYTES, _traffic)


def encode_reading(r: Reading) -> bytes:
    if not NAME_RE.match(r.sensor):
        raise ValueError(f"invalid sensor name {r.sensor!r}: 1-32 characters of [A-Za-z0-9_-]")
    if len(r.points) > MAX_READING_POINTS:
        raise ValueError(f"{len(r.points)} points in one reading, over {MAX_READING_POINTS}")
    if not -READING_LIMIT <= r.value <= READING_LIMIT:
        raise ValueError(f"reading value {r.value} is not finite within +-{READING_LIMIT:g}")
    try:
        points = [(_q(x, 100.0, _INT32, "x"), _q(y, 100.0, _INT32, "y"), float(v)) for x, y, v in r.points]
    except (ValueError, OverflowError) as exc:
        raise ValueError(f"cannot encode a reading of {r.sensor}: {exc}") from None
    if any(not -READING_LIMIT <= p[2] <= READING_LIMIT for p in points):
        raise ValueError("a point value is not finite")
    return _encode(ReadingWire(r.uav, r.sensor, r.seq & 0xFFFFFFFF, _us(r.t_meas), _us(r.t_sent), float(r.value), points))


decode_reading = READING.decode

def encode_actuation(a: Actuation) -> bytes:
    if not NAME_RE.match(a.actuator):
        raise ValueError(f"invalid actuator name {a.actuator!r}: 1-32 characters of [A-Za-z0-9_-]")
    if not 0.0 <= a.amount <= AMOUNT_LIMIT:
        raise ValueError(f"actuation amount {a.amount} outside 0..{AMOUNT_LIMIT:g}")
    return _encode(ActuationWire(a.uav, a.actuator, a.seq & 0xFFFFFFFF, _us(a.t_wall), float(a.amount)))


decode_actuation = ACTUATION.decode

def encode_traffic(t: Traffic) -> bytes:
    """Positions as 1e-7 degrees and cm (about 1 cm), velocities in cm/s, like the pose."""
    if len(t.reports) > MAX_TRAFFIC_REPORTS:
        raise ValueError(f"{len(t.reports)} traffic reports in one message, over {MAX_TRAFFIC_REPORTS}")
    try:
        reports = [(r.track & 0xFFFFFFFF, _us(r.t_wall), _q(r.lat, 1e7, 900_000_000, "lat"), _q(r.lon, 1e7, 1_800_000_000, "lon"),
                    _q(r.alt, 100.0, _INT32, "alt"), _q(r.ve, 100.0, _INT16, "ve"), _q(r.vn, 100.0, _INT16, "vn"),
                    _q(r.vu, 100.0, _INT16, "vu")) for r in t.reports]
    except (ValueError, OverflowError) as exc:
        raise ValueError(f"cannot encode traffic: {exc}") from None
    return _encode(TrafficWire(t.seq & 0xFFFFFFFF, _us(t.t_wall), reports))


decode_traffic = TRAFFIC.decode

# --- behaviour reports (uav_stack/sdk) -------------------------------------------------------
def _behaviour_report(w: BehaviourReportWire) -> BehaviourReport:
    return BehaviourReport(w.uav, w.seq, w.t_wall / 1e6, tuple((t / 1e6, name, v) for t, name, v in w.samples),
                           {topic: TopicCounts(*c) for topic, c in w.topics.items()}, w.dropped, w.refused)


BEHAVIOUR_REPORT = Codec(Kind.BEHAVIOUR_REPORT, BehaviourReportWire, MAX_REPORT_BYTES, _behaviour_report)


def _age_ms(v: float | None) -> float | None:
    return float(v) if v is not None and 0.0 <= v <= AGE_LIMIT_MS else None  # NaN fails the comparison too


def encode_behaviour_report(r: BehaviourReport) -> bytes:
    """``[tag, uav, seq, t_wall_us, samples, topics, dropped, refused]`` (:class:`BehaviourReportWire`)."""
    if len(r.samples) > MAX_REPORT_SAMPLES:
        raise ValueError(f"{len(r.samples)} samples in one behaviour report, over {MAX_REPORT_SAMPLES}")
    if len(r.topics) > MAX_REPORT_TOPICS:
        raise ValueError(f"{len(r.topics)} topics in one behaviour report, over {MAX_REPORT_TOPICS}")
    samples = []
    for t, name, value in r.samples:
        if not VALUE_NAME_RE.match(name):
            raise ValueError(f"invalid value name {name!r}: 1-64 characters of [A-Za-z0-9_.-]")
        samples.append((_us(t), name, float(value)))
    topics = {}
    for topic, c in r.topics.items():
        if len(topic) > MAX_TOPIC_LEN or not TOPIC_RE.match(topic):
            raise ValueError(f"invalid topic {topic!r}")
        topics[topic] = (c.sent, c.send_errors, c.received, c.rejected, c.dropped, _age_ms(c.age_mean_ms), _age_ms(c.age_max_ms))
    return _encode(BehaviourReportWire(r.uav, r.seq & 0xFFFFFFFF, _us(r.t_wall), samples, topics, min(r.dropped, _UINT32),
                                       min(r.refused, _UINT32)))


decode_behaviour_report = BEHAVIOUR_REPORT.decode

CODECS: dict[Kind, Codec[Any, Any]] = {c.kind: c for c in (POSE, TELEMETRY, STATE, SWARM_MESSAGE, COMMAND, COMMAND_ACK,
                                                           POSE_BATCH, FAULT, READING, ACTUATION, TRAFFIC, BEHAVIOUR_REPORT)}
"""Every kind's codec: its wire struct, size limit and check (the one way a payload of it is read)."""


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
