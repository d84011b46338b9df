"""The recordings of real autopilots that the virtual FCU and the agent are held to.

``../shared/fixtures/`` beside the checkout holds tlogs and summaries of a real ArduCopter 4.7 SITL
(``ardupilot-copter-4.7/``) and a real PX4 1.16 SIH SITL (``px4-sih-1.16/``): a boot, stream
requests, arming too early, a flight, the parameters, a mission and failsafes. ``MRSWARM_CAPTURES``
names another folder. A test that needs them fails, rather than skips, when they are missing.
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uav_stack.mav import mavlink

ROOT = Path(os.environ.get("MRSWARM_CAPTURES") or Path(__file__).resolve().parents[1].parent / "shared" / "fixtures")
ARDUPILOT = "ardupilot-copter-4.7"
PX4 = "px4-sih-1.16"


def folder(autopilot: str, capture: str) -> Path:
    path = ROOT / autopilot / capture
    assert path.is_dir(), f"no capture {path} (set MRSWARM_CAPTURES to the folder holding {ARDUPILOT}/ and {PX4}/)"
    return path


def summary(autopilot: str, capture: str) -> dict[str, Any]:
    return json_file(autopilot, capture, "summary.json")


def json_file(autopilot: str, capture: str, name: str) -> dict[str, Any]:
    """A JSON file of a capture's folder (summary.json, params.json)."""
    data: dict[str, Any] = json.loads((folder(autopilot, capture) / name).read_text())
    return data


@dataclass(frozen=True)
class Frame:
    """One MAVLink frame of a tlog: its wall-clock time (s), raw bytes and the parsed message."""

    t: float
    raw: bytes
    msg: Any  # a pymavlink message of mrswarm's dialect (uav_stack.mav)


def frames(autopilot: str, capture: str) -> Iterator[Frame]:
    """Every frame of a capture's tlog (both directions), parsed with mrswarm's dialect."""
    data = (folder(autopilot, capture) / "capture.tlog").read_bytes()
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    i = 0
    while i + 10 <= len(data):
        (stamp,) = struct.unpack_from(">Q", data, i)
        stx = data[i + 8]
        if stx == 0xFD:
            n = 12 + data[i + 9] + (13 if data[i + 10] & 1 else 0)
        elif stx == 0xFE:
            n = 8 + data[i + 9]
        else:
            raise ValueError(f"{autopilot}/{capture}: no MAVLink frame at byte {i + 8}")
        raw = data[i + 8:i + 8 + n]
        for msg in parser.parse_buffer(raw) or []:
            yield Frame(stamp / 1e6, raw, msg)
        i += 8 + n
