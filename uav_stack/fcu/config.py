"""Constructor settings of a virtual FCU fleet: built in code from an already validated UAV configuration
(`uav_stack.config.VirtualUavConfig`) or from `mrswarm fcu` flags; never read from a file, so no schema here."""

from __future__ import annotations

from dataclasses import dataclass, field

from uav_stack.fcu.dynamics import MultirotorParams
from uav_stack.geo import GeoPoint

# Default telemetry rates (Hz, sim time) per message name; SET_MESSAGE_INTERVAL changes
# them per vehicle (0 Hz = off). Names are MAVLink message names, except that
# NAMED_VALUE_FLOAT is the "RTF" value. The agent needs GLOBAL_POSITION_INT at 10 Hz; the
# rest is for ground stations, at about PX4's rates for a GCS link (LOCAL_POSITION_NED 1 Hz,
# GLOBAL_POSITION_INT 5 Hz there), since every message costs CPU in every UAV process.
DEFAULT_STREAM_RATES: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "GLOBAL_POSITION_INT": 10.0,
    "LOCAL_POSITION_NED": 2.0,
    "ATTITUDE": 5.0,
    "SYS_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 1.0,
    "HOME_POSITION": 0.5,
    "BATTERY_STATUS": 0.5,
    "GPS_RAW_INT": 1.0,
    "VFR_HUD": 2.0,
    "SYSTEM_TIME": 1.0,
    "NAMED_VALUE_FLOAT": 1.0,
    "ATTITUDE_QUATERNION": 0.0,
}


@dataclass
class VehicleConfig:
    sysid: int = 1
    home: GeoPoint = field(default_factory=lambda: GeoPoint(47.397742, 8.545594, 488.0))
    flavour: str = "px4"  # "px4" | "ardupilot"
    listen: tuple[str, int] = ("127.0.0.1", 0)  # this vehicle's UDP MAVLink endpoint
    remotes: tuple[tuple[str, int], ...] = ()  # static peers to stream to (PX4 SITL style)
    yaw: float = 0.0  # initial heading, rad
    params: dict[str, float] = field(default_factory=dict)  # parameter overrides by name
    owner: tuple[str, int] | None = None  # the companion's address: never churned out; None: the first peer heard
    owner_only: bool = False  # answer the owner only (a virtual UAV: ground stations use the agent's router)

    def __post_init__(self) -> None:
        if not 1 <= int(self.sysid) <= 255:
            raise ValueError(f"sysid must be 1..255, got {self.sysid}")


@dataclass
class FcuConfig:
    vehicles: list[VehicleConfig]
    physics_hz: float = 50.0
    target_rtf: float = 1.0  # < 1 runs slower than real time
    max_catchup_s: float = 0.1  # wall lag beyond this is dropped (sim slows down instead of bursting)
    max_step_batch_s: float = 0.1  # physics steps between two wake-ups at most (0 = wake every step)
    coalesce_datagrams: bool = True  # several MAVLink messages per UDP datagram (as PX4 does)
    dynamics: MultirotorParams = field(default_factory=MultirotorParams)
    stream_rates: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_STREAM_RATES))
    max_peers: int = 8  # learned UDP peers per vehicle (like mavlink-router server endpoints)
    peer_timeout_s: float = 30.0  # wall seconds of silence before a learned peer is dropped

    def __post_init__(self) -> None:
        if not self.vehicles:
            raise ValueError("FcuConfig needs at least one vehicle")
        sysids = [v.sysid for v in self.vehicles]
        if len(set(sysids)) != len(sysids):
            raise ValueError(f"duplicate sysids in one FCU: {sysids}")
        unknown = set(self.stream_rates) - set(DEFAULT_STREAM_RATES)
        if unknown:
            raise ValueError(f"unknown stream names {sorted(unknown)}; known: {sorted(DEFAULT_STREAM_RATES)}")
