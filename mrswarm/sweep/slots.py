"""A slot's folder under the campaign folder: ``runs/<cell>_seed-<k>/``.

It holds ``slot.json`` (what the sweep flies there, and every attempt), each attempt's console
output (``attempt-<n>.log``) and the run folders ``mrswarm run --out <slot>`` made
(``<scenario>-<time>/``). A run is *complete* when its ``summary.json`` says it was not
interrupted (the runner writes it once, atomically, at the end of every run, also an
interrupted one): such a run is never flown again. A run whose runner gave up (``aborted``) or
that recorded nothing (``error``) is complete but *failed*; ``--retry-failed`` flies its slot
again. An interrupted run, or a run folder without a summary (its runner killed outright),
stays where it is and the slot is flown again; the table uses the complete run only.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import msgspec

from mrswarm.records.summary import write_atomic

RUNS = "runs"
SLOT_FILE = "slot.json"


class SlotState(str, Enum):
    PENDING = "pending"  # never flown, or every attempt interrupted
    OK = "ok"  # a complete run
    FAILED = "failed"  # a complete run whose runner gave up, or that recorded nothing


class Attempt(msgspec.Struct):
    """One ``mrswarm run`` of a slot, as the sweep saw it."""

    number: int
    started: float  # wall
    run_dir: str | None = None  # the run folder it made (relative to the slot)
    ended: float | None = None  # wall
    exit_code: int | None = None  # mrswarm run's (docs: 0 ok, 1 aborted, 2 bad input, 3 safety events, 128+N signal)
    wall_s: float | None = None
    cpu_s: float | None = None  # CPU time of the runner and every process it waited for (its UAVs, services, recorder)
    concurrent: int = 1  # most runs of the sweep flying at once during this one (itself included)
    machine_busy: float | None = None  # mean share of the machine's CPU in use while it flew (every process, 0..1)
    where: str = "local"  # local, or swarm:<node> (docs/campaigns.md, "On a Docker Swarm")


class SlotRecord(msgspec.Struct):
    """``slot.json``."""

    cell: dict[str, Any]  # grid key -> value
    seed: int
    overrides: list[str]  # the --set texts of its runs
    digest: str  # of the resolved scenario (mrswarm.sweep.campaign.scenario_digest)
    attempts: list[Attempt] = []


@dataclass
class SlotStatus:
    """What a slot's folder holds now."""

    state: SlotState
    run_dir: Path | None  # the complete run's folder
    summary: dict[str, Any] | None  # its summary.json
    attempts: int  # run folders in the slot (complete or not)
    interrupted: int  # ... of which interrupted or without a summary
    record: SlotRecord | None
    why: str = ""  # a failed run: aborted or error


def slot_dir(campaign_dir: Path, name: str) -> Path:
    return campaign_dir / RUNS / name


def read_record(folder: Path) -> SlotRecord | None:
    try:
        return msgspec.json.decode((folder / SLOT_FILE).read_bytes(), type=SlotRecord)
    except (OSError, msgspec.DecodeError, msgspec.ValidationError):
        return None


def write_record(folder: Path, record: SlotRecord) -> None:
    write_atomic(folder / SLOT_FILE, msgspec.json.format(msgspec.json.encode(record), indent=2) + b"\n")


def run_folders(folder: Path) -> list[Path]:
    """The run folders ``mrswarm run`` made in the slot, oldest first (their names carry the time)."""
    if not folder.is_dir():
        return []
    runs = [d for d in folder.iterdir() if d.is_dir() and ((d / "run.json").exists() or (d / "scenario.yaml").exists())]
    return sorted(runs, key=lambda d: (_started(d), d.name))


def _started(run_dir: Path) -> float:
    """When the run started (its run.json), else when its folder was made."""
    try:
        return float(json.loads((run_dir / "run.json").read_bytes())["started"])
    except (OSError, ValueError, KeyError, TypeError):
        try:
            return run_dir.stat().st_mtime
        except OSError:
            return 0.0


def read_summary(run_dir: Path) -> dict[str, Any] | None:
    """``summary.json`` if it is there and readable, else None."""
    try:
        data = json.loads((run_dir / "summary.json").read_bytes())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def status(folder: Path) -> SlotStatus:
    record = read_record(folder)
    runs = run_folders(folder)
    done: tuple[Path, dict[str, Any]] | None = None
    interrupted = 0
    for d in runs:
        s = read_summary(d)
        if s is None or s.get("interrupted") is not False:
            interrupted += 1
            continue
        done = (d, s)  # the latest complete one
    if done is None:
        return SlotStatus(SlotState.PENDING, None, None, len(runs), interrupted, record)
    d, s = done
    why = str(s.get("aborted") or s.get("error") or "")
    return SlotStatus(SlotState.FAILED if why else SlotState.OK, d, s, len(runs), interrupted, record, why)


def new_attempt(record: SlotRecord) -> Attempt:
    a = Attempt(number=len(record.attempts) + 1, started=time.time())
    record.attempts.append(a)
    return a


def attempt_of(record: SlotRecord | None, run_dir: Path) -> Attempt | None:
    """The sweep's record of the attempt that made ``run_dir`` (None: not flown by a sweep, or slot.json lost)."""
    if record is None:
        return None
    return next((a for a in record.attempts if a.run_dir == run_dir.name), None)
