"""The behaviour SDK: bring your own swarm algorithm (docs/sdk.md).

The public names are re-exported by :mod:`mrswarm.api`, which is what users import. Here, in
the UAV process: :mod:`.behaviour` (the base class), :mod:`.context` (what a step sees and can
do), :mod:`.intents` (what it returns), :mod:`.loader` (finding a behaviour by name, validating
its parameters), :mod:`.adapter` (the agent's mission around a behaviour, guarded) and
:mod:`.builtins` (our own missions written on the SDK).
"""

from uav_stack.sdk.behaviour import Behaviour, NoParams
from uav_stack.sdk.context import Context, Message, Neighbour
from uav_stack.sdk.intents import Altitude, GoTo, Hold, Intent, Land, Velocity

__all__ = ["Altitude", "Behaviour", "Context", "GoTo", "Hold", "Intent", "Land", "Message", "Neighbour", "NoParams",
           "Velocity"]
