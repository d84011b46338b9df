"""Virtual sensors, actuators and airspace traffic on the wire: the UAV's end and the world's end.

The world service (``world/``) computes every UAV's sensor readings at the edge from the poses
the UAVs already share, and pushes each reading to that UAV alone (docs/keyspace.md says why
push and not a query). Both ends sit on an open :class:`~swarmnet.node.SwarmNode`, so their
subscriptions and publications use its session (and whatever transport security it has):

- :class:`UavSensing` (a UAV): readings on ``mrs/<swarm>/<me>/sense/*`` (its own, nothing
  else), the airspace feed on ``mrs/airspace/<swarm>/traffic``; actuator requests out on
  ``mrs/<swarm>/<me>/act/<actuator>``.
- :class:`WorldSensing` (the world service, role ``edge``): actuator requests of every UAV of
  the swarm in; readings out per UAV and sensor; the swarm's traffic feed out.

Everything received goes through the one receive path (:mod:`swarmnet.receive`) with the
acceptance rules of :mod:`swarmnet.messages` (a reading names the key's UAV and sensor, and that
UAV is this one; an actuation names the key's UAV), counted in the node's ``stats``.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import zenoh

from swarmnet.messages import (
    Actuation,
    AgentState,
    Reading,
    Traffic,
    accept_actuation,
    accept_reading,
    accept_state,
    accept_traffic,
    encode_actuation,
    encode_reading,
    encode_traffic,
)
from swarmnet.node import SwarmNode
from swarmnet.receive import DRAIN_BUDGET, Inlet, receive, subscribe


def _session(node: SwarmNode) -> zenoh.Session:
    if node.session is None:
        raise RuntimeError("open the SwarmNode before attaching sensing to it")
    return node.session


class UavSensing:
    """A UAV's end: its readings and its swarm's airspace feed in, its actuator requests out."""

    def __init__(self, node: SwarmNode, traffic: bool = True):
        s = _session(node)
        self.node = node
        me = node.identity.uav
        # stamped as they arrive (a rare stream: a few readings a second per sensor), so that a reading's measured
        # delay is its latency and transport, not also the wait for the owner's next tick
        self._readings = Inlet(256, how="callback")
        self._subs = [subscribe(s, node.keys.all_senses(me), self._readings)]
        self._traffic: Inlet | None = None
        if traffic:
            self._traffic = Inlet(16, how="ring")
            self._subs.append(subscribe(s, node.keys.traffic, self._traffic))
        self._accept_reading = partial(accept_reading, me=me)
        self._pubs: dict[str, Any] = {}
        self._seq = 0

    def poll(self, budget: int = DRAIN_BUDGET) -> tuple[list[Reading], list[Traffic]]:
        """The readings and traffic messages that arrived since the last call, oldest first."""
        readings, traffic = self.poll_arrivals(budget)
        return [r for _, r in readings], traffic

    def poll_arrivals(self, budget: int = DRAIN_BUDGET) -> tuple[list[tuple[float, Reading]], list[Traffic]]:
        """As :meth:`poll`, each reading with the wall time it arrived in this process."""
        stats = self.node.stats
        readings = [(a.at, a.item) for a in receive(self._readings, self._accept_reading, stats, budget)]
        stats.received["reading"] += len(readings)
        traffic: list[Traffic] = []
        if self._traffic is not None:
            traffic = [a.item for a in receive(self._traffic, accept_traffic, stats, budget)]
            stats.received["traffic"] += len(traffic)
        return readings, traffic

    def actuate(self, actuator: str, amount: float) -> None:
        """Ask the world to apply ``amount`` (the actuator's unit) of ``actuator`` where it tracks this UAV."""
        node = self.node
        pub = self._pubs.get(actuator)
        if pub is None:
            pub = self._pubs[actuator] = _session(node).declare_publisher(
                node.keys.act(node.identity.uav, actuator), priority=zenoh.Priority.INTERACTIVE_HIGH, express=True)
        a = Actuation(node.identity.uav, actuator, self._seq, node.clock(), amount)
        self._seq = (self._seq + 1) & 0xFFFFFFFF
        pub.put(encode_actuation(a))
        node.stats.sent["actuation"] += 1


class WorldSensing:
    """The world's end for one swarm: actuator requests and agent states in, readings and traffic out.

    (The agent states tell the world when the swarm's mission starts: experiment time 0.)
    """

    def __init__(self, node: SwarmNode):
        s = _session(node)
        self.node = node
        self._acts = Inlet(4096, how="ring")
        self._states = Inlet(1024, how="ring")
        self._subs = [subscribe(s, node.keys.all_acts, self._acts), subscribe(s, node.keys.all_states, self._states)]
        self._pubs: dict[tuple[int, str], Any] = {}
        self._traffic_pub: Any = None

    def states(self, budget: int = DRAIN_BUDGET) -> list[AgentState]:
        """The agent states that arrived since the last call."""
        out = [a.item for a in receive(self._states, accept_state, self.node.stats, budget)]
        self.node.stats.received["state"] += len(out)
        return out

    def actuations(self, budget: int = DRAIN_BUDGET) -> list[Actuation]:
        """The actuator requests that arrived since the last call, oldest first."""
        stats = self.node.stats
        out = [a.item for a in receive(self._acts, accept_actuation, stats, budget)]
        stats.received["actuation"] += len(out)
        return out

    def publish(self, reading: Reading) -> None:
        """Push ``reading`` to its UAV's key for its sensor (one publisher per pair, declared once)."""
        k = (reading.uav, reading.sensor)
        pub = self._pubs.get(k)
        if pub is None:
            pub = self._pubs[k] = _session(self.node).declare_publisher(
                self.node.keys.sense(reading.uav, reading.sensor), congestion_control=zenoh.CongestionControl.DROP,
                priority=zenoh.Priority.DATA_HIGH, express=True)
        pub.put(encode_reading(reading))
        self.node.stats.sent["reading"] += 1

    def publish_traffic(self, traffic: Traffic) -> None:
        if self._traffic_pub is None:
            self._traffic_pub = _session(self.node).declare_publisher(
                self.node.keys.traffic, congestion_control=zenoh.CongestionControl.DROP, priority=zenoh.Priority.DATA_HIGH,
                express=True)
        self._traffic_pub.put(encode_traffic(traffic))
        self.node.stats.sent["traffic"] += 1
