"""The ``world`` section of ``summary.json`` (docs/world.md): what the world service and the UAVs recorded about it.

Units are in the names as everywhere in summary.json: ``_m`` metres, ``_m2`` square metres,
``_s`` seconds from the mission start, ``_ms`` milliseconds, ``_l`` litres. A part that does
not apply (no fire, no plume, one swarm) is left out.
"""

from __future__ import annotations

from msgspec import UNSET, Struct, UnsetType


class SensorDelivery(Struct):
    """One sensor over every UAV: readings received, their rate and their delay (arrival in the UAV's process minus
    the instant described: the configured latency, the world's tick, the transport), then the wait for the UAV's
    next control tick."""

    type: str
    received: int
    rate_hz_median: float | None  # median over the UAVs
    delay_ms_p50: float | None
    delay_ms_p99: float | None
    latency_s: float  # what the sensor's configuration asks for
    wait_ms_p50: float | None = None  # arrival to the control tick that took the reading in (None: a run before it was kept)
    wait_ms_p99: float | None = None
    world_tick_ms: float | None = None  # the world service's tick (world.tick_hz): a reading is released up to one late


class PlumeReport(Struct):
    """Source localisation: the UAVs' estimates (``plume/estimate``) against the true source."""

    source: list[float]  # x, y, m
    estimates: int  # estimates recorded
    uavs_estimating: int
    first_estimate_s: float | None
    error_final_m: float | None  # median over the UAVs' latest estimates at the end
    error_best_final_m: float | None  # the best UAV's at the end
    below_5m_at_s: float | None  # first time the median error was under 5 m
    error_curve: list[tuple[float, float | None, float | None]]  # (s, median m, best m), once a second


class FireReport(Struct):
    """The fire: how much burnt, how fast it was put out, what was sprayed."""

    burnt_area_m2: float  # cells that caught fire (burning, burnt out or extinguished)
    cells_ignited: int
    cells_extinguished: int
    cells_burning_at_end: int
    extinguished_at_s: float | None  # when the last burning cell went out (None: it never did)
    sprayed_l: float
    actuations: int
    area_curve: list[tuple[float, float, int]]  # (s, burnt area m^2, cells burning), once a second


class ZoneReport(Struct):
    """No-fly zones and obstacles against the UAVs' own positions (10 Hz, airborne only)."""

    zones: int
    entries: int  # samples of an airborne UAV inside a zone, at a height the zone spans
    uavs_entering: list[int]
    min_clearance_m: float | None  # closest an airborne UAV came to a zone's edge from outside


class AirspaceReport(Struct):
    """Swarms sharing the airspace: separation between UAVs of different swarms, and data isolation."""

    swarms: dict[str, list[int]]  # swarm -> UAV ids
    feed: bool  # the world service published the airspace feed
    min_separation_m: float | None  # between UAVs of different swarms, airborne
    conflicts: int  # onsets of a cross-swarm pair closer than the safety distance
    collisions: int  # onsets of a cross-swarm pair closer than the collision distance
    cross_swarm_samples: int  # poses a UAV received from a UAV of another swarm (must be 0)
    traffic_messages: int  # airspace feed messages the UAVs received


class WorldService(Struct):
    cpu_percent: float | None  # of one core, over the service's life
    uavs_tracked: int
    readings: dict[str, int]  # computed, per sensor type
    rejected: dict[str, int]  # what the service refused, per reason


class WorldSummary(Struct):
    service: WorldService | None  # None: the service wrote nothing
    sensors: dict[str, SensorDelivery]
    plume: PlumeReport | UnsetType = UNSET
    fire: FireReport | UnsetType = UNSET
    zones: ZoneReport | UnsetType = UNSET
    airspace: AirspaceReport | UnsetType = UNSET
