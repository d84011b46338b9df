"""What a behaviour's step returns: the intent the agent flies until the next step.

All positions are in the swarm's ENU frame (metres from the swarm's origin: x east, y north,
z up); velocities in m/s. Collision avoidance and no-fly zones adjust the horizontal velocity
an intent becomes (unless the behaviour set ``avoidance = False``); the agent's altitude hold
flies ``z``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Velocity:
    """Fly at this horizontal velocity (m/s, ENU: ``vx`` east, ``vy`` north), limited to the
    flight's cruise speed (``flight.speed``); ``z``: also change the altitude target (m above the origin)."""

    vx: float
    vy: float
    z: float | None = None


@dataclass(frozen=True, slots=True)
class GoTo:
    """Fly to the point ``(x, y)`` (m, ENU) and stay there; ``z``: at that altitude (m above the
    origin; None: the current altitude target). The speed falls off over the last metres, so the
    UAV stops at the point instead of overshooting it."""

    x: float
    y: float
    z: float | None = None


@dataclass(frozen=True, slots=True)
class Altitude:
    """Change the altitude target to ``z`` (m above the swarm's origin) and hold the horizontal
    position the UAV has when the intent is given."""

    z: float


@dataclass(frozen=True, slots=True)
class Hold:
    """Hold the horizontal position the UAV has when the intent is given (at the current altitude target)."""


@dataclass(frozen=True, slots=True)
class Land:
    """Land where the UAV is. The behaviour is not stepped again."""


Intent = Velocity | GoTo | Altitude | Hold | Land
INTENTS = (Velocity, GoTo, Altitude, Hold, Land)


def intent_problem(intent: object) -> str:
    """"" if ``intent`` is an intent with finite numbers, else what is wrong with it."""
    if not isinstance(intent, INTENTS):
        return f"step returned {type(intent).__name__}, not an intent (Velocity, GoTo, Altitude, Hold, Land) or None"
    for name in ("vx", "vy", "x", "y", "z"):
        v = getattr(intent, name, None)
        if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v)):
            return f"{type(intent).__name__}.{name} is {v!r}, not a finite number"
    return ""
