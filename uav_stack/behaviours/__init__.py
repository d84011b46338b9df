"""Swarm behaviours: pure algorithms (no I/O) the UAV agent calls at its control rate.

- :mod:`.base`: shared types (``SelfState``, ``Neighbour``, ``Area``, the ``Mission`` protocol).
- :mod:`.coverage`: missions producing a preferred velocity (``RandomDirectionCoverage``,
  ``LawnmowerCoverage``, ``GoTo``).
- :mod:`.avoidance`: age-aware ORCA (``CollisionAvoidance``) adjusting that velocity.
- :mod:`.lp`: the small linear programs behind ORCA.
"""

from uav_stack.behaviours.avoidance import AvoidanceResult, CollisionAvoidance
from uav_stack.behaviours.base import Area, Mission, Neighbour, SelfState, Vec2
from uav_stack.behaviours.coverage import GoTo, LawnmowerCoverage, RandomDirectionCoverage

__all__ = [
    "Area",
    "AvoidanceResult",
    "CollisionAvoidance",
    "GoTo",
    "LawnmowerCoverage",
    "Mission",
    "Neighbour",
    "RandomDirectionCoverage",
    "SelfState",
    "Vec2",
]
