"""The agent's phases: one vocabulary for the agent, its overrides, the runner and the results.

An agent publishes its phase in every ``AgentState`` message (``swarmnet.messages``) as the
enum's string value, so a ground station or the runner that reads the wire sees exactly these
names. ``AgentPhase`` is a ``str`` enum: ``AgentPhase.MISSION == "mission"`` holds, and a phase
received as a string converts back with ``AgentPhase(text)``.
"""

from __future__ import annotations

from enum import Enum


class AgentPhase(str, Enum):
    """Where an agent is in its flight, from power-on to landed.

    The normal sequence is INIT -> READY -> ARMING -> TAKEOFF -> OFFBOARD -> HOVER -> MISSION
    -> DONE (-> LANDING -> LANDED). Ground-station overrides (``uav_stack.overrides``) add HOLD,
    GOTO, RTL and KILLED; YIELDED means someone else (a pilot, a ground station or the FCU's own
    failsafe) took the flight controller and the agent stopped sending setpoints.
    """

    INIT = "init"  # waiting for the FCU's heartbeat and position
    READY = "ready"  # FCU up, waiting for the "takeoff"/"start" command
    ARMING = "arming"
    TAKEOFF = "takeoff"
    OFFBOARD = "offboard"  # streaming setpoints before switching to OFFBOARD (PX4) / GUIDED (ArduPilot)
    HOVER = "hover"  # airborne under our control, waiting for "start" (the swarm begins together)
    MISSION = "mission"
    DONE = "done"  # mission complete, hovering
    YIELDED = "yielded"  # someone else changed the FCU's mode: we stopped sending setpoints
    LANDING = "landing"
    LANDED = "landed"
    ERROR = "error"
    HOLD = "hold"  # holding a point under our control (still avoiding neighbours)
    GOTO = "goto"  # flying to an operator's point, then holding there
    RTL = "rtl"  # the FCU returns to launch on our command; no setpoints
    KILLED = "killed"  # motors stopped on the operator's command

    def __str__(self) -> str:  # "mission", not "AgentPhase.MISSION", in logs and f-strings
        return self.value


# airborne phases in which the agent streams setpoints (and so must notice a human taking over)
CONTROLLED = frozenset({AgentPhase.HOVER, AgentPhase.MISSION, AgentPhase.DONE, AgentPhase.HOLD, AgentPhase.GOTO})
# phases in which a UAV works on its mission (coverage counts only these)
WORKING = frozenset({AgentPhase.MISSION, AgentPhase.DONE})
# phases after which an agent will not fly its mission again without a new command
FINISHED = frozenset({AgentPhase.DONE, AgentPhase.LANDED})
