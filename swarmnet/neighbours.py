"""The neighbour table: latest pose of every other UAV, with age, rate and loss."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from swarmnet.messages import Pose

_SEQ_MOD = 1 << 16
_HALF = _SEQ_MOD // 2
_RATE_ALPHA = 0.2  # EWMA weight of the newest inter-arrival interval


@dataclass(slots=True)
class Neighbour:
    pose: Pose
    first_seen: float  # local wall time of the first pose
    last_recv: float  # local wall time the latest pose arrived (its arrival stamp)
    used: bool = False  # the latest pose was used by the controller (SwarmNode.take_neighbours)
    received: int = 1
    lost: int = 0  # poses missing from seq gaps
    duplicates: int = 0
    out_of_order: int = 0  # arrived after a newer one; not applied
    interval: float = 0.0  # EWMA of the interval between received poses (sender clock), s

    @property
    def uav(self) -> int:
        return self.pose.uav

    def age(self, now: float) -> float:
        """Age of the information: now minus the sender's sampling time (>= 0)."""
        a = now - self.pose.t_wall
        return a if a > 0.0 else 0.0

    def silence(self, now: float) -> float:
        """Time since the last pose arrived, on the local clock (immune to clock offsets)."""
        return now - self.last_recv

    @property
    def rate(self) -> float:
        return 1.0 / self.interval if self.interval > 0 else 0.0

    @property
    def loss(self) -> float:
        total = self.received + self.lost
        return self.lost / total if total else 0.0


class NeighbourTable:
    """Latest pose per UAV. ``stale_after`` hides silent neighbours, ``forget_after`` drops them."""

    def __init__(self, stale_after: float = 1.0, forget_after: float = 10.0):
        if not 0 < stale_after <= forget_after:
            raise ValueError("need 0 < stale_after <= forget_after")
        self.stale_after = stale_after
        self.forget_after = forget_after
        self._table: dict[int, Neighbour] = {}

    def update(self, pose: Pose, now: float) -> bool:
        """Apply a pose that arrived at ``now`` (local wall time); return False if it was a
        duplicate or older than what we have."""
        n = self._table.get(pose.uav)
        if n is None:
            self._table[pose.uav] = Neighbour(pose=pose, first_seen=now, last_recv=now)
            return True
        diff = (pose.seq - n.pose.seq) % _SEQ_MOD
        if diff == 0 and pose.t_wall == n.pose.t_wall:
            n.duplicates += 1
            return False
        if diff >= _HALF or diff == 0:
            # Behind us in sequence space. A restarted sender (seq back to 0) is told apart from
            # a late packet by its timestamp being clearly newer.
            if pose.t_wall <= n.pose.t_wall + 1.0:
                n.out_of_order += 1
                return False
            diff = 1
        n.lost += diff - 1
        n.received += 1
        # Rate from the sender's sampling times, so transport jitter does not enter it; lost
        # poses lengthen the interval, as they should.
        gap = pose.t_wall - n.pose.t_wall
        if gap > 0.0:
            n.interval = gap if n.interval == 0.0 else n.interval + _RATE_ALPHA * (gap - n.interval)
        n.pose = pose
        n.last_recv = now
        n.used = False
        return True

    def get(self, uav: int) -> Neighbour | None:
        return self._table.get(uav)

    def fresh(self, now: float) -> list[Neighbour]:
        """Neighbours heard from within ``stale_after``."""
        return [n for n in self._table.values() if now - n.last_recv <= self.stale_after]

    def expire(self, now: float) -> list[int]:
        """Forget neighbours silent for ``forget_after``; return their ids."""
        gone = [u for u, n in self._table.items() if now - n.last_recv > self.forget_after]
        for u in gone:
            del self._table[u]
        return gone

    def remove(self, uav: int) -> None:
        self._table.pop(uav, None)

    def snapshot(self) -> list[Neighbour]:
        """Every neighbour, in a list of its own (the table may change while it is used)."""
        return list(self._table.values())

    def around(self, x: float, y: float, radius: float) -> list[Neighbour]:
        """The neighbours whose latest pose is at most ``radius`` (m, horizontal) from (x, y)."""
        r2 = radius * radius
        return [n for n in self._table.values() if (n.pose.x - x) ** 2 + (n.pose.y - y) ** 2 <= r2]

    def __iter__(self) -> Iterator[Neighbour]:
        return iter(self.snapshot())

    def __len__(self) -> int:
        return len(self._table)

    def __contains__(self, uav: object) -> bool:
        return uav in self._table


def neighbour_counters(neighbours: Iterable[Neighbour]) -> dict[str, dict[str, float]]:
    """Each neighbour's pose counters by UAV id, as a counters file lists them (``neighbours``)."""
    return {str(n.uav): {"received": n.received, "lost": n.lost, "duplicates": n.duplicates, "out_of_order": n.out_of_order,
                         "rate": round(n.rate, 2)}
            for n in neighbours}
