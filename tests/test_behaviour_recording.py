"""What an SDK behaviour records, and its message counters, in the flight recording (run.mcap).

The agent sends them in a behaviour report on the UAV's own key (``mrs/<swarm>/<uav>/behaviour``);
the recorder writes ``/uav/<N>/behaviour/values`` (one message per step that recorded) and
``/uav/<N>/behaviour/topics`` (the counters, once a second). A real run on a secured swarm
flies a behaviour that records good values, a NaN and two it may not record; its recording
holds every value of the UAVs' own ``behaviour_uav<N>.csv`` and their last counters.
"""

from __future__ import annotations

import csv
import json
import math
import time
from pathlib import Path
from typing import Any

import msgpack
import pytest
from mcap.reader import make_reader

from mrswarm.recorder.capture import Sample
from mrswarm.recorder.cli import export_main
from mrswarm.recorder.export import export_csv
from mrswarm.recorder.reader import RecordedMessage
from mrswarm.recorder.records import Translator
from mrswarm.recorder.replay import BehaviourReports
from mrswarm.recorder.schemas import SCHEMAS
from mrswarm.testing import fly
from swarmnet.keyspace import SwarmKeys
from swarmnet.messages import (
    MAX_REPORT_BYTES,
    MAX_REPORT_SAMPLES,
    MAX_REPORT_TOPICS,
    BehaviourReport,
    Kind,
    Rejected,
    TopicCounts,
    accept_behaviour_report,
    decode_behaviour_report,
    encode_behaviour_report,
    tag,
)
from swarmnet.security.acl import uav_puts, uav_receives
from tests.test_sdk import agent_config, me
from uav_stack.sdk.adapter import MAX_VALUES, make_behaviour_mission
from uav_stack.sdk.reports import MIN_REPORT_PERIOD_S, BehaviourReporter


def _report(**kw: Any) -> BehaviourReport:
    base: dict[str, Any] = {
        "uav": 3, "seq": 7, "t_wall": 1_800_000_000.25,
        "samples": ((1_800_000_000.1, "err", 1.5), (1_800_000_000.1, "est.x", math.nan),
                    (1_800_000_000.1, "err", 1.25), (1_800_000_000.2, "err", -math.inf)),
        "topics": {"task/bid": TopicCounts(4, 1, 6, 2, 0, 12.5, 30.0), "idle": TopicCounts(0, 0, 0, 0, 0, None, None)},
        "dropped": 2, "refused": 5}
    base.update(kw)
    return BehaviourReport(**base)


def test_a_behaviour_report_round_trips_within_its_bounds() -> None:
    r = _report()
    back = accept_behaviour_report("mrs/s/3/behaviour", encode_behaviour_report(r))
    assert back.topics == r.topics and (back.uav, back.seq, back.dropped, back.refused) == (3, 7, 2, 5)
    assert back.samples[0] == r.samples[0] and math.isnan(back.samples[1][2]) and back.samples[3][2] == -math.inf
    # the largest report its bounds allow fits its size limit, and decodes
    name = "n" * 64
    big = BehaviourReport(uav=65535, seq=2**32 - 1, t_wall=4e9,
                          samples=tuple((4e9, name, 1e300) for _ in range(MAX_REPORT_SAMPLES)),
                          topics={f"{'t' * 60}{i:04d}": TopicCounts(*[2**63] * 5, 1e12, 1e12) for i in range(MAX_REPORT_TOPICS)},
                          dropped=2**40, refused=2**40)
    data = encode_behaviour_report(big)
    assert len(data) <= MAX_REPORT_BYTES
    assert decode_behaviour_report(data).dropped == 2**32 - 1  # counters saturate, never wrap
    with pytest.raises(ValueError, match="over 256"):
        encode_behaviour_report(_report(samples=((1.0, "x", 1.0),) * (MAX_REPORT_SAMPLES + 1)))
    with pytest.raises(ValueError, match="invalid value name"):
        encode_behaviour_report(_report(samples=((1.0, "no spaces", 1.0),)))


@pytest.mark.parametrize(("key", "payload", "reason"), [
    ("mrs/s/4/behaviour", encode_behaviour_report(_report()), "key_mismatch"),  # UAV 3's report on UAV 4's key
    ("mrs/s/3/behaviour", bytes(MAX_REPORT_BYTES + 1), "oversized"),
    ("mrs/s/3/behaviour", b"\x93garbage", "malformed"),
    ("mrs/s/3/behaviour", msgpack.packb([tag(Kind.BEHAVIOUR_REPORT), 3, 0, 1, [[1, "bad name", 1.0]], {}, 0, 0]), "bad_field"),
    ("mrs/s/3/behaviour", msgpack.packb([tag(Kind.BEHAVIOUR_REPORT), 3, 0, 1, [[1, "x", "1.0"]], {}, 0, 0]), "bad_field"),
    ("mrs/s/3/behaviour", msgpack.packb([tag(Kind.BEHAVIOUR_REPORT), 3, 0, 1, [], {"t": [1, 2, 3]}, 0, 0]), "bad_field"),
    ("mrs/s/3/behaviour", msgpack.packb([tag(Kind.BEHAVIOUR_REPORT), 3, 0, 1, [], {"t": [-1, 0, 0, 0, 0, None, None]}, 0, 0]),
     "bad_field"),
    ("mrs/s/3/behaviour", msgpack.packb([tag(Kind.BEHAVIOUR_REPORT), 3, 0, 1, [], {}, 0]), "malformed"),
])
def test_a_bad_report_is_rejected_with_its_reason(key: str, payload: bytes, reason: str) -> None:
    with pytest.raises(Rejected) as exc:
        accept_behaviour_report(key, payload)
    assert exc.value.reason == reason


def test_only_the_uav_itself_may_put_its_reports_and_no_uav_receives_another_s() -> None:
    keys = SwarmKeys("alpha")
    assert "mrs/alpha/3/behaviour" in uav_puts(keys, 3)
    assert "mrs/alpha/3/behaviour" not in uav_puts(keys, 4)
    assert not any(k.endswith("/behaviour") for k in uav_receives(keys, 3))


def test_the_recorder_writes_a_message_per_step_and_the_counters_and_counts_a_bad_report() -> None:
    tr = Translator("s")
    now = time.time()
    recs = list(tr.translate([Sample("mrs/s/3/behaviour", encode_behaviour_report(_report()), now),
                              Sample("mrs/s/3/behaviour", b"\x93garbage", now)]))
    values = [r for r in recs if r.topic == "/uav/3/behaviour/values"]
    assert all(r.schema == "mrswarm.BehaviourValues" and r.sequence == 7 and r.log_time == int(now * 1e9) for r in values)
    # the same step recorded err twice: two messages, nothing lost; a NaN and an infinity are null
    assert [json.loads(r.data)["values"] for r in values] == [{"err": 1.5, "est.x": None}, {"err": 1.25}, {"err": None}]
    first = json.loads(values[0].data)
    assert values[0].publish_time == int(round(1_800_000_000.1 * 1e6)) * 1000
    assert first["timestamp"]["sec"] == 1_800_000_000 and abs(first["timestamp"]["nsec"] - 100_000_000) < 1000
    (topics,) = [r for r in recs if r.topic == "/uav/3/behaviour/topics"]
    d = json.loads(topics.data)
    assert topics.schema == "mrswarm.BehaviourTopics" and recs.index(topics) > recs.index(values[-1])
    assert d["topics"]["task/bid"] == {"sent": 4, "send_errors": 1, "received": 6, "rejected": 2, "dropped": 0,
                                       "age_mean_ms": 12.5, "age_max_ms": 30.0}
    assert d["topics"]["idle"]["age_mean_ms"] is None and (d["values_dropped"], d["values_refused"]) == (2, 5)
    assert tr.received["behaviour"] == 1 and tr.rejected == {"malformed": 1}
    assert {"mrswarm.BehaviourValues", "mrswarm.BehaviourTopics"} <= set(SCHEMAS)
    # the replay puts the report together again from its messages
    msgs = [RecordedMessage(r.topic, r.schema, r.log_time, r.publish_time, r.sequence, r.data) for r in recs
            if r.topic.startswith("/uav/3/behaviour/")]
    reports = BehaviourReports()
    for m in msgs[:-1]:
        reports.add_values(m)
    key, payload = reports.encode(msgs[-1], lambda t: t)
    again = accept_behaviour_report(f"mrs/replay-s/{key}", payload)
    assert again.topics == _report().topics and [(n, v) for _, n, v in again.samples][:1] == [("err", 1.5)]
    assert len(again.samples) == 4 and math.isnan(again.samples[1][2])


def test_record_refuses_a_bad_name_or_value_counts_it_and_never_faults_the_behaviour() -> None:
    m = make_behaviour_mission(agent_config("tests.sdk_behaviours:Recording"))
    for k in range(3):
        m.velocity(me(10.0 + 0.2 * k), (2,))
    assert m.exceptions == 0 and m.in_a_row == 0 and m.state == "running"
    b = m.stats()
    assert b["records_refused"] == {"bad_name": 3, "bad_value": 3} and b["reports"]["values_refused"] == 6
    assert b["values"]["step"] == 3.0 and math.isnan(b["values"]["nothing.yet"])
    assert [(t, n) for t, n, _ in m.reporter.samples[:3]] == [(10.0, "step"), (10.0, "heard"), (10.0, "nothing.yet")]
    ctx = m.ctx
    assert ctx.record("count", 2) and ctx.record("flag", True) and not ctx.record("obj", object())  # type: ignore[arg-type]
    assert not ctx.record("huge", 10**400)  # an int beyond a float
    for i in range(MAX_VALUES):
        ctx.record(f"n{i}", i)
    assert len(m.values) == MAX_VALUES and m.stats()["records_refused"]["too_many_names"] > 0


def test_the_reporter_keeps_a_report_s_worth_drops_beyond_and_sends_at_most_four_a_second() -> None:
    import logging

    r = BehaviourReporter(3, logging.getLogger("test"))
    assert not r.due(100.0)  # nothing recorded, no topics: nothing to say
    for i in range(MAX_REPORT_SAMPLES + 10):
        r.add(100.0, "x", float(i))
    assert len(r.samples) == MAX_REPORT_SAMPLES and r.dropped == 10
    assert r.due(100.0)  # full: at once
    r._last = 100.0  # as if one went out now
    assert not r.due(100.0 + MIN_REPORT_PERIOD_S / 2) and r.due(100.0 + MIN_REPORT_PERIOD_S)
    r.samples.clear()
    r.add(100.3, "x", 1.0)
    assert not r.due(100.5) and r.due(101.0)  # not full: once a second


def _csv_values(path: Path) -> list[tuple[float, str, float | None]]:
    with open(path, newline="") as f:
        return [(round(float(r["t_wall"]), 3), r["name"], None if r["value"] == "nan" else float(r["value"]))
                for r in csv.DictReader(f)]


@pytest.mark.e2e
def test_a_flown_behaviour_s_values_and_counters_are_channels_of_run_mcap(tmp_path: Path,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    flight = fly("tests.sdk_behaviours:Recording", out=tmp_path, uavs=2, duration=8, record=True)
    assert flight.summary.get("aborted") is None
    run = next(p.parent for p in tmp_path.glob("*/run.mcap"))
    with open(run / "run.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        channels = {ch.topic: summary.schemas[ch.schema_id] for ch in summary.channels.values()}
        msgs = [(ch.topic, m) for _, ch, m in reader.iter_messages(topics=[t for t in channels if "/behaviour/" in t])]
    for u in (1, 2):
        for what, schema in (("values", "mrswarm.BehaviourValues"), ("topics", "mrswarm.BehaviourTopics")):
            s = channels[f"/uav/{u}/behaviour/{what}"]
            assert s.name == schema and s.encoding == "jsonschema" and json.loads(s.data)["title"] == schema
        # every value the UAV wrote into its behaviour_uav<N>.csv, in order, NaN as null
        recorded = [(round(d["t_wall"], 3), name, v) for topic, m in msgs if topic == f"/uav/{u}/behaviour/values"
                    for d in [json.loads(m.data)] for name, v in d["values"].items()]
        own = _csv_values(run / f"behaviour_uav{u}.csv")
        assert recorded == own and len(own) >= 3 * 10  # step, heard, nothing.yet: at least 10 steps
        assert {n for _, n, _ in own} == {"step", "heard", "nothing.yet"}
        assert all(v is None for _, n, v in own if n == "nothing.yet")
        # the counters: the last report holds what the UAV's stats file says at the end
        counters = [json.loads(m.data) for topic, m in msgs if topic == f"/uav/{u}/behaviour/topics"]
        seqs = [c["seq"] for c in counters]
        assert seqs == sorted(set(seqs)) and len(counters) >= 5
        b = flight.stats[u]["behaviour"]
        assert counters[-1]["topics"]["test/note"] == b["topics"]["test/note"]
        assert b["topics"]["test/note"]["sent"] > 0 and b["topics"]["test/note"]["received"] > 0  # they heard each other
        steps = b["steps"]
        assert counters[-1]["values_refused"] == 2 * steps and b["records_refused"] == {"bad_name": steps, "bad_value": steps}
        assert b["faults"] == {"exceptions": 0, "overruns": 0, "bad_intents": 0} and b["state"] == "running"
    # `mrswarm export --topics` lists the channels
    assert export_main(["--topics", str(run / "run.mcap")]) == 0
    listed = {line.split()[0]: line.split()[1:] for line in capsys.readouterr().out.splitlines() if line.startswith("/")}
    for u in (1, 2):
        assert listed[f"/uav/{u}/behaviour/values"][0] == "mrswarm.BehaviourValues"
        assert int(listed[f"/uav/{u}/behaviour/topics"][1]) == sum(t == f"/uav/{u}/behaviour/topics" for t, _ in msgs)
    # export --csv writes the values as the UAVs do, from the recording alone
    info = export_csv(run / "run.mcap", tmp_path / "export")
    assert {"behaviour_uav1.csv", "behaviour_uav2.csv"} <= set(info["files"])
    for u in (1, 2):
        assert _csv_values(tmp_path / "export" / f"behaviour_uav{u}.csv") == _csv_values(run / f"behaviour_uav{u}.csv")
