"""The airspace feed: each swarm learns where the other swarms' UAVs are, and nothing else.

Swarms sharing an airspace keep their data apart (their own keys, their own credentials), yet
must not collide. The edge sees every swarm's poses, so it publishes into each swarm's
``mrs/airspace/<swarm>/traffic`` the UAVs of all the *other* swarms as traffic reports, like
Remote ID broadcasts: a track number, latitude, longitude, altitude, velocity, and the time of
the fix. The track number is a keyed hash of swarm and UAV id with a key drawn per run, so a
report does not say which swarm or which UAV it is, only that it is the same one as before.
Positions go out geodetic, so swarms whose frames have different origins read them correctly;
each UAV converts them into its own frame (``uav_stack.sensors.TrafficTable``).
"""

from __future__ import annotations

import hashlib
import os

from swarmnet.messages import Traffic, TrafficReport
from uav_stack.geo import GeoPoint, LocalFrame
from world.model import UavKey
from world.sensing import Track


class TrafficFeed:
    """Builds the traffic message of each swarm from the tracks of every swarm."""

    def __init__(self, origins: dict[str, GeoPoint], key: bytes | None = None):
        self.frames = {s: LocalFrame(o) for s, o in origins.items()}
        self._key = key if key is not None else os.urandom(16)
        self._tracks: dict[UavKey, int] = {}
        self._seq = 0
        self.reports = 0  # traffic reports sent, all swarms

    def track_id(self, k: UavKey) -> int:
        t = self._tracks.get(k)
        if t is None:
            h = hashlib.blake2s(f"{k[0]}/{k[1]}".encode(), digest_size=4, key=self._key)
            t = self._tracks[k] = int.from_bytes(h.digest(), "big")
        return t

    def messages(self, now: float, tracks: dict[UavKey, Track]) -> dict[str, Traffic]:
        """For every swarm, the traffic of the others (fresh tracks only)."""
        by_swarm: dict[UavKey, TrafficReport] = {}
        for k, tr in tracks.items():
            frame = self.frames.get(k[0])
            if frame is None or not tr.fresh(now):
                continue
            p = tr.pose
            lat, lon, alt = frame.to_geodetic(p.x, p.y, p.z)
            by_swarm[k] = TrafficReport(self.track_id(k), p.t_wall, lat, lon, alt, p.vx, p.vy, p.vz)
        out = {}
        for swarm in self.frames:
            others = tuple(r for k, r in by_swarm.items() if k[0] != swarm)
            out[swarm] = Traffic(self._seq, now, others)
            self.reports += len(others)
        self._seq = (self._seq + 1) & 0xFFFFFFFF
        return out
