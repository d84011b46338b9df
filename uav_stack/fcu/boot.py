"""A vehicle's boot timeline: when each stage of the firmware's start-up is reached, and its one-off output.

Each flavour lists its firmware's milestones (``ardupilot.MILESTONES``, ``px4.MILESTONES``: seconds after
launch, as recorded from the real firmware) and one of them as the moment the vehicle becomes ready to
arm. The ``boot`` setting of a vehicle (``VehicleConfig.boot``) picks the durations:

* ``"firmware"``: the firmware's own times (ArduCopter is ready after about 42 s, PX4 after about 4.5 s);
* ``"short"`` (the default): the same milestones in the same order, every time scaled so that the vehicle
  is ready at ``SHORT_READY_S`` (1 s of sim time): a swarm of virtual UAVs does not wait 42 s each.

Only the boot is scaled; periodic behaviour (TIMESYNC every 10 s, auto-disarm, pre-arm reports) keeps
its own period either way. Times are sim seconds since ``VirtualFcu.open()``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

BOOT_PROFILES = ("short", "firmware")
SHORT_READY_S = 1.0  # sim seconds from launch to ready with boot="short"


def check_profile(boot: str) -> str:
    """The boot profile, or a ValueError that names the field."""
    if boot not in BOOT_PROFILES:
        raise ValueError(f"boot: expected one of {', '.join(repr(p) for p in BOOT_PROFILES)}, got {boot!r}")
    return boot


@dataclass(order=True)
class BootEvent:
    t: float  # sim s (already scaled)
    kind: str = field(compare=False)  # what to do: "statustext", "param_value", ... (the flavour's own)
    payload: Any = field(compare=False, default=None)


class BootTimeline:
    """Milestone times of one vehicle's boot, scaled to its profile, and the boot's one-off events in order."""

    def __init__(self, milestones: dict[str, float], ready: str, profile: str,
                 events: Iterable[tuple[float, str, Any]] = ()) -> None:  # fmt: skip
        check_profile(profile)
        self.profile = profile
        self.scale = 1.0 if profile == "firmware" else SHORT_READY_S / milestones[ready]
        self.at: dict[str, float] = {name: t * self.scale for name, t in milestones.items()}
        self.ready_at = self.at[ready]
        self._events = sorted(BootEvent(t * self.scale, kind, payload) for t, kind, payload in events)
        self._next = 0
        self.done_at = max([*self.at.values(), *(e.t for e in self._events)], default=0.0)

    def scaled(self, t_firmware: float) -> float:
        """A firmware time after launch on this vehicle's timeline."""
        return t_firmware * self.scale

    def passed(self, name: str, now: float) -> bool:
        return now + 1e-9 >= self.at[name]

    def due(self, now: float) -> list[BootEvent]:
        """The events whose time has come since the last call, in order."""
        ev, k = self._events, self._next
        if k >= len(ev) or ev[k].t > now + 1e-9:
            return []
        out = []
        while k < len(ev) and ev[k].t <= now + 1e-9:
            out.append(ev[k])
            k += 1
        self._next = k
        return out

    def skip(self) -> None:
        """Booted already (tests, benchmarks): every milestone passed, no boot output left."""
        self.at = {name: -math.inf for name in self.at}
        self.ready_at = self.done_at = -math.inf
        self._next = len(self._events)
