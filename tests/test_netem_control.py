"""The netem control message (``mrs/<swarm>/netem/set``): its bytes, its one decode, and a node's intake of it.

The payloads below are what ``mrswarm netem set``, the chaos controller and any sender publish
(UTF-8 JSON, docs/netem.md); the refused ones carry the reason they are counted under and the
field their detail names. The node-level tests feed a node's netem inlet directly (no Zenoh):
a change applied and acked, a bad config refused, counted and nacked, a bad payload counted
and never acked, a change for other UAVs left alone.
"""

from __future__ import annotations

import json
import math
import random
import re
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


@pytest.mark.parametrize(("msg", "names"), [
    (NetemSet(id=1, sender="a", t_wall=1.0, config={}, targets=(0,)), "netem_set.targets.0"),
    (NetemSet(id=1, sender="a", t_wall=-1.0, config={}), "netem_set.t_wall"),
    (NetemSet(id=1, sender="a", t_wall=math.nan, config={}), "netem_set.t_wall"),
    (NetemSet(id=1, sender="a", t_wall=1.0, config={"a": [[[[[[[[]]]]]]]]}), "nested deeper than 8"),
])
def test_a_sender_cannot_write_what_receivers_refuse(msg: NetemSet, names: str) -> None:
    """Before the msgspec codec only the sender's name and the size were checked: these were sent, and refused by every UAV."""
    with pytest.raises(ValueError, match=re.escape(names)):
        encode_netem_set(msg)


def test_numbers_of_other_types_are_written_as_json_numbers() -> None:
    np = pytest.importorskip("numpy")
    msg = NetemSet(id=1, sender="a", t_wall=np.float64(2.5), config={"seed": np.int64(4), "v2v": {"duplicate": np.float32(0.5)}})
    assert encode_netem_set(msg) == (b'{"v":1,"id":1,"sender":"a","t_wall":2.5,"targets":null,'
                                     b'"config":{"seed":4,"v2v":{"duplicate":0.5}}}')
    with pytest.raises(TypeError, match="JSON values only"):
        encode_netem_set(NetemSet(id=1, sender="a", t_wall=1.0, config={"x": object()}))


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
    (payload(config={"links": [{"src": 1, "dst": 2, "outage": {"every_s": 9, "duration_ms": [1, 2]}}]}),  # as deep as one gets
     (1, "x", 1.0, None, {"links": [{"src": 1, "dst": 2, "outage": {"every_s": 9, "duration_ms": [1, 2]}}]})),
    # 8 levels of objects and lists, config's own counted
    (payload(config={"a": {"b": [[[[[[]]]]]]}}), (1, "x", 1.0, None, {"a": {"b": [[[[[[]]]]]]}})),
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
    (payload(v=True), "wrong_version", "version"),  # taken before the msgspec codec (Python's True == 1)
    (payload(v=1.0), "wrong_version", "version"),  # ditto
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
    # not JSON (Python's decoder read them, and the range check refused them as bad_field)
    (b'{"v":1,"id":1,"sender":"x","t_wall":NaN,"targets":null,"config":{}}', "malformed", "JSON"),
    (b'{"v":1,"id":1,"sender":"x","t_wall":Infinity,"targets":null,"config":{}}', "malformed", "JSON"),
    (payload(t_wall=...), "bad_field", "t_wall"),
    (payload(targets=[0]), "bad_field", "targets"),
    (payload(targets=[65536]), "bad_field", "targets"),
    (payload(targets=[True]), "bad_field", "targets"),
    (payload(targets=[1.0]), "bad_field", "targets"),
    (payload(targets=1), "bad_field", "targets"),
    (payload(config=[]), "bad_field", "config"),
    (payload(config=None), "bad_field", "config"),
    (payload(config=...), "bad_field", "config"),
    (payload(config={"a": {"b": [[[[[[[]]]]]]]}}), "malformed", "netem_set.config.a.b.0.0.0.0.0.0: nested deeper than 8"),
    (b'{"v":1,"id":1,"sender":"x","t_wall":1,"config":{"a":' + b"[" * 5000 + b"]" * 5000 + b"}}", "malformed", "nested"),
    (bytes(MAX_BYTES + 1), "oversized", ""),
    (b"[" * 100_000, "oversized", ""),
]


@pytest.mark.parametrize(("data", "reason", "names"), REFUSED)
def test_a_bad_netem_set_is_refused_with_its_reason_naming_the_field(data: bytes, reason: str, names: str) -> None:
    with pytest.raises(DecodeError) as err:
        decode_netem_set(data)
    assert err.value.reason == reason, err.value
    assert names in err.value.detail, err.value
    assert reason == "oversized" or err.value.detail.startswith("netem_set"), err.value


def test_a_refusal_names_the_field_and_what_it_must_be() -> None:
    def detail(data: bytes) -> str:
        with pytest.raises(DecodeError) as err:
            decode_netem_set(data)
        return err.value.detail

    assert detail(payload(t_wall=-1)) == "netem_set.t_wall: must be a number in [0, 9.22337e+18), got -1"
    assert detail(payload(id=2**32)) == "netem_set.id: must be an integer in [0, 4294967295], got 4294967296"
    assert detail(payload(targets=[1, 0])) == "netem_set.targets.1: must be an integer in [1, 65535], got 0"
    assert detail(payload(config=[])) == "netem_set.config: must be a mapping, got []"
    assert detail(payload(id=...)) == "netem_set.id: required"
    assert detail(payload(x=1)) == "netem_set.x: unknown field (expected one of: config, id, sender, t_wall, targets, v)"


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
    """Before the msgspec codec this payload decoded, and the config's merge raised RecursionError,
    which the node caught (with TypeError, KeyError...) and nacked; now it never decodes."""
    n, inlet, pub = _node()
    deep = b"[" * 900 + b"]" * 900
    _arrive(inlet, b'{"v":1,"id":81,"sender":"x","t_wall":1,"targets":null,"config":{"v2v":{"delay":{"x":' + deep + b"}}}}")
    n._apply_netem_sets(11.0, 100)
    assert dict(n.stats.rejected) == {"malformed": 1} and n.netem is None and not pub.acks


def test_whatever_a_node_is_sent_it_applies_or_refuses_and_answers_never_raising() -> None:
    """Random configs (valid ones among them) and random JSON in random places: each message is
    applied and acked, refused as a bad config and nacked, or refused as a payload; nothing else."""
    from tests.test_netem_shim import random_config

    rng = random.Random(4)
    n, inlet, pub = _node()
    sent = applied = 0
    for i in range(2000):
        cfg = random_config(rng)
        if not isinstance(cfg, dict) or rng.random() < 0.1:
            data = payload(id=i, config=cfg if rng.random() < 0.5 else {"v2v": cfg})
        else:
            data = payload(id=i, config=cfg)
        _arrive(inlet, data)
        n._apply_netem_sets(11.0, 100)
        received, rejected = n.stats.received["netem_set"], sum(n.stats.rejected.values())
        assert received + rejected == i + 1
        if len(pub.acks) > sent:
            sent = len(pub.acks)
            assert pub.acks[-1].cmd_id == i
            applied += pub.acks[-1].ok
    assert applied == n.stats.received["netem_set"] > 100
    assert sent == applied + n.stats.rejected["bad_netem_config"]


_NO_SHIM = """
import sys
from swarmnet.messages import SwarmMessage, encode_swarm_message
from swarmnet.node import MESSAGE, Inbox, NodeIdentity, SwarmNode
from swarmnet.receive import Accepted, Inlet

n = SwarmNode(NodeIdentity("alpha", 2), connectivity=None)
n._netem_inlet = Inlet(16)  # subscribed, as every UAV's is, and empty
msg = SwarmMessage(1, 0, "chat", 0, 1.0, "hi")
inbox = Inbox()
for _ in range(3):
    n._apply_netem_sets(2.0, 100)
    n._take_in(iter([(MESSAGE, Accepted("mrs/alpha/1/msg/chat", msg, encode_swarm_message(msg), 1.5))]), 2.0, inbox)
assert len(inbox.messages) == 3 and n.netem is None and n.expected_poses_due() is None
print(sorted(m for m in sys.modules if m.startswith("swarmnet.netem") or m == "groundfloor.schema"))
"""


def test_a_node_without_netem_never_loads_the_shim_nor_the_control_codec() -> None:
    """The shim is an optional stage: a node that was never configured and was sent no change
    delivers what it takes in straight away, and never imports the netem package's modules."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _NO_SHIM], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
