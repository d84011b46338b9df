"""``mrswarm replay run.mcap``: the recording published again, under its own swarm name, as if it flew now.

Each recorded pose, telemetry, agent state, acknowledgement, swarm message and behaviour report
(its values and counters, ``/uav/<N>/behaviour/...``, put together again) is encoded again
with the swarm's own codec and put on its key in the replay's swarm (``mrs/<replay>/...``) at its
recorded arrival time, mapped onto the wall clock: ``now = start + (arrival - from) / speed``.
Time stamps inside the messages are mapped the same way, so a pose's age at a ground station is
its recorded age divided by the speed. Every UAV that was alive holds a liveliness token
(``mrs/<replay>/alive/uav/<id>``) while the recording says it was up. Before the first message of
the window, the last pose, telemetry and state of every UAV before ``--from`` are published, so
a viewer that joins shows every UAV at once. Commands and netem changes are not published: a
replay informs, it never instructs anything.

The replay joins a Zenoh router as a client, through swarmnet's connectivity like the ground
station: the one given with ``--connect``, or its own, started on ``--listen`` (loopback).
"""

from __future__ import annotations

import json
import math
import re
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from groundfloor.errors import MrswarmError
from mrswarm.recorder.reader import RecordedMessage, Recording, RecordingError, read_recording
from swarmnet.connectivity import Rendezvous
from swarmnet.keyspace import SwarmKeys, check_swarm
from swarmnet.messages import (
    MAX_REPORT_SAMPLES,
    AgentState,
    BehaviourReport,
    CommandAck,
    Pose,
    Realm,
    SwarmMessage,
    Telemetry,
    TopicCounts,
    encode_ack,
    encode_behaviour_report,
    encode_pose,
    encode_state,
    encode_swarm_message,
    encode_telemetry,
)
from swarmnet.observer import SwarmObserver

REPLAYED = ("mrswarm.Pose", "mrswarm.Telemetry", "mrswarm.AgentState", "mrswarm.CommandAck", "mrswarm.SwarmMessage",
            "mrswarm.BehaviourTopics")  # with the mrswarm.BehaviourValues of the same report (see BehaviourReports)
_OFFSET_RE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*(h|m|s|ms)?\s*$")
_UNIT = {"h": 3600.0, "m": 60.0, "s": 1.0, "ms": 0.001, None: 1.0}


class ReplayError(MrswarmError):
    """A usage problem (bad offset, swarm name, unreadable file): one line, exit code 2."""


def parse_offset(text: str, name: str = "--from") -> float:
    """``30s``, ``2m``, ``1.5h``, ``500ms`` or plain seconds -> seconds."""
    m = _OFFSET_RE.match(text)
    if m is None:
        raise ReplayError(f"{name} {text!r}: expected a time such as 30s, 2m or 90")
    return float(m.group(1)) * _UNIT[m.group(2)]


def encode(schema: str, d: dict[str, Any], shift: Callable[[float], float]) -> tuple[str, bytes] | None:
    """(key suffix after ``mrs/<swarm>/``, payload) of a recorded message, its times mapped by ``shift``."""
    if schema == "mrswarm.Pose":
        p = Pose(uav=d["uav"], realm=Realm.parse(d["realm"]), seq=d["seq"], t_sim=d["t_sim"], t_wall=shift(d["t_wall"]),
                 x=d["x"], y=d["y"], z=d["z"], vx=d["vx"], vy=d["vy"], vz=d["vz"], yaw=d["yaw"])
        return f"{p.uav}/pose", encode_pose(p)
    if schema == "mrswarm.Telemetry":
        t = Telemetry(uav=d["uav"], realm=Realm.parse(d["realm"]), seq=d["seq"], t_wall=shift(d["t_wall"]), mode=d["mode"],
                      armed=d["armed"], battery=_num(d["battery"], -1.0), voltage=_num(d["voltage"], -1.0), lat=d["lat"],
                      lon=d["lon"], alt=d["alt"], rtf=_num(d["rtf"], 0.0))
        return f"{t.uav}/telemetry", encode_telemetry(t)
    if schema == "mrswarm.AgentState":
        s = AgentState(uav=d["uav"], realm=Realm.parse(d["realm"]), seq=d["seq"], t_wall=shift(d["t_wall"]), phase=d["phase"],
                       behaviour=d["behaviour"], override=d["override"], detail=d["detail"])
        return f"{s.uav}/state", encode_state(s)
    if schema == "mrswarm.CommandAck":
        a = CommandAck(uav=d["uav"], cmd_id=d["cmd_id"], ok=d["ok"], message=d["message"], t_wall=shift(d["t_wall"]))
        return f"{a.uav}/ack", encode_ack(a)
    if schema == "mrswarm.SwarmMessage":
        m = SwarmMessage(src=d["src"], dst=d["dst"], topic=d["topic"], seq=d["seq"], t_wall=shift(d["t_wall"]), body=d["body"])
        key = f"msg/{m.topic}" if m.dst == 0 else f"{m.dst}/msg/{m.topic}"
        return key, encode_swarm_message(m)
    return None


class BehaviourReports:
    """A behaviour report put together again: the recorder writes a report's values messages, then its counters
    (``/uav/<N>/behaviour/topics``), all with the report's seq as their sequence; the values wait here for them."""

    def __init__(self) -> None:
        self.values: dict[int, list[RecordedMessage]] = {}  # uav -> the values messages since its last counters

    def add_values(self, m: RecordedMessage) -> None:
        try:
            uav = int(m.json()["uav"])
        except (KeyError, TypeError, ValueError):
            return  # a message this version cannot read
        waiting = self.values.setdefault(uav, [])
        if len(waiting) < MAX_REPORT_SAMPLES:
            waiting.append(m)

    def encode(self, m: RecordedMessage, shift: Callable[[float], float]) -> tuple[str, bytes]:
        """(key suffix, payload) of the report whose counters ``m`` holds, with its values."""
        d = m.json()
        uav = int(d["uav"])
        samples: list[tuple[float, str, float]] = []
        for v in self.values.pop(uav, []):
            if v.sequence != m.sequence:
                continue  # of a report whose counters are not in the file (before --from, or a cut recording)
            vd = v.json()
            t = shift(float(vd["t_wall"]))
            samples.extend((t, str(name), math.nan if x is None else float(x)) for name, x in vd["values"].items())
        topics = {str(name): TopicCounts(c["sent"], c["send_errors"], c["received"], c["rejected"], c["dropped"],
                                         c["age_mean_ms"], c["age_max_ms"]) for name, c in d["topics"].items()}
        r = BehaviourReport(uav=uav, seq=int(d["seq"]), t_wall=shift(float(d["t_wall"])),
                            samples=tuple(samples[:MAX_REPORT_SAMPLES]), topics=topics, dropped=int(d["values_dropped"]),
                            refused=int(d["values_refused"]))
        return f"{uav}/behaviour", encode_behaviour_report(r)


def _num(v: Any, default: float) -> float:
    return float(v) if isinstance(v, int | float) else default


class _Router:
    """The replay's own Zenoh router on ``listen`` (a thread), when no --connect is given."""

    def __init__(self, listen: str):
        from discovery.rendezvous import serve

        self.stop = threading.Event()
        self.thread = threading.Thread(target=serve, args=([listen], self.stop), daemon=True, name="replay-router")
        self.thread.start()
        time.sleep(0.6)  # a router's open() waits for its scouting delay

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)


def replay(path: Path, *, speed: float = 1.0, start: float = 0.0, end: float | None = None, swarm: str | None = None,
           connect: tuple[str, ...] = (), listen: str = "tcp/127.0.0.1:7448", run_dir: Path | None = None,
           quiet: bool = False, clock: Callable[[], float] = time.time) -> int:
    """Publish the recording ``path`` from ``start`` to ``end`` s into it at ``speed``; returns the messages published."""
    rec = Recording(path)
    try:
        stream = read_recording(path, rec)
        first = next(stream, None)
    except RecordingError as exc:
        raise ReplayError(str(exc)) from None
    if first is None:
        raise ReplayError(f"{path}: the recording holds no message")
    recorded = rec.metadata.get("recording", {}).get("swarm", "")
    name = swarm or (f"replay-{recorded}"[:32] if recorded else "replay")
    try:
        check_swarm(name)
    except ValueError as exc:
        raise ReplayError(f"--swarm: {exc}") from None
    if name == recorded:
        raise ReplayError(f"--swarm {name}: that is the recorded swarm's name; a replay uses its own")
    router = _Router(listen) if not connect else None
    endpoints = connect or (listen,)
    keys = SwarmKeys(name)
    try:
        obs = SwarmObserver(name, Rendezvous(endpoints, mode="client"), role="observer", name="replay").open()
    except Exception as exc:
        if router is not None:
            router.close()
        raise ReplayError(f"cannot reach a Zenoh router at {', '.join(endpoints)}: {exc}") from None
    if run_dir is not None:
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "network.json").write_text(json.dumps({"swarm": name, "endpoints": list(endpoints), "replay_of": str(path)}))
    if not quiet:
        print(f"replaying {path} as swarm '{name}' at {speed:g}x from {start:g} s: "
              f"mrswarm gcs watch --connect {endpoints[0]} --swarm {name}", flush=True)
    session = obs.node.session
    assert session is not None
    tokens: dict[str, Any] = {}
    t0 = first.log_time / 1e9
    t_from = t0 + start
    t_end = t0 + end if end is not None else float("inf")
    wall0 = clock() + 0.5  # the first message goes out half a second from now (subscriptions settle)

    def shift(t: float) -> float:
        return wall0 + (t - t_from) / speed

    def alive(d: dict[str, Any]) -> None:
        if d.get("role") != "uav":
            return
        key = keys.alive("uav", d["id"])
        if d["event"] == "joined" and key not in tokens:
            tokens[key] = session.liveliness().declare_token(key)
        elif d["event"] == "left" and key in tokens:
            tokens.pop(key).undeclare()

    reports = BehaviourReports()

    def publish(m: RecordedMessage) -> bool:
        try:
            out = reports.encode(m, shift) if m.schema == "mrswarm.BehaviourTopics" else encode(m.schema, m.json(), shift)
        except (KeyError, TypeError, ValueError):
            return False  # a message this version cannot encode again
        if out is None:
            return False
        session.put(f"{keys.prefix}/{out[0]}", out[1])
        return True

    n = 0
    seed: dict[tuple[str, str], RecordedMessage] = {}
    seeded = False
    try:
        for m in _chain(first, stream):
            t = m.log_time / 1e9
            if t > t_end:
                break
            if m.schema == "mrswarm.Liveliness":
                alive(m.json())
                continue
            if m.schema == "mrswarm.BehaviourValues":
                if t >= t_from:
                    reports.add_values(m)
                continue
            if m.schema not in REPLAYED:
                continue
            if t < t_from:
                if m.schema in ("mrswarm.Pose", "mrswarm.Telemetry", "mrswarm.AgentState"):
                    seed[(m.topic, m.schema)] = m
                continue
            if not seeded:
                seeded = True
                n += _publish_seed(seed, publish, clock, wall0)
            _sleep_until(shift(t), clock)
            n += publish(m)
        if not seeded:
            n += _publish_seed(seed, publish, clock, wall0)
        time.sleep(0.3)  # let the last samples leave before the session closes
    finally:
        for tok in tokens.values():
            tok.undeclare()
        obs.close()
        if router is not None:
            router.close()
    if rec.error and not quiet:
        print(f"note: the recording ends early ({rec.error})")
    return n


def _publish_seed(seed: dict[tuple[str, str], RecordedMessage], publish: Callable[[RecordedMessage], bool],
                  clock: Callable[[], float], wall0: float) -> int:
    """Every UAV's last pose, telemetry and state before the window (with their true ages, mapped like the rest)."""
    _sleep_until(wall0, clock)
    n = sum(publish(m) for m in seed.values())
    seed.clear()
    return n


def _chain(first: RecordedMessage, rest: Any) -> Any:
    yield first
    yield from rest


def _sleep_until(t: float, clock: Callable[[], float]) -> None:
    while True:
        dt = t - clock()
        if dt <= 0:
            return
        time.sleep(min(dt, 0.5))
