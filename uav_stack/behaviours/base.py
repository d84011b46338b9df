"""Shared types for the swarm behaviours: own state, neighbour views, rectangles, the Behaviour protocol.

Everything is in the swarm's shared ENU frame (x east, y north, metres) and 2-D: the agent
holds altitude separately.  Vectors are plain ``tuple[float, float]`` (alias ``Vec2``) so the
agent can pass what it already has without wrapping; the helpers below do the arithmetic on
scalars with ``math``, which for 2-D is much cheaper than numpy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

Vec2 = tuple[float, float]


# --- 2-D helpers (scalars, no allocation beyond the result tuple) ----------------------------
def dist(a: Vec2, b: Vec2) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


def clip_norm(a: Vec2, limit: float) -> Vec2:
    """``a`` scaled down (never up) so that its length is at most ``limit``."""
    n = math.hypot(a[0], a[1])
    if n <= limit or n == 0.0:
        return a
    k = limit / n
    return (a[0] * k, a[1] * k)


def is_finite(a: Vec2) -> bool:
    return math.isfinite(a[0]) and math.isfinite(a[1])


# --- state --------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class SelfState:
    """The UAV's own state as the behaviours see it."""

    uav: int
    pos: Vec2  # ENU x (east), y (north), metres
    vel: Vec2  # m/s, wall-clock (what the vehicle really does, not what a slowed simulator thinks)
    t: float  # wall time, seconds


@dataclass(slots=True)
class NeighbourView:
    """What collision avoidance sees of one neighbour (built by the agent from ``swarmnet``'s
    neighbour table for each control tick).

    Treat as immutable. It is not ``frozen`` because a UAV of 50 builds up to 49 of them every
    tick, and a frozen dataclass's ``__init__`` costs 2.5 times as much (0.80 against 0.32 µs
    warm), as for :class:`swarmnet.messages.Pose`."""

    uav: int
    pos: Vec2  # as last received
    vel: Vec2
    age: float  # seconds since that pose was sampled (network delay + staleness); < 0 (a clock ahead of ours): fresh
    reciprocal: bool = True  # False for physical UAVs / agents that will not share avoidance effort


@dataclass(frozen=True, slots=True)
class Rect:
    """Axis-aligned rectangle in ENU metres: a coverage area, one UAV's strip of it."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float

    def __post_init__(self) -> None:
        vals = (self.x_min, self.x_max, self.y_min, self.y_max)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"area bounds must be finite, got {vals}")
        if not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ValueError(f"need x_min < x_max and y_min < y_max, got {vals}")

    @property
    def width(self) -> float:
        return self.x_max - self.x_min

    @property
    def height(self) -> float:
        return self.y_max - self.y_min

    @property
    def size(self) -> float:
        return self.width * self.height

    @property
    def centre(self) -> Vec2:
        return (0.5 * (self.x_min + self.x_max), 0.5 * (self.y_min + self.y_max))

    def contains(self, p: Vec2, tol: float = 0.0) -> bool:
        return (
            self.x_min - tol <= p[0] <= self.x_max + tol and self.y_min - tol <= p[1] <= self.y_max + tol
        )

    def clamp(self, p: Vec2) -> Vec2:
        """Nearest point of the rectangle."""
        return (min(max(p[0], self.x_min), self.x_max), min(max(p[1], self.y_min), self.y_max))

    def shrunk(self, margin: float) -> Rect:
        """The rectangle inset by ``margin`` on every side (capped so it never inverts)."""
        mx = min(margin, 0.49 * self.width)
        my = min(margin, 0.49 * self.height)
        return Rect(self.x_min + mx, self.x_max - mx, self.y_min + my, self.y_max - my)


@runtime_checkable
class Behaviour(Protocol):
    """A mission behaviour (coverage, go-to): the preferred velocity at each control tick,
    before collision avoidance adjusts it."""

    def velocity(self, me: SelfState, members: Sequence[int]) -> Vec2:
        """Preferred velocity (m/s). ``members`` = ids alive in the swarm, including ``me.uav``."""
        ...

    @property
    def done(self) -> bool: ...


@runtime_checkable
class Cooperative(Protocol):
    """A mission behaviour that talks to its swarm (plume detections, fire cells), still without I/O:
    the agent hands it the swarm messages on its ``topics`` and broadcasts what it leaves in its outbox."""

    topics: tuple[str, ...]

    def receive(self, src: int, topic: str, body: Any, now: float) -> None:
        """A swarm message from UAV ``src`` on one of ``topics`` (``body`` is untrusted input)."""
        ...

    def outbox(self) -> list[tuple[str, Any]]:
        """The ``(topic, body)`` messages to broadcast now (the list is handed over and emptied)."""
        ...

    @property
    def status(self) -> str:
        """A short word for the agent's state detail (``surge``, ``fire fighting``, ...)."""
        ...
