"""Virtual flight controller: MAVLink 2 over UDP that answers as PX4 1.16 or ArduCopter 4.7 do (held to
recordings of the real firmware), numpy multirotor dynamics for N vehicles, and a sim clock with a
measurable real-time factor.

See docs/fcu.md for the supported messages, commands, modes, parameters and failsafes.
"""

from uav_stack.fcu.clock import SimClock
from uav_stack.fcu.config import FcuConfig, VehicleConfig
from uav_stack.fcu.dynamics import MultirotorArray, MultirotorParams
from uav_stack.fcu.fcu import VehicleTruth, VirtualFcu
from uav_stack.fcu.stats import FcuStats

__all__ = [
    "FcuConfig",
    "FcuStats",
    "MultirotorArray",
    "MultirotorParams",
    "SimClock",
    "VehicleConfig",
    "VehicleTruth",
    "VirtualFcu",
]
