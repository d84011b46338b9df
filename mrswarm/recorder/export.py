"""``mrswarm export run.mcap``: a run folder (CSV trajectories and the run's files) or JSON Lines from a recording.

``--csv`` writes what ``mrswarm results`` reads: one ``uav<N>.csv`` per UAV with the columns the
UAVs write themselves (uav_stack/recorder.py), one row per recorded pose (the position each UAV
published, 1 cm resolution, at its pose rate), with the phase and the FCU mode of the last state and
telemetry received before it; plus the files the runner's recorder kept inside the recording
(``scenario.yaml``, ``run.json``, ``network.json``, ``uav<N>.json``, ``age_uav<N>.csv``), and
``behaviour_uav<N>.csv`` (``t_wall,name,value``, as the UAVs write it) from the values its SDK
behaviour recorded (``/uav/<N>/behaviour/values``; NaN and infinities, null in the recording,
become ``nan``). A
recording cut short (its writer killed) has no ``run.json``: one is rebuilt from the recording
itself (the mission starts at the runner's ``start`` command).

``--topics`` lists the recording's channels: topic, schema and how many messages each holds
(``/uav/<N>/behaviour/values`` and ``/topics`` among them for a run of SDK behaviours).

``--jsonl`` writes the ground station's JSON Lines format (mrswarm/gcs/record.py), so
``mrswarm gcs plot`` draws a recording too.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, TextIO

import msgspec
import yaml

from groundfloor.errors import MrswarmError
from mrswarm.recorder.reader import Recording, RecordingError, read_recording
from uav_stack.recorder import TRAJECTORY_COLUMNS
from uav_stack.sdk.reports import VALUES_HEADER

RUN_FILES = ("scenario.yaml", "network.json", "run.json")


class ExportError(MrswarmError):
    """A recording that cannot be exported (unreadable, or not of a run where a run folder is asked for)."""


def default_out(path: Path) -> Path:
    """``results/x/run.mcap`` -> ``results/x/run-export``: never the folder the UAVs wrote their own CSVs into."""
    return path.with_name(path.stem + "-export")


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.3f}"
    if v is None:
        return "nan"
    return str(v)


def export_csv(path: Path, out: Path) -> dict[str, Any]:
    """Write the run folder of recording ``path`` into ``out``; returns what was written."""
    out.mkdir(parents=True, exist_ok=True)
    rec = Recording(path)
    files: dict[int, TextIO] = {}
    values: dict[int, TextIO] = {}  # behaviour_uav<N>.csv
    value_rows: dict[int, int] = {}
    rows: dict[int, int] = {}
    phase: dict[int, str] = {}
    tel: dict[int, tuple[str, bool, float | None]] = {}
    first = last = None
    start_cmd: float | None = None
    try:
        for m in read_recording(path, rec):
            first = m.log_time if first is None else first
            last = m.log_time
            if not m.topic.startswith("/uav/"):
                if m.schema == "mrswarm.Command" and start_cmd is None:
                    d = m.json()
                    if d.get("verb") == "start" and d.get("sender") == "runner":
                        start_cmd = float(d["t_wall"])
                continue
            if m.schema == "mrswarm.Pose":
                d = m.json()
                u = int(d["uav"])
                f = files.get(u)
                if f is None:
                    f = files[u] = open(out / f"uav{u}.csv", "w", encoding="utf-8")  # noqa: SIM115 (closed below)
                    f.write(",".join(TRAJECTORY_COLUMNS) + "\n")
                mode, armed, rtf = tel.get(u, ("", False, None))
                row = (d["t_wall"], d["t_sim"], d["x"], d["y"], d["z"], d["vx"], d["vy"], d["vz"], d["yaw"],
                       phase.get(u, "init"), mode, int(armed), -1.0 if rtf is None else float(rtf))  # as the UAVs write it
                f.write(",".join(_fmt(v) for v in row) + "\n")
                rows[u] = rows.get(u, 0) + 1
            elif m.schema == "mrswarm.AgentState":
                d = m.json()
                phase[int(d["uav"])] = str(d["phase"])
            elif m.schema == "mrswarm.BehaviourValues":
                d = m.json()
                u = int(d["uav"])
                f = values.get(u)
                if f is None:
                    f = values[u] = open(out / f"behaviour_uav{u}.csv", "w", encoding="utf-8")  # noqa: SIM115 (closed below)
                    f.write(VALUES_HEADER)
                t = float(d["t_wall"])
                for name, v in d["values"].items():
                    f.write(f"{t:.3f},{name},{'nan' if v is None else repr(float(v))}\n")
                    value_rows[u] = value_rows.get(u, 0) + 1
            elif m.schema == "mrswarm.Telemetry":
                d = m.json()
                tel[int(d["uav"])] = (str(d["mode"]), bool(d["armed"]), d["rtf"])
            elif m.schema == "mrswarm.Command" and start_cmd is None:
                d = m.json()
                if d.get("verb") == "start" and d.get("sender") == "runner":
                    start_cmd = float(d["t_wall"])
    except RecordingError as exc:
        raise ExportError(str(exc)) from None
    finally:
        for f in (*files.values(), *values.values()):
            f.close()
    written = [f"uav{u}.csv" for u in sorted(rows)] + [f"behaviour_uav{u}.csv" for u in sorted(values)]
    for name, data in rec.attachments.items():
        if name in RUN_FILES or _is_uav_file(name):
            (out / name).write_bytes(data)
            written.append(name)
    if "run.json" not in rec.attachments and "scenario.yaml" in rec.attachments and first is not None:
        _rebuild_run_json(out, rec, first, last or first, start_cmd)
        written.append("run.json (rebuilt from the recording)")
    return {"out": str(out), "uavs": len(rows), "rows": sum(rows.values()), "values": sum(value_rows.values()),
            "files": written, "complete": rec.complete, "error": rec.error}


def _is_uav_file(name: str) -> bool:
    stem = name.rsplit(".", 1)[0]
    return (name.endswith(".json") and stem[:3] == "uav" and stem[3:].isdigit()) or \
        (name.endswith(".csv") and stem[:7] == "age_uav" and stem[7:].isdigit())


def _rebuild_run_json(out: Path, rec: Recording, first_ns: int, last_ns: int, start_cmd: float | None) -> None:
    from mrswarm.records.summary import RunInfo

    try:
        name = str(yaml.safe_load(rec.attachments["scenario.yaml"])["name"])
    except (yaml.YAMLError, KeyError, TypeError):
        name = "recording"
    info = RunInfo(scenario=name, started=first_ns / 1e9, mission_start=start_cmd, stopped=last_ns / 1e9,
                   aborted=f"recording ended early ({rec.error})" if rec.error else None)
    (out / "run.json").write_bytes(msgspec.json.encode(info))


def export_jsonl(path: Path, out: Path) -> dict[str, Any]:
    """The ground station's JSON Lines (``{"t": arrival, "kind": ..., fields}``): poses, telemetry, states, acks, liveliness."""
    kinds = {"mrswarm.Pose": "pose", "mrswarm.Telemetry": "telemetry", "mrswarm.AgentState": "state", "mrswarm.CommandAck": "ack"}
    n = 0
    rec = Recording(path)
    try:
        with open(out, "w", encoding="utf-8") as f:
            for m in read_recording(path, rec):
                kind = kinds.get(m.schema)
                d = m.json()
                if kind is None:
                    if m.schema != "mrswarm.Liveliness":
                        continue
                    kind, d = d["event"], {"key": d["key"]}
                d.pop("age_ms", None)
                d.pop("latency_ms", None)
                fields = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}
                f.write(json.dumps({"t": round(m.log_time / 1e9, 6), "kind": kind, **fields}, separators=(",", ":")) + "\n")
                n += 1
    except RecordingError as exc:
        raise ExportError(str(exc)) from None
    return {"out": str(out), "messages": n, "complete": rec.complete, "error": rec.error}


def list_topics(path: Path) -> dict[str, Any]:
    """Every channel of recording ``path`` in the order they first appear: ``{"topics": [(topic, schema, messages)]}``."""
    counts: dict[tuple[str, str], int] = {}
    rec = Recording(path)
    try:
        for m in read_recording(path, rec):
            k = (m.topic, m.schema)
            counts[k] = counts.get(k, 0) + 1
    except RecordingError as exc:
        raise ExportError(str(exc)) from None
    return {"topics": [(t, s, n) for (t, s), n in counts.items()], "messages": rec.messages, "complete": rec.complete,
            "error": rec.error}
