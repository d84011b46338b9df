"""What the emulated firmwares are, as recorded from the real ones: their parameter tables and boot output.

``data/ardupilot_copter.json`` holds ArduCopter 4.7.0-dev's parameters (name, MAV_PARAM_TYPE and factory
default, in the firmware's index order: the 1338 a SITL with wiped EEPROM lists) and what it says at boot on
its first MAVLink port (STATUSTEXTs and unsolicited PARAM_VALUEs, with their times after launch).
``data/px4.json`` holds PX4 1.16's (SIH quadrotor airframe, default parameters): 901 parameters, the
``_HASH_CHECK`` value of that set, and the PARAM_VALUEs its airframe start-up sends. Both were read off
recordings of the real firmware; docs/fcu.md says what the emulator does with them.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path

DATA = Path(__file__).with_name("data")
_FILES = {"ardupilot": "ardupilot_copter.json", "px4": "px4.json"}


@dataclass(frozen=True)
class FirmwareParam:
    name: str
    ptype: int  # MAV_PARAM_TYPE
    default: float


@dataclass(frozen=True)
class Firmware:
    """One firmware's recorded facts (shared, read-only)."""

    name: str  # e.g. "ArduCopter V4.7.0-dev (2598e9d4)"
    params: tuple[FirmwareParam, ...]  # in index order
    hash_check: int | None  # PX4's _HASH_CHECK of the default set; None for ArduPilot
    boot_statustexts: tuple[tuple[float, int, str], ...]  # (t after launch, severity, text)
    # (t after launch, parameter name, value or None for the table's, MAV_PARAM_TYPE or None, param_count or None)
    boot_param_values: tuple[tuple[float, str, float | None, int | None, int | None], ...]


@functools.cache
def firmware(flavour: str) -> Firmware:
    raw = json.loads((DATA / _FILES[flavour]).read_text())
    pvs = []
    for row in raw["boot_param_values"]:
        t, name, *rest = row
        value, ptype, count = (rest + [None, None, None])[:3]
        pvs.append((float(t), str(name), value, ptype, count))
    return Firmware(
        name=raw["firmware"],
        params=tuple(FirmwareParam(n, int(ty), float(v)) for n, ty, v in raw["params"]),
        hash_check=raw.get("hash_check"),
        boot_statustexts=tuple((float(t), int(s), str(x)) for t, s, x in raw.get("boot_statustexts", [])),
        boot_param_values=tuple(pvs),
    )
