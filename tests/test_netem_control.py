"""The netem control message (``mrs/<swarm>/netem/set``): its bytes, its one decode, and a node's intake of it.

The payloads below are what ``mrswarm netem set``, the chaos controller and any sender publish
(UTF-8 JSON, docs/netem.md); the refused ones carry the reason they are counted under and the
field their detail names. The node-level tests feed a node's netem inlet directly (no Zenoh):
a change applied and acked, a bad config refused, counted and nacked, a bad payload counted
and never acked, a change for other UAVs left alone.
"""

from __future__ import annotations

import json
import random
from types import SimpleNamespace
from typing import Any

import pytest

from swarmnet.keyspace import SwarmKeys
from swarmnet.messages import DecodeError, decode_ack
from swarmnet.netem.control import MAX_BYTES, NetemSet, decode_netem_set, encode_netem_set
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.receive import Inlet

GOOD: dict[str, Any] = {"v": 1, "id": 1, "sender": "x", "t_wall": 1, "targets": None, "config": {}}


def payload(**fields: Any) -> bytes:
    """GOOD with ``fields`` changed (a value of ``...``: the field left out)."""
    o = {**GOOD, **fields}
    return json.dumps({k: v for k, v in o.items() if v is not ...}).encode()


# ---- the bytes senders write ------------------------------------------------------------------------
ENCODED = [
    (NetemSet(id=5, sender="cli", t_wall=1700000000.123, config={"preset": "lan"}, targets=(2, 3)),
     b'{"v":1,"id":5,"sender":"cli","t_wall":1700000000.123,"targets":[2,3],"config":{"preset":"lan"}}'),
    (NetemSet(id=5, sender="cli", t_wall=1, config={}),
     b'{"v":1,"id":5,"sender":"cli","t_wall":1,"targets":null,"config":{}}'),
    (NetemSet(id=2**32 + 7, sender="chaos", t_wall=2.5, config={"partitions": {"a": [1, 2], "b": [3]}}),  # the id wraps
     b'{"v":1,"id":7,"sender":"chaos","t_wall":2.5,"targets":null,"config":{"partitions":{"a":[1,2],"b":[3]}}}'),
]


@pytest.mark.parametrize(("msg", "data"), ENCODED)
def test_a_netem_set_is_written_as_senders_always_wrote_it(msg: NetemSet, data: bytes) -> None:
    assert encode_netem_set(msg) == data
    back = decode_netem_set(data)
    assert (back.id, back.sender, back.t_wall, back.targets, back.config) == (msg.id & 0xFFFFFFFF, msg.sender, msg.t_wall,
                                                                               msg.targets, msg.config)


def test_what_a_sender_writes_any_json_reader_reads_alike() -> None:
    msg = NetemSet(id=9, sender="cli", t_wall=3.25, config={"partitions": {"nörd": [1]}, "v2v": {"delay": {"ms": 50}}})
    assert json.loads(encode_netem_set(msg)) == {"v": 1, "id": 9, "sender": "cli", "t_wall": 3.25, "targets": None,
                                                 "config": {"partitions": {"nörd": [1]}, "v2v": {"delay": {"ms": 50}}}}


def test_a_sender_cannot_write_a_bad_sender_name_or_an_oversized_message() -> None:
    with pytest.raises(ValueError, match="sender"):
        encode_netem_set(NetemSet(id=1, sender="a b", t_wall=1.0, config={}))
    with pytest.raises(ValueError, match="65536"):
        encode_netem_set(NetemSet(id=1, sender="a", t_wall=1.0, config={"x": "y" * MAX_BYTES}))


# ---- what a receiver takes ----------------------------------------------------------------------------
ACCEPTED = [
    (payload(), (1, "x", 1.0, None, {})),
    (payload(targets=...), (1, "x", 1.0, None, {})),  # targets may be left out: every node
    (payload(targets=[1, 65535]), (1, "x", 1.0, (1, 65535), {})),
    (payload(targets=[]), (1, "x", 1.0, (), {})),
    (payload(id=0xFFFFFFFF, sender="x" * 32), (0xFFFFFFFF, "x" * 32, 1.0, None, {})),
    (payload(t_wall=1700000000.5, config={"preset": "lte", "seed": 3}),
     (1, "x", 1700000000.5, None, {"preset": "lte", "seed": 3})),
    (b"  " + payload() + b"\n", (1, "x", 1.0, None, {})),  # JSON whitespace
    (b'{"v":1,"id":1,"id":2,"sender":"x","t_wall":1,"targets":null,"config":{}}', (2, "x", 1.0, None, {})),  # the last one counts
    (b'{"config":{},"targets":null,"t_wall":1,"sender":"x","id":1,"v":1}', (1, "x", 1.0, None, {})),  # in any order
    (payload(v=True), (1, "x", 1.0, None, {})),  # (Python's True == 1)
    (payload(v=1.0), (1, "x", 1.0, None, {})),
]


@pytest.mark.parametrize(("data", "fields"), ACCEPTED)
def test_a_valid_netem_set_is_taken(data: bytes, fields: tuple[Any, ...]) -> None:
    m = decode_netem_set(data)
    assert (m.id, m.sender, m.t_wall, m.targets, m.config) == fields
    assert type(m.t_wall) is float


# (payload, reason, what the detail names)
REFUSED = [
    (b"", "malformed", ""),
    (b"\xff\xfe", "malformed", ""),
    (payload()[:-1], "malformed", ""),
    (payload() + b"x", "malformed", ""),
    (b"[]", "malformed", "object"),
    (b"null", "malformed", "object"),
    (b"{}", "wrong_version", "version"),
    (b'{"v": 2}', "wrong_version", "version"),
    (payload(v=2), "wrong_version", "version"),
    (payload(v=...), "wrong_version", "version"),
    (payload(v="1"), "wrong_version", "version"),
    (payload(x=1), "malformed", "x"),
    (payload(id=-1), "bad_field", "id"),
    (payload(id=2**32), "bad_field", "id"),
    (payload(id=True), "bad_field", "id"),
    (payload(id=1.0), "bad_field", "id"),
    (payload(id=...), "bad_field", "id"),
    (payload(sender="x y"), "bad_field", "sender"),
    (payload(sender="x" * 33), "bad_field", "sender"),
    (payload(sender=""), "bad_field", "sender"),
    (payload(sender=1), "bad_field", "sender"),
    (payload(sender=...), "bad_field", "sender"),
    (payload(t_wall=-1), "bad_field", "t_wall"),
    (payload(t_wall=True), "bad_field", "t_wall"),
    (payload(t_wall="1"), "bad_field", "t_wall"),
    (payload(t_wall=2**63), "bad_field", "t_wall"),
    (b'{"v":1,"id":1,"sender":"x","t_wall":NaN,"targets":null,"config":{}}', "bad_field", "t_wall"),
    (b'{"v":1,"id":1,"sender":"x","t_wall":Infinity,"targets":null,"config":{}}', "bad_field", "t_wall"),
    (payload(t_wall=...), "bad_field", "t_wall"),
    (payload(targets=[0]), "bad_field", "targets"),
    (payload(targets=[65536]), "bad_field", "targets"),
    (payload(targets=[True]), "bad_field", "targets"),
    (payload(targets=[1.0]), "bad_field", "targets"),
    (payload(targets=1), "bad_field", "targets"),
    (payload(config=[]), "bad_field", "config"),
    (payload(config=None), "bad_field", "config"),
    (payload(config=...), "bad_field", "config"),
    (bytes(MAX_BYTES + 1), "oversized", ""),
    (b"[" * 100_000, "oversized", ""),
]


@pytest.mark.parametrize(("data", "reason", "names"), REFUSED)
def test_a_bad_netem_set_is_refused_with_its_reason_naming_the_field(data: bytes, reason: str, names: str) -> None:
    with pytest.raises(DecodeError) as err:
        decode_netem_set(data)
    assert err.value.reason == reason, err.value
    assert names in err.value.detail, err.value


def test_random_bytes_and_mangled_messages_only_ever_raise_decode_errors() -> None:
    rng = random.Random(46)
    good = encode_netem_set(NetemSet(id=1, sender="cli", t_wall=1.0, config={"v2v": {"delay": {"ms": 5}}}, targets=(2,)))
    samples = [bytes(rng.randrange(256) for _ in range(rng.randrange(200))) for _ in range(2000)]
    for _ in range(2000):
        b = bytearray(good)
        for _ in range(rng.randrange(1, 4)):
            b[rng.randrange(len(b))] = rng.choice(b'{}[]",:0123456789-eE.tfn \\')
        samples.append(bytes(b))
    for data in samples:
        try:
            decode_netem_set(data)
        except DecodeError:
            pass


# ---- a node's intake: applied and acked, refused and counted ---------------------------------------------
class _AckPublisher:
    def __init__(self) -> None:
        self.acks: list[Any] = []

    def put(self, data: bytes) -> None:
        self.acks.append(decode_ack(data))


def _node(uav: int = 2) -> tuple[SwarmNode, Inlet, _AckPublisher]:
    """A node with a netem inlet and an ack publisher of its own, never opened (no Zenoh)."""
    n = SwarmNode(NodeIdentity("alpha", uav), connectivity=None)  # type: ignore[arg-type]
    inlet = n._netem_inlet = Inlet(16)
    pub = n._pubs["ack"] = _AckPublisher()  # type: ignore[assignment]
    return n, inlet, pub


def _arrive(inlet: Inlet, data: bytes) -> None:
    key = SwarmKeys("alpha").netem_set
    inlet.handler()(SimpleNamespace(key_expr=key, payload=SimpleNamespace(to_bytes=lambda: data)))


def test_a_node_applies_a_change_and_acks_it() -> None:
    n, inlet, pub = _node()
    _arrive(inlet, encode_netem_set(NetemSet(id=77, sender="cli", t_wall=10.0, config={"v2v": {"delay": {"ms": 300}}})))
    n._apply_netem_sets(11.0, 100)
    assert n.netem is not None and "delay 300ms" in n.netem.config.describe()
    assert n.stats.received["netem_set"] == 1 and not n.stats.rejected
    assert n.netem_changes[-1]["source"] == "cli" and n.netem_changes[-1]["id"] == 77 and n.netem_changes[-1]["t_sent"] == 10.0
    [ack] = pub.acks
    assert ack.cmd_id == 77 and ack.ok and "delay 300ms" in ack.message


def test_a_node_refuses_a_bad_config_counts_it_nacks_it_and_keeps_the_old_one() -> None:
    n, inlet, pub = _node()
    n.set_netem({"v2v": {"delay": {"ms": 100}}}, source="config")
    _arrive(inlet, encode_netem_set(NetemSet(id=78, sender="cli", t_wall=10.0,
                                             config={"v2v": {"loss": {"model": "bernoulli", "p": 2}}})))
    n._apply_netem_sets(11.0, 100)
    assert n.stats.rejected["bad_netem_config"] == 1 and n.stats.received["netem_set"] == 0
    [ack] = pub.acks
    assert ack.cmd_id == 78 and not ack.ok and "v2v.loss.p" in ack.message
    assert n.netem is not None and "delay 100ms" in n.netem.config.describe()


@pytest.mark.parametrize(("data", "reason"), [(b"{not json", "malformed"), (payload(v=2), "wrong_version"),
                                               (payload(t_wall=-1), "bad_field"), (bytes(MAX_BYTES + 1), "oversized")])
def test_a_node_counts_a_bad_payload_under_its_reason_and_acks_nothing(data: bytes, reason: str) -> None:
    n, inlet, pub = _node()
    _arrive(inlet, data)
    n._apply_netem_sets(11.0, 100)
    assert dict(n.stats.rejected) == {reason: 1} and not pub.acks and n.netem is None


def test_a_node_leaves_a_change_for_other_uavs_alone() -> None:
    n, inlet, pub = _node(2)
    _arrive(inlet, encode_netem_set(NetemSet(id=79, sender="cli", t_wall=10.0, config={"preset": "lte"}, targets=(1, 3))))
    _arrive(inlet, encode_netem_set(NetemSet(id=80, sender="cli", t_wall=10.0, config={"preset": "x"}, targets=(1,))))
    n._apply_netem_sets(11.0, 100)
    assert n.netem is None and not pub.acks and not n.stats.rejected and n.stats.received["netem_set"] == 0


def test_a_node_refuses_a_config_nested_too_deep_to_copy() -> None:
    n, inlet, pub = _node()
    deep = b"[" * 900 + b"]" * 900  # (JSON's own decoder takes it; copying it in the config's merge does not)
    _arrive(inlet, b'{"v":1,"id":81,"sender":"x","t_wall":1,"targets":null,"config":{"v2v":{"delay":{"x":' + deep + b"}}}}")
    n._apply_netem_sets(11.0, 100)
    assert dict(n.stats.rejected) == {"bad_netem_config": 1} and n.netem is None
    [ack] = pub.acks
    assert ack.cmd_id == 81 and not ack.ok
