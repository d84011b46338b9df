"""From raw swarm samples to recording records: the one translation the MCAP file and Foxglove share.

:class:`Translator` decodes each sample with the swarm's own decoders (swarmnet.messages), writes
it on its channel (schemas.py) with the sender's stamp as publish time and the arrival as log
time (in a lock-step run, :class:`Translator` with ``lockstep``, the simulated time of the last clock
step heard: swarmnet/lockstep.py), and derives the Foxglove views: a LocationFix per telemetry, a Log line per event (a UAV
joins or leaves, changes phase, yields to a failsafe, gets a command, acknowledges it), and a
SceneUpdate of the swarm at most :data:`SCENE_PERIOD` apart. A payload that does not decode is
counted under ``rejected[reason]`` (the swarm's reason names) and logged, never raised.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterable, Iterator
from typing import Any, NamedTuple

import msgpack

from mrswarm.recorder import schemas as sc
from mrswarm.recorder.capture import Sample
from swarmnet.keyspace import uav_from_key
from swarmnet.lockstep import LOCKSTEP_EPOCH, decode_step
from swarmnet.messages import (
    AgentState,
    BehaviourReport,
    Pose,
    Rejected,
    accept_ack,
    accept_behaviour_report,
    accept_pose,
    accept_state,
    accept_telemetry,
    decode_command,
    decode_swarm_message,
)
from swarmnet.netem.control import decode_netem_set

SCENE_PERIOD = 0.2  # s between two SceneUpdates (5 Hz: smooth in Foxglove, a fraction of the pose volume)
LOG_NAME = "mrswarm"
STAMP_AHEAD_S = 1.0  # lock-step: s a sender's stamp may be ahead of the last clock step and still be its arrival


class Record(NamedTuple):
    """One message of the recording."""

    topic: str
    schema: str  # a name in schemas.SCHEMAS
    log_time: int  # ns since the epoch: arrival at the recorder (lock-step: the simulated time then)
    publish_time: int  # ns since the epoch: the sender's stamp (the arrival when the message has none)
    sequence: int
    data: bytes  # JSON


def _ns(t: float) -> int:
    return max(0, int(t * 1e9))


class Translator:
    """Turns samples of one swarm into records; keeps what the derived views need (last states, commands)."""

    def __init__(self, swarm: str, lockstep: bool = False):
        self.swarm = swarm
        self.prefix = f"mrs/{swarm}/"
        # a lock-step run's simulated time: the last clock step's (the epoch before the first); None: the wall's
        self.sim_now: float | None = LOCKSTEP_EPOCH if lockstep else None
        self.states: dict[int, AgentState] = {}
        self.poses: dict[int, Pose] = {}
        self._scene_due: dict[int, Pose] = {}
        self._next_scene = 0.0
        self._commands: dict[int, float] = {}  # cmd_id -> t_wall of the command, for the ack latency
        self.received: Counter[str] = Counter()
        self.rejected: Counter[str] = Counter()

    def clock(self, wall: float) -> float:
        """The recording's time for what arrives at ``wall`` (s): the wall clock's, or in a lock-step run
        the simulated time of the last clock step heard, so that the recording plays in the run's time."""
        return wall if self.sim_now is None else self.sim_now

    # ---- one sample ------------------------------------------------------------------------
    def translate(self, samples: Iterable[Sample]) -> Iterator[Record]:
        for s in samples:
            try:
                if self.sim_now is None:
                    yield from self._one(s)
                else:
                    yield from self._after_stamp(self._one(s))
            except Rejected as exc:
                self.rejected[exc.reason] += 1
                yield self._log(self.clock(s.arrival), sc.LOG_WARNING, f"rejected {exc.reason} on {s.key}: {exc.detail}"[:300])

    def _one(self, s: Sample) -> Iterator[Record]:
        if s.alive is not None:
            yield from self._liveliness(s)
            return
        rest = s.key[len(self.prefix):] if s.key.startswith(self.prefix) else s.key
        parts = rest.split("/")
        uav = uav_from_key(s.key)
        stream = parts[1] if uav is not None and len(parts) == 2 else None
        if parts[0] == "clock":  # the lock-step clock: its time, not a record (10 a second of simulated time)
            yield from self._clock(s, parts)
            return
        t = self.clock(s.arrival)
        if stream == "pose":
            p = accept_pose(s.key, s.payload)
            self.received["pose"] += 1
            self.poses[p.uav] = self._scene_due[p.uav] = p
            yield Record(sc.uav_topic(p.uav, "pose"), "mrswarm.Pose", _ns(t), _ns(p.t_wall), p.seq, sc.dumps(sc.pose_json(p, t)))
        elif stream == "telemetry":
            tel = accept_telemetry(s.key, s.payload)
            self.received["telemetry"] += 1
            pub = _ns(tel.t_wall)
            yield Record(sc.uav_topic(tel.uav, "telemetry"), "mrswarm.Telemetry", _ns(t), pub, tel.seq,
                         sc.dumps(sc.telemetry_json(tel)))
            yield Record(sc.uav_topic(tel.uav, "location"), "foxglove.LocationFix", _ns(t), pub, tel.seq,
                         sc.dumps(sc.location_fix(tel)))
        elif stream == "state":
            yield from self._state(accept_state(s.key, s.payload), t)
        elif stream == "ack":
            a = accept_ack(s.key, s.payload)
            self.received["ack"] += 1
            sent = self._commands.get(a.cmd_id)
            latency = round((t - sent) * 1000.0, 3) if sent is not None else None
            yield Record(sc.uav_topic(a.uav, "ack"), "mrswarm.CommandAck", _ns(t), _ns(a.t_wall), a.cmd_id,
                         sc.dumps(sc.ack_json(a, latency)))
            level = sc.LOG_INFO if a.ok else sc.LOG_ERROR
            yield self._log(t, level, f"uav {a.uav} {'ok' if a.ok else 'FAILED'} cmd {a.cmd_id}: {a.message}")
        elif stream == "behaviour":
            yield from self._behaviour(accept_behaviour_report(s.key, s.payload), t)
        elif stream == "cmd" or rest == "cmd":
            c = decode_command(s.payload)
            self.received["cmd"] += 1
            self._commands[c.cmd_id] = c.t_wall
            if len(self._commands) > 10_000:  # bounded: forget the oldest half
                for k in list(self._commands)[:5000]:
                    del self._commands[k]
            topic = sc.uav_topic(uav, "cmd") if uav is not None else sc.SWARM_CMD
            yield Record(topic, "mrswarm.Command", _ns(t), _ns(c.t_wall), c.cmd_id, sc.dumps(sc.command_json(c)))
            to = f"uav {c.target}" if c.target else "every UAV"
            args = f" {json.dumps(sc.jsonable(c.args))}" if c.args else ""
            yield self._log(t, sc.LOG_INFO, f"{c.sender} -> {to}: {c.verb}{args} (cmd {c.cmd_id})")
        elif (uav is not None and len(parts) > 2 and parts[1] == "msg") or (parts[0] == "msg" and len(parts) > 1):
            m = decode_swarm_message(s.payload)
            self.received["msg"] += 1
            topic = f"/uav/{uav}/msg/{m.topic}" if uav is not None else f"/swarm/msg/{m.topic}"
            yield Record(topic, "mrswarm.SwarmMessage", _ns(t), _ns(m.t_wall), m.seq, sc.dumps(sc.swarm_message_json(m)))
        elif rest == "netem/set":
            n = decode_netem_set(s.payload)
            self.received["netem_set"] += 1
            targets = list(n.targets) if n.targets is not None else None
            d = {"id": n.id, "sender": n.sender, "t_wall": n.t_wall, "targets": targets, "config": n.config}
            yield Record(sc.NETEM_SET, "mrswarm.NetemSet", _ns(t), _ns(n.t_wall), n.id, sc.dumps(d))
            yield self._log(t, sc.LOG_INFO, f"{n.sender}: netem set {json.dumps(n.config)[:200]}")
        elif rest == "feed/poses":
            self.received["pose_batch"] += 1  # the edge's batches repeat the UAVs' own poses, recorded above
        else:
            self.received["other"] += 1
            yield Record("/raw/" + rest, "mrswarm.Raw", _ns(t), _ns(t), 0, sc.dumps(raw_json(s.key, s.payload)))

    def _after_stamp(self, records: Iterator[Record]) -> Iterator[Record]:
        """Lock-step: a record arrives no earlier than its sender stamped it. A pose of the next instant can
        come before that instant's clock step (the clock's messages travel at the lowest priority); one
        stamped more than :data:`STAMP_AHEAD_S` ahead of the clock keeps the clock's time."""
        assert self.sim_now is not None
        now = _ns(self.sim_now)
        ahead = _ns(self.sim_now + STAMP_AHEAD_S)
        for r in records:
            yield r._replace(log_time=r.publish_time) if now < r.publish_time <= ahead else r

    def _clock(self, s: Sample, parts: list[str]) -> Iterator[Record]:
        if parts[1:2] != ["step"]:
            self.received["clock_done"] += 1  # the pools' answers
            return
        step = decode_step(s.payload)
        self.received["clock_step"] += 1
        if self.sim_now is None:  # a recorder not told (gcs record without --lockstep): simulated time from here on
            self.sim_now = step.t
            yield self._log(step.t, sc.LOG_WARNING, "a lock-step run: its records from here on are in simulated time "
                            "(record it with --lockstep to have them all so)")
        self.sim_now = max(self.sim_now, step.t)

    def _state(self, st: AgentState, t: float) -> Iterator[Record]:
        self.received["state"] += 1
        prev = self.states.get(st.uav)
        self.states[st.uav] = st
        yield Record(sc.uav_topic(st.uav, "state"), "mrswarm.AgentState", _ns(t), _ns(st.t_wall), st.seq,
                     sc.dumps(sc.state_json(st)))
        if prev is None or (prev.phase, prev.override) != (st.phase, st.override):
            was = f"{prev.phase} -> " if prev is not None else ""
            why = f" (override {st.override})" if st.override else ""
            detail = f": {st.detail}" if st.detail else ""
            failsafe = st.override.startswith("fcu:") or st.phase in ("error", "killed", "yielded")
            yield self._log(t, sc.LOG_WARNING if failsafe else sc.LOG_INFO, f"uav {st.uav}: {was}{st.phase}{why}{detail}")

    def _behaviour(self, r: BehaviourReport, t: float) -> Iterator[Record]:
        """A behaviour report: a values message per step that recorded, then the counters (the report's seq in both)."""
        self.received["behaviour"] += 1
        values = sc.behaviour_topic(r.uav, "values")
        for at, d in sc.behaviour_values(r):
            yield Record(values, "mrswarm.BehaviourValues", _ns(t), _ns(at), r.seq, sc.dumps(d))
        yield Record(sc.behaviour_topic(r.uav, "topics"), "mrswarm.BehaviourTopics", _ns(t), _ns(r.t_wall), r.seq,
                     sc.dumps(sc.behaviour_topics(r)))

    def _liveliness(self, s: Sample) -> Iterator[Record]:
        tail = s.key[len(self.prefix) + len("alive/"):] if s.key.startswith(self.prefix + "alive/") else s.key
        role, _, node = tail.partition("/")
        event = "joined" if s.alive else "left"
        self.received[event] += 1
        d = {"key": s.key, "role": role, "id": node, "event": event}
        t = self.clock(s.arrival)
        yield Record(sc.ALIVE, "mrswarm.Liveliness", _ns(t), _ns(t), 0, sc.dumps(d))
        level = sc.LOG_WARNING if event == "left" and role == "uav" else sc.LOG_INFO
        yield self._log(t, level, f"{role} {node} {event}")

    def _log(self, t: float, level: int, message: str) -> Record:
        return Record(sc.LOG, "foxglove.Log", _ns(t), _ns(t), 0, sc.dumps(sc.log_entry(t, level, LOG_NAME, message)))

    # ---- periodic views ------------------------------------------------------------------------
    def scene(self, now: float) -> Record | None:
        """The swarm's 3D scene: the UAVs whose pose changed since the last update (None: not due, or none)."""
        if now < self._next_scene or not self._scene_due:
            return None
        self._next_scene = now + SCENE_PERIOD
        entities = [sc.scene_entity(p, self.states.get(u)) for u, p in sorted(self._scene_due.items())]
        self._scene_due.clear()
        return Record(sc.SCENE, "foxglove.SceneUpdate", _ns(now), _ns(now), 0, sc.dumps({"deletions": [], "entities": entities}))

    def stats_record(self, now: float) -> Record:
        d = {"received": dict(self.received), "rejected": dict(self.rejected), "uavs": len(self.poses)}
        return Record(sc.RECORDER_STATS, "mrswarm.RecorderStats", _ns(now), _ns(now), 0, sc.dumps(d))


def raw_json(key: str, payload: bytes) -> dict[str, Any]:
    """A payload of an unknown key: decoded as msgpack, else as JSON, else kept as base64."""
    import base64

    value: Any = None
    b64: str | None = None
    try:
        value = sc.jsonable(msgpack.unpackb(payload, raw=False, strict_map_key=False))
    except (ValueError, TypeError, msgpack.UnpackException, RecursionError):
        try:
            value = json.loads(payload)
        except (ValueError, RecursionError):
            b64 = base64.b64encode(payload).decode()
    return {"key": key, "size": len(payload), "value": value, "base64": b64}
