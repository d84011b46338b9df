"""The Zenoh key space of a swarm (documented in docs/keyspace.md).

Every key starts with ``mrs/<swarm>/``, so two swarms on one network never receive each
other's traffic unless a node subscribes across swarms on purpose (``mrs/*/...``): Zenoh
routes data only towards matching subscribers.

UAV ids are decimal integers (1..65535); the words ``alive``, ``msg``, ``cmd``, ``feed`` and ``netem``
are reserved segment names and can never be mistaken for a UAV id. Everything a UAV publishes
sits under its own id (``mrs/<swarm>/<uav>/...``, its swarm messages too), so access control
can bind each key to the certificate of the UAV it names (swarmnet/security/acl.py).

One key tree lies outside every swarm: ``mrs/airspace/<swarm>/traffic``, the traffic feed the
edge publishes into each swarm (the other swarms' UAVs as position and velocity only), so
``airspace`` is not a valid swarm name.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

ROOT = "mrs"
SWARM_RE = re.compile(r"^(?!airspace$)[A-Za-z0-9_\-]{1,32}$")  # "airspace" heads the cross-swarm traffic keys
AIRSPACE = "airspace"


def check_swarm(swarm: str) -> str:
    if not isinstance(swarm, str) or not SWARM_RE.match(swarm):
        raise ValueError(f"swarm name {swarm!r} must be 1-32 characters of [A-Za-z0-9_-], and not {AIRSPACE!r}")
    return swarm


def traffic_key(swarm: str) -> str:
    """The airspace feed for ``swarm``: every UAV of the *other* swarms sharing the airspace, as
    traffic (position and velocity only), published by the edge (world/airspace.py)."""
    return f"{ROOT}/{AIRSPACE}/{check_swarm(swarm)}/traffic"


@dataclass(frozen=True)
class SwarmKeys:
    """Key builders for one swarm."""

    swarm: str

    def __post_init__(self) -> None:
        check_swarm(self.swarm)

    @property
    def prefix(self) -> str:
        return f"{ROOT}/{self.swarm}"

    # per-UAV streams
    def pose(self, uav: int | str) -> str:
        return f"{self.prefix}/{uav}/pose"

    def telemetry(self, uav: int | str) -> str:
        return f"{self.prefix}/{uav}/telemetry"

    def state(self, uav: int | str) -> str:
        return f"{self.prefix}/{uav}/state"

    def cmd(self, uav: int | str) -> str:
        return f"{self.prefix}/{uav}/cmd"

    def ack(self, uav: int | str) -> str:
        return f"{self.prefix}/{uav}/ack"

    def alive(self, role: str, node: int | str) -> str:
        return f"{self.prefix}/alive/{role}/{node}"

    def sense(self, uav: int | str, sensor: str) -> str:
        """Readings of one virtual sensor of one UAV, computed and published by the world service."""
        return f"{self.prefix}/{uav}/sense/{sensor}"

    def act(self, uav: int | str, actuator: str) -> str:
        """Requests of one UAV's virtual actuator (spray), to the world service."""
        return f"{self.prefix}/{uav}/act/{actuator}"
    def behaviour(self, uav: int | str) -> str:
        """What the UAV's SDK behaviour recorded (``ctx.record``) and its message counters, once a second (docs/sdk.md)."""
        return f"{self.prefix}/{uav}/behaviour"

    def fault(self, uav: int | str) -> str:
        """Fault injection into a virtual UAV (the experiment controller only; docs/reliability.md)."""
        return f"{self.prefix}/{uav}/fault"

    # swarm-wide
    @property
    def pose_feed(self) -> str:
        """Batches of every UAV's latest pose, published by the edge (see swarmnet/feed.py)."""
        return f"{self.prefix}/feed/poses"

    def near_feed(self, uav: int | str) -> str:
        """Batches of the poses within UAV ``uav``'s interest radius, for it only (swarmnet/interest.py)."""
        return f"{self.prefix}/feed/near/{uav}"

    def pool_near_feed(self, pool: int) -> str:
        """Batches of the poses within the interest radius of any UAV of pool ``pool`` (a process of
        virtual UAVs on one session), each pose once, for that pool only (swarmnet/interest.py)."""
        return self.near_feed(f"pool-{pool}")

    @property
    def netem_set(self) -> str:
        """Runtime changes of the netem shim's configuration (see swarmnet/netem/control.py)."""
        return f"{self.prefix}/netem/set"

    @property
    def clock_step(self) -> str:
        """Lock-step time: the leader's steps of simulated time (see swarmnet/lockstep.py)."""
        return f"{self.prefix}/clock/step"

    def clock_done(self, pool: int | str) -> str:
        """Lock-step time: pool ``pool``'s answers to the leader's steps."""
        return f"{self.prefix}/clock/done/pool-{pool}"

    @property
    def clock_world_step(self) -> str:
        """Lock-step time: the leader's steps for the world service (after the pools' of the tick)."""
        return f"{self.prefix}/clock/step/world"

    @property
    def clock_done_world(self) -> str:
        """Lock-step time: the world service's answers."""
        return f"{self.prefix}/clock/done/world"

    @property
    def all_clock_done(self) -> str:
        return f"{self.prefix}/clock/done/*"

    @property
    def swarm_cmd(self) -> str:
        return f"{self.prefix}/cmd"

    # swarm messages sit under the sender's id, so access control can bind them to its certificate
    def broadcast(self, src: int | str, topic: str) -> str:
        return f"{self.prefix}/{src}/msg/{topic}"

    def unicast(self, src: int | str, dst: int | str, topic: str) -> str:
        return f"{self.prefix}/{src}/to/{dst}/{topic}"

    # wildcards for subscribers
    @property
    def all_poses(self) -> str:
        return f"{self.prefix}/*/pose"

    @property
    def all_telemetry(self) -> str:
        return f"{self.prefix}/*/telemetry"

    @property
    def all_states(self) -> str:
        return f"{self.prefix}/*/state"

    @property
    def all_acks(self) -> str:
        return f"{self.prefix}/*/ack"

    @property
    def all_alive(self) -> str:
        return f"{self.prefix}/alive/**"

    @property
    def all_broadcast(self) -> str:
        return f"{self.prefix}/*/msg/**"

    def all_unicast(self, uav: int | str) -> str:
        """Every unicast message to ``uav``, from any sender."""
        return f"{self.prefix}/*/to/{uav}/**"

    def all_senses(self, uav: int | str) -> str:
        """Every virtual sensor reading for ``uav`` (what that UAV subscribes to, and nobody else)."""
        return f"{self.prefix}/{uav}/sense/*"

    @property
    def all_acts(self) -> str:
        """Every actuator request of the swarm (what the world service subscribes to)."""
        return f"{self.prefix}/*/act/*"

    @property
    def traffic(self) -> str:
        """This swarm's airspace feed (see :func:`traffic_key`)."""
        return traffic_key(self.swarm)


def uav_from_key(key: str) -> int | None:
    """The UAV id in ``mrs/<swarm>/<uav>/...`` or None if that segment is not a UAV id."""
    parts = key.split("/", 3)
    if len(parts) < 3 or parts[0] != ROOT:
        return None
    seg = parts[2]
    if seg.isdigit() and len(seg) <= 5:
        uav = int(seg)
        if 1 <= uav <= 65535:
            return uav
    return None


def message_route(key: str) -> tuple[int, int] | None:
    """``(src, dst)`` of a swarm message's key: ``mrs/<swarm>/<src>/msg/<topic>`` -> (src, 0),
    ``mrs/<swarm>/<src>/to/<dst>/<topic>`` -> (src, dst); None for any other key."""
    parts = key.split("/", 5)
    src = uav_from_key(key)
    if src is None or len(parts) < 5:
        return None
    if parts[3] == "msg":
        return src, 0
    if parts[3] == "to" and len(parts) == 6:
        dst = uav_from_key(f"{ROOT}/_/{parts[4]}")
        if dst is not None:
            return src, dst
    return None


def swarm_from_key(key: str) -> str | None:
    parts = key.split("/", 2)
    if len(parts) < 2 or parts[0] != ROOT:
        return None
    return parts[1]
