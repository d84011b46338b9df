"""MAVLink system ids for swarms of any size (no imports: the UAV process and the CLI share it).

A MAVLink network has 8-bit system ids, and ground stations take some of them (MAVSDK 245,
QGroundControl and MAVProxy 255). So UAVs are split into *shards* of 240: shard
``k = (uav - 1) // 240`` is its own MAVLink network, reached on its own ground-station port
(``base_port + k``), and inside it the UAV's sysid is ``(uav - 1) % 240 + 1``. Ids stay
unique within every network, and 241..255 are left to ground stations.

    UAV 1..240     -> shard 0, sysid 1..240   (GCS port 14550)
    UAV 241..480   -> shard 1, sysid 1..240   (GCS port 14551)
    UAV 1000       -> shard 4, sysid 40       (GCS port 14554)
"""

from __future__ import annotations

SHARD_SIZE = 240


def allocate_sysid(uav: int, shard_size: int = SHARD_SIZE) -> tuple[int, int]:
    """(shard, sysid) of a UAV id (1..65535)."""
    if isinstance(uav, bool) or not isinstance(uav, int) or not 1 <= uav <= 65535:
        raise ValueError(f"UAV id must be an integer in 1..65535, got {uav!r}")
    if not 1 <= shard_size <= 250:
        raise ValueError(f"shard size must be in 1..250, got {shard_size}")
    shard, rest = divmod(uav - 1, shard_size)
    return shard, rest + 1


def uav_of(shard: int, sysid: int, shard_size: int = SHARD_SIZE) -> int:
    """The UAV id behind a (shard, sysid) pair: what a ground station shows, back to the swarm id."""
    if not 1 <= sysid <= shard_size or shard < 0:
        raise ValueError(f"sysid {sysid} is not a UAV sysid (1..{shard_size})")
    return shard * shard_size + sysid
