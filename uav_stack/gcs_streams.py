"""The FCU's telemetry for ground stations, asked for only while a ground station listens.

A flight controller streams more than the agent reads. The agent needs HEARTBEAT,
GLOBAL_POSITION_INT (its position, 10 Hz), SYS_STATUS (battery), EXTENDED_SYS_STATE (landed
state), HOME_POSITION and the RTF value (uav_stack/fcu_link.py). The rest is for ground
stations: QGroundControl's instruments, MAVSDK's and MAVProxy's telemetry. Every message costs
the virtual FCU an encode, the agent a parse and its router a forward, in every UAV process:
the streams below are 12.5 of the virtual FCU's 27 messages a second (docs/benchmarks.md).

So the agent asks its FCU to stop those streams while no ground station has spoken through its
MAVLink router for :data:`GCS_QUIET_S`, and to send them at their default rates again as soon
as one does (``MAV_CMD_SET_MESSAGE_INTERVAL``, interval -1 then 0; PX4 and ArduPilot apply it
to the link it came on, so only the companion's link changes). Ground stations send a
heartbeat every second (MAVLink's rule for any component, and what QGroundControl, MAVProxy
and MAVSDK do), so one that connects sees heartbeats and positions at once (QGroundControl
lists the vehicle from them) and the rest from its first datagram on. The request to send
them again leaves before the router forwards that datagram's own messages, so a ground station
that sets its own rates (MAVSDK does) keeps them.

Requests are not acknowledged here: a stream that should be off and still arrives (a lost
request, an FCU that restarted) is asked off again, at most every :data:`ASK_AGAIN_S`.
"""

from __future__ import annotations

import math

from uav_stack.fcu_link import FcuLink
from uav_stack.mav import mavlink

# The streams only ground stations use, as MAVLink message names; the agent reads none of them
# (ATTITUDE's yaw also comes in GLOBAL_POSITION_INT's heading, BATTERY_STATUS's charge in SYS_STATUS).
GCS_STREAMS: tuple[str, ...] = ("LOCAL_POSITION_NED", "ATTITUDE", "VFR_HUD", "GPS_RAW_INT", "SYSTEM_TIME",
                                "BATTERY_STATUS", "MISSION_CURRENT")
GCS_QUIET_S = 5.0  # s without a datagram from any ground station before its streams are asked off
ASK_AGAIN_S = 2.0  # s before a stream asked off that still arrives is asked off again
_IDS = {name: getattr(mavlink, f"MAVLINK_MSG_ID_{name}") for name in GCS_STREAMS}
_OFF, _DEFAULT = -1, 0  # SET_MESSAGE_INTERVAL's interval (us): -1 stops the stream, 0 restores its default rate


class GcsStreams:
    """Keeps the FCU's ground-station streams off while no ground station listens (module docstring).

    Call :meth:`update` once per tick, after the router has read the ground stations' datagrams
    and before it forwards them to the FCU.
    """

    def __init__(self, link: FcuLink) -> None:
        self.link = link
        self.on = True  # what was last asked (an FCU starts with its defaults: on)
        self._asked_at = -math.inf  # when the streams were last asked off (wall clock, s)
        self.switches = 0  # times the streams were asked on or off as a ground station came or went
        self.asked_again = 0  # times a stream asked off still arrived and was asked off again

    def update(self, now: float, gcs_heard_at: float) -> None:
        """``now``: the wall clock (s); ``gcs_heard_at``: when a ground station last spoke
        through the router (-inf: never, or no router)."""
        if self.link.fcu_ids is None:  # no FCU yet: nobody to ask
            return
        want = now - gcs_heard_at < GCS_QUIET_S
        if want != self.on:
            self.on = want
            self.switches += 1
            self._ask(GCS_STREAMS, _DEFAULT if want else _OFF, now)
        elif not want and now - self._asked_at >= ASK_AGAIN_S:
            seen = self.link.seen_at
            late = [name for name in GCS_STREAMS if seen.get(name, -math.inf) > self._asked_at + 0.5]
            if late:  # arrived well after it was asked off: a lost request, or a restarted FCU
                self.asked_again += 1
                self._ask(late, _OFF, now)

    def _ask(self, names: tuple[str, ...] | list[str], interval_us: int, now: float) -> None:
        for name in names:
            self.link.set_message_interval(_IDS[name], interval_us)
        if interval_us == _OFF:
            self._asked_at = now

    def as_dict(self) -> dict[str, object]:
        return {"on": self.on, "switches": self.switches, "asked_again": self.asked_again}
