"""The runtime control message: ``mrs/<swarm>/netem/set``, and its one codec.

Payload: UTF-8 JSON, at most 64 KiB::

    {"v": 1, "id": 12345, "sender": "cli", "t_wall": 1700000000.123,
     "targets": [1, 2] | null, "config": {<the network.netem mapping>}}

``config`` replaces the node's whole netem configuration (a missing ``seed`` keeps the
current one). ``targets`` limits the change to some UAVs (null or left out: every node of the
swarm). Every UAV that applies or refuses it answers on its ack key (``mrs/<swarm>/<uav>/ack``)
with ``cmd_id = id``, so a sender can wait for the swarm to confirm.

The codec is the other kinds' (:mod:`swarmnet.messages`) in JSON: :class:`NetemSetWire` is the
message as a msgspec Struct whose field types carry the bounds, and :func:`decode_netem_set` is
one msgspec call that checks the version, the fields present and every field's type and range.
A payload refused is read once more to name the reason (:func:`_refusal`): a
:class:`~swarmnet.messages.DecodeError` counted under ``malformed``, ``wrong_version``,
``bad_field`` or ``oversized``, its detail naming the field
(``netem_set.t_wall: must be a number in [0, 9.22337e+18), got -1``). Nothing here raises any other
exception on bad input. The envelope is checked here; the config, by
:func:`swarmnet.netem.config.parse_netem` (msgspec too) in the node, which then knows the
message's id and can answer a bad config with the field that is wrong. What the envelope asks of
the config is what every netem mapping is: a JSON object nested at most :data:`CONFIG_DEPTH`
levels deep, so that nothing the node does with it later can recurse without bound.

Why a wire struct next to :class:`NetemSet`, as for the msgpack kinds: the wire form carries
the version ``v`` and writes its fields in the order the hand-written encoder before it did
(byte for byte, tests/test_netem_control.py); what senders build and receivers get has neither.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated, Any, Final, Literal

import msgspec

from swarmnet.messages import UAV_ID_MAX, DecodeError, Name, Seq, Uav

VERSION: Final = 1  # the wire struct's v
MAX_BYTES = 64 * 1024
CONFIG_DEPTH = 8  # mappings and lists, config itself included; a netem mapping needs 5 (config.links[i].outage.duration_ms)


@dataclass(frozen=True)
class NetemSet:
    id: int
    sender: str
    t_wall: float
    config: dict[str, Any] = field(default_factory=dict)
    targets: tuple[int, ...] | None = None

    def applies_to(self, uav: int) -> bool:
        """The change is for UAV ``uav`` (no targets: for every node of the swarm)."""
        return self.targets is None or uav in self.targets


_Scalar = bool | int | float | str | None


def _nested(levels: int) -> Any:
    """A JSON value with at most ``levels`` levels of lists and objects."""
    t: Any = _Scalar
    for _ in range(levels):
        t = _Scalar | list[t] | dict[str, t]
    return t


if TYPE_CHECKING:
    ConfigMapping = dict[str, Any]
else:
    ConfigMapping = dict[str, _nested(CONFIG_DEPTH - 1)]
_TOO_DEEP = "Expected `bool | int | float | str | null`, got "  # msgspec's words for a list or object below the last level


class NetemSetWire(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """The message on the wire, in the order the fields are written."""

    v: Literal[1]  # VERSION
    id: Seq
    sender: Name
    t_wall: Annotated[float, msgspec.Meta(ge=0.0, lt=2.0**63)]  # s since the Unix epoch
    targets: Annotated[tuple[Uav, ...], msgspec.Meta(max_length=UAV_ID_MAX)] | None = None
    config: ConfigMapping


def _plain_number(obj: Any) -> Any:
    """A number of another type (numpy's) as the int or float JSON writes."""
    if isinstance(obj, numbers.Integral):
        return int(obj)
    if isinstance(obj, numbers.Real):
        return float(obj)
    raise TypeError(f"a netem config holds JSON values only, not {type(obj).__name__}")


_encode = msgspec.json.Encoder(enc_hook=_plain_number).encode
_decode = msgspec.json.Decoder(NetemSetWire).decode


def encode_netem_set(m: NetemSet) -> bytes:
    """The message as every receiver reads it; a ValueError naming the field for one they would refuse."""
    data = _encode(NetemSetWire(v=VERSION, id=m.id & 0xFFFFFFFF, sender=m.sender, t_wall=m.t_wall,
                                targets=tuple(m.targets) if m.targets is not None else None, config=m.config))
    if len(data) > MAX_BYTES:
        raise ValueError(f"netem set message is {len(data)} bytes, over {MAX_BYTES}")
    try:
        decode_netem_set(data)  # refused here, naming the field, rather than by every UAV
    except DecodeError as exc:
        raise ValueError(f"cannot send this netem set: {exc.detail}") from None
    return data


def decode_netem_set(data: bytes) -> NetemSet:
    """``data`` as a :class:`NetemSet`, or :class:`~swarmnet.messages.DecodeError` with the reason."""
    if len(data) > MAX_BYTES:
        raise DecodeError("oversized", f"{len(data)} bytes > {MAX_BYTES}")
    try:
        w = _decode(data)
    except (msgspec.DecodeError, RecursionError) as exc:  # (a msgspec.ValidationError is a DecodeError)
        raise _refusal(data, exc) from None
    return NetemSet(w.id, w.sender, w.t_wall, w.config, w.targets)


def accept_netem_set(key: str, data: bytes) -> NetemSet:
    """A runtime change on ``mrs/<swarm>/netem/set``, the swarm's one control key: it decodes.

    Whether it is for this UAV (:meth:`NetemSet.applies_to`: a change for others is not a
    rejection) and whether its config is valid, the node decides: it answers either way."""
    return decode_netem_set(data)


def _refusal(data: bytes, exc: Exception) -> DecodeError:
    """Why msgspec refused ``data``: the JSON is read once more to tell a payload that is not a
    netem set (``malformed``: not UTF-8 JSON, not an object, an unknown field, nested too deep)
    or not this version (``wrong_version``, checked first, as a later version may add fields)
    from one with a field out of its bounds (``bad_field``, naming the field)."""
    try:
        o = msgspec.json.decode(data)
    except RecursionError:
        return DecodeError("malformed", "netem_set: nested too deeply")
    except msgspec.DecodeError as err:
        return DecodeError("malformed", f"netem_set: not UTF-8 JSON ({err})")
    if type(o) is not dict:
        return DecodeError("malformed", "netem_set: must be a JSON object")
    v = o.get("v")
    if type(v) is not int or v != VERSION:
        return DecodeError("wrong_version", f"netem_set version {v!r:.20}, this node speaks {VERSION}")
    if not isinstance(exc, msgspec.ValidationError):  # (msgspec read what the JSON decoder could not)
        return DecodeError("malformed", f"netem_set: {exc}")
    from groundfloor.schema_errors import explain

    path, what = explain(exc, o, NetemSetWire)
    if what.startswith("unknown field"):
        return DecodeError("malformed", f"netem_set.{path}: {what}")
    if str(exc).startswith(_TOO_DEEP):
        return DecodeError("malformed", f"netem_set.{path}: nested deeper than {CONFIG_DEPTH} levels")
    return DecodeError("bad_field", f"netem_set.{path}: {what}")
