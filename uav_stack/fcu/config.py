"""Constructor settings of a virtual FCU fleet: built in code from an already validated UAV configuration
(`uav_stack.config.VirtualUavConfig`) or from `mrswarm fcu` flags; never read from a file, so no schema here.
A bad value raises ValueError naming the field."""

from __future__ import annotations

from dataclasses import dataclass, field

from uav_stack.fcu.boot import check_profile
from uav_stack.fcu.dynamics import MultirotorParams
from uav_stack.fcu.streams import STREAM_NAMES
from uav_stack.geo import GeoPoint


@dataclass
class VehicleConfig:
    sysid: int = 1
    home: GeoPoint = field(default_factory=lambda: GeoPoint(47.397742, 8.545594, 488.0))
    flavour: str = "px4"  # "px4" | "ardupilot"
    listen: tuple[str, int] = ("127.0.0.1", 0)  # this vehicle's UDP MAVLink endpoint
    remotes: tuple[tuple[str, int], ...] = ()  # static peers to stream to (PX4 SITL style)
    yaw: float = 0.0  # initial heading, rad
    params: dict[str, float] = field(default_factory=dict)  # parameter overrides by name (as if saved before boot)
    owner: tuple[str, int] | None = None  # the companion's address: never churned out; None: the first peer heard
    owner_only: bool = False  # answer the owner only (a virtual UAV: ground stations use the agent's router)
    # the link is an in-process channel (inproc:<name>, uav_stack/inproc.py) instead of a UDP socket on
    # ``listen``: for a vehicle whose agent runs in the FCU's own process (a pool of virtual UAVs)
    inproc: bool = False
    # the boot's durations: "short" (ready to arm 1 s after launch) or "firmware" (the firmware's own times,
    # ArduCopter about 42 s); the sequence of states and messages is the firmware's either way (uav_stack/fcu/boot.py)
    boot: str = "short"

    def __post_init__(self) -> None:
        if not 1 <= int(self.sysid) <= 255:
            raise ValueError(f"sysid must be 1..255, got {self.sysid}")
        if self.flavour not in ("px4", "ardupilot"):
            raise ValueError(f"flavour: expected 'px4' or 'ardupilot', got {self.flavour!r}")
        check_profile(self.boot)


@dataclass
class FcuConfig:
    vehicles: list[VehicleConfig]
    physics_hz: float = 50.0
    target_rtf: float = 1.0  # < 1 runs slower than real time
    max_catchup_s: float = 0.1  # wall lag beyond this is dropped (sim slows down instead of bursting)
    max_step_batch_s: float = 0.1  # physics steps between two wake-ups at most (0 = wake every step)
    coalesce_datagrams: bool = True  # several MAVLink messages per UDP datagram (as PX4 does)
    dynamics: MultirotorParams = field(default_factory=MultirotorParams)
    # stream rates (Hz of sim time, 0 = off) by message name, over each flavour's own from boot
    # (uav_stack/fcu/streams.py): as if a companion had sent SET_MESSAGE_INTERVAL before anything else
    stream_rates: dict[str, float] = field(default_factory=dict)
    max_peers: int = 8  # learned UDP peers per vehicle (like mavlink-router server endpoints)
    peer_timeout_s: float = 30.0  # wall seconds of silence before a learned peer is dropped
    # s (wall, in [0, 1)) by which every vehicle's first heartbeat is later than its boot sends it. A real
    # autopilot boots at an arbitrary moment, so its 1 Hz heartbeat falls anywhere between two agent ticks;
    # a fleet opened on a tick (lock-step time) would otherwise beat exactly on the ticks' grid
    heartbeat_offset_s: float = 0.0

    def __post_init__(self) -> None:
        if not self.vehicles:
            raise ValueError("FcuConfig needs at least one vehicle")
        sysids = [v.sysid for v in self.vehicles]
        if len(set(sysids)) != len(sysids):
            raise ValueError(f"duplicate sysids in one FCU: {sysids}")
        unknown = set(self.stream_rates) - STREAM_NAMES
        if unknown:
            raise ValueError(f"stream_rates: unknown message names {sorted(unknown)}; known: {sorted(STREAM_NAMES)}")
        if not 0.0 <= self.heartbeat_offset_s < 1.0:
            raise ValueError(f"heartbeat_offset_s: must be in [0, 1) s, got {self.heartbeat_offset_s!r}")
        bad = {k: v for k, v in self.stream_rates.items() if not (isinstance(v, (int, float)) and v >= 0)}
        if bad:
            raise ValueError(f"stream_rates: rates must be >= 0 Hz, got {bad}")
