"""Spatial interest: full-rate poses only from the UAVs near each UAV, the rest slowly (docs/scale.md).

With the edge pose feed every UAV receives every other UAV's pose, 10 (N - 1) a second: its
download, its receive CPU and the edge's work per UAV grow with N. Collision avoidance needs
only the UAVs within a few tens of metres at full rate; the rest of the swarm matters for
membership (liveliness, not poses) and for a map, which a slow update serves.

The filter runs where every pose already passes, in the edge pose feed (:mod:`swarmnet.feed`):
the edge knows each UAV's latest position, so for each pose it takes in it knows exactly which
UAVs are within ``radius_m``. A pose leaves the edge

- on ``mrs/<swarm>/feed/near/<uav>`` (one batch per recipient) for every UAV within
  ``radius_m`` of its sender (horizontal distance), or, for the UAVs of a pool (one process, one
  Zenoh session: uav_stack/pool.py), on the pool's ``mrs/<swarm>/feed/near/pool-<n>``: one batch
  per pool holding every sender near any of its UAVs, each once (:class:`PoolMembers`), and
- on the swarm's shared feed ``mrs/<swarm>/feed/poses`` once every ``1 / far_rate_hz`` s per
  sender (and then to no UAV on its near key: every UAV gets it there), for all the others.

A pair that came within ``radius_m`` stays at full rate until it is farther than
``radius_m + margin_m`` (hysteresis: a pair flying along the border does not flap between the
two rates). Why at the edge and not with geographic cells in the key space: cells make Zenoh
filter, but the 3 x 3 block of cells of side ``>= radius_m`` around a UAV holds 2.6 - 3.3 times
as many UAVs as the disc of that radius, and every border crossing re-declares subscriptions
that travel to every peer of the mesh; the edge computes the exact disc from the positions it
already has (docs/scale.md compares the two).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from typing import Annotated

import numpy as np
from msgspec import Meta

from groundfloor.schema import Config, ConfigError, convert

FORGET_S = 2.0  # a UAV whose pose the edge has not heard this long is no recipient (it is not flying here)
UavId = Annotated[int, Meta(ge=1, le=65535)]
_POOL_RE = re.compile(r"^pool-([0-9]{1,5})=([0-9,\-]+)$")


class Interest(Config, frozen=True):
    """``network.interest``: which poses each UAV receives at full rate (docs/scale.md)."""

    radius_m: Annotated[float, Meta(gt=0.0, le=100_000.0,
                                    description="full-rate poses from UAVs within this horizontal distance, m")]
    margin_m: Annotated[float, Meta(ge=0.0, le=100_000.0,
                                    description="a neighbour stays at full rate until this much farther than radius_m, m")] = 5.0
    far_rate_hz: Annotated[float, Meta(ge=0.0, le=100.0,
                                       description="rate of every UAV's pose to the whole swarm (0: none), Hz")] = 1.0

    def __post_init__(self) -> None:
        if self.margin_m > self.radius_m:
            raise ConfigError("margin_m", f"must not exceed radius_m ({self.radius_m:g} m), got {self.margin_m:g}")

    def argv(self) -> list[str]:
        """The edge router's command-line options for this interest (discovery/rendezvous.py)."""
        return ["--interest-radius-m", repr(self.radius_m), "--interest-margin-m", repr(self.margin_m),
                "--interest-far-hz", repr(self.far_rate_hz)]


class PoolMembers(Config, frozen=True):
    """A pool of virtual UAVs as the edge feed sees it (``--pool pool-<n>=<ids>``): the UAVs whose
    near poses leave in one batch for the pool's one session, on ``mrs/<swarm>/feed/near/pool-<n>``."""

    number: Annotated[int, Meta(ge=1, le=65535, description="the pool's number: its session speaks as pool-<number>")]
    uavs: Annotated[tuple[UavId, ...], Meta(min_length=1, description="the UAV ids the pool hosts")]

    def __post_init__(self) -> None:
        if len(set(self.uavs)) != len(self.uavs):
            raise ConfigError("uavs", f"a UAV twice in pool-{self.number}: {sorted(self.uavs)}")

    @property
    def name(self) -> str:
        """``pool-<n>``: the pool's identity in its swarm, and the tail of its near feed key."""
        return f"pool-{self.number}"

    def arg(self) -> str:
        """The router's ``--pool`` value: ``pool-<n>=<ids>``, runs of consecutive ids as ``a-b``."""
        runs: list[str] = []
        ids = sorted(self.uavs)
        start = prev = ids[0]
        for u in [*ids[1:], None]:
            if u is not None and u == prev + 1:
                prev = u
                continue
            runs.append(str(start) if start == prev else f"{start}-{prev}")
            if u is not None:
                start = prev = u
        return f"{self.name}={','.join(runs)}"

    @classmethod
    def parse(cls, text: str) -> PoolMembers:
        """:meth:`arg`'s inverse (``pool-3=1-50,52``); :class:`~groundfloor.schema.ConfigError` says what is wrong."""
        m = _POOL_RE.match(text.strip())
        if m is None:
            raise ConfigError("", f"expected pool-<n>=<ids> (e.g. pool-1=1-50,52), got {text!r}")
        uavs: list[int] = []
        for part in m.group(2).split(","):
            lo, sep, hi = part.partition("-")
            if not lo.isdigit() or (sep and not hi.isdigit()):
                raise ConfigError("uavs", f"{part!r} in {text!r} is not a UAV id or a range a-b")
            a, b = int(lo), int(hi) if sep else int(lo)
            if not 1 <= a <= b <= 65535:
                raise ConfigError("uavs", f"{part!r} in {text!r}: ids are 1..65535, a range a-b has a <= b")
            uavs.extend(range(a, b + 1))
        return convert({"number": int(m.group(1)), "uavs": uavs}, cls)


def pool_groups(pools: Iterable[PoolMembers]) -> dict[int, str]:
    """UAV -> the pool whose near batch it is in (``pool-<n>``); ConfigError when a pool is named
    twice or a UAV is in two pools."""
    groups: dict[int, str] = {}
    named: set[int] = set()
    for p in pools:
        if p.number in named:
            raise ConfigError("pools", f"{p.name} given twice")
        named.add(p.number)
        for u in p.uavs:
            if u in groups:
                raise ConfigError("pools", f"UAV {u} in both {groups[u]} and {p.name}")
            groups[u] = p.name
    return groups


class NearFilter:
    """For one swarm: who receives each pose at full rate. Owned by one thread (the feed's worker).

    :meth:`seen` records each UAV's latest position; :meth:`split` takes the poses of one feed
    batch and returns the senders due on the shared (far) feed and, per destination, the senders
    to send it at full rate. A destination is a UAV id, or for the UAVs of ``groups`` (UAV ->
    ``pool-<n>``, :func:`pool_groups`) their pool's name: a sender near several UAVs of a pool is
    listed once for the pool, as the pool's one session decodes it once for all its UAVs.
    """

    def __init__(self, interest: Interest, groups: Mapping[int, str] | None = None):
        self.interest = interest
        self._far_period = 1.0 / interest.far_rate_hz if interest.far_rate_hz > 0.0 else float("inf")
        self._groups = dict(groups or {})
        self._dest: list[int | str] = []  # per recipient index: its near batch's destination (itself, or its pool)
        self._ids: list[int] = []  # recipients, in the order of the arrays below
        self._index: dict[int, int] = {}
        self._xy = np.zeros((0, 2))
        self._heard = np.zeros(0)  # when each UAV's latest pose arrived, s (the edge's clock)
        self._last_far: dict[int, float] = {}  # sender -> when its pose last went on the shared feed
        self._near: dict[int, set[int]] = {}  # sender -> indices of its recipients at full rate (hysteresis)

    def seen(self, uav: int, x: float, y: float, at: float) -> None:
        i = self._index.get(uav)
        if i is None:
            i = self._index[uav] = len(self._ids)
            self._ids.append(uav)
            self._dest.append(self._groups.get(uav, uav))
            self._xy = np.vstack([self._xy, (x, y)])
            self._heard = np.append(self._heard, at)
        else:
            self._xy[i] = (x, y)
            self._heard[i] = at

    def split(self, senders: list[int], now: float) -> tuple[list[int], dict[int | str, list[int]]]:
        """``(far, near)``: the senders due on the shared feed now, and destination (a UAV, or a
        pool's name) -> senders within reach of it (of any of the pool's UAVs), each once."""
        far: list[int] = []
        near: dict[int | str, list[int]] = {}
        if not self._ids:
            return list(senders), near
        live = self._heard >= now - FORGET_S
        r_in = self.interest.radius_m
        r_out = r_in + self.interest.margin_m
        dest = self._dest
        for s in senders:
            if now - self._last_far.get(s, -1e18) >= self._far_period:
                self._last_far[s] = now
                far.append(s)  # every UAV gets this one on the shared feed
                continue
            i = self._index.get(s)
            if i is None:
                continue
            d2 = ((self._xy - self._xy[i]) ** 2).sum(axis=1)
            inside = live & (d2 <= r_in * r_in)
            inside[i] = False  # not to itself
            now_near = set(np.flatnonzero(inside).tolist())
            before = self._near.get(s)
            if before:  # hysteresis: who was near stays near while within r_out
                now_near.update(j for j in before if live[j] and d2[j] <= r_out * r_out and j != i)
            self._near[s] = now_near
            for d in {dest[j] for j in now_near}:  # a pool once, however many of its UAVs are near
                near.setdefault(d, []).append(s)
        return far, near
