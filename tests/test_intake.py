"""The compiled intake of edge-feed batches (swarmnet/_intake.c) against the Python rules it stands in for.

What a user relies on: a UAV that runs the compiled intake ends with the same neighbour table,
the same counters (received, rejected, by reason) and the same pose ages as one that runs the
Python rules, for any batch, valid, corrupted or forged; and the compiled one really runs.
"""

from __future__ import annotations

import dataclasses
import random
import struct
from functools import partial
from typing import Any

import msgpack
import pytest

from swarmnet.connectivity import Rendezvous
from swarmnet.intake import INTAKE, PoseIntake
from swarmnet.messages import (
    BATCH_VERSION,
    Kind,
    Pose,
    PoseBatch,
    Realm,
    accept_neighbour_pose,
    batched_pose_count,
    encode_pose,
    encode_pose_batch,
    tag,
)
from swarmnet.neighbours import NeighbourTable
from swarmnet.node import POSE, Inbox, NodeIdentity, SwarmNode
from swarmnet.receive import Accepted

OWN = 1
KEY = "mrs/alpha/feed/poses"
BATCH_TAG = tag(Kind.POSE_BATCH, BATCH_VERSION)


def _node(compiled: bool) -> SwarmNode:
    """A UAV's node, never opened: the intake needs no session."""
    node = SwarmNode(NodeIdentity("alpha", OWN), Rendezvous(("tcp/127.0.0.1:9",)))
    node.waker.close()  # its file descriptor, which a node never opened keeps otherwise
    node.intake = PoseIntake(node.neighbours, compiled=compiled)
    return node


def _state(node: SwarmNode) -> dict[str, Any]:
    """Everything the intake may change, in comparable form."""
    table = {n.uav: (dataclasses.astuple(n.pose), n.first_seen, n.last_recv, n.used, n.received, n.lost, n.duplicates,
                     n.out_of_order, n.interval) for n in node.neighbours}
    return {"table": table, "stats": node.stats.to_dict(links=True)}


def _pose_payload(rng: random.Random, uav: int, seq: int, t_wall: float) -> bytes:
    edge = rng.random() < 0.1  # now and then the limits of every field
    return encode_pose(Pose(
        uav=uav, realm=rng.choice([Realm.VIRTUAL, Realm.PHYSICAL]), seq=seq,
        t_sim=rng.uniform(0, 4e6) if not edge else 4294967.295, t_wall=t_wall,
        x=rng.uniform(-5e3, 5e3) if not edge else 21474836.47, y=rng.uniform(-5e3, 5e3) if not edge else -21474836.47,
        z=rng.uniform(-10, 300) if not edge else 327.67, vx=rng.uniform(-20, 20), vy=rng.uniform(-20, 20),
        vz=rng.uniform(-5, 5) if not edge else -327.67, yaw=rng.uniform(-3.14159, 3.14159),
    ))


def _corrupt(rng: random.Random, payload: bytes, senders: list[int], poses: list[bytes], t: float) -> bytes:
    """One of the ways a batch goes wrong: on the wire, or from a forger who speaks msgpack."""
    how = rng.randrange(14)
    if how == 0:  # a flipped byte
        i = rng.randrange(len(payload))
        return payload[:i] + bytes([payload[i] ^ (1 << rng.randrange(8))]) + payload[i + 1:]
    if how == 1:  # cut short
        return payload[: rng.randrange(len(payload))]
    if how == 2:  # a byte too many
        return payload + b"\x00"
    if how == 3 and senders:  # a pose under another UAV's name
        s = list(senders)
        s[rng.randrange(len(s))] = rng.randrange(2, 12)
        return msgpack.packb([BATCH_TAG, 3, int(t * 1e6), s, poses], use_bin_type=True)
    if how == 4 and poses:  # a pose field of the wrong type (a bool, a float)
        p = msgpack.unpackb(poses[0])
        p[rng.randrange(1, 13)] = rng.choice([True, 1.5, "x", None])
        return msgpack.packb([BATCH_TAG, 3, int(t * 1e6), senders, [msgpack.packb(p)] + poses[1:]], use_bin_type=True)
    if how == 5 and poses:  # a field out of range
        p = msgpack.unpackb(poses[0])
        i = rng.randrange(1, 13)
        p[i] = rng.choice([-1, 70000, 2**40, -(2**40)])
        return msgpack.packb([BATCH_TAG, 3, int(t * 1e6), senders, [msgpack.packb(p)] + poses[1:]], use_bin_type=True)
    if how == 6 and poses:  # a stamp past int64, that the Python rules still take (up to 2**64 - 1 us)
        p = msgpack.unpackb(poses[0])
        p[5] = 2**64 - 1 - rng.randrange(1000)
        return msgpack.packb([BATCH_TAG, 3, int(t * 1e6), senders, [msgpack.packb(p)] + poses[1:]], use_bin_type=True)
    if how == 7 and poses:  # a valid pose in a 16-bit bin: valid msgpack the fast path does not read
        body = b"".join(b"\xc5" + struct.pack(">H", len(p)) + p for p in poses)
        head = msgpack.packb([BATCH_TAG, 3, int(t * 1e6), senders])  # an array of 4, made one of 5 below
        arr = (bytes([0x90 | len(poses)]) if len(poses) < 16 else b"\xdc" + struct.pack(">H", len(poses)))
        return bytes([0x95]) + head[1:] + arr + body
    if how == 8:  # a pose too long
        return msgpack.packb([BATCH_TAG, 3, int(t * 1e6), senders[:1] or [2], [b"\x9d" + b"\x01" * 60]], use_bin_type=True)
    if how == 9:  # another kind or version
        return msgpack.packb([tag(Kind.POSE_BATCH, 1), 3, int(t * 1e6), senders, poses], use_bin_type=True)
    if how == 10:  # more senders than poses
        return msgpack.packb([BATCH_TAG, 3, int(t * 1e6), senders + [9], poses], use_bin_type=True)
    if how == 11:  # a sender id out of range
        return msgpack.packb([BATCH_TAG, 3, int(t * 1e6), [0] + senders[1:], poses], use_bin_type=True)
    if how == 12 and poses:  # a pose with a 14th field
        p = msgpack.unpackb(poses[0]) + [0]
        return msgpack.packb([BATCH_TAG, 3, int(t * 1e6), senders, [msgpack.packb(p)] + poses[1:]], use_bin_type=True)
    return b"\x95\xc0"  # not even a batch


def _batches(seed: int, n: int) -> list[tuple[bytes, float]]:
    """``n`` batches from UAVs 1..8 (1 is the receiver's own), with what real feeds bring:
    sequence gaps, duplicates, late poses, sequence wrap-around, restarted senders; a third of
    them corrupted."""
    rng = random.Random(seed)
    seq = {u: rng.randrange(65536) for u in range(1, 9)}
    last: dict[int, bytes] = {}
    stamp = {u: 1.8e9 for u in range(1, 9)}  # the last stamp of each, s
    t = 1.8e9
    out = []
    for _ in range(n):
        t += rng.uniform(0.0, 0.2)
        senders, poses = [], []
        for u in rng.sample(range(1, 9), rng.randrange(0, 9)):
            r = rng.random()
            if r < 0.08 and u in last:  # the same pose again
                senders.append(u)
                poses.append(last[u])
                continue
            if r < 0.1:
                s, tw = seq[u], t - 0.1  # the same number with another stamp
            elif r < 0.2:
                s, tw = (seq[u] - rng.randrange(1, 40)) % 65536, t - 0.5  # late
            elif r < 0.25:
                s, tw = 0, t + rng.choice([0.0, 2.0])  # a restarted sender
            elif r < 0.3:
                # behind, with a stamp a second newer than the last: the edge of the restart rule
                s, tw = (seq[u] - 1) % 65536, (round(stamp[u] * 1e6) + 1_000_000) / 1e6
            else:
                s, tw = (seq[u] + rng.choice([1, 1, 1, 2, 5, 40000])) % 65536, t
            seq[u], stamp[u] = s, tw
            senders.append(u)
            poses.append(_pose_payload(rng, u, s, tw))
            last[u] = poses[-1]
        payload = encode_pose_batch(PoseBatch(rng.randrange(2**32), t, senders, poses))
        if rng.random() < 0.33:
            payload = _corrupt(rng, payload, senders, poses, t)
        out.append((payload, t + rng.uniform(0.0, 0.02)))
    return out


def test_the_compiled_intake_is_built_and_takes_a_clean_batch() -> None:
    """The test environment builds it (scripts/test installs gcc), so the UAVs of the other tests run it."""
    assert INTAKE == "compiled"
    node = _node(compiled=True)
    assert node.intake.compiled
    p = _pose_payload(random.Random(1), 2, 7, 1.8e9)
    srcs: list[int] = []
    ages: list[float] = []
    assert node.intake.take(encode_pose_batch(PoseBatch(1, 1.8e9, [2], [p])), OWN, 1.8e9 + 0.004, srcs, ages) == 1
    assert srcs == [2] and ages == pytest.approx([0.004], abs=1e-6)
    assert node.neighbours.get(2) is not None and node.neighbours.get(2).pose.seq == 7  # type: ignore[union-attr]


@pytest.mark.parametrize("seed", range(6))
def test_compiled_and_python_intake_end_alike_on_any_batch(seed: int) -> None:
    fast, slow = _node(compiled=True), _node(compiled=False)
    took_fast = 0
    for payload, at in _batches(seed, 400):
        fast._take_batch(KEY, payload, at)
        slow._take_batch(KEY, payload, at)
        assert _state(fast) == _state(slow), payload.hex()
        took_fast += PoseIntake(NeighbourTable()).take(payload, OWN, at, [], []) is not None
    # both paths were exercised: most batches clean, a third corrupted
    assert 200 < took_fast < 330
    rejected = _state(slow)["stats"]["rejected"]
    assert sum(rejected.values()) > 20 and "key_mismatch" in rejected and "malformed" in rejected


@pytest.mark.parametrize("seed", range(3))
def test_the_compiled_count_of_an_instant_is_the_python_one(seed: int) -> None:
    intake = PoseIntake(NeighbourTable())
    for payload, _ in _batches(100 + seed, 300):
        for exclude in (OWN, 3, 0):
            assert intake.count(payload, exclude) == batched_pose_count(payload, exclude), payload.hex()


def test_a_declined_batch_leaves_the_table_untouched() -> None:
    """A batch with one bad pose among good ones: the compiled pass declines all of it, so the
    Python rules take the good ones and count the bad one, once."""
    node = _node(compiled=True)
    rng = random.Random(5)
    good = [_pose_payload(rng, u, 10, 1.8e9) for u in (2, 3)]
    bad = msgpack.packb([tag(Kind.POSE), 4, 0, 10, 0, int(1.8e15), 0, 0, 0, 0, 0, 0, 99999])  # yaw out of range
    payload = encode_pose_batch(PoseBatch(1, 1.8e9, [2, 4, 3], [good[0], bad, good[1]]))
    assert node.intake.take(payload, OWN, 1.8e9, [], []) is None and len(node.neighbours) == 0
    node._take_batch(KEY, payload, 1.8e9 + 0.01)
    assert sorted(n.uav for n in node.neighbours) == [2, 3]
    assert node.stats.rejected == {"bad_field": 1}
    assert node.stats.received["pose"] == 2 and node.stats.received["pose_batch"] == 1


_LIMITS = [(1, 1, 65535), (2, 0, 1), (3, 0, 0xFFFF), (4, 0, 2**32 - 1), (5, 0, 2**64 - 1), (6, -(2**31 - 1), 2**31 - 1),
           (7, -(2**31 - 1), 2**31 - 1), (8, -32767, 32767), (9, -32767, 32767), (10, -32767, 32767), (11, -32767, 32767),
           (12, -31416, 31416)]  # (field index, lowest, highest) of the pose's integers on the wire


@pytest.mark.parametrize(("field", "lo", "hi"), _LIMITS)
def test_every_pose_field_at_and_past_its_limits(field: int, lo: int, hi: int) -> None:
    """Each field at its lowest and highest value is taken alike, one past them refused alike."""
    base = msgpack.unpackb(_pose_payload(random.Random(field), 2, 5, 1.8e9))
    for value in (lo, hi, lo - 1, hi + 1):
        p = list(base)
        p[field] = value
        if field == 1:
            sender = value if 1 <= value <= 65535 else 2
        else:
            sender = 2
        try:
            payload = msgpack.packb([BATCH_TAG, 1, int(1.8e15), [sender], [msgpack.packb(p)]], use_bin_type=True)
        except OverflowError:  # past what msgpack can write at all
            continue
        fast, slow = _node(compiled=True), _node(compiled=False)
        fast._take_batch(KEY, payload, 1.8e9)
        slow._take_batch(KEY, payload, 1.8e9)
        assert _state(fast) == _state(slow), (field, value)
        assert len(slow.neighbours) == (1 if lo <= value <= hi and sender != OWN else 0), (field, value)


def _direct(seed: int, n: int) -> list[tuple[str, bytes, float]]:
    """``n`` direct poses: those of ``_batches`` one by one, each on its sender's key, and keys
    that go wrong (another UAV's id, our own, leading zeros, non-ASCII digits, too many digits,
    another root, too short)."""
    rng = random.Random(seed)
    out = []
    for payload, at in _batches(seed, n):
        try:
            o = msgpack.unpackb(payload)
            senders, poses = o[3], o[4]
        except Exception:  # noqa: BLE001 - a corrupted batch: its bytes sent as one pose
            out.append((f"mrs/alpha/{rng.randrange(1, 9)}/pose", payload[:48], at))
            continue
        if type(senders) is not list or type(poses) is not list:
            continue
        for s, p in zip(senders, poses, strict=False):  # a corrupted batch may list more of one
            if type(p) is not bytes:
                continue
            seg = str(s)
            r = rng.random()
            if r < 0.05:
                seg = str(rng.randrange(2, 9))
            elif r < 0.08:
                seg = "000" + seg
            elif r < 0.1:
                seg = "\u0663"  # ARABIC-INDIC DIGIT THREE: a digit to str.isdigit
            elif r < 0.12:
                seg = rng.choice(["123456", "00000" + seg])  # six digits: too many, whatever their value
            if r > 0.98:
                key = f"mrx/alpha/{seg}/pose"  # another root
            elif r > 0.96:
                key = f"mrs/{seg}"  # no UAV segment
            else:
                key = f"mrs/alpha/{seg}/pose"
            out.append((key, p, at + rng.uniform(0.0, 0.01)))
    return out


@pytest.mark.parametrize("seed", range(4))
def test_compiled_and_python_direct_poses_end_alike(seed: int) -> None:
    """The default network up to 25 UAVs sends each pose on its sender's key: the compiled pass
    and the Python rules end alike there too, on the same kinds of input and on bad keys."""
    fast, slow = _node(compiled=True), _node(compiled=False)
    fast._pose_rule = slow._pose_rule = partial(accept_neighbour_pose, me=OWN)
    took = 0
    for key, payload, at in _direct(seed, 150):
        for node in (fast, slow):
            arrival = Accepted(key, payload, payload, at)
            node._take_in(iter([(POSE, arrival)]), at, Inbox())
        assert _state(fast) == _state(slow), (key, payload.hex())
        took += PoseIntake(NeighbourTable()).take_pose(key, payload, OWN, at, [], [])
    rejected = _state(slow)["stats"]["rejected"]
    assert took > 200 and "key_mismatch" in rejected and "own_id" in rejected, (took, rejected)
