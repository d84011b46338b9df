"""The scenario's ``faults:`` schedule: what to break, when, and the rules an entry follows (docs/reliability.md).

Each entry happens at ``at`` seconds after the mission start, or at a random time within
``window: [from, to]`` drawn from the scenario's seed (the same seed gives the same schedule, :func:`plan`).
The kinds: UAV processes (``kill_uav``, ``stop_uav``, ``continue_uav``, ``restart_uav``), the edge
services (``kill_discovery``, ``restart_discovery``, ``kill_router``, ``restart_router``), a virtual
UAV's FCU (``fcu_link_loss``, ``gps_jump``, ``gps_noise``, ``battery_drop``) and the network
(``partition``, ``outage``). How each is injected and watched during the run: mrswarm/run/chaos.py;
the per-fault table of the summary: mrswarm/results/fault_report.py.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from msgspec import Meta

from groundfloor.schema import Config, ConfigError
from uav_stack.config import UavId

FaultKind = Literal[
    "kill_uav", "stop_uav", "continue_uav", "restart_uav",
    "kill_discovery", "restart_discovery", "kill_router", "restart_router",
    "fcu_link_loss", "gps_jump", "gps_noise", "battery_drop",
    "partition", "outage",
]
UAV_PROCESS = ("kill_uav", "stop_uav", "continue_uav", "restart_uav")
SERVICE = ("kill_discovery", "restart_discovery", "kill_router", "restart_router")
INJECTED = ("fcu_link_loss", "gps_jump", "gps_noise", "battery_drop")
NETWORK = ("partition", "outage")
Seconds = Annotated[float, Meta(ge=0.0, le=7200.0, description="s after the mission start")]
STALE_S = 1.0  # a UAV's pose older than this counts as stale (the agents' default stale_after)


class FaultSpec(Config, frozen=True):
    """One entry of a scenario's ``faults:`` list."""

    kind: FaultKind
    at: Seconds | None = None
    window: tuple[Seconds, Seconds] | None = None  # a random time in [from, to], seeded
    uav: UavId | None = None  # the UAV (UAV process and FCU faults)
    uavs: tuple[UavId, ...] | None = None  # outage: the UAVs cut off (default: all)
    groups: tuple[tuple[UavId, ...], ...] | None = None  # partition: groups that cannot hear each other
    duration: Annotated[float, Meta(gt=0.0, le=600.0, description="s")] | None = None
    offset: tuple[Annotated[float, Meta(ge=-1000.0, le=1000.0)], Annotated[float, Meta(ge=-1000.0, le=1000.0)]] | None = None
    sigma: Annotated[float, Meta(gt=0.0, le=100.0, description="m")] | None = None
    level: Annotated[float, Meta(ge=0.0, le=1.0, description="remaining battery fraction")] | None = None

    def __post_init__(self) -> None:
        if (self.at is None) == (self.window is None):
            raise ConfigError("at", "give either 'at' (s after the mission start) or 'window: [from, to]'")
        if self.window is not None and not self.window[0] < self.window[1]:
            raise ConfigError("window", f"needs from < to, got {list(self.window)}")
        k = self.kind
        needs = {"uav": k in UAV_PROCESS or k in INJECTED,
                 "duration": k in ("fcu_link_loss", "gps_jump", "gps_noise") or k in NETWORK,
                 "offset": k == "gps_jump", "sigma": k == "gps_noise", "level": k == "battery_drop", "groups": k == "partition"}
        allowed = dict(needs, uavs=k == "outage", duration=needs["duration"] or k == "stop_uav")
        for name, required in needs.items():
            if required and getattr(self, name) is None:
                raise ConfigError(name, f"required for {k}")
        for name, ok in allowed.items():
            if not ok and getattr(self, name) is not None:
                raise ConfigError(name, f"not used by {k}")
        if self.groups is not None:
            flat = [u for g in self.groups for u in g]
            if len(self.groups) < 2 or any(not g for g in self.groups):
                raise ConfigError("groups", "at least two non-empty groups")
            if len(flat) != len(set(flat)):
                raise ConfigError("groups", "a UAV is in two groups")

    def targets(self) -> list[int]:
        if self.uav is not None:
            return [self.uav]
        if self.groups is not None:
            return sorted(u for g in self.groups for u in g)
        return sorted(self.uavs or ())


@dataclass
class PlannedFault:
    index: int
    spec: FaultSpec
    at: float  # s after the mission start


def plan(faults: tuple[FaultSpec, ...], seed: int) -> list[PlannedFault]:
    """Every fault with its time, in time order; a window's time is drawn from ``seed`` and the entry's index."""
    out = []
    for i, f in enumerate(faults):
        at = f.at if f.at is not None else random.Random(f"faults:{seed}:{i}").uniform(*f.window)  # type: ignore[misc]
        out.append(PlannedFault(i, f, round(at, 3)))
    return sorted(out, key=lambda p: (p.at, p.index))


def fit_to_duration(data: dict[str, Any], duration: float) -> list[str]:
    """A mission shortened on the command line (``--set duration=N``): leave out of the scenario mapping ``data``
    (before validation) the scheduled faults that cannot happen in ``duration`` s, and say what was left out.

    A fault fits when it is due before the end: ``at`` (or the end of its ``window``) earlier than ``duration``.
    Entries that are not well formed are left for validation to name. Returns a sentence naming what was
    left out (numbered as in the scenario file), or nothing.
    """
    faults = data.get("faults")
    if not isinstance(faults, list):
        return []
    keep, dropped = [], []
    for i, f in enumerate(faults):
        last = None
        if isinstance(f, dict):
            window = f.get("window")
            last = f.get("at") if "at" in f else window[1] if isinstance(window, list) and len(window) == 2 else None
        if isinstance(last, int | float) and not isinstance(last, bool) and last >= duration:
            when = f"at {f['at']:g} s" if "at" in f else f"in [{f['window'][0]:g}, {f['window'][1]:g}] s"
            dropped.append(f"{i} ({f.get('kind', '?')} {when})")
        else:
            keep.append(f)
    data["faults"] = keep
    if not dropped:
        return []
    return [f"faults: {len(keep)} of {len(faults)} kept; left out, not within the {duration:g} s mission: " + ", ".join(dropped)]


def check_against(faults: tuple[FaultSpec, ...], ids: set[int], duration: float, connectivity: str) -> None:
    """Rules between the schedule and the rest of the scenario (``ConfigError`` naming ``faults.<i>.<field>``)."""
    for i, f in enumerate(faults):
        where = f"faults.{i}"
        unknown = sorted(set(f.targets()) - ids)
        if unknown:
            field = "uav" if f.uav is not None else "groups" if f.groups is not None else "uavs"
            raise ConfigError(f"{where}.{field}", f"UAV {unknown[0]} is not in the fleet ({len(ids)} UAVs)")
        last = f.at if f.at is not None else f.window[1]  # type: ignore[index]
        if last >= duration:
            raise ConfigError(f"{where}.{'at' if f.at is not None else 'window'}",
                              f"{last:g} s is not within the mission's {duration:g} s")
        if "discovery" in f.kind and connectivity != "discovery":
            raise ConfigError(f"{where}.kind", f"{f.kind} needs network.connectivity: discovery "
                                               "(this run has no discovery server)")
