"""The public API of mrswarm's behaviour SDK: bring your own swarm algorithm (docs/sdk.md).

Write a behaviour::

    import msgspec
    from mrswarm.api import Behaviour, Context, Velocity

    class Params(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
        speed: float = 3.0  # m/s

    class Eastward(Behaviour[Params]):
        Params = Params

        def step(self, ctx: Context) -> Velocity:
            return Velocity(self.params.speed, 0.0)

and fly it from a scenario: ``mission: {behaviour: "mypkg.east:Eastward", params: {speed: 4}}``.

Units everywhere: metres in the swarm's ENU frame (x east, y north, z up, from the swarm's
origin), m/s, seconds, degrees for latitude and longitude. These names are stable; their
implementation lives in :mod:`uav_stack.sdk` (it runs in each UAV process).
"""

from uav_stack.sdk.behaviour import Behaviour, NoParams
from uav_stack.sdk.context import Context, Message, Neighbour
from uav_stack.sdk.intents import Altitude, GoTo, Hold, Intent, Land, Velocity
from uav_stack.sdk.loader import ENTRY_POINT_GROUP
from uav_stack.sensors import SensorReading

__all__ = ["ENTRY_POINT_GROUP", "Altitude", "Behaviour", "Context", "GoTo", "Hold", "Intent", "Land", "Message",
           "Neighbour", "NoParams", "SensorReading", "Velocity"]
