"""Swarm behaviours: pure algorithms (no I/O) the UAV agent calls at its control rate.

- :mod:`.base`: shared types (``SelfState``, ``NeighbourView``, ``Rect``, the ``Behaviour`` protocol).
- :mod:`.coverage`: mission behaviours producing a preferred velocity (``RandomDirectionCoverage``,
  ``LawnmowerCoverage``, ``GoTo``).
- :mod:`.avoidance`: age-aware ORCA (``CollisionAvoidance``) adjusting that velocity.
- :mod:`.lp`: the small linear programs behind ORCA.
"""

from uav_stack.behaviours.avoidance import AvoidanceResult, CollisionAvoidance
from uav_stack.behaviours.base import Behaviour, NeighbourView, Rect, SelfState, Vec2
from uav_stack.behaviours.coverage import GoTo, LawnmowerCoverage, RandomDirectionCoverage

__all__ = [
    "AvoidanceResult",
    "Behaviour",
    "CollisionAvoidance",
    "GoTo",
    "LawnmowerCoverage",
    "NeighbourView",
    "RandomDirectionCoverage",
    "Rect",
    "SelfState",
    "Vec2",
]
