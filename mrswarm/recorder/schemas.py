"""The recording's topics and schemas: what one swarm message becomes in an MCAP file and in Foxglove.

Every channel is JSON (``message_encoding = "json"``, ``schema encoding = "jsonschema"``), which
Foxglove reads without plug-ins and any language parses. Foxglove's well-known schemas are used
where they fit (it picks its panels by the schema name):

* ``foxglove.LocationFix`` per UAV from its telemetry (lat/lon/AMSL altitude): the Map panel;
* ``foxglove.SceneUpdate`` for the whole swarm in the swarm frame (``swarm``: metres east, north,
  up from the swarm origin): the 3D panel;
* ``foxglove.Log`` for events (joins and leaves, phase changes, failsafes, commands, acks).

The swarm's own messages keep their fields (``mrswarm.*`` schemas below, one per kind); docs/
recording.md lists them. Times inside a message are seconds since the Unix epoch, as on the wire;
an MCAP message's ``publish_time`` is the sender's stamp and its ``log_time`` the arrival at the
recorder, both in nanoseconds.
"""

from __future__ import annotations

import math
from typing import Any

import msgspec

from swarmnet.messages import AgentState, BehaviourReport, Command, CommandAck, Pose, SwarmMessage, Telemetry

JSON = "json"
JSONSCHEMA = "jsonschema"

_encoder = msgspec.json.Encoder()


def dumps(obj: Any) -> bytes:
    """Compact JSON (NaN and infinities become null, which JSON cannot hold)."""
    return _encoder.encode(obj)


# ---- topics ---------------------------------------------------------------------------------------


def uav_topic(uav: int, stream: str) -> str:
    """``/uav/3/pose``: one channel per UAV and stream, so Foxglove plots ``/uav/3/pose.z`` directly."""
    return f"/uav/{uav}/{stream}"


def behaviour_topic(uav: int, what: str) -> str:
    """``/uav/3/behaviour/values`` and ``/uav/3/behaviour/topics``: what UAV 3's SDK behaviour recorded, its message counters."""
    return f"/uav/{uav}/behaviour/{what}"


SCENE = "/swarm/scene"
LOG = "/swarm/log"
SWARM_CMD = "/swarm/cmd"
ALIVE = "/swarm/alive"
NETEM_SET = "/swarm/netem/set"
RECORDER_STATS = "/recorder/stats"
SWARM_FRAME = "swarm"  # the SceneUpdate frame: ENU metres from the swarm origin

# ---- JSON schemas -----------------------------------------------------------------------------------

_NUM = {"type": "number"}
_INT = {"type": "integer"}
_STR = {"type": "string"}
_BOOL = {"type": "boolean"}
_TIME = {"type": "object", "properties": {"sec": _INT, "nsec": _INT}, "description": "s and ns since the Unix epoch"}
_VEC3 = {"type": "object", "properties": {"x": _NUM, "y": _NUM, "z": _NUM}}
_QUAT = {"type": "object", "properties": {"x": _NUM, "y": _NUM, "z": _NUM, "w": _NUM}}
_COLOR = {"type": "object", "properties": {"r": _NUM, "g": _NUM, "b": _NUM, "a": _NUM}}
_POSE3 = {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}}
_KV = {"type": "array", "items": {"type": "object", "properties": {"key": _STR, "value": _STR}}}


def _obj(title: str, description: str, props: dict[str, Any]) -> dict[str, Any]:
    return {"title": title, "description": description, "type": "object", "properties": props}


_REALM = {"type": "string", "enum": ["virtual", "physical"]}
_T_WALL = {"type": "number", "description": "s since the Unix epoch, the sender's clock"}

SCHEMAS: dict[str, dict[str, Any]] = {
    "mrswarm.Pose": _obj("mrswarm.Pose", "A UAV's pose in the swarm frame (m east, north, up from the swarm origin)", {
        "uav": _INT, "realm": _REALM, "seq": {**_INT, "description": "16-bit, wraps"},
        "t_sim": {**_NUM, "description": "FCU time since boot, s"}, "t_wall": _T_WALL,
        "x": _NUM, "y": _NUM, "z": _NUM, "vx": _NUM, "vy": _NUM, "vz": _NUM,
        "yaw": {**_NUM, "description": "rad, ENU (0 = east, counter-clockwise)"},
        "age_ms": {**_NUM, "description": "arrival at the recorder minus t_wall"},
    }),
    "mrswarm.Telemetry": _obj("mrswarm.Telemetry", "Flight-controller state, 2 Hz", {
        "uav": _INT, "realm": _REALM, "seq": _INT, "t_wall": _T_WALL, "mode": _STR, "armed": _BOOL,
        "battery": {**_NUM, "description": "remaining fraction 0..1, -1 unknown"},
        "voltage": {**_NUM, "description": "V, -1 unknown"},
        "lat": _NUM, "lon": _NUM, "alt": {**_NUM, "description": "m AMSL"}, "rtf": {**_NUM, "description": "real-time factor"},
    }),
    "mrswarm.AgentState": _obj("mrswarm.AgentState", "The agent's phase, on every change and at 1 Hz", {
        "uav": _INT, "realm": _REALM, "seq": _INT, "t_wall": _T_WALL, "phase": _STR, "behaviour": _STR,
        "override": {**_STR, "description": "why the swarm behaviour is suspended (e.g. fcu:RTL), empty if not"},
        "detail": _STR,
    }),
    "mrswarm.Command": _obj("mrswarm.Command", "A command to one UAV (target) or to every UAV (target 0)", {
        "sender": _STR, "cmd_id": _INT, "target": _INT, "verb": _STR, "args": {"type": "object"}, "t_wall": _T_WALL,
    }),
    "mrswarm.CommandAck": _obj("mrswarm.CommandAck", "A UAV's answer to a command (cmd_id pairs it with the command)", {
        "uav": _INT, "cmd_id": _INT, "ok": _BOOL, "message": _STR, "t_wall": _T_WALL,
        "latency_ms": {**_NUM, "description": "ack arrival minus the command's t_wall, when the command was recorded"},
    }),
    "mrswarm.SwarmMessage": _obj("mrswarm.SwarmMessage", "An application message between UAVs (dst 0: broadcast)", {
        "src": _INT, "dst": _INT, "topic": _STR, "seq": _INT, "t_wall": _T_WALL, "body": {},
    }),
    "mrswarm.NetemSet": _obj("mrswarm.NetemSet", "A runtime change of the link impairments (docs/netem.md)", {
        "id": _INT, "sender": _STR, "t_wall": _T_WALL, "targets": {"type": ["array", "null"]}, "config": {"type": "object"},
    }),
    "mrswarm.Liveliness": _obj("mrswarm.Liveliness", "A node's liveliness token appeared (joined) or disappeared (left)", {
        "key": _STR, "role": _STR, "id": _STR, "event": {"type": "string", "enum": ["joined", "left"]},
    }),
    "mrswarm.BehaviourValues": _obj("mrswarm.BehaviourValues", "What a UAV's behaviour recorded at one step (ctx.record)", {
        "uav": _INT, "t_wall": {**_NUM, "description": "the step's time, s since the Unix epoch (the UAV's clock)"},
        "timestamp": {**_TIME, "description": "t_wall as a Foxglove time: plot by it (the log time is the report's arrival)"},
        "values": {"type": "object", "additionalProperties": {"type": ["number", "null"]},
                   "description": "name -> value (null: NaN or an infinity)"},
    }),
    "mrswarm.BehaviourTopics": _obj("mrswarm.BehaviourTopics", "A UAV's behaviour's counters since its start, every second", {
        "uav": _INT, "seq": _INT, "t_wall": _T_WALL,
        "topics": {"type": "object", "description": "message topic -> its counters", "additionalProperties": {
            "type": "object", "properties": {
                "sent": _INT, "send_errors": _INT, "received": _INT, "rejected": {**_INT, "description": "did not fit its type"},
                "dropped": {**_INT, "description": "over the inbox's bound between two steps"},
                "age_mean_ms": {"type": ["number", "null"], "description": "of what arrived, sending to arrival"},
                "age_max_ms": {"type": ["number", "null"]}}}},
        "values_dropped": {**_INT, "description": "recorded values no report carried (over 256 waiting)"},
        "values_refused": {**_INT, "description": "ctx.record calls refused: a bad name or value, too many names"},
    }),
    "mrswarm.Counters": _obj("mrswarm.Counters", "A UAV's counters file (uav<N>.json): messages, neighbours, netem links", {}),
    "mrswarm.RecorderStats": _obj("mrswarm.RecorderStats", "What the recorder received and could not decode, every second", {
        "received": {"type": "object"}, "rejected": {"type": "object"}, "uavs": _INT,
    }),
    "mrswarm.Raw": _obj("mrswarm.Raw", "A message on a key this version does not know (e.g. a newer service's)", {
        "key": _STR, "size": _INT, "value": {"description": "the payload decoded as msgpack or JSON, else null"},
        "base64": {"type": ["string", "null"], "description": "the payload when it decodes as neither"},
    }),
    # Foxglove's well-known schemas (the fields used here; names as Foxglove defines them)
    "foxglove.LocationFix": _obj("foxglove.LocationFix", "A navigation satellite fix", {
        "timestamp": _TIME, "frame_id": _STR, "latitude": _NUM, "longitude": _NUM, "altitude": _NUM,
        "position_covariance": {"type": "array", "items": _NUM, "minItems": 9, "maxItems": 9},
        "position_covariance_type": _INT, "color": _COLOR,
    }),
    "foxglove.Log": _obj("foxglove.Log", "A log message", {
        "timestamp": _TIME, "level": {**_INT, "description": "1 debug, 2 info, 3 warning, 4 error, 5 fatal"},
        "message": _STR, "name": _STR, "file": _STR, "line": _INT,
    }),
    "foxglove.SceneUpdate": _obj("foxglove.SceneUpdate", "An update to the entities of a 3D scene", {
        "deletions": {"type": "array", "items": {"type": "object"}},
        "entities": {"type": "array", "items": _obj("foxglove.SceneEntity", "A visual element in a 3D scene", {
            "timestamp": _TIME, "frame_id": _STR, "id": _STR, "lifetime": _TIME, "frame_locked": _BOOL, "metadata": _KV,
            "arrows": {"type": "array"}, "cubes": {"type": "array", "items": {
                "type": "object", "properties": {"pose": _POSE3, "size": _VEC3, "color": _COLOR}}},
            "spheres": {"type": "array"}, "cylinders": {"type": "array"}, "lines": {"type": "array"},
            "triangles": {"type": "array"}, "models": {"type": "array"},
            "texts": {"type": "array", "items": {"type": "object", "properties": {
                "pose": _POSE3, "billboard": _BOOL, "font_size": _NUM, "scale_invariant": _BOOL, "color": _COLOR, "text": _STR}}},
        })},
    }),
}


def schema_bytes(name: str) -> bytes:
    return dumps(SCHEMAS[name])


# ---- messages to JSON ---------------------------------------------------------------------------------


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None


def stamp(t: float) -> dict[str, int]:
    """A Foxglove time from seconds since the epoch."""
    ns = max(0, int(round(t * 1e9)))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def pose_json(p: Pose, arrival: float) -> dict[str, Any]:
    return {"uav": p.uav, "realm": p.realm.label, "seq": p.seq, "t_sim": p.t_sim, "t_wall": p.t_wall,
            "x": p.x, "y": p.y, "z": p.z, "vx": p.vx, "vy": p.vy, "vz": p.vz, "yaw": p.yaw,
            "age_ms": round((arrival - p.t_wall) * 1000.0, 3)}


def telemetry_json(t: Telemetry) -> dict[str, Any]:
    return {"uav": t.uav, "realm": t.realm.label, "seq": t.seq, "t_wall": t.t_wall, "mode": t.mode, "armed": t.armed,
            "battery": _finite(t.battery), "voltage": _finite(t.voltage), "lat": t.lat, "lon": t.lon, "alt": t.alt,
            "rtf": _finite(t.rtf)}


def state_json(s: AgentState) -> dict[str, Any]:
    return {"uav": s.uav, "realm": s.realm.label, "seq": s.seq, "t_wall": s.t_wall, "phase": s.phase, "behaviour": s.behaviour,
            "override": s.override, "detail": s.detail}


def command_json(c: Command) -> dict[str, Any]:
    return {"sender": c.sender, "cmd_id": c.cmd_id, "target": c.target, "verb": c.verb, "args": jsonable(c.args),
            "t_wall": c.t_wall}


def ack_json(a: CommandAck, latency_ms: float | None) -> dict[str, Any]:
    return {"uav": a.uav, "cmd_id": a.cmd_id, "ok": a.ok, "message": a.message, "t_wall": a.t_wall, "latency_ms": latency_ms}


def swarm_message_json(m: SwarmMessage) -> dict[str, Any]:
    return {"src": m.src, "dst": m.dst, "topic": m.topic, "seq": m.seq, "t_wall": m.t_wall, "body": jsonable(m.body)}


def behaviour_values(r: BehaviourReport) -> list[tuple[float, dict[str, Any]]]:
    """The samples of a report as (t_wall, message): one message per step that recorded (a name recorded twice in
    one step begins the next message, so no value is lost)."""
    out: list[tuple[float, dict[str, Any]]] = []
    values: dict[str, float | None] = {}
    t_group = math.nan
    for t, name, v in r.samples:
        if t != t_group or name in values:
            values = {}
            t_group = t
            out.append((t, {"uav": r.uav, "t_wall": t, "timestamp": stamp(t), "values": values}))
        values[name] = v if math.isfinite(v) else None
    return out


def behaviour_topics(r: BehaviourReport) -> dict[str, Any]:
    topics = {name: {"sent": c.sent, "send_errors": c.send_errors, "received": c.received, "rejected": c.rejected,
                     "dropped": c.dropped, "age_mean_ms": c.age_mean_ms, "age_max_ms": c.age_max_ms}
              for name, c in r.topics.items()}
    return {"uav": r.uav, "seq": r.seq, "t_wall": r.t_wall, "topics": topics, "values_dropped": r.dropped,
            "values_refused": r.refused}


def location_fix(t: Telemetry) -> dict[str, Any]:
    virtual = t.realm.label == "virtual"
    return {"timestamp": stamp(t.t_wall), "frame_id": f"uav{t.uav}", "latitude": t.lat, "longitude": t.lon, "altitude": t.alt,
            "position_covariance": [0.0] * 9, "position_covariance_type": 0,
            "color": {"r": 0.2, "g": 0.5, "b": 1.0, "a": 1.0} if virtual else {"r": 1.0, "g": 0.55, "b": 0.1, "a": 1.0}}


LOG_INFO, LOG_WARNING, LOG_ERROR = 2, 3, 4


def log_entry(t: float, level: int, name: str, message: str) -> dict[str, Any]:
    return {"timestamp": stamp(t), "level": level, "message": message, "name": name, "file": "", "line": 0}


def _color(realm: str, phase: str, override: str) -> dict[str, float]:
    if override.startswith("fcu:") or phase in ("error", "killed"):
        return {"r": 0.9, "g": 0.15, "b": 0.1, "a": 1.0}
    if override:
        return {"r": 0.95, "g": 0.8, "b": 0.1, "a": 1.0}
    if realm == "physical":
        return {"r": 1.0, "g": 0.55, "b": 0.1, "a": 1.0}
    return {"r": 0.2, "g": 0.5, "b": 1.0, "a": 1.0}


_IDENTITY = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
_WHITE = {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0}


def scene_entity(p: Pose, state: AgentState | None) -> dict[str, Any]:
    """A UAV in the 3D panel: a flat box turned to its heading and a label with its id and phase."""
    phase = state.phase if state is not None else ""
    override = state.override if state is not None else ""
    half = p.yaw / 2.0
    orientation = {"x": 0.0, "y": 0.0, "z": math.sin(half), "w": math.cos(half)}
    pos = {"x": p.x, "y": p.y, "z": p.z}
    label = f"{p.uav} {phase}" + (f" ({override})" if override else "")
    return {
        "timestamp": stamp(p.t_wall), "frame_id": SWARM_FRAME, "id": f"uav{p.uav}", "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False, "metadata": [{"key": "phase", "value": phase}, {"key": "realm", "value": p.realm.label}],
        "arrows": [], "spheres": [], "cylinders": [], "lines": [], "triangles": [], "models": [],
        "cubes": [{"pose": {"position": pos, "orientation": orientation}, "size": {"x": 1.2, "y": 0.8, "z": 0.3},
                   "color": _color(p.realm.label, phase, override)}],
        "texts": [{"pose": {"position": {"x": p.x, "y": p.y, "z": p.z + 1.2}, "orientation": _IDENTITY},
                   "billboard": True, "font_size": 14.0, "scale_invariant": True, "color": _WHITE, "text": label}],
    }


def jsonable(v: Any, depth: int = 0) -> Any:
    """Any msgpack value as JSON: bytes as base64 text, map keys as text (bounded depth)."""
    import base64

    if depth > 32:
        return None
    if isinstance(v, bytes | bytearray | memoryview):
        return base64.b64encode(bytes(v)).decode()
    if isinstance(v, dict):
        return {str(k): jsonable(x, depth + 1) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [jsonable(x, depth + 1) for x in v]
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if v is None or isinstance(v, bool | int | float | str):
        return v
    return str(v)
