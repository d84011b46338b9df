"""A small closed-loop point-mass swarm simulator for the behaviour tests (numpy, no I/O).

- Physics at ``dt`` (0.05 s): first-order velocity response ``dv/dt = (cmd - v)/tau`` with the
  acceleration magnitude limited to ``accel_limit``.  An agent with ``rtf < 1`` lives in a slowed
  simulator: its sim clock advances ``rtf * dt`` per wall step, so it moves and responds
  ``rtf`` times slower in wall time (the paper's overloaded virtual UAV).  It reports its
  wall-clock velocity.
- Control at ``control_period`` (0.1 s wall): every agent samples its pose, broadcasts it, and
  computes mission -> avoidance.  Each (sender, receiver) copy is lost with probability ``loss``
  and otherwise delivered ``U(delay)`` seconds later; receivers keep the newest pose per sender,
  and pass its age = now - sampling time.
- Membership seen by an agent: itself plus every sender heard within ``member_timeout``.
- Agents can be killed at a time (they stop sending and are removed from the physics).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from uav_stack.behaviours.avoidance import CollisionAvoidance
from uav_stack.behaviours.base import Behaviour, NeighbourView, Rect, SelfState


@dataclass
class SimAgent:
    uav: int
    start: tuple[float, float]
    mission: Behaviour
    avoidance: CollisionAvoidance | None = None
    rtf: float = 1.0
    reciprocal: bool = True  # how *others* see it
    dies_at: float = math.inf


@dataclass
class SimConfig:
    dt: float = 0.05
    control_period: float = 0.1
    tau: float = 0.4
    accel_limit: float = 3.0
    delay: tuple[float, float] = (0.1, 0.3)
    loss: float = 0.1
    member_timeout: float = 5.0
    seed: int = 0


@dataclass
class SimResult:
    t: float
    min_separation: float  # over all alive pairs and all physics steps
    min_pair: tuple[int, int] | None
    done_at: dict[int, float]  # first time each mission reported done
    max_speed_cmd: float  # largest commanded speed seen
    infeasible_ticks: int
    trace: list[np.ndarray] = field(default_factory=list)  # positions per control tick (if kept)


class PointMassSim:
    def __init__(self, agents: list[SimAgent], cfg: SimConfig | None = None, keep_trace: bool = False):
        self.cfg = cfg or SimConfig()
        self.agents = agents
        n = len(agents)
        self.pos = np.array([a.start for a in agents], dtype=float)
        self.vel = np.zeros((n, 2))
        self.cmd = np.zeros((n, 2))
        self.alive = np.ones(n, dtype=bool)
        self.t = 0.0
        self.rng = np.random.default_rng(self.cfg.seed)
        self.rtf = np.array([a.rtf for a in agents], dtype=float)
        self._pending: list[list[tuple[float, int, int, float, tuple[float, float], tuple[float, float]]]] = [
            [] for _ in agents
        ]
        self._seq = 0
        self.latest: list[dict[int, tuple[float, tuple[float, float], tuple[float, float]]]] = [{} for _ in agents]
        self.min_sep = math.inf
        self.min_pair: tuple[int, int] | None = None
        self.done_at: dict[int, float] = {}
        self.max_speed_cmd = 0.0
        self.infeasible = 0
        self.keep_trace = keep_trace
        self.trace: list[np.ndarray] = []
        self._steps_per_tick = max(1, round(self.cfg.control_period / self.cfg.dt))
        self._step_count = 0
        self.on_tick: list[Callable[[PointMassSim], None]] = []

    # -- network -----------------------------------------------------------------------------
    def _broadcast(self) -> None:
        lo, hi = self.cfg.delay
        for i in range(len(self.agents)):
            if not self.alive[i]:
                continue
            p = (float(self.pos[i, 0]), float(self.pos[i, 1]))
            v = (float(self.vel[i, 0] * self.rtf[i]), float(self.vel[i, 1] * self.rtf[i]))
            for j in range(len(self.agents)):
                if j == i or self.rng.random() < self.cfg.loss:
                    continue
                d = lo if hi <= lo else float(self.rng.uniform(lo, hi))
                self._seq += 1
                heapq.heappush(self._pending[j], (self.t + d, self._seq, i, self.t, p, v))

    def _deliver(self, j: int) -> None:
        q = self._pending[j]
        while q and q[0][0] <= self.t + 1e-9:
            _, _, i, stamp, p, v = heapq.heappop(q)
            old = self.latest[j].get(i)
            if old is None or stamp > old[0]:
                self.latest[j][i] = (stamp, p, v)

    # -- control -----------------------------------------------------------------------------
    def _control(self) -> None:
        self._broadcast()
        for j, a in enumerate(self.agents):
            if not self.alive[j]:
                continue
            self._deliver(j)
            me = SelfState(
                a.uav,
                (float(self.pos[j, 0]), float(self.pos[j, 1])),
                (float(self.vel[j, 0] * self.rtf[j]), float(self.vel[j, 1] * self.rtf[j])),
                self.t,
            )
            nbs = []
            members = [a.uav]
            for i, (stamp, p, v) in self.latest[j].items():
                age = self.t - stamp
                if age <= self.cfg.member_timeout:
                    members.append(self.agents[i].uav)
                nbs.append(NeighbourView(self.agents[i].uav, p, v, age, self.agents[i].reciprocal))
            pref = a.mission.velocity(me, members)
            if a.avoidance is not None:
                res = a.avoidance.adjust(me, pref, nbs)
                cmd = res.velocity
                if not res.feasible:
                    self.infeasible += 1
            else:
                cmd = pref
            self.cmd[j] = cmd
            self.max_speed_cmd = max(self.max_speed_cmd, math.hypot(cmd[0], cmd[1]))
            if a.mission.done and a.uav not in self.done_at:
                self.done_at[a.uav] = self.t
        if self.keep_trace:
            self.trace.append(self.pos.copy())
        for cb in self.on_tick:
            cb(self)

    # -- physics -----------------------------------------------------------------------------
    def _physics(self) -> None:
        c = self.cfg
        h = (c.dt * self.rtf)[:, None]  # sim-time step per agent
        acc = (self.cmd - self.vel) / c.tau
        an = np.linalg.norm(acc, axis=1, keepdims=True)
        acc = np.where(an > c.accel_limit, acc * (c.accel_limit / np.maximum(an, 1e-12)), acc)
        self.vel = np.where(self.alive[:, None], self.vel + acc * h, 0.0)
        self.pos = self.pos + self.vel * h
        self.t += c.dt
        self._step_count += 1
        idx = np.flatnonzero(self.alive)
        if len(idx) >= 2:
            p = self.pos[idx]
            d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=2)
            np.fill_diagonal(d, np.inf)
            k = int(np.argmin(d))
            m = float(d.flat[k])
            if m < self.min_sep:
                self.min_sep = m
                a, b = divmod(k, len(idx))
                self.min_pair = (self.agents[idx[a]].uav, self.agents[idx[b]].uav)

    def step(self) -> None:
        for j, a in enumerate(self.agents):
            if self.alive[j] and self.t >= a.dies_at:
                self.alive[j] = False
        if self._step_count % self._steps_per_tick == 0:
            self._control()
        self._physics()

    def run(self, t_end: float, until: Callable[[PointMassSim], bool] | None = None) -> SimResult:
        while self.t < t_end - 1e-9:
            self.step()
            if until is not None and self._step_count % self._steps_per_tick == 0 and until(self):
                break
        return SimResult(
            self.t, self.min_sep, self.min_pair, dict(self.done_at), self.max_speed_cmd, self.infeasible, self.trace
        )


class CoverageGrid:
    """Cells of ``area`` (size ``cell``) seen by a disk footprint of radius ``radius``."""

    def __init__(self, area: Rect, cell: float, radius: float):
        self.area = area
        self.cell = cell
        self.radius = radius
        self.nx = max(1, round(area.width / cell))
        self.ny = max(1, round(area.height / cell))
        self.cx = area.x_min + (np.arange(self.nx) + 0.5) * area.width / self.nx
        self.cy = area.y_min + (np.arange(self.ny) + 0.5) * area.height / self.ny
        self.seen = np.zeros((self.nx, self.ny), dtype=bool)

    def mark(self, points: np.ndarray) -> None:
        r2 = self.radius * self.radius
        for x, y in points:
            i0 = np.searchsorted(self.cx, x - self.radius)
            i1 = np.searchsorted(self.cx, x + self.radius, side="right")
            j0 = np.searchsorted(self.cy, y - self.radius)
            j1 = np.searchsorted(self.cy, y + self.radius, side="right")
            if i0 >= i1 or j0 >= j1:
                continue
            dx = (self.cx[i0:i1] - x)[:, None]
            dy = (self.cy[j0:j1] - y)[None, :]
            self.seen[i0:i1, j0:j1] |= dx * dx + dy * dy <= r2

    def fraction(self, sub: Rect | None = None) -> float:
        if sub is None:
            return float(self.seen.mean())
        mi = (self.cx >= sub.x_min) & (self.cx <= sub.x_max)
        mj = (self.cy >= sub.y_min) & (self.cy <= sub.y_max)
        return float(self.seen[np.ix_(mi, mj)].mean())
