"""The runtime control message: ``mrs/<swarm>/netem/set``.

Payload: UTF-8 JSON, at most 64 KiB::

    {"v": 1, "id": 12345, "sender": "cli", "t_wall": 1700000000.123,
     "targets": [1, 2] | null, "config": {<the network.netem mapping>}}

``config`` replaces the node's whole netem configuration (a missing ``seed`` keeps the
current one). ``targets`` limits the change to some UAVs (null: every node of the swarm).
Every UAV that applies or refuses it answers on its ack key (``mrs/<swarm>/<uav>/ack``) with
``cmd_id = id``, so a sender can wait for the swarm to confirm. The JSON is validated here
(:class:`~swarmnet.messages.DecodeError` with a counter name, like every other message); the
config itself by :func:`swarmnet.netem.config.parse_netem` in the node.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from swarmnet.messages import NAME_RE, DecodeError

VERSION = 1
MAX_BYTES = 64 * 1024


@dataclass(frozen=True)
class NetemSet:
    id: int
    sender: str
    t_wall: float
    config: dict[str, Any] = field(default_factory=dict)
    targets: tuple[int, ...] | None = None


def encode_netem_set(m: NetemSet) -> bytes:
    if not NAME_RE.match(m.sender):
        raise ValueError(f"sender {m.sender!r} must be 1-32 characters of [A-Za-z0-9_-]")
    data = json.dumps({"v": VERSION, "id": m.id & 0xFFFFFFFF, "sender": m.sender, "t_wall": m.t_wall,
                       "targets": list(m.targets) if m.targets is not None else None, "config": m.config},
                      separators=(",", ":")).encode()
    if len(data) > MAX_BYTES:
        raise ValueError(f"netem set message is {len(data)} bytes, over {MAX_BYTES}")
    return data


def decode_netem_set(data: bytes) -> NetemSet:
    if len(data) > MAX_BYTES:
        raise DecodeError("oversized", f"{len(data)} bytes > {MAX_BYTES}")
    try:
        o = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        raise DecodeError("malformed", "netem set is not UTF-8 JSON") from None
    if not isinstance(o, dict):
        raise DecodeError("malformed", "netem set must be a JSON object")
    if o.get("v") != VERSION:
        raise DecodeError("wrong_version", f"netem set version {o.get('v')!r}, this node speaks {VERSION}")
    extra = set(o) - {"v", "id", "sender", "t_wall", "targets", "config"}
    if extra:
        raise DecodeError("malformed", f"unknown fields {sorted(extra)}")
    mid, sender, t, cfg, targets = o.get("id"), o.get("sender"), o.get("t_wall"), o.get("config"), o.get("targets")
    if type(mid) is not int or not 0 <= mid <= 0xFFFFFFFF:
        raise DecodeError("bad_field", f"id={mid!r}")
    if type(sender) is not str or not NAME_RE.match(sender):
        raise DecodeError("bad_field", f"sender={sender!r:.40}")
    if not isinstance(t, (int, float)) or type(t) is bool or not 0 <= t < 2**63:
        raise DecodeError("bad_field", f"t_wall={t!r:.40}")
    if not isinstance(cfg, dict):
        raise DecodeError("bad_field", "config must be an object")
    if targets is not None:
        if not isinstance(targets, list) or len(targets) > 65535 or not all(type(u) is int and 1 <= u <= 65535 for u in targets):
            raise DecodeError("bad_field", "targets must be null or a list of UAV ids")
        targets = tuple(targets)
    return NetemSet(id=mid, sender=sender, t_wall=float(t), config=cfg, targets=targets)
