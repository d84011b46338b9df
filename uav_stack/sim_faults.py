"""Injected faults in a virtual UAV process: applied to its virtual FCU or to the link between them.

The experiment controller sends a :class:`~swarmnet.messages.FaultInjection` on the UAV's
fault key (docs/reliability.md); the agent hands it to :meth:`SimFaults.apply`, never to its
behaviour code, and acknowledges the answer. Kinds and their arguments (units in the names):

* ``fcu_link_loss`` ``{duration_s}``: the UDP link between the virtual FCU and the agent
  carries nothing either way, as if the serial cable were pulled. The FCU notices the
  missing setpoints (PX4 offboard loss -> Hold); the agent notices the missing heartbeat.
* ``gps_jump`` ``{dx_m, dy_m, duration_s}``: the FCU's reported position (its estimate, in
  GLOBAL_POSITION_INT, LOCAL_POSITION_NED and GPS_RAW_INT) is offset east/north; the vehicle
  itself does not move.
* ``gps_noise`` ``{sigma_m, duration_s}``: the reported position gets Gaussian noise of this
  standard deviation per axis, fresh every tick.
* ``battery_drop`` ``{level}``: the battery's state of charge falls to ``level`` (0..1).

Durations run on wall time. :class:`SimFaults` wraps the FCU the process loop drives
(``poll_io``/``service``), so a link cut also holds back what the FCU would send.
"""

from __future__ import annotations

import logging
import math
import random
import time
from typing import TYPE_CHECKING

from swarmnet.messages import FaultInjection

if TYPE_CHECKING:
    from uav_stack.fcu import VirtualFcu

log = logging.getLogger(__name__)

MAX_DURATION_S = 600.0
MAX_OFFSET_M = 1000.0
# kind -> {argument: (low, high)}; every argument is required
KINDS: dict[str, dict[str, tuple[float, float]]] = {
    "fcu_link_loss": {"duration_s": (0.0, MAX_DURATION_S)},
    "gps_jump": {"dx_m": (-MAX_OFFSET_M, MAX_OFFSET_M), "dy_m": (-MAX_OFFSET_M, MAX_OFFSET_M),
                 "duration_s": (0.0, MAX_DURATION_S)},
    "gps_noise": {"sigma_m": (0.0, 100.0), "duration_s": (0.0, MAX_DURATION_S)},
    "battery_drop": {"level": (0.0, 1.0)},
}


def check_fault(kind: str, args: dict[str, float]) -> str:
    """"" if ``kind`` with ``args`` can be applied, else why not."""
    spec = KINDS.get(kind)
    if spec is None:
        return f"unknown fault {kind!r} (one of: {', '.join(KINDS)})"
    extra = sorted(set(args) - set(spec))
    if extra:
        return f"{kind}: unknown arguments {extra} (expected {', '.join(spec)})"
    for name, (lo, hi) in spec.items():
        v = args.get(name)
        if v is None:
            return f"{kind}: missing argument {name}"
        if not (lo <= v <= hi) or (name.endswith("_s") and v <= 0.0):
            return f"{kind}: {name}={v:g} outside {'(' if name.endswith('_s') else '['}{lo:g}, {hi:g}]"
    return ""


class SimFaults:
    """Faults of one vehicle of a virtual FCU (``index``; a UAV process has one, a pool several),
    wrapping the FCU for a one-UAV process loop (:meth:`poll_io`, :meth:`service`)."""

    def __init__(self, fcu: VirtualFcu, seed: int = 0, index: int = 0):
        self.fcu = fcu
        self.vehicle = fcu.vehicles[index]
        self.link_cut_until = -math.inf  # wall time (time.time())
        self.gps_offset = (0.0, 0.0)  # east, north, m
        self.gps_offset_until = -math.inf
        self.gps_sigma = 0.0
        self.gps_noise_until = -math.inf
        self.dropped_datagrams = 0
        self.applied: list[dict[str, object]] = []
        self._rng = random.Random(seed)
        self._cut = False

    def apply(self, f: FaultInjection, now: float) -> tuple[bool, str]:
        """Apply an injected fault at wall time ``now``; (accepted, what happened or why not)."""
        why = check_fault(f.kind, f.args)
        if why:
            return False, why
        a = f.args
        v = self.vehicle
        if f.kind == "fcu_link_loss":
            self.link_cut_until = now + a["duration_s"]
            msg = f"FCU link cut for {a['duration_s']:g} s"
        elif f.kind == "gps_jump":
            self.gps_offset = (a["dx_m"], a["dy_m"])
            self.gps_offset_until = now + a["duration_s"]
            msg = f"reported position offset by ({a['dx_m']:g}, {a['dy_m']:g}) m for {a['duration_s']:g} s"
        elif f.kind == "gps_noise":
            self.gps_sigma = a["sigma_m"]
            self.gps_noise_until = now + a["duration_s"]
            msg = f"reported position noise of {a['sigma_m']:g} m for {a['duration_s']:g} s"
        else:
            before = float(self.fcu.dyn.battery[v.i])
            self.fcu.dyn.battery[v.i] = min(before, a["level"])
            v.battery_failed = True  # below PX4's simulated floor too (SIM_BAT_MIN_PCT limits the drain only)
            msg = f"battery {100 * before:.0f} % -> {100 * float(self.fcu.dyn.battery[v.i]):.0f} %"
        self.applied.append({"t": round(now, 3), "kind": f.kind, "args": dict(a), "id": f.fault_id})
        self.update(now)
        return True, msg

    @property
    def cut(self) -> bool:
        """The link between this vehicle and its agent is cut now."""
        return self._cut

    def update(self, now: float) -> None:
        """Start or end the link cut, and set the position error the FCU reports, for ``now``."""
        cut = now < self.link_cut_until
        v = self.vehicle
        if cut and not self._cut:
            v.link.send = lambda buf: None  # type: ignore[method-assign]  # nothing leaves the FCU
        elif not cut and self._cut:
            del v.link.send  # the class's send again
        self._cut = cut
        de, dn = self.gps_offset if now < self.gps_offset_until else (0.0, 0.0)
        if now < self.gps_noise_until:
            de += self._rng.gauss(0.0, self.gps_sigma)
            dn += self._rng.gauss(0.0, self.gps_sigma)
        v.position_error = (dn, de, 0.0)

    # ---- the FCU interface the process loop drives ---------------------------------------------
    def poll_io(self) -> None:
        if self._cut:
            for v in self.fcu.vehicles:  # datagrams from the agent are lost on the cut link
                self.dropped_datagrams += len(v.link.recv())
            return
        self.fcu.poll_io()

    def service(self, now: float | None = None) -> float:
        self.update(time.time())
        return self.fcu.service(now)
