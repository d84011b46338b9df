"""Simulation clock: fixed sim-time steps paced against wall time.

RTF (real-time factor) = elapsed sim time / elapsed wall time (measured over a sliding window
by :class:`uav_stack.rtf.RtfMeter`).
A physics step of ``dt = 1/physics_hz`` sim seconds is due every ``dt / target_rtf`` wall
seconds. The FCU may run several due steps in one wake-up (it plans its wake-ups with
``plan_wake``); when the caller comes back more than ``max_catchup_s`` of wall time after
the planned wake-up, the excess backlog is dropped: sim time falls behind wall time
(RTF < target) instead of the simulation bursting forward. It is dropped in whole multiples of
``phase_steps`` steps, so that the steps keep their phase to the wall clock. Nothing else breaks, because
every FCU timer runs on sim time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class SimClock:
    physics_hz: float = 50.0
    target_rtf: float = 1.0
    max_catchup_s: float = 0.1
    steps: int = 0  # physics steps taken; sim_time = steps * dt exactly (no drift)
    dropped_wall_s: float = 0.0  # wall time given up because the caller was late
    wall_start: float = 0.0
    next_step_wall: float = 0.0
    planned_wake: float = 0.0  # when the host loop was asked to come back
    phase_steps: int = 1  # a backlog is dropped in whole multiples of this many steps' wall time
    _started: bool = field(default=False, repr=False)
    # Derived, kept as plain attributes (read several times a tick in every virtual UAV; a
    # property is a call each time): physics_hz and target_rtf do not change after construction.
    dt: float = field(init=False)  # sim s per step: 1 / physics_hz
    wall_per_step: float = field(init=False)  # wall s per step: 1 / (physics_hz * target_rtf)
    sim_time: float = field(init=False)  # sim s since start: steps / physics_hz, set as steps advance

    def __post_init__(self) -> None:
        if not self.physics_hz > 0 or not self.target_rtf > 0:
            raise ValueError("physics_hz and target_rtf must be positive")
        self.max_catchup_s = max(0.0, self.max_catchup_s)
        self.dt = 1.0 / self.physics_hz
        self.wall_per_step = 1.0 / (self.physics_hz * self.target_rtf)
        self.sim_time = self.steps / self.physics_hz

    @property
    def started(self) -> bool:
        return self._started

    def start(self, wall_now: float) -> None:
        self.wall_start = wall_now
        self.next_step_wall = wall_now + self.wall_per_step
        self.planned_wake = self.next_step_wall
        self.steps = 0
        self.sim_time = 0.0
        self.dropped_wall_s = 0.0
        self._started = True

    def due_steps(self, wall_now: float) -> int:
        """How many steps to run now; drops any backlog beyond ``max_catchup_s``."""
        if not self._started:
            self.start(wall_now)
            return 0
        late = wall_now - max(self.planned_wake, self.next_step_wall)
        if late > self.max_catchup_s:
            # whole multiples of phase_steps steps: the steps (and the telemetry on them) keep
            # their phase to the wall clock, which aligned ticks rely on (uav_stack.runtime)
            per = self.wall_per_step * self.phase_steps
            drop = math.floor((late - self.max_catchup_s) / per) * per
            self.dropped_wall_s += drop
            self.next_step_wall += drop
        lag = wall_now - self.next_step_wall
        if lag < 0.0:
            return 0
        return int(lag / self.wall_per_step + 1e-9) + 1

    def wall_of_step(self, k: int) -> float:
        """Wall time at which step number k (1-based count after it) is due."""
        return self.next_step_wall + (k - self.steps - 1) * self.wall_per_step

    def plan_wake(self, wall: float) -> None:
        self.planned_wake = wall

    def advance(self, k: int = 1) -> None:
        """Account for k steps taken."""
        self.steps += k
        self.sim_time = self.steps / self.physics_hz
        self.next_step_wall += k * self.wall_per_step

    def rtf_total(self, wall_now: float) -> float:
        """RTF since :meth:`start`; NaN before (the convention of :mod:`uav_stack.rtf`)."""
        el = wall_now - self.wall_start
        return self.sim_time / el if self._started and el > 1e-6 else math.nan
